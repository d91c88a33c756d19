"""RGB-D odometry: the sim-only default, the untrained dense fit, the classical ``pnp`` plug-in, and
``deepslam adapt`` on the sequence's own frames (no poses), side by side.

Sequences: TUM fr3/teddy (real, ../shared/data) and two rooms rendered as a Kinect would see them (640x480,
f = 537 px, 30 Hz, ``--depth-noise kinect``, TUM layout; seed 52 with random lighting). Per sequence, VO ATE
(m, SE3-aligned) of: the shipped default (``tum_cons``: learned on rendered rooms only), the solve head with
every weight 1 and the Cauchy kernel (``scripts/solve_unit_weights.py`` + ``set-solve``: a dense least-squares
fit of DIS flow with the sensor depth, nothing learned), ``--odometry pnp``, and on teddy the model
``deepslam adapt`` makes from teddy's own single frames (VO and SLAM; it has seen teddy's frames, so these rows
are never "unseen"), with the minutes adapt took. Work that exists under ``--out`` is reused (adapt resumes).

Writes results.json and results.md into ``out/results/adapt`` (``python -m bench.results_adapt``; about
20 minutes on 2 cores the first time, seconds after).
"""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

from bench.results_common import results_main, write_report

REPO = Path(__file__).resolve().parents[1]


@dataclasses.dataclass(frozen=True)
class ResultsAdaptConfig:
    """What is measured."""

    room_seeds: tuple[int, ...] = (51, 52)
    """Rendered RGB-D rooms (seed 52 with random lighting)."""
    room_frames: int = 150
    """Frames per room (30 Hz)."""
    adapt_samples: int = 6000
    """``deepslam adapt --samples`` (its default)."""
    adapt_epochs: int = 5
    """``deepslam adapt --epochs`` (its default)."""


QUICK = ResultsAdaptConfig(room_seeds=(51,), room_frames=12, adapt_samples=128, adapt_epochs=1)


def _cli(*args: str) -> None:
    from deepslam.cli import main

    if main([str(a) for a in args]) != 0:
        raise RuntimeError(f"deepslam {' '.join(map(str, args))} failed")


def _vo(seq: Path, out: Path, *extra: str) -> dict:
    if not out.with_suffix(".metrics.json").is_file():
        _cli("vo", "--sequence", seq, "--out", out, "--quiet", *extra)
    return json.loads(out.with_suffix(".metrics.json").read_text())


def run(cfg: ResultsAdaptConfig, out: Path, data_dir: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    fit = out / "dense_fit_cauchy.safetensors"
    if not fit.is_file():
        plain = out / "dense_fit.safetensors"
        subprocess.run([sys.executable, str(REPO / "scripts" / "solve_unit_weights.py"),
                        str(REPO / "models" / "tum_cons.safetensors"), str(plain)], check=True, capture_output=True)
        _cli("set-solve", plain, "--robust", "cauchy", "--iterations", "6", "--out", fit)
    seqs = {}
    teddy = data_dir / "tum" / "rgbd_dataset_freiburg3_teddy"
    if (teddy / "rgb.txt").is_file():
        seqs["TUM fr3/teddy (real)"] = teddy
    for s in cfg.room_seeds:
        room = out / f"rgbd_room{s}"
        if not (room / "rgb.txt").is_file():
            _cli("render", "--scene", "room", "--frames", cfg.room_frames, "--width", 640, "--height", 480,
                 "--focal-px", 537, "--rate", 30, "--stereo-baseline", 0, "--depth-noise", "kinect", "--seed", s,
                 "--format", "tum", "--out", room, "--quiet", *(["--random-lighting"] if s == 52 else []),
                 *(["--resume"] if room.exists() else []))
        seqs[f"room {s}, Kinect-like depth{' and random lighting' if s == 52 else ''} (rendered)"] = room
    rows = []
    for name, seq in seqs.items():
        tag = seq.name
        row = {"data": name,
               "default_ate_m": _vo(seq, out / f"{tag}_default.txt")["ate_m"],
               "dense_fit_ate_m": _vo(seq, out / f"{tag}_fit.txt", "--model", str(fit))["ate_m"],
               "pnp_ate_m": _vo(seq, out / f"{tag}_pnp.txt", "--odometry", "pnp")["ate_m"]}
        if seq == teddy:
            adapted = out / f"{tag}_adapted"
            if not (adapted / "adapt.json").is_file():  # the record of the run that made it, kept
                _cli("adapt", "--sequence", seq, "--out", adapted, "--samples", cfg.adapt_samples, "--epochs",
                     cfg.adapt_epochs, "--quiet", *(["--resume"] if adapted.exists() else []))
            record = json.loads((adapted / "adapt.json").read_text())
            row["adapted_vo_ate_m"] = _vo(seq, out / f"{tag}_adapted_vo.txt", "--model",
                                          str(adapted / "model.safetensors"))["ate_m"]
            slam_out = out / f"{tag}_adapted_slam.txt"
            if not (out / f"{tag}_adapted_slam.json").is_file():
                _cli("slam", "--sequence", seq, "--model-cons", adapted / "model.safetensors", "--model-loops",
                     adapted / "loops.safetensors", "--out", slam_out)
            slam = json.loads((out / f"{tag}_adapted_slam.json").read_text())
            row["adapted_slam_ate_m"] = (slam.get("metrics_slam") or {}).get("ate_m")
            row["adapt_minutes_first_run"] = round(record["seconds"] / 60, 1)
            row["adapt_stop"] = {k: v["stop_reason"] for k, v in record["stages"].items()}
        rows.append(row)
        print(f"{name}: {row}", flush=True)
    report = {"config": dataclasses.asdict(cfg), "rows": rows}
    write_report(out, report, markdown)
    return report


def markdown(report: dict) -> str:
    f = lambda v: "" if v is None else f"{v:.3f}"  # noqa: E731
    lines = ["VO ATE (m, SE3-aligned); adapted rows saw the sequence's own frames (no poses)", "",
             "| data | default (sim-only) | untrained dense fit | pnp | adapted VO | adapted SLAM | adapt minutes |",
             "|---|---|---|---|---|---|---|"]
    for r in report["rows"]:
        lines.append(f"| {r['data']} | {f(r['default_ate_m'])} | {f(r['dense_fit_ate_m'])} | {f(r['pnp_ate_m'])} | "
                     f"{f(r.get('adapted_vo_ate_m'))} | {f(r.get('adapted_slam_ate_m'))} | "
                     f"{'' if r.get('adapt_minutes_first_run') is None else r['adapt_minutes_first_run']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    return results_main("results_adapt", __doc__, ResultsAdaptConfig(), QUICK, "adapt", run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
