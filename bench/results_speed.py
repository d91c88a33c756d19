"""Scale from flow or from a prior? The shipped KITTI models' forward read against the true speed.

A held-out simulated street (a town no shipped model was trained on; seed 7, as in results_vo) and
the real KITTI 06 slice (depth from stereo; its single frames WERE in the shipped models' training,
without poses) are driven straight forward at 0-30 m/s (10 Hz) by single-frame synthesis; each
model reads the flow it was made for: ``kitti_cons`` the exact synthetic flow, ``kitti_cons_dis``
DIS on a second view rendered from the frame. read/true = 1 at every speed is a model that reads
metric motion from flow; a slope is a learned speed prior. Beside each read: its spread from frame to
frame and the model's own predicted std (a model whose std does not follow the spread does not know
where its read is uncertain). Candidates beside the shipped models:
``--model NAME=PATH[@FLOW]`` (FLOW: exact, dis, learned or learned-dis; a DIS model's recorded DIS
options are used). Writes results.json, results.md and speed_sweep.png into ``out/results/speed``
(``python -m bench.results_speed [--model NAME=PATH[@FLOW]] [--no-shipped]``, about 1 minute a model).
"""
from __future__ import annotations

import dataclasses
import os
import sys
from pathlib import Path

from deepslam.core.paths import out_dir, shared_data_dir
from deepslam.core.plots import new_figure, save_figure
from deepslam.core.readers import open_sequence



@dataclasses.dataclass(frozen=True)
class ResultsSpeedConfig:
    """Sizes of the sweep."""

    width: int = 414
    """Rendered width of the held-out street, pixels."""
    heldout_seed: int = 7
    """Town of the held-out street (no shipped model saw it)."""
    heldout_frames: int = 60
    """Frames rendered; the sweep draws from them."""
    samples: int = 48
    """Frames per speed."""
    rate_hz: float = 10.0
    """Frame rate: speed / rate = metres per frame (KITTI: 10 Hz)."""
    seed: int = 0
    """Which frames are drawn."""


QUICK = ResultsSpeedConfig(heldout_frames=12, samples=8)


FLOWS = ("exact", "dis", "learned", "learned-dis")
"""Flows a candidate may read: the exact synthetic flow, or an estimator run on the rendered second view."""
SHIPPED = (("shipped kitti_cons", "kitti", "exact"), ("shipped kitti_cons_dis", "kitti", "dis"))
"""The shipped KITTI models swept by default: (row name, model, flow)."""


def _sweep(name: str, model: str, flow: str, seq, kind: str, cfg: ResultsSpeedConfig, loaded: dict) -> dict:
    """One model's sweep on one sequence's frames (``kind``: ``rendered`` or ``stereo`` depth). ``loaded``
    keeps that sequence's frames for the next candidate (stereo depth of 06 is seconds a load): the images at
    their size for every estimator, the depth at twice a model's input size for the exact flow."""
    from deepslam.studies import scale_sweep
    from deepslam.vo.data.frames import load_frames, load_image_frames
    from deepslam.vo.data.synthetic import EstimatedFlowSource, SyntheticSource
    from deepslam.vo.modelfiles import models
    from deepslam.vo.odometry import load_predictor

    path, shipped = models.locate(model, None, flow=None if flow == "exact" else flow)
    pred = load_predictor(path, shipped)
    h, w = pred.input_size
    unknown = pred.model.cfg.unknown_flow

    def frames_of(key, load):
        if key not in loaded:
            loaded[key] = load()
        return loaded[key]

    if flow == "exact":
        frames = frames_of((2 * w, 2 * h), lambda: load_frames([seq], 2 * w, 2 * h, depth=kind, progress=False))

        def make(sample, frames=frames, unknown=unknown):
            return SyntheticSource(frames, sample, cfg.samples, synth_factor=2, unknown=unknown)
    else:
        frames = frames_of("images", lambda: load_image_frames([seq], depth=kind, progress=False))
        # DIS set up as the model's file records it (medium on every pixel for today's file)
        options = {"preset": "medium", **models.recorded_flow_options(path, "dis")} if flow == "dis" else {}

        def make(sample, frames=frames, h=h, w=w, unknown=unknown, options=options):
            return EstimatedFlowSource(frames, sample, flow, w, h, cfg.samples, estimator_options=options,
                                       unknown=unknown)
    reads = scale_sweep.speed_sweep(pred, make, cfg.samples, cfg.rate_hz, seed=cfg.seed)
    return {"name": name, "model": pred.name, "flow": flow, "reads": [dataclasses.asdict(r) for r in reads],
            "flatness": scale_sweep.flatness(reads, min_speed_mps=2.5)}


def run(cfg: ResultsSpeedConfig, out: Path, data_dir: Path,
        candidates: tuple[tuple[str, str, str], ...] = SHIPPED) -> dict:
    """Sweep each candidate (row name, model file or shipped spec, flow in :data:`FLOWS`) on the held-out
    street and on KITTI 06's frames; results.json, results.md and speed_sweep.png into ``out``."""
    from bench.results_common import write_report
    from deepslam.studies.demo import render_once

    out.mkdir(parents=True, exist_ok=True)
    log: list[str] = []
    held = render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                       out / f"street_heldout_s{cfg.heldout_seed}", log)
    report = {"config": dataclasses.asdict(cfg), "sets": {}}
    sets = {"simulated street, held out (seed 7; never trained on)": (open_sequence(held), "rendered")}
    k06 = data_dir / "kitti" / "sequences" / "06"
    if (k06 / "calib.txt").is_file():
        sets["KITTI 06 slice (stereo depth; its single frames were in training, no poses)"] = (open_sequence(k06),
                                                                                              "stereo")
    for set_name, (seq, kind) in sets.items():
        rows = report["sets"][set_name] = {}
        loaded: dict = {}
        for name, model, flow in candidates:
            rows[name] = r = _sweep(name, model, flow, seq, kind, cfg, loaded)
            print(f"{name} on {set_name.split(' (')[0]}: read/true {r['flatness']['ratio_min']:.3f}-"
                  f"{r['flatness']['ratio_max']:.3f} over 2.5-30 m/s", flush=True)
    write_report(out, report, markdown)
    _plot(report, out / "speed_sweep.png")
    return report


def _plot(report: dict, path: Path) -> None:
    fig = new_figure((7, 4))
    ax = fig.subplots()
    for name, sweeps in report["sets"].items():
        for s in sweeps.values():
            rs = [r for r in s["reads"] if r["ratio_median"] is not None]
            ax.plot([r["speed_mps"] for r in rs], [r["ratio_median"] for r in rs], marker="o",
                    label=f"{s['name']} ({s['flow']} flow), {name.split(' (')[0]}")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set(xlabel="true speed [m/s] (10 Hz)", ylabel="forward read / true (median)",
           title="translation read vs true speed (straight forward)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=90)


def markdown(report: dict) -> str:
    speeds = [r["speed_mps"] for r in next(iter(next(iter(report["sets"].values())).values()))["reads"]]
    lines = ["| frames | model (flow) | " + " | ".join(f"{v:g} m/s" for v in speeds) + " | largest abs(read/true - 1), "
             "2.5-30 m/s |", "|---|---|" + "---|" * (len(speeds) + 1)]
    for name, sweeps in report["sets"].items():
        for s in sweeps.values():
            cells = [f"{r['read_median_m']:.3f} m" if r["ratio_median"] is None else f"{r['ratio_median']:.3f}"
                     for r in s["reads"]]
            lines.append(f"| {name} | {s['name']} ({s['flow']}) | " + " | ".join(cells)
                         + f" | {s['flatness']['max_abs_dev']:.3f} |")
    moving = [v for v in speeds if v > 0]
    spread = ["| frames | model (flow) | " + " | ".join(f"{v:g} m/s" for v in moving) + " |",
              "|---|---|" + "---|" * len(moving)]
    for name, sweeps in report["sets"].items():
        for s in sweeps.values():
            cells = [f"{r['ratio_spread']:.3f} / {r['std_ratio_median']:.3f}" if r.get("ratio_spread") is not None
                     else "-" for r in s["reads"] if r["speed_mps"] > 0]
            spread.append(f"| {name} | {s['name']} ({s['flow']}) | " + " | ".join(cells) + " |")
    return ("read/true of the forward translation (median over frames; at 0 m/s the read itself)\n\n"
            + "\n".join(lines) + "\n\nhow much the read varies from frame to frame (std of read/true over the frames) / "
            "how much the model says it varies (median predicted std over the true motion)\n\n"
            + "\n".join(spread) + "\n")


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
    from bench.results_common import candidate_parser, parse_model_specs, run_locked

    ap = candidate_parser("results_speed", __doc__, FLOWS)
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    args = ap.parse_args(argv)
    out = args.out or out_dir() / "results" / ("speed_quick" if args.quick else "speed")

    def work() -> dict:
        cands = ([] if args.no_shipped else list(SHIPPED)) + parse_model_specs(args.model, FLOWS)
        return run(QUICK if args.quick else ResultsSpeedConfig(), out, args.data or shared_data_dir(), tuple(cands))

    code = run_locked("results_speed", out, work, markdown)
    if code == 0:
        print(f"wrote {out / 'results.json'}, {out / 'results.md'} and {out / 'speed_sweep.png'}")
    return code


if __name__ == "__main__":
    sys.exit(main())
