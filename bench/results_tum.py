"""RGB-D odometry on the TUM fr3/teddy slice: the shipped learned models against two baselines.

Rows: (a) ``tum_cons`` (the default for TUM: simulated rooms only, never a frame of teddy; DIS flow of
rendered views, the solve pose head), (b) ``tum_cons_teddy`` (the paper's unsupervised adaptation: the
same rooms plus teddy's single frames, no poses; trained on DIS flow of rendered views with DIS's
textureless pixels left out, ``--dis-min-texture``; the solve pose head,
:mod:`vo.geometry.posesolve`, which also reads each frame's sensor depth), each as VO and as SLAM (with ``tum_loops``), each
on DIS set up as its model was trained (:func:`vo.modelfiles.models.flow_for_model`); baselines measured in the
same run: standing still (every pose the first), the classical plug-in ``pnp`` (SIFT + PnP-RANSAC
with the sensor depth) and the dense fit of DIS's flow with the sensor depth (the solve head with every
weight 1), by least squares and Cauchy-reweighted (:func:`vo.geometry.posesolve.solve_pose`). ATE after se3 and sim3 alignment (evo's definition), RPE per frame, on the
frames the ground truth covers. Targets: VO ATE <= 0.05 m, SLAM no worse than VO. Writes
results.json, results.md and trajectories.png into ``out/results/tum`` (``python -m bench.results_tum``,
about 2.5 minutes).
"""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

from bench.results_common import write_report
from deepslam.core import metrics, plots
from deepslam.core.readers import open_sequence
from deepslam.core.se3 import chain_euler6
from deepslam.core.trajectory import Trajectory

TEDDY = "tum/rgbd_dataset_freiburg3_teddy"


@dataclasses.dataclass(frozen=True)
class ResultsTumConfig:
    """What to run."""

    flow: str = "dis"
    """Flow estimator of the learned models (each set up as its model was trained: DIS's preset and texture threshold)."""
    end: int = 0
    """Use frames [0, end) (0 = all)."""


QUICK = ResultsTumConfig(end=40)
ROBUST_ITERATIONS = 6
"""Gauss-Newton steps of the Cauchy-reweighted dense baseline (the first unweighted, then five reweighted)."""


def _scored(seq, world_from_cam: np.ndarray, frames: np.ndarray) -> dict:
    gt, est = metrics.on_covered_frames(seq, world_from_cam, frames)
    se3_res = metrics.evaluate(gt, est, align="se3")
    sim3_res = metrics.evaluate(gt, est, align="sim3")
    return {"ate_se3_m": se3_res["ate_m"], "ate_sim3_m": sim3_res["ate_m"], "rpe_t_m": se3_res["rpe_t_m"],
            "rpe_r_deg": se3_res["rpe_r_deg"], "frames_scored": len(gt), "_positions": est.positions,
            "_gt_positions": gt.positions}


def run(cfg: ResultsTumConfig, out: Path, data: Path) -> dict:
    from deepslam.slam.pipeline import PipelineConfig, SlamParams, run_slam
    from deepslam.slam.plugins import load_odometry
    from deepslam.vo.geometry.posesolve import unit_weight_net
    from deepslam.vo.infer import VOPredictor
    from deepslam.vo.modelfiles import models
    from deepslam.vo.odometry import model_odometry

    seq = open_sequence(data / TEDDY)
    n = len(seq) if cfg.end <= 0 else min(cfg.end, len(seq))
    frames = np.arange(n)
    pairs = np.stack([frames[:-1], frames[1:]], axis=1)
    rows, tracks = [], {}

    def add(name: str, seen: str, world_from_cam: np.ndarray, kind: str) -> None:
        r = _scored(seq, world_from_cam, frames)
        tracks["ground truth"] = r.pop("_gt_positions")
        tracks[f"{name} ({kind})"] = r.pop("_positions")
        rows.append({"odometry": name, "kind": kind, "frames_seen_in_training": seen, **r})

    add("standing still", "-", np.repeat(np.eye(4)[None], n, 0), "baseline")
    pnp = load_odometry("pnp")
    add("pnp (SIFT + PnP with sensor depth)", "-", chain_euler6(pnp.predict(seq, pairs)[0]), "VO")
    sub = seq if n == len(seq) else _head(seq, n)
    loops_path = models.models_dir() / "tum_loops.safetensors"
    loops = model_odometry(loops_path, cfg.flow, pose="epipolar", scale="network")  # as deepslam slam runs NN_loops
    shipped = {}
    for name, seen in (("tum_cons", "none"), ("tum_cons_teddy", "single frames, no poses")):
        path = models.models_dir() / f"{name}.safetensors"
        cons, est = shipped[name] = VOPredictor.from_file(path), models.flow_for_model(cfg.flow, path)
        mean6, _ = cons.predict_pairs(seq, pairs, est, progress=False)
        label = f"{name} ({est.name})"
        add(label, seen, chain_euler6(mean6), "VO")
        res = run_slam(sub, cons.as_odometry(est, progress=False), loops, SlamParams(), PipelineConfig(),
                       show_progress=False)
        add(label, seen, res.slam.world_from_cam, "SLAM")
    # a classical dense baseline through the same path: the solve head untrained (every weight 1) is the
    # plain least-squares fit of the flow, set up as tum_cons_teddy's, with the sensor depth
    cons, est = shipped["tum_cons_teddy"]
    plain = VOPredictor(unit_weight_net(cons.model.cfg), name="least squares")
    add(f"dense flow + depth least squares ({est.name}; the solve head, every weight 1, untrained)", "-",
        chain_euler6(plain.predict_pairs(seq, pairs, est, progress=False)[0]), "VO")
    robust = VOPredictor(unit_weight_net(cons.model.cfg, robust="cauchy", iterations=ROBUST_ITERATIONS),
                         name="cauchy")
    add(f"dense flow + depth, Cauchy-reweighted ({est.name}; the solve head untrained, {ROBUST_ITERATIONS} steps)", "-",
        chain_euler6(robust.predict_pairs(seq, pairs, est, progress=False)[0]), "VO")
    report = {"config": dataclasses.asdict(cfg), "frames": int(n), "rows": rows,
              "targets": {"vo_ate_m": 0.05, "slam_no_worse_than_vo": True}}
    out.mkdir(parents=True, exist_ok=True)
    write_report(out, report, markdown)
    plots.plot_trajectories_topdown(out / "trajectories.png", tracks, title=f"TUM fr3/teddy, {n} frames")
    return report


def _head(seq, n: int):
    """The first n frames of a sequence (for --quick)."""
    import dataclasses as dc

    keep = seq.gt_frames[seq.gt_frames < n] if seq.gt_frames is not None else None
    gt = None
    if seq.gt is not None:
        k = len(keep) if keep is not None else n
        gt = Trajectory(seq.gt.world_from_cam[:k], seq.gt.timestamps_s[:k])
    return dc.replace(seq, timestamps_s=seq.timestamps_s[:n], image_paths=seq.image_paths[:n],
                      depth_paths=None if seq.depth_paths is None else seq.depth_paths[:n], gt=gt, gt_frames=keep)


def markdown(report: dict) -> str:
    lines = [f"TUM fr3/teddy, {report['frames']} frames (scored where the ground truth covers them); each learned model "
             "on the flow named beside it, as it was trained; targets: VO ATE <= 0.05 m, SLAM no worse than VO.", "",
             "| odometry | as | frames of teddy seen in training | ATE se3 m | ATE sim3 m | RPE m / deg per frame |",
             "|---|---|---|---|---|---|"]
    for r in report["rows"]:
        lines.append(f"| {r['odometry']} | {r['kind']} | {r['frames_seen_in_training']} | {r['ate_se3_m']:.3f} | "
                     f"{r['ate_sim3_m']:.3f} | {r['rpe_t_m']:.4f} / {r['rpe_r_deg']:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from bench.results_common import results_main

    return results_main("results_tum", __doc__, ResultsTumConfig(), QUICK, "tum", run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
