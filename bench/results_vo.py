"""``python -m bench.results_vo``: the paper's comparison of synthetic and supervised training.

NN_cons and NN_loops are trained (a) synthetically from single frames (depth + the Student-t motion
model fitted to KITTI 00-05, 07-10 -> flow on the fly; no pose of any training frame is used) and
(b) supervised (pairs of the same training renders, the simulator's exact flow, ground-truth
poses), with the same network, recipe and time budget, over several seeds. Then, per seed:

- held-out simulated street (another town, a loop closed): VO of NN_cons (dead reckoning; ATE, RPE,
  KITTI t_err / r_err), NN_loops on the ground-truth loop pairs (RMS translation / rotation error of
  the relative pose), and SLAM with both (ATE, t_err), each with the simulator's exact flow and with
  OpenCV DIS flow;
- the real KITTI 06 slice (frames 0-50, DIS flow): VO of NN_cons trained on simulation only and, for
  the synthetic mode, also trained with the slice's own single frames (depth from stereo: still no
  pose is used);

and writes ``results.json`` and ``results.md`` (mean +- std over seeds) under ``--out``. The headline
is the synthetic / supervised t_err ratio (the paper: 2.7 on KITTI, about 1 on EuRoC).

Every step is a ``deepslam`` subcommand or a cached evaluation; a step whose output exists is
skipped, so a killed run resumes where it stopped. A folder made with other settings (the config or
the motion model's bytes) is refused (``settings.json``), never reused. ``--quick``: one seed, tiny budgets (a smoke run).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

from bench.results_common import write_report
from deepslam.core import atomic, metrics, se3
from deepslam.core.metrics import relative_pose_errors
from deepslam.core.readers import open_sequence
from deepslam.core.se3 import chain_euler6
from deepslam.core.trajectory import Trajectory

MODES = ("synthetic", "supervised")


@dataclasses.dataclass(frozen=True)
class ResultsVOConfig:
    """Sizes of the comparison; the defaults take about 25 minutes on 2 cores."""

    width: int = 414
    """Rendered width in pixels (KITTI's 1241 / 3; KITTI's camera otherwise)."""
    train_seeds: tuple[int, ...] = (1, 2)
    """Towns (scene + trajectory seeds) of the training renders."""
    train_frames: int = 300
    """Frames per training render (the car closes its loop within 300: supervised NN_loops needs it)."""
    heldout_seed: int = 7
    """Town of the held-out test sequence."""
    heldout_frames: int = 300
    """Frames of the held-out sequence."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Training seeds (weights, data order, synthetic samples)."""
    samples_cons: int = 49152
    """Training budget of each NN_cons in samples seen (the same for both modes: synthetic epochs of
    ``samples_per_epoch``, supervised epochs over its pairs). A sample count, not minutes, so that
    the comparison does not depend on the machine's load and every model is bit-reproducible."""
    samples_loops: int = 32768
    """Training budget of each NN_loops in samples seen."""
    samples_per_epoch: int = 4096
    """Synthetic samples per epoch."""
    nll_epochs: int = 4
    """Epochs of the uncertainty stage."""
    net: str = "cpu"
    """Network preset (vo.net; the paper's layout narrowed to train on a CPU)."""
    motion: str = "kitti_s1.json"
    """Student-t motion model in ``models/motion/`` (KITTI 00-05, 07-10 at stride 1; 06 is the real test slice)."""
    loop_min_gap_frames: int = 50
    """Ground-truth loop pairs (NN_loops evaluation, supervised NN_loops): frames at least this far apart."""
    loop_max_distance_m: float = 3.0
    """... and camera centres at most this far apart."""
    loop_eval_pairs: int = 100
    """At most this many evaluation loop pairs (evenly spaced)."""


def _train(run_command, log, out: Path, mode: str, which: str, seed: int, cfg: ResultsVOConfig,
           train_dirs: list[str], extra_frames: list[str] = ()) -> Path:
    model = out / "model.safetensors"
    if model.is_file():
        return model
    budget = cfg.samples_cons if which == "cons" else cfg.samples_loops
    args = ["train", "--mode", mode, "--net", cfg.net, "--nll-epochs", str(cfg.nll_epochs), "--seed", str(seed),
            "--out", str(out), "--quiet"]
    if mode == "synthetic":
        from deepslam.vo.modelfiles.models import models_dir

        args += ["--source", *train_dirs, *extra_frames, "--motion",
                 str(models_dir() / "motion" / cfg.motion) + (":loops" if which == "loops" else ""), "--samples-per-epoch", str(cfg.samples_per_epoch),
                 "--max-epochs", str(max(1, round(budget / cfg.samples_per_epoch)))]
    else:
        n_train = _supervised_pairs(train_dirs, which) * 0.9  # the train CLI holds 10 % out
        args += ["--sequence", *train_dirs, "--flow", "gt", "--pairs", "consecutive" if which == "cons" else "loops",
                 "--max-epochs", str(max(1, round(budget / max(1.0, n_train))))]
    if (out / "checkpoint.safetensors").is_file():
        args.append("--resume")
    run_command(args, log)
    return model


def _supervised_pairs(train_dirs: list[str], which: str) -> int:
    """How many pairs ``deepslam train --mode supervised`` makes of the training renders (its defaults)."""
    from deepslam.vo.data.supervised import PairSpec, frame_pairs

    spec = PairSpec(kind="consecutive" if which == "cons" else "loops")
    return sum(len(frame_pairs(open_sequence(d).gt.world_from_cam, spec)) for d in train_dirs)


def _loop_pairs(seq, cfg: ResultsVOConfig) -> np.ndarray:
    from deepslam.vo.data.supervised import PairSpec, frame_pairs

    return frame_pairs(seq.gt.world_from_cam, PairSpec(kind="loops", loop_min_gap_frames=cfg.loop_min_gap_frames,
                                                       loop_max_distance_m=cfg.loop_max_distance_m,
                                                       max_pairs=cfg.loop_eval_pairs))


def pair_errors(seq, pairs: np.ndarray, mean6: np.ndarray) -> dict:
    """RMS translation error (m) and rotation error (deg) of predicted ``cam_j_from_cam_i`` against
    the ground truth, over the pairs."""
    gt = seq.gt.world_from_cam
    true = se3.relative(gt[pairs[:, 1]], gt[pairs[:, 0]])  # cam_j_from_cam_i
    err = relative_pose_errors(true, se3.from_euler6(mean6))
    return {"pairs": int(len(pairs)), "t_rmse_m": err["t_rmse_m"], "r_rmse_deg": err["r_rmse_deg"],
            "true_t_mean_m": float(np.linalg.norm(true[:, :3, 3], axis=1).mean())}


def metric_subset(ev: dict) -> dict:
    """The figures the results tables report, from a :func:`core.metrics.evaluate` record."""
    keys = ("ate_m", "rpe_t_m", "rpe_r_deg", "kitti_t_err_pct", "kitti_r_err_deg_per_100m")
    return {k: ev.get(k) for k in keys}


def evaluate_street(seq, cons: Path, loops: Path, flow: str, cfg: ResultsVOConfig) -> dict:
    """VO, loop-pair and SLAM figures of one (NN_cons, NN_loops) on the held-out street."""
    from deepslam.slam.pipeline import run_slam
    from deepslam.vo.infer import VOPredictor
    from deepslam.vo.modelfiles import models

    # each model on the flow its file records (DIS's defaults where it records none)
    est_cons, est_loops = models.flow_for_model(flow, cons), models.flow_for_model(flow, loops)
    p_cons, p_loops = VOPredictor.from_file(cons), VOPredictor.from_file(loops)
    res = run_slam(seq, p_cons.as_odometry(est_cons, progress=False), p_loops.as_odometry(est_loops, progress=False),
                   show_progress=False)
    pairs = _loop_pairs(seq, cfg)
    mean6, _ = p_loops.predict_pairs(seq, pairs, est_loops, progress=False)
    return {"vo": metric_subset(metrics.evaluate(seq.gt, res.vo)),
            "vo_epipolar": evaluate_vo(seq, cons, flow, pose="epipolar"),
            "slam": metric_subset(metrics.evaluate(seq.gt, res.slam)),
            "loops": pair_errors(seq, pairs, mean6), "loop_edges": int(len(res.loops))}


def evaluate_vo(seq, cons: Path, flow: str, pose: str = "net") -> dict:
    """VO (dead reckoning of NN_cons) on a sequence without loop closure; ``pose``: ``net`` (the network's
    6DoF) or ``epipolar`` (rotation and direction from the essential matrix of the flow, the network's
    distance: ``deepslam vo --pose epipolar``)."""
    from deepslam.slam.pipeline import consecutive_pairs
    from deepslam.vo.infer import VOPredictor
    from deepslam.vo.modelfiles import models

    p = VOPredictor.from_file(cons)
    mean6, _ = p.predict_pairs(seq, consecutive_pairs(len(seq)), models.flow_for_model(flow, cons), progress=False,
                               epipolar=models.epipolar_config(cons, pose))
    traj = Trajectory(seq.gt.world_from_cam[0] @ chain_euler6(mean6), seq.timestamps_s)
    return metric_subset(metrics.evaluate(seq.gt, traj))


def _cached(path: Path, fn) -> dict:
    if path.is_file():
        return json.loads(path.read_text())
    rec = fn()
    atomic.write_json(path, rec)
    return rec


def _agg(values: list) -> dict:
    v = np.array([x for x in values if x is not None], np.float64)
    if not len(v):
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0, "n": int(len(v))}


def _get(rec: dict, path: str):
    for k in path.split("."):
        rec = rec.get(k) if isinstance(rec, dict) else None
    return rec


ROWS = [  # (table row, record path)
    ("NN_cons VO ATE [m]", "vo.ate_m"),
    ("NN_cons VO RPE [m/frame]", "vo.rpe_t_m"),
    ("NN_cons VO RPE [deg/frame]", "vo.rpe_r_deg"),
    ("NN_cons VO t_err [%]", "vo.kitti_t_err_pct"),
    ("NN_cons VO r_err [deg/100 m]", "vo.kitti_r_err_deg_per_100m"),
    ("NN_cons VO ATE, epipolar pose [m]", "vo_epipolar.ate_m"),
    ("NN_cons VO t_err, epipolar pose [%]", "vo_epipolar.kitti_t_err_pct"),
    ("NN_cons VO r_err, epipolar pose [deg/100 m]", "vo_epipolar.kitti_r_err_deg_per_100m"),
    ("NN_loops loop pairs, t RMSE [m]", "loops.t_rmse_m"),
    ("NN_loops loop pairs, r RMSE [deg]", "loops.r_rmse_deg"),
    ("SLAM ATE [m]", "slam.ate_m"),
    ("SLAM t_err [%]", "slam.kitti_t_err_pct"),
]


def _pm(a: dict, f: str = ".3g") -> str:
    if a["mean"] is None:
        return "n/a"
    return f"{a['mean']:{f}} ± {a['std']:{f}}" if a["n"] > 1 else f"{a['mean']:{f}}"


def run(cfg: ResultsVOConfig, out: Path, data: Path) -> dict:
    from deepslam.studies.demo import render_once, run_command

    from bench.results_common import reuse_only_with_same_settings
    from deepslam.vo.modelfiles.models import models_dir

    motion = models_dir() / "motion" / cfg.motion
    reuse_only_with_same_settings(out, {"config": dataclasses.asdict(cfg), "motion_sha256": hashlib.sha256(
        motion.read_bytes()).hexdigest() if motion.is_file() else None})
    atomic.write_json(out / "config.json", dataclasses.asdict(cfg))
    log: list[str] = []
    t0 = time.perf_counter()
    train_dirs = [str(render_once("street", "car", cfg.train_frames, cfg.width, s, out / f"street_train_s{s}", log,
                                  ("--quiet",))) for s in cfg.train_seeds]
    held = render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                       out / f"street_heldout_s{cfg.heldout_seed}", log, ("--quiet",))
    k06 = data / "kitti" / "sequences" / "06"
    seq_held = open_sequence(held)
    seq_k06 = open_sequence(k06) if k06.is_dir() else None

    per_seed: dict = {m: [] for m in MODES}
    kitti_plus: list = []
    for seed in cfg.seeds:
        for mode in MODES:
            models = {which: _train(run_command, log, out / "models" / f"{mode}_{which}_s{seed}", mode, which, seed, cfg,
                                    train_dirs) for which in ("cons", "loops")}
            rec = {"seed": seed}
            for flow in ("gt", "dis"):
                print(f"evaluate {mode} seed {seed} on {held.name}, {flow} flow", flush=True)
                rec[f"street_{flow}"] = _cached(out / "eval" / f"{mode}_s{seed}_street_{flow}.json",
                                                lambda: evaluate_street(seq_held, models["cons"], models["loops"], flow, cfg))
            if seq_k06 is not None:
                rec["kitti06_dis"] = _cached(out / "eval" / f"{mode}_s{seed}_kitti06_dis.json",
                                             lambda: evaluate_vo(seq_k06, models["cons"], "dis"))
            per_seed[mode].append(rec)
        if seq_k06 is not None:  # synthetic, also with the real slice's single frames (depth from stereo)
            m = _train(run_command, log, out / "models" / f"synthetic_kitti_cons_s{seed}", "synthetic", "cons", seed, cfg,
                       train_dirs, [str(k06)])
            kitti_plus.append({"seed": seed, "kitti06_dis": _cached(out / "eval" / f"synthetic_kitti_s{seed}_kitti06_dis.json",
                                                                   lambda: evaluate_vo(seq_k06, m, "dis"))})
    report = summarize(cfg, per_seed, kitti_plus, seq_held)
    report["commands"] = log
    report["minutes"] = (time.perf_counter() - t0) / 60
    write_report(out, report, markdown)
    return report


def summarize(cfg: ResultsVOConfig, per_seed: dict, kitti_plus: list, seq_held) -> dict:
    table = []
    for flow in ("gt", "dis"):
        for name, path in ROWS:
            table.append({"data": f"street, {'exact' if flow == 'gt' else 'DIS'} flow", "measure": name,
                          **{m: _agg([_get(r[f"street_{flow}"], path) for r in per_seed[m]]) for m in MODES}})
    for name, path in (("NN_cons VO ATE [m]", "ate_m"), ("NN_cons VO RPE [m/frame]", "rpe_t_m"),
                       ("NN_cons VO RPE [deg/frame]", "rpe_r_deg")):
        if all("kitti06_dis" in r for m in MODES for r in per_seed[m]) and per_seed["synthetic"]:
            table.append({"data": "KITTI 06 slice, DIS flow", "measure": name,
                          **{m: _agg([r["kitti06_dis"][path] for r in per_seed[m]]) for m in MODES},
                          "synthetic + KITTI 06 frames": _agg([r["kitti06_dis"][path] for r in kitti_plus])})
    headline = {}
    for flow in ("gt", "dis"):
        for key, vo in ((flow, "vo"), (f"{flow}_epipolar", "vo_epipolar")):
            s = _agg([_get(r[f"street_{flow}"], f"{vo}.kitti_t_err_pct") for r in per_seed["synthetic"]])
            u = _agg([_get(r[f"street_{flow}"], f"{vo}.kitti_t_err_pct") for r in per_seed["supervised"]])
            headline[key] = None if not (s["mean"] and u["mean"]) else s["mean"] / u["mean"]
    return {"config": dataclasses.asdict(cfg), "heldout": {"name": seq_held.name, "frames": len(seq_held)},
            "table": table, "ratio_synthetic_over_supervised_t_err": headline, "per_seed": per_seed,
            "synthetic_with_kitti06_frames": kitti_plus}


def markdown(report: dict) -> str:
    cfg = report["config"]
    h = report["ratio_synthetic_over_supervised_t_err"]

    def r(x):
        return "n/a" if x is None else f"{x:.2f}"

    md = ["# Synthetic (single frames) vs supervised training of NN_cons / NN_loops", "",
          f"Held-out simulated street `{report['heldout']['name']}` ({report['heldout']['frames']} frames); "
          f"training renders: towns {cfg['train_seeds']} ({cfg['train_frames']} frames each, {cfg['width']} px wide); "
          f"seeds {list(cfg['seeds'])} (mean ± std); network preset `{cfg['net']}`; budget {cfg['samples_cons']} samples "
          f"(NN_cons) and {cfg['samples_loops']} (NN_loops) per model in both modes. Synthetic: single frames + "
          f"`{cfg['motion']}` (no pose of any training frame). Supervised: consecutive (NN_cons) or loop (NN_loops) "
          "pairs of the same renders with the simulator's exact flow and ground-truth poses. Metrics se3-aligned.", "",
          f"**Synthetic / supervised t_err: {r(h.get('gt'))} with exact flow, {r(h.get('dis'))} with DIS flow** "
          "(the paper: 2.7 on KITTI, about 1 on EuRoC); with the epipolar pose (rotation and direction from the "
          f"flow's essential matrix, each network's distance): {r(h.get('gt_epipolar'))} with exact flow, "
          f"{r(h.get('dis_epipolar'))} with DIS flow.", "",
          "| data | measure | synthetic | supervised | synthetic + KITTI 06 frames |", "|---|---|---|---|---|"]
    for row in report["table"]:
        extra = row.get("synthetic + KITTI 06 frames")
        md.append(f"| {row['data']} | {row['measure']} | {_pm(row['synthetic'])} | {_pm(row['supervised'])} | "
                  f"{_pm(extra) if extra else ''} |")
    md += ["", f"Run time: {report.get('minutes', 0):.1f} min.", "", "## Commands", "", "```"] + report.get("commands", []) + ["```"]
    return "\n".join(md) + "\n"


def main(argv: list[str] | None = None) -> int:
    from bench.results_common import results_main

    quick = dataclasses.replace(ResultsVOConfig(), width=207, train_frames=300, seeds=(0,), samples_cons=512,
                                samples_loops=512, samples_per_epoch=256, nll_epochs=1, loop_eval_pairs=20)
    return results_main("results_vo", __doc__, ResultsVOConfig(), quick, "vo",
                        lambda cfg, out, data: run(cfg, out, data), markdown, argv)

if __name__ == "__main__":
    sys.exit(main())
