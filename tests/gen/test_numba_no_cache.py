"""The compiled kernels (numba closures, made on first use) write nothing into the installed package: a
closure's on-disk cache can never be hit, so each process only added a file there."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import deepslam.gen
import deepslam.sim

SCRIPT = """
import numpy as np
from deepslam.core.camera import PinholeCamera
from deepslam.gen.flow import synthesize
from deepslam.gen.novel_view import render_novel_view
from deepslam.sim.flow import occlusion_mask
cam = PinholeCamera(fx=50.0, fy=50.0, cx=31.5, cy=23.5, width=64, height=48)
depth = np.full((48, 64), 5.0, np.float32)
motion = np.eye(4); motion[2, 3] = -0.2
flow, valid = synthesize(depth, cam, motion, backend="numba")
img = np.zeros((48, 64, 3), np.uint8)
render_novel_view(img, depth, cam, motion)
flow_hw = np.ascontiguousarray(np.asarray(flow)[0].transpose(1, 2, 0)) if np.asarray(flow).ndim == 4 else np.asarray(flow)
occlusion_mask(flow_hw.astype(np.float32), depth, depth)
print("ran")
"""


def _cache_files() -> set[Path]:
    dirs = [Path(deepslam.gen.__file__).parent, Path(deepslam.sim.__file__).parent]
    return {p for d in dirs for p in d.rglob("*") if p.suffix in (".nbi", ".nbc")}


def test_kernels_leave_no_cache_files_in_the_package():
    before = _cache_files()
    for _ in range(2):
        r = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300)
        assert r.returncode == 0 and "ran" in r.stdout, r.stderr[-2000:]
    assert _cache_files() - before == set()
