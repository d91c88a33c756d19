"""Where a figure was measured: date, commit and machine, written beside every results table
(``stamp.json``) and shown above it in docs/results.md (:mod:`bench.results_doc`)."""
from __future__ import annotations

import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from deepslam.core import atomic

REPO = Path(__file__).resolve().parents[1]


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return ""


def machine() -> str:
    """One line: CPU model, logical cores, the widest x86 vector extension, and the GPU torch sees (if loaded)."""
    model, flags = platform.processor() or platform.machine(), set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name") and model in ("", platform.machine(), platform.processor()):
                model = line.split(":", 1)[1].strip()
            elif line.startswith("flags"):
                flags = set(line.split(":", 1)[1].split())
                break
    except OSError:
        pass
    vec = "AVX-512" if "avx512f" in flags else "AVX2" if "avx2" in flags else "no AVX2"
    torch = sys.modules.get("torch")  # only where the run imported it: torch takes seconds to import
    gpu = torch.cuda.get_device_name(0) if torch is not None and torch.cuda.is_available() else "no GPU"
    return f"{model}, {os.cpu_count()} cores, {vec}, {gpu}"


def stamp() -> dict:
    """``{"date", "commit", "machine"}`` now: UTC date and time, the checkout's commit (``-dirty`` with
    uncommitted changes to tracked files), :func:`machine`."""
    commit = _git("rev-parse", "--short", "HEAD") or "unknown"
    if _git("status", "--porcelain", "--untracked-files=no"):
        commit += "-dirty"
    return {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "commit": commit, "machine": machine()}


def reusable_at(recorded_commit: str | None, commit: str) -> bool:
    """Whether a figure measured at ``recorded_commit`` may be reused by a run at ``commit`` (both
    :func:`stamp` commits): only at the same commit of a clean checkout (``-dirty`` never matches), since
    the code measures as much as the models and settings do."""
    return not commit.endswith("-dirty") and recorded_commit == commit


def write_stamp(folder: Path, **extra) -> dict:
    """:func:`stamp` (and ``extra``) written to ``folder/stamp.json``; returns it."""
    s = {**stamp(), **extra}
    atomic.write_json(Path(folder) / "stamp.json", s)
    return s
