"""Where things are: the checkout (when running from one), the shared real data, the default output folder.

Installed normally, deepslam has no repository around it: the defaults then hang off the current
working directory. From a checkout (an editable install, what ``make`` sets up) they hang off the
repository root, so tests and benchmarks find ``../shared/data`` wherever they are started.
The real data (KITTI, EuRoC and TUM slices, reference trajectories) lives in ``../shared/data``
beside the repository; the environment variable ``DEEPSLAM_SHARED_DATA`` points elsewhere when set.
"""
from __future__ import annotations

import os
from pathlib import Path


def checkout_root() -> Path | None:
    """The repository root when this code runs from a checkout (the folder holding pyproject.toml,
    core/ and deepslam/), else None (a normal install into site-packages)."""
    root = Path(__file__).resolve().parents[1]
    if (root / "pyproject.toml").is_file() and (root / "deepslam" / "cli.py").is_file() and (root / "core").is_dir():
        return root
    return None


def base_dir() -> Path:
    """The checkout's root, or the current working directory for an installed package."""
    return checkout_root() or Path.cwd()


def shared_data_dir() -> Path:
    """``$DEEPSLAM_SHARED_DATA`` if set, else ``<base>/../shared/data`` (resolved; may not exist)."""
    env = os.environ.get("DEEPSLAM_SHARED_DATA")
    if env:
        return Path(env).expanduser().resolve()
    return (base_dir() / ".." / "shared" / "data").resolve()


def out_dir() -> Path:
    """``<base>/out``: where demos and benchmarks write by default."""
    return base_dir() / "out"
