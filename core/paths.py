"""Where things are: the repository root, the shared real data, the default output folder.

The real data (KITTI and EuRoC slices, reference trajectories) lives in ``../shared/data`` beside the
repository; the environment variable ``DEEPSLAM_SHARED_DATA`` points elsewhere when set.
"""
from __future__ import annotations

import os
from pathlib import Path


def repo_root() -> Path:
    """The repository root (the folder holding core/, deepslam/, tests/)."""
    return Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """``$DEEPSLAM_SHARED_DATA`` if set, else ``<repo>/../shared/data`` (resolved; may not exist)."""
    env = os.environ.get("DEEPSLAM_SHARED_DATA")
    if env:
        return Path(env).expanduser().resolve()
    return (repo_root() / ".." / "shared" / "data").resolve()


def out_dir() -> Path:
    """``<repo>/out``: where demos and benchmarks write by default."""
    return repo_root() / "out"
