"""core.camera: projection round trips, K, scaling with the pixel-centre convention, GL <-> CV axes."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.camera import (CV_FROM_GL, GL_FROM_CV, PinholeCamera, world_from_cam_cv_from_gl,
                         world_from_cam_gl_from_cv)

CAM = PinholeCamera(160, 120, fx=140.0, fy=138.0, cx=79.3, cy=61.2)


def test_project_unproject_round_trip():
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [160, 120], size=(500, 2))
    z = rng.uniform(0.5, 80.0, size=500)
    p_cam = CAM.unproject(uv, z)
    np.testing.assert_allclose(p_cam[:, 2], z)
    uv2, z2 = CAM.project(p_cam)
    np.testing.assert_allclose(uv2, uv, atol=1e-10)
    np.testing.assert_allclose(z2, z)
    # whole image grid
    grid = CAM.pixel_grid()
    assert grid.shape == (120, 160, 2) and tuple(grid[5, 7]) == (7.0, 5.0)
    uv3, _ = CAM.project(CAM.unproject(grid, np.full((120, 160), 3.0)))
    np.testing.assert_allclose(uv3, grid, atol=1e-10)


def test_k_and_projection_against_k():
    k = CAM.k
    np.testing.assert_array_equal(k, [[140.0, 0, 79.3], [0, 138.0, 61.2], [0, 0, 1]])
    p = np.array([0.4, -0.3, 2.0])
    h = k @ p
    uv, z = CAM.project(p)
    np.testing.assert_allclose(uv, h[:2] / h[2])
    assert z == 2.0
    assert PinholeCamera.from_k(k, 160, 120) == CAM


def test_fov_and_dict_round_trip():
    cam = PinholeCamera.from_fov_y(640, 480, 60.0)
    assert cam.fov_y_deg == pytest.approx(60.0)
    assert (cam.cx, cam.cy) == (319.5, 239.5)
    assert PinholeCamera.from_dict(cam.to_dict()) == cam
    with pytest.raises(ValueError):
        PinholeCamera(0, 10, 1.0, 1.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        PinholeCamera(10, 10, -1.0, 1.0, 0.0, 0.0)


def test_scaled_keeps_pixel_centre_convention():
    half = CAM.scaled(80, 60)
    p = np.array([[0.3, 0.2, 4.0], [-1.0, 0.5, 10.0]])
    uv_full, _ = CAM.project(p)
    uv_half, _ = half.project(p)
    # pixel u covers [u - 0.5, u + 0.5]: its left edge -0.5 maps to -0.5, so u' = (u + 0.5) s - 0.5
    np.testing.assert_allclose(uv_half, (uv_full + 0.5) * 0.5 - 0.5, atol=1e-12)
    assert half.fov_y_deg == pytest.approx(CAM.fov_y_deg)
    assert CAM.scaled(160, 120) == CAM


def test_gl_cv_round_trip_and_axes():
    rng = np.random.default_rng(1)
    world_from_cam_cv = se3.from_euler6(rng.normal(size=(6, 6)))
    gl = world_from_cam_gl_from_cv(world_from_cam_cv)
    np.testing.assert_allclose(world_from_cam_cv_from_gl(gl), world_from_cam_cv, atol=1e-15)
    np.testing.assert_array_equal(GL_FROM_CV @ CV_FROM_GL, np.eye(4))
    # the same camera: the CV optical axis (+z) is GL's -z, CV's down (+y) is GL's -y
    np.testing.assert_allclose(gl[:, :3, 3], world_from_cam_cv[:, :3, 3])
    np.testing.assert_allclose(gl[:, :3, 2], -world_from_cam_cv[:, :3, 2])
    np.testing.assert_allclose(gl[:, :3, 1], -world_from_cam_cv[:, :3, 1])
    np.testing.assert_allclose(gl[:, :3, 0], world_from_cam_cv[:, :3, 0])
    assert np.all(np.linalg.det(gl[:, :3, :3]) > 0)


def test_ray_depth_conversion():
    z = np.full((120, 160), 5.0)
    ray = CAM.ray_depth_from_z(z)
    assert ray.min() >= 5.0
    v, u = 61, 79  # nearest pixel to the principal point: ray ~= z
    assert ray[v, u] == pytest.approx(5.0, rel=1e-4)
    p = CAM.unproject(CAM.pixel_grid(), z)
    np.testing.assert_allclose(ray, np.linalg.norm(p, axis=-1), rtol=1e-12)
    np.testing.assert_allclose(CAM.z_from_ray_depth(ray), z, rtol=1e-12)


def test_principal_point_offset_from_the_image_centre():
    """(cx - (W - 1) / 2, cy - (H - 1) / 2): zero for a centred camera, KITTI 04-12's left of and above its centre."""
    assert PinholeCamera.from_fov_y(414, 125, 50.0).principal_point_offset == (0.0, 0.0)
    dx, dy = PinholeCamera(1226, 370, 707.0912, 707.0912, 601.8873, 183.1104).principal_point_offset
    assert abs(dx + 10.6127) < 1e-9 and abs(dy + 1.3896) < 1e-9
