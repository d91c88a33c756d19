"""What loop closure gives on a route: the pose graph with an exact loop edge on every revisit.

Given the ground truth, :func:`perfect_loops` solves the SLAM's own graph (the same consecutive edges, the same
C_s and C_r) with its loop edges replaced by the ground truth's relative pose from every frame that sees a place
again to the nearest earlier view of it (:func:`core.trajectory.revisit_pairs` with ``nearest_only``: one edge a
frame, as the SLAM's own search keeps one loop a query, so that a camera standing still adds n edges, not n^2).
Its ATE tells a SLAM that misses or mismeasures loops from a route that has few revisits: on a route that closes
one cycle, a drift-like odometry error keeps most of its size whatever the loops
(docs/experiments/2026-12-05_slam_reach.md).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from deepslam.core import metrics
from deepslam.core.trajectory import Trajectory, revisit_pairs
from deepslam.slam.posegraph import Edges, PoseGraphConfig, optimize


@dataclasses.dataclass(frozen=True)
class PerfectLoopsConfig:
    """Which frames count as revisits, and the weight of their exact edges."""

    max_distance_m: float = 3.0
    """Revisits: camera centres at most this far apart, metres."""
    max_angle_deg: float = 20.0
    """Revisits: relative rotation at most this, degrees."""
    std6: tuple[float, ...] = (1e-3, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2)
    """Std of the exact loop edges in the graph (rad x3, m x3): tight against any odometry's."""
    opposite_max_distance_m: float = 6.0
    """Revisits the opposite way: camera centres at most this far apart, metres (the other lane, 3.5 m over)."""
    opposite_min_angle_deg: float = 160.0
    """Revisits the opposite way: relative rotation at least this, degrees."""


@dataclasses.dataclass(frozen=True)
class PerfectLoops:
    """Outcome of :func:`perfect_loops`.

    Attributes:
        world_from_cam: (N, 4, 4) float64 optimised poses (world_from_cam, OpenCV camera axes, metres).
        pairs: (P, 2) int64 the revisit pairs (i, j), i < j, that got an exact loop edge (at most one per frame j).
    """

    world_from_cam: np.ndarray
    pairs: np.ndarray


def perfect_loops(gt_world_from_cam: np.ndarray, cons: Edges, min_gap_frames: int,
                  graph: PoseGraphConfig = PoseGraphConfig(), config: PerfectLoopsConfig = PerfectLoopsConfig(),
                  world_from_cam0: np.ndarray | None = None, both_ways: bool = False) -> PerfectLoops:
    """The graph of ``cons`` with an exact loop edge on every revisit of the ground-truth route, each revisiting
    frame tied to its nearest earlier view (:func:`core.trajectory.revisit_pairs` with ``nearest_only``).

    Args:
        gt_world_from_cam: (N, 4, 4) float64 ground-truth poses, one per graph node (frame).
        cons: the consecutive edges (i, i+1) of the SLAM being judged (its odometry).
        min_gap_frames: revisits are at least this many frames apart (the SLAM's T_loop).
        graph: pose-graph settings (the SLAM's own, with its C_s and C_r).
        config: what counts as a revisit, and the exact edges' std.
        world_from_cam0: (4, 4) pose of the first node (None: the identity).
        both_ways: also an exact edge on every revisit the opposite way (:func:`opposite_revisits`), which
            appearance-based retrieval of the same view cannot find.

    Returns:
        :class:`PerfectLoops`; on a route with no revisit, the graph equals dead reckoning of ``cons``.
    """
    gt = np.asarray(gt_world_from_cam, np.float64)
    pairs = revisit_pairs(gt, min_gap_frames, config.max_distance_m, config.max_angle_deg, nearest_only=True)
    if both_ways:
        pairs = np.concatenate([pairs, opposite_revisits(gt, min_gap_frames, config)])
    loops = Edges.from_poses(gt, pairs, config.std6)
    return PerfectLoops(optimize(len(gt), cons, loops, graph, world_from_cam0).world_from_cam, pairs)


def perfect_loops_record(seq, cons: Edges, t_loop: int, graph: PoseGraphConfig, align: str = "se3",
                         config: PerfectLoopsConfig = PerfectLoopsConfig()) -> dict | None:
    """``{"ate_m", "revisit_pairs", "max_distance_m", "max_angle_deg"}`` of :func:`perfect_loops` on ``seq`` (ATE
    ``align``-aligned, metres), the first pose at the ground truth's as in :func:`slam.pipeline.run_slam`; None
    where the sequence's ground truth does not give every frame a pose (TUM's motion capture starting late).

    Args:
        seq: a :class:`core.sequence.Sequence` with ``gt``.
        cons: the SLAM's consecutive edges (its odometry).
        t_loop: the SLAM's T_loop: revisits are at least this many frames apart.
        graph: the SLAM's pose-graph settings, its C_s and C_r in them.
    """
    gt = getattr(seq, "gt", None)
    if gt is None or getattr(seq, "gt_frames", None) is not None or len(gt) != len(cons) + 1:
        return None
    got = perfect_loops(gt.world_from_cam, cons, t_loop, graph, config, gt.world_from_cam[0])
    ate = metrics.evaluate(gt, Trajectory(got.world_from_cam, gt.timestamps_s), align=align)["ate_m"]
    record = {"ate_m": ate, "revisit_pairs": int(len(got.pairs)), "max_distance_m": config.max_distance_m,
              "max_angle_deg": config.max_angle_deg}
    opposite = opposite_revisits(gt.world_from_cam, t_loop, config)
    record["opposite_revisit_pairs"] = int(len(opposite))
    if len(opposite):
        both = perfect_loops(gt.world_from_cam, cons, t_loop, graph, config, gt.world_from_cam[0], both_ways=True)
        record["ate_both_ways_m"] = metrics.evaluate(gt, Trajectory(both.world_from_cam, gt.timestamps_s),
                                                     align=align)["ate_m"]
    return record


def opposite_revisits(gt_world_from_cam: np.ndarray, min_gap_frames: int,
                      config: PerfectLoopsConfig = PerfectLoopsConfig()) -> np.ndarray:
    """(P, 2) int64 frame pairs (i, j), i < j, where the camera passes again the opposite way (the other lane of
    the same road): centres within ``config.opposite_max_distance_m``, optical axes at least
    ``config.opposite_min_angle_deg`` apart, at least ``min_gap_frames`` apart; one pair a later frame."""
    return revisit_pairs(gt_world_from_cam, min_gap_frames, config.opposite_max_distance_m, 180.0, nearest_only=True,
                         min_angle_deg=config.opposite_min_angle_deg)


def loops_by_direction(gt_world_from_cam: np.ndarray, pairs: np.ndarray) -> dict:
    """How many loop pairs (P, 2) (i, j) join views the same way (ground-truth optical axes under 90 degrees
    apart) and the opposite way: ``{"same": n, "opposite": n}``."""
    gt = np.asarray(gt_world_from_cam, np.float64)
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    if not len(pairs):
        return {"same": 0, "opposite": 0}
    cos = np.einsum("ij,ij->i", gt[pairs[:, 0], :3, 2], gt[pairs[:, 1], :3, 2])
    return {"same": int((cos >= 0).sum()), "opposite": int((cos < 0).sum())}
