"""Does a KITTI model read a turning camera's sideways slide as more yaw, or a straight street's layout as a turn?

A car's camera that turns also slides sideways (KITTI 00-05, 08-10: t_x = 0.88 x yaw x forward metres,
:data:`deepslam.studies.scale_sweep.SLIDE_PER_YAW_PER_M`). Single frames of a held-out simulated street
(seed 7, never trained on) and of the real KITTI 06 slice (stereo depth; its single frames were in the
shipped models' training, without poses) are turned by +-0.04 rad at 0.5 and 1.0 m forward, without and
with that slide, and driven straight 1 m a frame as they are and mirrored left-right, by single-frame
synthesis; each model reads the flow it was made for (DIS or the learned
estimator on a second view rendered from the frame). ``yaw_gain`` is how much the slide raises the yaw
read (0 for a model that reads the flow), ``slide_read_fraction`` how much of the slide t_x reads
(1 = all), the straight drive's yaw read how much of a turn the model sees in the scene's left-right layout
(0 for a model that reads the flow; a mirrored street has its near kerb on the other hand). No frame of
KITTI 07 is used. Writes results.json and results.md into ``out/results/turn``
(``python -m bench.results_turn [--model NAME=PATH[@FLOW]] [--no-shipped]``, about 2 minutes a model).
"""
from __future__ import annotations

import dataclasses
import os
import sys
from pathlib import Path

from deepslam.core.errors import InputError
from deepslam.core.paths import out_dir, shared_data_dir
from deepslam.core.readers import open_sequence

SAMPLES = 48
"""Frames per turn."""
HELDOUT = ("street", "car", 60, 414, 7)
"""The held-out street: scene, trajectory, frames, width, seed (as bench.results_speed)."""
STRAIGHT_M = 1.0
"""Forward metres a frame of the straight drive whose yaw read is reported (true yaw 0)."""


def _reads(name: str, model: str, flow: str, frames) -> dict:
    from deepslam.studies import scale_sweep
    from deepslam.vo.data.frames import with_mirrored
    from deepslam.vo.data.synthetic import EstimatedFlowSource
    from deepslam.vo.modelfiles import models
    from deepslam.vo.odometry import load_predictor

    path, shipped = models.locate(model, None, flow=flow)
    pred = load_predictor(path, shipped)
    h, w = pred.input_size
    options = {"preset": "medium", **models.recorded_flow_options(path, "dis")} if flow == "dis" else {}

    def maker(fr):
        def make(sample):
            return EstimatedFlowSource(fr, sample, flow, w, h, SAMPLES, estimator_options=options,
                                       unknown=pred.model.cfg.unknown_flow)
        return make

    reads = scale_sweep.turn_reads(pred, maker(frames), SAMPLES)
    straight = {"as is": scale_sweep.straight_yaw_read(pred, maker(frames), SAMPLES, STRAIGHT_M),
                "mirrored": scale_sweep.straight_yaw_read(pred, maker(with_mirrored(frames, False)), SAMPLES,
                                                          STRAIGHT_M)}
    return {"model": name, "model_file": pred.name, "flow": flow, "reads": [dataclasses.asdict(r) for r in reads],
            **scale_sweep.slide_effect(reads), "straight_yaw": straight}


def run(candidates: list[tuple[str, str, str]], out: Path, data_dir: Path) -> dict:
    from bench.results_common import write_report
    from deepslam.studies import scale_sweep
    from deepslam.studies.demo import render_once
    from deepslam.vo.data.frames import load_image_frames

    out.mkdir(parents=True, exist_ok=True)
    scene, traj, n, width, seed = HELDOUT
    held = render_once(scene, traj, n, width, seed, out / f"street_heldout_s{seed}", [])
    k06 = data_dir / "kitti" / "sequences" / "06"
    if not (k06 / "calib.txt").is_file():
        raise InputError(k06, "KITTI 06 slice not found (../shared/data)")
    sets = {"simulated street s7 (never trained on)": (open_sequence(held), "rendered"),
            "KITTI 06 (single frames seen in training, no poses)": (open_sequence(k06), "stereo")}
    rows = []
    for set_name, (seq, kind) in sets.items():
        frames = load_image_frames([seq], depth=kind, progress=False)
        for name, model, flow in candidates:
            r = _reads(name, model, flow, frames)
            rows.append({"frames": set_name, **r})
            print(f"{name} on {set_name}: yaw gain {r['yaw_gain']:+.3f}, slide read {r['slide_read_fraction']:.2f}",
                  flush=True)
    report = {"rows": rows, "slide_per_yaw_per_m": scale_sweep.SLIDE_PER_YAW_PER_M}
    write_report(out, report, markdown)
    return report


def markdown(report: dict) -> str:
    lines = ["| frames | model (flow) | yaw read/true, no slide (range) | yaw gain from the slide | slide read by t_x | "
             "yaw read driving straight, mrad a frame: as is / mirrored |",
             "|---|---|---|---|---|---|"]
    for r in report["rows"]:
        plain = [x["yaw_ratio_median"] for x in r["reads"] if x["slide_m"] == 0]
        lines.append(f"| {r['frames']} | {r['model']} ({r['flow']}) | {min(plain):.3f}-{max(plain):.3f} | "
                     f"{r['yaw_gain']:+.3f} | {r['slide_read_fraction']:.2f} | "
                     f"{1e3 * r['straight_yaw']['as is']['yaw_median_rad']:+.2f} / "
                     f"{1e3 * r['straight_yaw']['mirrored']['yaw_median_rad']:+.2f} |")
    return ("Turns of +-0.04 rad at 0.5 and 1.0 m forward, without and with KITTI's sideways slide (median over "
            f"{SAMPLES} frames; yaw gain 0 and slide read 1 = the flow read as it is)\n\n" + "\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
    from bench.results_common import candidate_parser, parse_model_specs, run_locked

    args = candidate_parser("results_turn", __doc__, ("dis", "learned")).parse_args(argv)
    shipped = [] if args.no_shipped else [("shipped kitti_cons_dis", "kitti", "dis"),
                                          ("shipped kitti_cons_learned", "kitti", "learned")]
    out = args.out or out_dir() / "results" / "turn"

    def work() -> dict:
        cands = shipped + parse_model_specs(args.model, ("dis", "learned"))
        return run(cands, out, args.data or shared_data_dir())

    return run_locked("results_turn", out, work, markdown)


if __name__ == "__main__":
    sys.exit(main())
