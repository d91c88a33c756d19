"""Dynamic pixels: the share of images that show a moving or deforming surface (instance mask > 0)."""
from __future__ import annotations

import numpy as np


def dynamic_fraction(*masks: np.ndarray | None) -> float:
    """Share (0-1) of all pixels of the instance masks that show a dynamic surface (id > 0), pooled over
    the masks: the dynamic pixels of all masks over all their pixels.

    masks: instance masks (H, W) of non-negative integer ids (0 = static), any sizes. A None among them (a
    frame without a mask: the sequence says nothing about what moves) or no mask at all gives 0.
    """
    dynamic = total = 0
    for m in masks:
        if m is None:
            return 0.0
        dynamic += int(np.count_nonzero(m))
        total += int(m.size)
    return float(dynamic) / float(total) if total else 0.0
