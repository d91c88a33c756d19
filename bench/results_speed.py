"""Scale from flow or from a prior? The shipped KITTI models' forward read against the true speed.

A held-out simulated street (a town no shipped model was trained on; seed 7, as in results_vo) and
the real KITTI 06 slice (depth from stereo; its single frames WERE in the shipped models' training,
without poses) are driven straight forward at 0-30 m/s (10 Hz) by single-frame synthesis; each
model reads the flow it was made for: ``kitti_cons`` the exact synthetic flow, ``kitti_cons_dis``
DIS on a second view rendered from the frame. read/true = 1 at every speed is a model that reads
metric motion from flow; a slope is a learned speed prior. Writes results.json, results.md and
speed_sweep.png into ``out/results/speed`` (``python -m bench.results_speed``, about 2 minutes).
"""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np


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


def _sweeps(seq, kind: str, cfg: ResultsSpeedConfig) -> dict:
    from deepslam.vo import data, models, scale_sweep

    out = {}
    for flow in ("exact", "dis"):
        path = models.shipped_path("kitti", "cons", None if flow == "exact" else "dis")
        pred = models.load(path, True)
        h, w = pred.input_size
        unknown = pred.model.cfg.unknown_flow
        if flow == "exact":
            frames = data.load_frames([seq], 2 * w, 2 * h, depth=kind, progress=False)

            def make(sample, frames=frames, unknown=unknown):
                return data.SyntheticSource(frames, sample, cfg.samples, synth_factor=2, unknown=unknown)
        else:
            frames = data.load_image_frames([seq], depth=kind, progress=False)
            # DIS set up as the model's file records it (medium on every pixel for today's file)
            options = {"preset": "medium", **models.recorded_flow_options(path, "dis")}

            def make(sample, frames=frames, h=h, w=w, unknown=unknown, options=options):
                return data.EstimatedFlowSource(frames, sample, "dis", w, h, cfg.samples, estimator_options=options,
                                                unknown=unknown)
        reads = scale_sweep.speed_sweep(pred, make, cfg.samples, cfg.rate_hz, seed=cfg.seed)
        out[flow] = {"model": pred.name, "reads": [dataclasses.asdict(r) for r in reads],
                     "flatness": scale_sweep.flatness(reads)}
    return out


def run(cfg: ResultsSpeedConfig, out: Path, data_dir: Path) -> dict:
    from deepslam.core import atomic
    from deepslam.core.readers import open_sequence
    from deepslam.studies.demo import render_once

    out.mkdir(parents=True, exist_ok=True)
    log: list[str] = []
    held = render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                       out / f"street_heldout_s{cfg.heldout_seed}", log)
    report = {"config": dataclasses.asdict(cfg), "sets": {}}
    report["sets"]["simulated street, held out (seed 7; never trained on)"] = _sweeps(open_sequence(held), "rendered", cfg)
    k06 = data_dir / "kitti" / "sequences" / "06"
    if (k06 / "calib.txt").is_file():
        report["sets"]["KITTI 06 slice (stereo depth; its single frames were in training, no poses)"] = \
            _sweeps(open_sequence(k06), "stereo", cfg)
    atomic.write_json(out / "results.json", report)
    atomic.write_text(out / "results.md", markdown(report))
    _plot(report, out / "speed_sweep.png")
    return report


def _plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from deepslam.core import atomic

    fig, ax = plt.subplots(figsize=(7, 4))
    for name, sweeps in report["sets"].items():
        for flow, s in sweeps.items():
            rs = [r for r in s["reads"] if r["ratio_median"] is not None]
            ax.plot([r["speed_mps"] for r in rs], [r["ratio_median"] for r in rs], marker="o",
                    label=f"{s['model']} ({flow} flow), {name.split(' (')[0]}")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set(xlabel="true speed [m/s] (10 Hz)", ylabel="forward read / true (median)",
           title="translation read vs true speed (straight forward)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def markdown(report: dict) -> str:
    speeds = [r["speed_mps"] for r in next(iter(next(iter(report["sets"].values())).values()))["reads"]]
    lines = ["| frames | model (flow) | " + " | ".join(f"{v:g} m/s" for v in speeds) + " |",
             "|---|---|" + "---|" * len(speeds)]
    for name, sweeps in report["sets"].items():
        for flow, s in sweeps.items():
            cells = [f"{r['read_median_m']:.3f} m" if r["ratio_median"] is None else f"{r['ratio_median']:.2f}"
                     for r in s["reads"]]
            lines.append(f"| {name} | {s['model']} ({flow}) | " + " | ".join(cells) + " |")
    return ("read/true of the forward translation (median over frames; at 0 m/s the read itself)\n\n"
            + "\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    from bench.results_common import results_main

    return results_main("results_speed", __doc__, ResultsSpeedConfig(), QUICK, "speed", run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
