"""slam.reference: the pose graph with an exact loop edge on every revisit of the ground-truth route."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.trajectory import revisit_pairs
from deepslam.slam.posegraph import Edges, PoseGraphConfig, chain
from deepslam.slam.reference import PerfectLoopsConfig, perfect_loops


def _drifting(gt: np.ndarray, bias6) -> Edges:
    """Consecutive edges of ``gt`` with the same small error ``bias6`` on each: a drifting odometry."""
    rel = se3.relative(gt[1:], gt[:-1])                                   # cam_{i+1}_from_cam_i
    mean6 = se3.to_euler6(se3.from_euler6(np.asarray(bias6, float)) @ rel)
    n = len(gt)
    return Edges(np.stack([np.arange(n - 1), np.arange(1, n)], 1), mean6, np.full((n - 1, 6), 0.01))


def _circle(n: int, laps: float) -> np.ndarray:
    step = se3.from_euler6(np.array([0.0, 2 * np.pi * laps / n, 0.0, 0.0, 0.0, 0.5]))
    return np.stack([np.linalg.matrix_power(step, k) for k in range(n)])


def test_perfect_loops_remove_the_drift_of_a_route_driven_twice():
    gt = _circle(160, laps=2.0)                                           # a 6.4 m radius, driven twice
    cons = _drifting(gt, [0.0, 0.004, 0.0, 0.0, 0.0, 0.01])
    got = perfect_loops(gt, cons, min_gap_frames=50, world_from_cam0=gt[0])
    drift = np.linalg.norm(chain(160, cons, gt[0])[:, :3, 3] - gt[:, :3, 3], axis=1).max()
    assert drift > 1.0 and 60 <= len(got.pairs) <= 110
    assert (got.pairs[:, 1] - got.pairs[:, 0] >= 50).all()
    assert np.linalg.norm(got.world_from_cam[:, :3, 3] - gt[:, :3, 3], axis=1).max() < 0.1 * drift


def test_perfect_loops_on_a_route_that_never_comes_back_is_dead_reckoning():
    gt = np.stack([se3.from_rt(np.eye(3), np.array([0.0, 0.0, 0.5 * k])) for k in range(80)])
    cons = _drifting(gt, [0.0, 0.004, 0.0, 0.0, 0.0, 0.01])
    got = perfect_loops(gt, cons, min_gap_frames=10, world_from_cam0=gt[0])
    assert got.pairs.shape == (0, 2)
    np.testing.assert_allclose(got.world_from_cam, chain(80, cons, gt[0]), atol=1e-6)


@pytest.mark.parametrize("config, expect_pairs", [
    (PerfectLoopsConfig(), True),
    (PerfectLoopsConfig(max_distance_m=0.01), False),      # the second lap passes 0.05 m from the first
    (PerfectLoopsConfig(max_angle_deg=1e-3), True),        # the laps' headings agree (to rounding)
])
def test_perfect_loops_revisits_follow_the_config(config, expect_pairs):
    gt = _circle(120, laps=2.0)
    gt[60:, 0, 3] += 0.05                                                 # the second lap 5 cm to the side
    got = perfect_loops(gt, _drifting(gt, np.zeros(6)), min_gap_frames=30, graph=PoseGraphConfig(), config=config)
    assert (len(got.pairs) > 0) == expect_pairs


def test_nearest_revisits_keep_each_frames_nearest_earlier_view():
    """revisit_pairs(nearest_only=True), what perfect_loops ties: one pair per revisiting frame, the nearest of
    its pairs: a camera standing still for 300 frames gives 250 edges, not 31,000."""
    still = np.tile(np.eye(4), (300, 1, 1))
    still[:, 0, 3] = np.linspace(0.0, 0.3, 300)            # creeping forward, 1 mm a frame
    pairs = revisit_pairs(still, 50, 3.0, 20.0, nearest_only=True)
    every = revisit_pairs(still, 50, 3.0, 20.0)
    assert len(every) == 250 * 251 // 2 and len(pairs) == 250
    np.testing.assert_array_equal(pairs[:, 1], np.arange(50, 300))
    np.testing.assert_array_equal(pairs[:, 0], pairs[:, 1] - 50)   # the nearest is the latest one allowed
    assert set(map(tuple, pairs)) <= set(map(tuple, every))
    gt = _circle(120, laps=2.0)
    lap_pairs = revisit_pairs(gt, 30, 3.0, 20.0, nearest_only=True)
    second = lap_pairs[:, 1] >= 60                             # a lap is 60 frames: the same place a lap earlier
    np.testing.assert_array_equal(lap_pairs[second, 0], lap_pairs[second, 1] - 60)
    assert second.sum() == 60 and (lap_pairs[~second, 0] == 0).all()   # nearing the start: the start
    assert revisit_pairs(np.zeros((0, 4, 4)), 5, 1.0, 20.0, nearest_only=True).shape == (0, 2)
