"""A user's test suite for their odometry against perfect ground truth (run: ``pytest examples``)."""
from __future__ import annotations

import numpy as np

from deepslam.core import se3
from deepslam.testing import assert_relative_motion_close, assert_trajectory_close
from my_odometry import make


def _trajectory(seq) -> np.ndarray:
    """world_from_cam (N, 4, 4) chained from the odometry's relative motions, starting at the first frame."""
    mean6, _ = make().predict(seq, [(i, i + 1) for i in range(len(seq) - 1)])
    poses = [np.eye(4)]
    for cam_j_from_cam_i in se3.from_euler6(mean6):
        poses.append(poses[-1] @ se3.inverse(cam_j_from_cam_i))
    return np.asarray(poses)


def _gt(seq) -> np.ndarray:
    return se3.inverse(seq.gt.world_from_cam[0]) @ seq.gt.world_from_cam


def test_static_street_is_exact(sim_sequence):
    seq = sim_sequence(scene="street", frames=6, width=160)
    assert_relative_motion_close(_gt(seq), _trajectory(seq), trans_m=0.01, rot_deg=0.1)
    assert_trajectory_close(_gt(seq), _trajectory(seq), ate_m=0.01)


def test_room_drone_is_exact(sim_sequence):
    seq = sim_sequence(scene="room", frames=6, width=160)
    assert_trajectory_close(_gt(seq), _trajectory(seq), ate_m=0.01)
