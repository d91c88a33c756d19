"""Depth and projection conventions of both render backends against known geometry."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.scenes.testing import looking_along_y, marker_scene, plane_scene
from deepslam.sim import KeyframeMotion, RenderConfig, SimConfig, Simulator, TrajectoryConfig

BACKENDS = ["mujoco", "pyrender"]
CAM = PinholeCamera(96, 64, 70.0, 70.0, 47.5, 31.5)


def _render(scene, backend, camera=CAM, world_from_cam=None):
    motion = KeyframeMotion(np.array([0.0]), (looking_along_y() if world_from_cam is None else world_from_cam)[None], 10.0)
    cfg = SimConfig(trajectory=TrajectoryConfig(frames=1), render=RenderConfig(backend=backend, width=camera.width,
                    height=camera.height, stereo_baseline_m=0.0, flow=False))
    scene.camera = camera
    with Simulator(cfg, scene=scene, motion=motion) as sim:
        assert sim.camera == camera
        return sim.frame(0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_fronto_parallel_plane_renders_its_distance(backend):
    distance = 3.7
    f = _render(plane_scene(distance, px_per_m=10), backend)
    assert (f.body == 0).all()
    tol = 1e-5 if backend == "mujoco" else 1e-4
    np.testing.assert_allclose(f.depth_z, distance, atol=tol, rtol=0)


def _plane_depth(camera, world_from_cam, normal_w, point_w):
    """Analytic depth_z of the plane n.(p - p0) = 0 along every pixel ray."""
    cam_from_world = se3.inverse(world_from_cam)
    n = cam_from_world[:3, :3] @ normal_w
    p0 = se3.transform_points(cam_from_world, point_w[None])[0]
    g = camera.pixel_grid()
    rays = np.stack([(g[..., 0] - camera.cx) / camera.fx, (g[..., 1] - camera.cy) / camera.fy, np.ones(g.shape[:2])], -1)
    return (n @ p0) / (rays @ n)


@pytest.mark.parametrize("backend", BACKENDS)
def test_tilted_plane_depth_matches_pixel_centre_rays(backend):
    """Depth of a strongly tilted plane at every pixel equals the analytic depth along the ray
    through that pixel's centre (u, v integers): a half-pixel error in the principal point or a
    wrong focal length would show up as centimetres here."""
    rot = Rotation.from_euler("zx", [35.0, 25.0], degrees=True).as_matrix()
    scene = plane_scene(3.0, rotation=rot, px_per_m=10)
    f = _render(scene, backend)
    assert (f.body == 0).all()
    expected = _plane_depth(CAM, f.world_from_cam, rot @ np.array([0, -1.0, 0]), np.array([0, 3.0, 0]))
    err = np.abs(f.depth_z - expected)
    # MuJoCo: float reversed-Z depth; pyrender: 24-bit depth, error ~ z^2 / (znear 2^24) (znear 0.05 m)
    tol = 2e-5 * expected if backend == "mujoco" else 1e-5 + 5e-6 * expected ** 2
    assert (err < tol).all(), (err / tol).max()
    # the same comparison with the principal point off by half a pixel fails by far
    shifted = PinholeCamera(CAM.width, CAM.height, CAM.fx, CAM.fy, CAM.cx + 0.5, CAM.cy)
    wrong = _plane_depth(shifted, f.world_from_cam, rot @ np.array([0, -1.0, 0]), np.array([0, 3.0, 0]))
    assert np.abs(f.depth_z - wrong).max() > 50 * err.max()


@pytest.mark.parametrize("backend", BACKENDS)
def test_known_points_render_at_predicted_pixels(backend):
    """A quad whose corners project to (u, v) = (20.3, 10.3) .. (60.7, 40.7) covers exactly the
    pixel centres inside: columns 21..60 and rows 11..40 (0.3 px from every edge, so any
    half-pixel error in either axis changes the covered set)."""
    scene = marker_scene(CAM, (20.3, 10.3, 60.7, 40.7), marker_depth_m=2.0, plane_depth_m=4.0)
    f = _render(scene, backend)
    covered = f.body == 1
    expected = np.zeros_like(covered)
    expected[11:41, 21:61] = True
    assert (covered == expected).all(), np.argwhere(covered != expected)[:5]
    np.testing.assert_allclose(f.depth_z[covered], 2.0, atol=1e-4)
    np.testing.assert_allclose(f.depth_z[~covered], 4.0, atol=1e-4)
    # the marker is red, the plane grey, in the colour image too (interior pixels)
    assert (f.rgb[13:39, 23:59, 0] > 200).all() and (f.rgb[13:39, 23:59, 1] < 80).all()
    assert (np.abs(f.rgb[~covered].astype(int) - 90) < 20).mean() > 0.95


@pytest.mark.parametrize("backend", BACKENDS)
def test_texture_orientation_matches_atlas(backend):
    """A fronto-parallel plane filling the view shows its texture upright and unmirrored: the
    rendered image correlates with the atlas region resampled to the image, not with its flips."""
    import cv2

    distance = 2.0
    scene = plane_scene(distance, half_size_m=0.5, px_per_m=80)
    # a camera whose view is exactly the plane's 1 m x 1 m front face at 2 m: f = 64 px * 2 m / 1 m
    cam = PinholeCamera(64, 64, 128.0, 128.0, 31.5, 31.5)
    f = _render(scene, backend, camera=cam)
    m = scene.bodies[0].mesh
    # the front face is the first quad (face "-y"), its texcoords give the atlas rectangle
    st = m.texcoords[:4]
    ah, aw = scene.atlas.shape[:2]
    x0, x1 = st[:, 0].min() * aw, st[:, 0].max() * aw
    y0, y1 = st[:, 1].min() * ah, st[:, 1].max() * ah
    region = scene.atlas[int(round(y0)):int(round(y1)), int(round(x0)):int(round(x1))]
    ref = cv2.resize(region, (64, 64), interpolation=cv2.INTER_AREA).astype(np.float64).mean(-1)
    img = f.rgb.astype(np.float64).mean(-1)

    def ncc(a, b):
        a, b = a - a.mean(), b - b.mean()
        return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))

    c = ncc(img, ref)
    assert c > 0.9, c
    assert c > ncc(img, ref[::-1]) + 0.2 and c > ncc(img, ref[:, ::-1]) + 0.2
