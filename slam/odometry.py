"""The odometry interface the SLAM pipeline consumes, and a ground-truth odometry with known noise.

THE PROTOCOL (kept stable; ``vo`` models implement it)::

    class Odometry(Protocol):
        name: str
        def predict(self, seq: core.sequence.Sequence,
                    pairs: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]: ...

``predict(seq, pairs)`` returns ``(mean6, std6)``, both float64 of shape (P, 6), one row per pair
``(i, j)`` in the order given:

- ``mean6[k]`` is the paper's 6DoF vector of ``cam_j_from_cam_i`` (the motion that maps points seen in
  frame i into frame j, what flow from i to j implies): ``(euler_x, euler_y, euler_z, t_x, t_y, t_z)``,
  radians and metres, R = Rz Ry Rx, as :func:`core.se3.to_euler6` returns it. For consecutive frames
  ``i + 1 == j``: ``cam_{t+1}_from_cam_t``.
- ``std6[k]`` is the predicted standard deviation of each of those six numbers (same units), > 0.

Pairs may have ``j > i`` (the pipeline always asks so) and any gap (loop pairs are hundreds of frames
apart). The odometry computes whatever it needs (optical flow, resizing) from ``seq`` itself; the
pipeline never passes images. It may show a progress bar. :func:`check_prediction` validates the
result; the pipeline calls it on every answer.

An odometry may also offer ``predict_verified(seq, pairs) -> (mean6, std6, rigid)`` (:class:`VerifiedOdometry`),
``rigid`` (P,) bool telling where the pair's input fits one rigid motion: the pipeline then leaves the loop pairs
where it does not out of the pose graph (:attr:`slam.pipeline.PipelineConfig.loop_check`). The network in the
epipolar pose mode offers it (:meth:`vo.infer.PredictorOdometry.predict_verified`).

:class:`GroundTruthOdometry` implements the protocol from ground-truth poses plus seeded Gaussian
noise of known std and an optional bias per pair (which accumulates into drift along consecutive
pairs), so the pose graph and loop closure can be tested against known answers.
"""
from __future__ import annotations

import dataclasses
from typing import Protocol, Sequence as SequenceT, runtime_checkable

import numpy as np

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.trajectory import Trajectory


@runtime_checkable
class Odometry(Protocol):
    """Relative motion (paper's 6DoF vector of ``cam_j_from_cam_i``) and its std for frame pairs."""

    name: str
    """Short human-readable name (e.g. the model file's name), shown in logs and reports."""

    def predict(self, seq, pairs: SequenceT[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        """Args:
            seq: a :class:`core.sequence.Sequence` (images, camera, ...).
            pairs: P index pairs (i, j) into ``seq``.

        Returns:
            (mean6, std6): float64 (P, 6) each; mean6 rows are ``to_euler6(cam_j_from_cam_i)``
            (rad, m), std6 rows the predicted std of those numbers (> 0).
        """
        ...


@runtime_checkable
class VerifiedOdometry(Odometry, Protocol):
    """An :class:`Odometry` that also tells, per pair, whether its input fits one rigid motion."""

    def predict_verified(self, seq, pairs: SequenceT[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(mean6, std6) as :meth:`Odometry.predict` returns them, and (P,) bool: True where the pair's input
        (e.g. its optical flow) fits one rigid motion, False where it does not and the motion is not to be used."""
        ...


MAX_TRANSLATION_M = 1e6
"""Largest translation an odometry may answer for one pair, metres: beyond it the chained trajectory, its
metrics and its plot overflow (1e200 m squared is infinite), and no camera moves 1000 km between frames."""


def check_prediction(odometry_name: str, pairs: SequenceT[tuple[int, int]], mean6, std6) -> tuple[np.ndarray, np.ndarray]:
    """Validate an odometry answer; returns (mean6, std6) as float64 (P, 6).

    Raises ValueError naming the odometry when shapes are wrong or values are not finite, or a std is
    not positive (a programming error in the model, not bad user input).
    """
    p = len(pairs)
    mean6 = np.asarray(mean6, dtype=np.float64)
    std6 = np.asarray(std6, dtype=np.float64)
    for what, arr in (("mean6", mean6), ("std6", std6)):
        if arr.shape != (p, 6):
            raise ValueError(f"odometry {odometry_name!r}: {what} has shape {arr.shape}, expected ({p}, 6)")
        if not np.isfinite(arr).all():
            bad = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
            raise ValueError(f"odometry {odometry_name!r}: {what} is not finite for pair {tuple(pairs[bad])}")
    if (std6 <= 0).any():
        bad = int(np.flatnonzero((std6 <= 0).any(axis=1))[0])
        raise ValueError(f"odometry {odometry_name!r}: std6 must be > 0, got {std6[bad]} for pair {tuple(pairs[bad])}")
    far = np.abs(mean6[:, 3:]).max(axis=1) > MAX_TRANSLATION_M if p else np.zeros(0, bool)
    if far.any():
        bad = int(np.flatnonzero(far)[0])
        raise ValueError(f"odometry {odometry_name!r}: a translation of {np.abs(mean6[bad, 3:]).max():.3g} m for pair "
                         f"{tuple(pairs[bad])}; at most {MAX_TRANSLATION_M:g} m between two frames")
    return mean6, std6


@dataclasses.dataclass(frozen=True)
class NoiseConfig:
    """Noise of :class:`GroundTruthOdometry`, per pair, in the paper's 6DoF vector order."""

    std6: tuple[float, float, float, float, float, float] = (0.002, 0.002, 0.002, 0.02, 0.02, 0.02)
    """True std of the Gaussian noise added to (euler x, y, z [rad], t x, y, z [m])."""
    bias6: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    """Constant added to every pair's vector (rad, m); along consecutive pairs it becomes drift."""
    claimed_std_scale: tuple[float, float, float, float, float, float] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    """The std the odometry reports is ``claimed_std_scale * std6`` (1 = honest uncertainty)."""
    seed: int = 0
    """Seed of the noise; the noise of pair (i, j) depends only on (seed, i, j), not on call order."""


class GroundTruthOdometry:
    """Odometry from ground truth plus seeded noise: implements :class:`Odometry`.

    Args:
        noise: the noise model.
        gt: poses to use instead of ``seq.gt`` (e.g. synthetic trajectories without images).
        name: shown in reports.
    """

    def __init__(self, noise: NoiseConfig = NoiseConfig(), gt: Trajectory | None = None, name: str = "gt-noisy"):
        self.noise = noise
        self.gt = gt
        self.name = name

    def predict(self, seq, pairs: SequenceT[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        gt = self.gt if self.gt is not None else getattr(seq, "gt", None)
        if gt is None:
            raise InputError(getattr(seq, "root", None), "the ground-truth odometry needs a sequence with ground truth")
        pairs_arr = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        if len(pairs_arr) and (pairs_arr.min() < 0 or pairs_arr.max() >= len(gt)):
            raise ValueError(f"pair index outside 0..{len(gt) - 1}")
        poses = gt.world_from_cam
        cam_j_from_cam_i = se3.relative(poses[pairs_arr[:, 1]], poses[pairs_arr[:, 0]])
        mean6 = se3.to_euler6(cam_j_from_cam_i).reshape(-1, 6)
        std = np.asarray(self.noise.std6, dtype=np.float64)
        noise = np.empty_like(mean6)
        for k, (i, j) in enumerate(pairs_arr):
            noise[k] = np.random.default_rng([self.noise.seed, int(i), int(j)]).standard_normal(6)
        mean6 = mean6 + np.asarray(self.noise.bias6) + noise * std
        std6 = np.broadcast_to(std * np.asarray(self.noise.claimed_std_scale), mean6.shape).copy()
        return mean6, np.maximum(std6, 1e-12)
