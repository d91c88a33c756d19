"""Supervised training samples: flow between real frames of a sequence (estimated or ground truth) at
network resolution + the ground-truth relative poses of the pairs (:func:`frame_pairs` chooses them)."""
from __future__ import annotations

import dataclasses

import numpy as np
from tqdm import tqdm

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.trajectory import revisit_pairs
from deepslam.flow.estimators import to_network_input
from deepslam.vo.data.frames import frame_inverse_depth

@dataclasses.dataclass(frozen=True)
class PairSpec:
    """Which frame pairs of a sequence become supervised samples."""

    strides: tuple[int, ...] = (1,)
    """Frame gaps k of the pairs (i, i + k) (``consecutive`` mode); several = a mixture."""
    kind: str = "consecutive"
    """``consecutive`` (pairs i, i + k) or ``loops`` (pairs far apart in time that see the same place)."""
    loop_min_gap_frames: int = 20
    """Loops: the two frames are at least this many frames apart."""
    loop_max_distance_m: float = 3.0
    """Loops: camera centres at most this far apart, metres."""
    loop_max_angle_deg: float = 20.0
    """Loops: relative rotation at most this, degrees."""
    max_pairs: int = 0
    """Keep at most this many pairs per sequence (evenly spaced; 0 = all)."""


def frame_pairs(gt_world_from_cam: np.ndarray, spec: PairSpec) -> np.ndarray:
    """(P, 2) int frame index pairs (i, j), i < j, of one sequence per ``spec``."""
    n = len(gt_world_from_cam)
    if spec.kind == "consecutive":
        pairs = [(i, i + k) for k in spec.strides for i in range(n - k)]
    elif spec.kind == "loops":
        pairs = revisit_pairs(gt_world_from_cam, spec.loop_min_gap_frames, spec.loop_max_distance_m,
                              spec.loop_max_angle_deg)
    else:
        raise InputError(None, f"unknown pair kind {spec.kind!r} (consecutive or loops)")
    pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    if spec.max_pairs and len(pairs) > spec.max_pairs:
        pairs = pairs[np.linspace(0, len(pairs) - 1, spec.max_pairs).round().astype(int)]
    return pairs


def supervised_samples(seq, pairs: np.ndarray, estimator, width: int, height: int, progress: bool = True,
                       unknown: str = "zero", inv_depth: bool = False) -> dict[str, np.ndarray]:
    """Flow between frame pairs of a sequence with ground truth, at network resolution, + targets.

    Args:
        seq: :class:`core.sequence.Sequence` with ``gt``.
        pairs: (P, 2) frame indices (i, j), each a frame the ground truth covers (``seq.gt_frames`` where
            it does not cover all: TUM).
        estimator: a :mod:`flow.estimators` estimator (``pair_flow(seq, i, j)``).
        width, height: network input size.
        unknown: how unknown flow is resized (:data:`flow.estimators.UNKNOWN_FLOW`: ``nan`` for a
            network with a validity channel).
        inv_depth: also give each pair's first-frame inverse depth as a depth-channel network reads it at test
            time (:func:`vo.data.frames.frame_inverse_depth`).

    Returns ``flow`` (P, 2, height, width) float32 px (NaN where unknown, with ``nan``), ``intrinsics`` (P, 4) float32, ``target``
    (P, 6) float32 = to_euler6(cam_j_from_cam_i), and with ``inv_depth`` ``"inv_depth"`` (P, 1, height, width)
    float32 1/m (0 = unknown).
    """
    if seq.gt is None:
        raise InputError(seq.root, "supervised training needs ground-truth poses; this sequence has none")
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    world_from_cam = [(seq.gt_pose(int(i)), seq.gt_pose(int(j))) for i, j in pairs]  # (w_i, w_j) per pair
    if any(w_i is None or w_j is None for w_i, w_j in world_from_cam):
        raise InputError(seq.root, "a frame pair outside the frames the ground truth covers")
    flows = np.zeros((len(pairs), 2, height, width), np.float32)
    intr = np.zeros((len(pairs), 4), np.float32)
    for p, (i, j) in enumerate(tqdm(pairs, desc=f"flow {seq.name}", unit="pair", disable=not progress, leave=False)):
        flows[p], intr[p] = to_network_input(estimator.pair_flow(seq, int(i), int(j)), seq.camera, width, height,
                                                unknown)
    target = se3.to_euler6(se3.relative(np.stack([w_j for _, w_j in world_from_cam]),
                                        np.stack([w_i for w_i, _ in world_from_cam]))) if len(pairs) else np.zeros((0, 6))
    out = {"flow": flows, "intrinsics": intr, "target": target.astype(np.float32)}
    if inv_depth:
        first = {int(i): frame_inverse_depth(seq, int(i), width, height)
                 for i in tqdm(np.unique(pairs[:, 0]), desc=f"depth {seq.name}", unit="frame", disable=not progress,
                               leave=False)}
        out["inv_depth"] = np.stack([first[int(i)] for i in pairs[:, 0]]) if len(pairs) else \
            np.zeros((0, 1, height, width), np.float32)
    return out
