"""core.se3 against explicit matrices: inverse, composition order, euler6 (R = Rz Ry Rx), quaternion orders."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepslam.core import se3


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _random_poses(rng, n):
    rot = Rotation.random(n, random_state=int(rng.integers(1 << 31))).as_matrix()
    return se3.from_rt(rot, rng.normal(scale=10.0, size=(n, 3)))


def test_inverse_and_composition():
    rng = np.random.default_rng(0)
    a_from_b, b_from_c = _random_poses(rng, 8), _random_poses(rng, 8)
    np.testing.assert_allclose(a_from_b @ se3.inverse(a_from_b), np.broadcast_to(np.eye(4), (8, 4, 4)), atol=1e-12)
    np.testing.assert_allclose(se3.inverse(se3.inverse(a_from_b)), a_from_b, atol=1e-12)
    np.testing.assert_allclose(se3.inverse(a_from_b), np.linalg.inv(a_from_b), atol=1e-12)
    p_c = rng.normal(size=(8, 5, 3))
    a_from_c = se3.compose(a_from_b, b_from_c)
    np.testing.assert_allclose(se3.transform_points(a_from_c, p_c),
                               se3.transform_points(a_from_b, se3.transform_points(b_from_c, p_c)), atol=1e-10)
    # inverse of a composition reverses the order
    np.testing.assert_allclose(se3.inverse(a_from_c), se3.inverse(b_from_c) @ se3.inverse(a_from_b), atol=1e-12)


def test_transform_points_single_pose_and_relative():
    world_from_a = se3.from_rt(_rz(np.pi / 2), [1.0, 0.0, 0.0])
    # a point 1 m along a's x lies 1 m along world y from a's origin
    np.testing.assert_allclose(se3.transform_points(world_from_a, np.array([[1.0, 0.0, 0.0]])), [[1.0, 1.0, 0.0]],
                               atol=1e-15)
    world_from_b = se3.from_rt(np.eye(3), [1.0, 2.0, 0.0])
    a_from_b = se3.relative(world_from_a, world_from_b)
    np.testing.assert_allclose(world_from_a @ a_from_b, world_from_b, atol=1e-15)
    np.testing.assert_allclose(a_from_b[:3, 3], [2.0, 0.0, 0.0], atol=1e-15)  # b is 2 m along a's x


def test_euler6_is_rz_ry_rx_and_round_trips():
    ex, ey, ez = 0.3, -0.2, 1.1
    t = np.array([1.0, -2.0, 3.0])
    pose = se3.from_euler6(np.array([ex, ey, ez, *t]))
    np.testing.assert_allclose(pose[:3, :3], _rz(ez) @ _ry(ey) @ _rx(ex), atol=1e-14)
    np.testing.assert_allclose(pose[:3, 3], t)
    np.testing.assert_allclose(se3.to_euler6(pose), [ex, ey, ez, *t], atol=1e-14)
    rng = np.random.default_rng(1)
    v = np.concatenate([rng.uniform(-1.2, 1.2, size=(20, 3)), rng.normal(size=(20, 3))], axis=1)
    np.testing.assert_allclose(se3.to_euler6(se3.from_euler6(v)), v, atol=1e-12)
    assert se3.from_euler6(v.reshape(4, 5, 6)).shape == (4, 5, 4, 4)


def test_quaternion_orders():
    # 90 deg about z: (w, x, y, z) = (c, 0, 0, s)
    c = s = np.sqrt(0.5)
    q_wxyz, q_xyzw = np.array([c, 0, 0, s]), np.array([0, 0, s, c])
    a = se3.from_quat_wxyz(q_wxyz, [1.0, 2.0, 3.0])
    b = se3.from_quat_xyzw(q_xyzw, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(a, b, atol=1e-15)
    np.testing.assert_allclose(a[:3, :3], _rz(np.pi / 2), atol=1e-15)
    np.testing.assert_allclose(se3.to_quat_wxyz(a), q_wxyz, atol=1e-15)
    np.testing.assert_allclose(se3.to_quat_xyzw(a), q_xyzw, atol=1e-15)
    # w >= 0 and round trip for random rotations
    poses = _random_poses(np.random.default_rng(2), 30)
    q = se3.to_quat_wxyz(poses)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(se3.from_quat_wxyz(q, poses[:, :3, 3]), poses, atol=1e-12)
    np.testing.assert_allclose(se3.from_quat_wxyz(-q, poses[:, :3, 3]), poses, atol=1e-12)  # q and -q


def test_rotation_angle_and_so3_helpers():
    for ang in (0.0, 1e-6, 0.5, np.pi - 1e-3, np.pi):
        pose = se3.from_rt(Rotation.from_rotvec(ang * np.array([1.0, 2.0, 2.0]) / 3).as_matrix(), np.zeros(3))
        assert se3.rotation_angle(pose) == pytest.approx(ang, abs=2e-8)
    r = _rz(0.4) @ _rx(0.3)
    assert se3.orthonormality_error(r) < 1e-14
    bad = r + 1e-3
    assert se3.orthonormality_error(bad) > 1e-4
    fixed = se3.project_to_so3(bad)
    assert se3.orthonormality_error(fixed) < 1e-14 and np.abs(fixed - r).max() < 2e-3
    assert se3.orthonormality_error(np.diag([1.0, 1.0, -1.0])) == pytest.approx(2.0)  # reflection: det = -1
