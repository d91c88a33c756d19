"""core.trajectory: the frame pairs that see the same place again."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.trajectory import revisit_pairs


def _out_and_back(n: int = 60, turn: bool = False) -> np.ndarray:
    """Out along x and back (n frames, 1 m apart); ``turn``: the way back faces the other way."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.r_[np.arange(n // 2), np.arange(n // 2)[::-1]] * 1.0
    if turn:
        poses[n // 2:, :3, :3] = se3.from_euler6(np.array([0.0, np.pi, 0.0, 0.0, 0.0, 0.0]))[:3, :3]
    return poses


def test_revisits_are_near_far_apart_in_time_and_ordered():
    poses = _out_and_back()
    pairs = revisit_pairs(poses, min_gap_frames=20, max_distance_m=1.0, max_angle_deg=20.0)
    assert len(pairs) > 0 and pairs.dtype == np.int64
    assert (pairs[:, 1] - pairs[:, 0] >= 20).all()
    assert (np.abs(poses[pairs[:, 0], 0, 3] - poses[pairs[:, 1], 0, 3]) <= 1.0).all()
    assert np.array_equal(pairs, pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))])
    # every pair within the thresholds is there: the brute force agrees
    brute = [(i, j) for i in range(60) for j in range(i + 20, 60) if abs(poses[i, 0, 3] - poses[j, 0, 3]) <= 1.0]
    assert [tuple(p) for p in pairs] == brute


@pytest.mark.parametrize("poses, gap, dist, angle", [
    (_out_and_back(turn=True), 20, 1.0, 20.0),      # the way back faces the other way: not a revisit
    (_out_and_back(), 60, 1.0, 20.0),                # the gap is the whole route
    (_out_and_back()[:25], 20, 1.0, 20.0),           # never back
    (np.zeros((0, 4, 4)), 5, 1.0, 20.0),             # no frames
])
def test_no_revisit(poses, gap, dist, angle):
    assert revisit_pairs(poses, gap, dist, angle).shape == (0, 2)


def test_a_gap_of_zero_never_pairs_a_frame_with_itself():
    pairs = revisit_pairs(_out_and_back(), 0, 0.0, 0.0)
    assert len(pairs) and (pairs[:, 1] > pairs[:, 0]).all()
