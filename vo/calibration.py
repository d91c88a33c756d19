"""Calibrating a VO model's predicted uncertainty on a sequence with ground truth (``deepslam calibrate``).

The network's std heads are trained on held-out samples of its own training data (the NLL stage); on another
flow (DIS against exact synthetic flow) or on real data the errors are larger or smaller than the std says. A
per-DoF factor fitted on a validation sequence of the target data (the ``coverage`` quantile of
``|error| / std``) makes ``coverage`` of that sequence's errors fall within the scaled 1-sigma; the factor is
recorded in the model file (meta ``std_scale``) and :class:`vo.infer.VOPredictor` applies it to every std it
predicts, so the SLAM's pose graph weighs the motions by it too. All 6DoF vectors are the paper's
``(euler_x, euler_y, euler_z, t_x, t_y, t_z)`` of ``cam_j_from_cam_i`` (radians, metres).
"""
from __future__ import annotations

import numpy as np

from deepslam.core import se3

ONE_SIGMA = 0.6827
"""Share of a Gaussian's draws within one standard deviation of its mean."""


def pair_errors(gt_world_from_cam: np.ndarray, pairs: np.ndarray, mean6: np.ndarray) -> np.ndarray:
    """(P, 6) float64 predicted minus true 6DoF of each pair (i, j): ``mean6`` (P, 6) against the ground truth's
    ``cam_j_from_cam_i`` from ``gt_world_from_cam`` (N, 4, 4) float64 (metres)."""
    gt = np.asarray(gt_world_from_cam, np.float64)
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    true6 = se3.to_euler6(se3.relative(gt[pairs[:, 1]], gt[pairs[:, 0]])).reshape(-1, 6)
    return np.asarray(mean6, np.float64).reshape(-1, 6) - true6


def within_one_sigma(err6: np.ndarray, std6: np.ndarray) -> np.ndarray:
    """(6,) float64 share of pairs whose error (P, 6) is within the std (P, 6), per DoF (a calibrated Gaussian: 0.68)."""
    return (np.abs(err6) <= std6).mean(axis=0)


def std_scale(err6: np.ndarray, std6: np.ndarray, coverage: float = ONE_SIGMA) -> np.ndarray:
    """(6,) float64 per-DoF factors ``s`` such that at least ``coverage`` of the pairs have ``|error| <= s * std``:
    the ``coverage`` quantile of ``|error| / std`` over the pairs (the next observed value above it, never an
    interpolation below it), clipped to [1e-3, 1e3].

    Raises:
        ValueError: fewer than 10 pairs, or a std that is not positive and finite.
    """
    err6, std6 = np.asarray(err6, np.float64), np.asarray(std6, np.float64)
    if len(err6) < 10:
        raise ValueError(f"calibration needs at least 10 pairs, got {len(err6)}")
    if not (np.isfinite(std6).all() and (std6 > 0).all()):
        raise ValueError("the predicted std must be positive and finite")
    # nudged up by 1e-9: the pair at the quantile stays inside after the std is rounded back
    return np.clip(np.quantile(np.abs(err6) / std6, coverage, axis=0, method="higher") * (1 + 1e-9), 1e-3, 1e3)


def widened_std(std6: np.ndarray, disagreement6: np.ndarray) -> np.ndarray:
    """Each std widened by a second reading's disagreement, per DoF: ``sqrt(std^2 + d^2)``.

    Args:
        std6: (N, 6) float64 predicted std (rad, m) of the network's readings.
        disagreement6: (N, 6) float64 the network's reading minus another of the same pair (the geometry's, zero
            where it read nothing), same units.

    Returns:
        (N, 6) float64: never below ``std6``; equal to it where the readings agree.
    """
    std6, d = np.asarray(std6, dtype=np.float64), np.asarray(disagreement6, dtype=np.float64)
    if std6.shape != d.shape:
        raise ValueError(f"std6 {std6.shape} and disagreement6 {d.shape} differ")
    return np.sqrt(std6 ** 2 + d ** 2)
