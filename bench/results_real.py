"""Learned odometry on the real KITTI slices: distance read and drift, with what each model saw.

For every model (the shipped KITTI NN_cons variants, plus any ``--model NAME=PATH`` candidates) and
its flow estimator, ``deepslam vo``'s computation runs on ``../shared/data/kitti/sequences/06``
(frames 0-50) and ``07`` (frames 0-159) and is scored against the ground truth with no alignment:
estimated / true path length and end-point drift in percent of the path (the issue's targets:
0.95-1.05 and <= 5 %), plus the se3-aligned ATE. Each row says which of the slice's frames the model
saw in training, from the model file's own record: ``none``, or ``single frames, no poses`` (the
paper's unsupervised adaptation). 07 is never trained on. Every model is scored with each pose mode of
``--pose`` (default both): ``net``, the network's 6DoF, and ``epipolar``, the rotation and direction of
travel from the essential matrix of the flow with the network's distance (``deepslam vo --pose epipolar
--scale network``: this table compares pose modes; the road scale is in ``bench.results_agreement``). Writes results.json and results.md into
``out/results/real`` (``python -m bench.results_real``, about 1 minute per model).
"""
from __future__ import annotations

import dataclasses
import os
import sys
from pathlib import Path

from deepslam.core import metrics
from deepslam.core.errors import InputError
from deepslam.core.paths import out_dir, shared_data_dir
from deepslam.core.readers import open_sequence
from deepslam.core.trajectory import Trajectory


SLICES = ("06", "07")
"""KITTI sequences with images in ../shared/data."""
FLOWS = ("dis", "learned", "learned-dis", "gt")
"""Flow estimators a ``--model NAME=PATH@FLOW`` candidate may read."""


@dataclasses.dataclass(frozen=True)
class Candidate:
    """A model to score: a display name, a path (or shipped spec) and the flow it reads."""

    name: str
    """Row label."""
    model: str
    """Model file, or a shipped spec such as ``kitti`` (see deepslam.vo.odometry.resolve_predictor)."""
    flow: str = "dis"
    """Flow estimator: one of :data:`FLOWS` (a name of :func:`deepslam.vo.flow_registry.make`)."""
    pose: str = "net"
    """``net`` (the network's 6DoF) or ``epipolar`` (rotation and direction from the essential matrix, distance
    from the network: ``deepslam vo --pose epipolar``)."""


SHIPPED = (Candidate("shipped kitti_cons_dis", "kitti", "dis"), Candidate("shipped kitti_cons_learned", "kitti", "learned"))


def seen_frames(meta: dict, seq_root: Path) -> str:
    """What a model's training saw of ``seq_root``: from its ``meta["data"]`` (frames / sequences lists)."""
    data = meta.get("data", {}) if isinstance(meta, dict) else {}
    seq_id = seq_root.resolve()
    for p in data.get("frames", []) or []:
        if Path(p).resolve() == seq_id:
            return "single frames, no poses"
    for p in (data.get("sequences") or {}):
        if Path(p).resolve() == seq_id:
            return "frame pairs WITH poses (supervised)"
    return "none"


def score(cand: Candidate, seq) -> dict:
    """``deepslam vo`` on the whole slice with ``cand`` (:func:`vo.pipeline.run_vo`, the distance from the
    network); the drift and ATE figures (core.metrics)."""
    from deepslam.vo.modelfiles import models, modeltree
    from deepslam.vo.pipeline import VOConfig, run_vo

    run = run_vo(seq, VOConfig(model=cand.model, flow=cand.flow, pose=cand.pose, scale="network", progress=False))
    meta = modeltree.meta(modeltree.read_header_tree(models.locate(cand.model, seq, flow=cand.flow)[0]))
    res = metrics.evaluate(seq.gt, Trajectory(run.world_from_cam, seq.timestamps_s), align="se3")
    return {"model": cand.name, "model_file": run.name, "flow": run.record["flow"], "pose": cand.pose,
            "slice": seq.name, "frames": len(seq),
            "seen_in_training": seen_frames(meta, Path(seq.root)), "gt_length_m": res["gt_length_m"],
            "path_length_ratio": res["path_length_ratio"], "endpoint_drift_pct": res["endpoint_drift_pct"],
            "ate_se3_m": res["ate_m"],
            "met": bool(0.95 <= res["path_length_ratio"] <= 1.05 and res["endpoint_drift_pct"] <= 5.0)}


def run(candidates: tuple[Candidate, ...], out: Path, data_dir: Path) -> dict:
    from bench.results_common import write_report

    rows = []
    for sl in SLICES:
        root = data_dir / "kitti" / "sequences" / sl
        if not root.is_dir():
            raise InputError(root, "KITTI slice not found (../shared/data)")
        seq = open_sequence(root)
        for c in candidates:
            rows.append(score(c, seq))
            print(f"{c.name} ({c.pose}) on {sl}: path x{rows[-1]['path_length_ratio']:.3f}, "
                  f"drift {rows[-1]['endpoint_drift_pct']:.1f} %", flush=True)
    report = {"rows": rows, "targets": {"path_length_ratio": [0.95, 1.05], "endpoint_drift_pct_max": 5.0}}
    write_report(out, report, markdown)
    return report


def markdown(report: dict) -> str:
    lines = ["| model | flow | pose | slice | frames the model saw in training | path est/true | end-point drift | ATE (se3) | target met |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in report["rows"]:
        lines.append(f"| {r['model']} | {r['flow']} | {r.get('pose', 'net')} | KITTI {r['slice'].split('/')[-1]} ({r['frames']} frames, {r['gt_length_m']:.0f} m) | "
                     f"{r['seen_in_training']} | {r['path_length_ratio']:.3f} | {r['endpoint_drift_pct']:.1f} % | "
                     f"{r['ate_se3_m']:.2f} m | {'yes' if r['met'] else 'no'} |")
    lines += ["", "Distance: each model's own (`--scale network`), to compare the models; what `deepslam vo` does by "
              "default on these slices (the distance read from the road) is in the agreement table."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from bench.results_common import candidate_parser, parse_model_specs, run_locked

    os.environ.setdefault("MUJOCO_GL", "egl")
    ap = candidate_parser("results_real", __doc__, FLOWS)
    ap.add_argument("--pose", default="net,epipolar", help="comma-separated pose modes each model is scored with: "
                    "net (the network's 6DoF), epipolar (deepslam vo --pose epipolar); default both")
    args = ap.parse_args(argv)
    poses = [p for p in args.pose.split(",") if p]
    out = args.out or out_dir() / "results" / "real"

    def work() -> dict:
        from deepslam.vo.modelfiles.models import POSES

        if not poses or any(p not in POSES for p in poses):
            raise InputError(None, f"--pose {args.pose!r}: expected a comma-separated list of {', '.join(POSES)}")
        models = ([] if args.no_shipped else list(SHIPPED)) + \
            [Candidate(*c) for c in parse_model_specs(args.model, FLOWS)]
        cands = [dataclasses.replace(c, pose=p) for c in models for p in poses]
        return run(tuple(cands), out, args.data or shared_data_dir())

    return run_locked("results_real", out, work, markdown)


if __name__ == "__main__":
    sys.exit(main())
