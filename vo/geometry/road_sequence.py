"""A sequence's per-pair road distances checked against their neighbours, outliers dropped and short gaps
filled (:func:`check_and_fill`, the last step of ``deepslam vo --scale road``)."""
from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class RoadSequenceConfig:
    """How a sequence's per-pair road distances are checked against their neighbours and gaps filled."""

    neighbours: int = 2
    """Pairs on each side whose distances predict a pair's (:func:`check_and_fill`)."""
    max_jump_frac: float = 0.3
    """A distance differing from what its neighbours predict by more than this fraction of it ..."""
    min_jump_m: float = 0.2
    """... and by more than this many metres is dropped (a car's speed changes little in a few frames)."""
    fill_pairs: int = 6
    """Runs of at most this many pairs without a distance, between two pairs with one, are interpolated; at
    either end of the sequence, such a run takes the nearest pair's distance. (A car's speed changes by at most
    about 3 m/s a second: across six pairs at 3.33 Hz the line between two readings errs by less than the
    network's distance, a speed prior, does at speed.)"""


def check_and_fill(distances: np.ndarray, cfg: RoadSequenceConfig = RoadSequenceConfig()) -> tuple[np.ndarray, np.ndarray]:
    """A sequence's road distances with outliers dropped and short gaps interpolated.

    Args:
        distances: (P,) float metres per consecutive pair, NaN where none was read.

    Returns:
        ((P,) float64 distances, NaN where still none; (P,) bool: dropped as an outlier). A distance is
        dropped where it differs from what its neighbours predict (the median, over each finite neighbour up
        to ``cfg.neighbours`` pairs before and each after, of the straight line through the two; at least one
        on each side) by more than ``cfg.max_jump_frac`` of that prediction and ``cfg.min_jump_m``; then gaps
        of up to ``cfg.fill_pairs`` pairs are filled (:class:`RoadSequenceConfig`).
    """
    d = np.asarray(distances, np.float64).ravel()
    n = len(d)
    dropped = np.zeros(n, bool)
    finite = np.isfinite(d)
    for i in np.flatnonzero(finite):
        before = [b for b in range(max(0, i - cfg.neighbours), i) if finite[b]]
        after = [a for a in range(i + 1, min(n, i + 1 + cfg.neighbours)) if finite[a]]
        if not (before and after):      # one side only: a speed-up or a slow-down would read as a jump
            continue
        # the distance each (before, after) pair of neighbours predicts by a straight line: a steady
        # speed-up is no jump, and one bad neighbour spoils only the lines through it
        pred = float(np.median([d[b] + (d[a] - d[b]) * (i - b) / (a - b) for b in before for a in after]))
        dropped[i] = abs(d[i] - pred) > max(cfg.max_jump_frac * abs(pred), cfg.min_jump_m)
    out = np.where(dropped, np.nan, d)
    known = np.flatnonzero(np.isfinite(out))
    for a, b in zip(known[:-1], known[1:]):
        if 1 < b - a <= cfg.fill_pairs + 1:
            out[a + 1:b] = np.interp(np.arange(a + 1, b), [a, b], [out[a], out[b]])
    if len(known) and 0 < known[0] <= cfg.fill_pairs:
        out[:known[0]] = out[known[0]]
    if len(known) and 0 < n - 1 - known[-1] <= cfg.fill_pairs:
        out[known[-1] + 1:] = out[known[-1]]
    return out, dropped
