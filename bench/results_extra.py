"""``python -m bench.results_extra``: do rendered frames help as extra training data for real data?

The same network (the ``cpu`` preset, the paper's L1 loss and cyclic learning rate) and the same budget of
samples, trained the paper's way (synthetic flow from single frames with depth, no poses of the training
frames) on three mixes of single frames:

- ``real``: KITTI 06's 51 stereo frames (depth from the stereo pair, :mod:`gen.stereo`);
- ``real + rendered``: those and the 600 frames of two rendered towns (seeds 1, 2; 414 px);
- ``rendered``: the rendered frames alone.

Every mix draws its motions from one model, fitted on KITTI 00's ground-truth poses (strides 1 and 2: only their
distribution, never a training pair's pose; 00 is neither a training nor a test sequence), so that only the
frames differ. Scored with the network's own pose (``deepslam vo --model M --pose net``) on data none of them
saw: the real KITTI 07 slice (DIS flow, as a user runs it) and a held-out rendered street (town 7, exact and DIS
flow). The question the table answers: on real data, does a mix with renders beat real frames alone, and by how
much. Writes results.json and results.md into ``out/results/extra``; renders and models are cached (a killed run
resumes; a model folder with a checkpoint continues with ``--resume``).
"""
from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

from bench.results_common import results_main, write_report
from deepslam.core import atomic

MIXES = ("real", "real + rendered", "rendered")


@dataclasses.dataclass(frozen=True)
class ResultsExtraConfig:
    """What is trained and scored."""

    samples: int = 80_000
    """Training samples per model (the same budget for every mix)."""
    seeds: tuple[int, ...] = (0,)
    """Training seeds (a row's mean over those)."""
    render_seeds: tuple[int, ...] = (1, 2)
    """Towns of the rendered training frames (the paper recipe's)."""
    render_frames: int = 300
    """Frames per rendered town."""
    width: int = 414
    """Width of the renders, pixels."""
    heldout_seed: int = 7
    """Town of the held-out street (none of the training towns)."""
    heldout_frames: int = 150
    """Frames of the held-out street."""
    motion_poses: str = "kitti/poses/00.txt"
    """Ground-truth poses (under the shared data folder) the motion model is fitted on."""


QUICK = ResultsExtraConfig(samples=2048, render_frames=20, heldout_frames=20)


def _motion(data: Path, cfg: ResultsExtraConfig, out: Path, log: list[str]) -> list[str]:
    """``--motion`` specs: KDE fits of the poses at strides 1 and 2, equal weights."""
    from deepslam.studies.demo import run_command

    specs = []
    for k in (1, 2):
        path = out / f"motion_s{k}.json"
        if not path.is_file():
            run_command(["fit-motion", "--poses", str(data / cfg.motion_poses), "--stride", str(k), "--consecutive",
                         "kde", "--out", str(path)], log)
        specs.append(f"{path}@1")
    return specs


def _train(mix: str, sources: list[str], motion: list[str], seed: int, cfg: ResultsExtraConfig, out: Path,
           log: list[str]) -> Path:
    from deepslam.studies.demo import run_command

    folder = out / f"{mix.replace(' + ', '_')}_s{seed}"
    if not (folder / "model.safetensors").is_file():
        args = ["train", "--mode", "synthetic", "--net", "cpu", "--loss", "l1", "--source", *sources, "--depth", "auto",
                *[a for m in motion for a in ("--motion", m)], "--max-samples", str(cfg.samples), "--seed", str(seed),
                "--threads", "2", "--quiet", "--out", str(folder)]
        run_command(args + (["--resume"] if (folder / "checkpoint.safetensors").is_file() else []), log)
    return folder / "model.safetensors"


def run(cfg: ResultsExtraConfig, out: Path, data: Path) -> dict:
    from bench.results_repro import vo_scores
    from deepslam.studies.demo import render_once

    out.mkdir(parents=True, exist_ok=True)
    log: list[str] = []
    t0 = time.perf_counter()
    real = str(data / "kitti" / "sequences" / "06")
    rendered = [str(render_once("street", "car", cfg.render_frames, cfg.width, s, out / f"street_train_s{s}", log,
                                ("--quiet",))) for s in cfg.render_seeds]
    heldout = render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                          out / f"street_heldout_s{cfg.heldout_seed}", log, ("--quiet",))
    kitti07 = data / "kitti" / "sequences" / "07"
    motion = _motion(data, cfg, out, log)
    sources = {"real": [real], "real + rendered": [real, *rendered], "rendered": rendered}
    rows = []
    for mix in MIXES:
        for seed in cfg.seeds:
            model = _train(mix, sources[mix], motion, seed, cfg, out, log)
            cache = out / "scores" / f"{model.parent.name}.json"
            if cache.is_file():
                rows.append(json.loads(cache.read_text()))
                continue
            scores = {}
            for name, seq, flow in (("KITTI 07 (real), DIS flow", kitti07, "dis"),
                                    (f"held-out street (town {cfg.heldout_seed}), exact flow", heldout, "gt"),
                                    (f"held-out street (town {cfg.heldout_seed}), DIS flow", heldout, "dis")):
                tmp = out / "scores" / f"{model.parent.name}_{flow}_{Path(seq).name}.txt"
                tmp.parent.mkdir(parents=True, exist_ok=True)
                scores[name] = vo_scores(Path(seq), tmp, "--model", str(model), "--pose", "net", "--flow", flow)
            row = {"mix": mix, "seed": seed, "model": str(model), "scores": scores}
            atomic.write_json(cache, row)
            rows.append(row)
    report = {"config": dataclasses.asdict(cfg), "rows": rows, "commands": log,
              "minutes": (time.perf_counter() - t0) / 60}
    write_report(out, report, markdown)
    return report


def _f(x, f=".3g") -> str:
    return "n/a" if x is None else format(x, f)


def markdown(report: dict) -> str:
    import numpy as np

    cfg = report["config"]
    rows = report["rows"]
    names = list(rows[0]["scores"]) if rows else []
    md = ["# Rendered frames as extra training data", "",
          f"The `cpu` network trained the paper's way (synthetic flow from single frames, no poses) for "
          f"{cfg['samples']:,} samples on each mix; motions from one KDE fit of {cfg['motion_poses']} (strides 1, 2); "
          "scored with its own pose (`deepslam vo --pose net`) on data none of the mixes saw. Mean over training seeds "
          f"{', '.join(map(str, cfg['seeds']))}.", "",
          "| training frames | " + " | ".join(f"{n}: drift [% of path] / ATE [m] / path x" for n in names) + " |",
          "|---|" + "---|" * len(names)]
    for mix in MIXES:
        got = [r for r in rows if r["mix"] == mix]
        if not got:
            continue
        cells = []
        for n in names:
            vals = [r["scores"][n] for r in got]
            cells.append(" / ".join(_f(float(np.mean([v[k] for v in vals]))) for k in
                                    ("endpoint_drift_pct", "ate_m", "path_length_ratio")))
        md.append(f"| {mix} | " + " | ".join(cells) + " |")
    kitti = names[0] if names else None
    if kitti:
        def drift(mix):
            vals = [r["scores"][kitti]["endpoint_drift_pct"] for r in rows if r["mix"] == mix]
            return float(np.mean(vals)) if vals else None
        a, b = drift("real"), drift("real + rendered")
        if a and b:
            md += ["", f"On {kitti}: real + rendered / real alone, drift x{b / a:.2f} "
                   f"({'the renders help' if b < a else 'the renders do not help'} at this budget)."]
    md += ["", f"Run time: {report['minutes']:.1f} min.", "", "## Commands", "", "```"] + report["commands"] + ["```"]
    return "\n".join(md) + "\n"


def main(argv: list[str] | None = None) -> int:
    return results_main("results_extra", __doc__, ResultsExtraConfig(), QUICK, "extra", run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
