"""The stress study with its defaults: flow, VO and SLAM errors against the fraction of moving pixels.

``deepslam stress`` on the default street (the KITTI-look street, seed 0, 300 frames per setting at 320 px,
``deepslam vo``'s default on exact and DIS flow; beside it the paper's network with its own pose and ``pnp``):
static, moving cars by count and size, waving flags, and the heaviest setting. Writes the study's outputs
(stress.json, stress.md, report.html, plots) into ``out/results/stress/study`` and results.md (the table) into
``out/results/stress``
(``python -m bench.results_stress [--quick]``, a few minutes on 2 cores).
"""
from __future__ import annotations

import dataclasses
import re
import shutil
import sys
import time
from pathlib import Path

from bench.results_common import results_main, write_report
from bench.stamp import reusable_at, stamp
from deepslam.core import atomic
from deepslam.core.errors import InputError


@dataclasses.dataclass(frozen=True)
class ResultsStressConfig:
    """The sweep: :class:`deepslam.studies.stress.StressConfig`'s defaults unless given here."""

    frames: int | None = None
    """Frames per setting (None: the study's default)."""
    objects: tuple[int, ...] | None = None
    """Moving-object counts (None: the study's default)."""
    object_sizes: tuple[float, ...] | None = None
    """Moving-object sizes (None: the study's default)."""
    deform_amplitudes_m: tuple[float, ...] | None = None
    """Flag amplitudes, metres (None: the study's default)."""
    combined: bool | None = None
    """The heaviest setting too (None: the study's default, yes)."""
    plugins: tuple[str, ...] = ("network", "pnp")
    """Odometries measured side by side with ``deepslam vo``'s default, each named in the table: the paper's
    network with its own pose on DIS flow (``network``) and SIFT + PnP-RANSAC on the render's depth (``pnp``)."""


QUICK = ResultsStressConfig(frames=100, objects=(0, 8), object_sizes=(2.0,), deform_amplitudes_m=(0.3,), combined=False,
                            plugins=("pnp",))


def run(cfg: ResultsStressConfig, out: Path, data_dir: Path) -> dict:
    from deepslam.studies.stress import StressConfig, run_stress  # deferred: torch and the renderers

    given = {k: v for k, v in dataclasses.asdict(cfg).items() if v is not None}
    t0 = time.perf_counter()
    study = out / "study"  # the study's own folder (and lock) inside the results folder
    # a killed run resumes only at the same clean commit: the odometry's code changes a setting's figures
    # as much as its configuration does
    commit = stamp()["commit"]
    marker = out / "study_commit.txt"
    resume = marker.is_file() and reusable_at(marker.read_text().strip(), commit)
    if study.exists() and not resume:
        if not marker.is_file():  # not made by this script: not ours to replace
            raise InputError(study, "holds a stress run this script did not make; remove it or choose another --out")
        shutil.rmtree(study)      # this script's run at other code: measured again
    atomic.write_text(marker, commit + "\n")
    run_stress(StressConfig(**given), study, resume=resume, progress=False)
    # the study's figures sit in study/: links relative to this folder
    table = re.sub(r"!\[([^\]]*)\]\(([^)/\s]+\.png)\)", r"![\1](study/\2)", (study / "stress.md").read_text())
    report = {"config": dataclasses.asdict(cfg), "markdown": table,
              "minutes": (time.perf_counter() - t0) / 60}
    write_report(out, report, markdown)
    return report


def markdown(report: dict) -> str:
    return (report["markdown"].strip() + f"\n\nRun time: {report['minutes']:.1f} min (a killed run resumed at the "
            "same commit reuses the settings it measured).\n")


def main(argv: list[str] | None = None) -> int:
    return results_main("results_stress", __doc__, ResultsStressConfig(), QUICK, "stress", run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
