"""Progress bars for long work: tqdm on stderr, shown when stderr is a terminal.

Set ``DEEPSLAM_PROGRESS=1`` to force the bar (e.g. into a log file) or ``0`` to hide it. Hidden bars
keep error output to the one line that names the problem.
"""
from __future__ import annotations

import os
from typing import Iterable, TypeVar

from tqdm import tqdm

T = TypeVar("T")


def _disable() -> bool | None:
    flag = os.environ.get("DEEPSLAM_PROGRESS")
    if flag is None:
        return None  # tqdm: disabled when stderr is not a TTY
    return flag.strip() in ("0", "", "false", "no")


def progress(iterable: Iterable[T] | None = None, **kwargs) -> tqdm:
    """``tqdm(iterable, **kwargs)`` with the project's display policy (see module docstring)."""
    kwargs.setdefault("disable", _disable())
    kwargs.setdefault("dynamic_ncols", True)
    return tqdm(iterable, **kwargs)
