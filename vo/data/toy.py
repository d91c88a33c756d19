"""Toy training data: flow of known motions over planes, computed with :mod:`core.camera` alone
(tests, benchmarks, smoke runs), and the analytic flow of one depth map under one motion."""
from __future__ import annotations

from typing import Callable

import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera

def plane_depth(camera: PinholeCamera, normal_cam: np.ndarray, distance_m: float) -> np.ndarray:
    """depth_z (H, W) float32 of the plane ``{p : normal . p = distance}`` seen by ``camera``.

    normal_cam: (3,) unit normal in camera axes pointing away from the camera (e.g. (0, 0, 1) for a
    fronto-parallel wall, (0, 1, 0) for a floor below). Pixels whose ray misses the plane get 0.
    """
    g = camera.pixel_grid()
    rays = np.stack([(g[..., 0] - camera.cx) / camera.fx, (g[..., 1] - camera.cy) / camera.fy,
                     np.ones(g.shape[:2])], axis=-1)
    denom = rays @ np.asarray(normal_cam, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(denom > 1e-6, distance_m / denom, 0.0)
    return z.astype(np.float32)


def flow_from_depth_np(camera: PinholeCamera, depth_z: np.ndarray, cam1_from_cam0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference flow (H, W, 2) float32 px and valid (H, W) bool from one depth map and one motion.

    Unproject with depth_z (m, 0 = none), move by ``cam1_from_cam0`` (4, 4), reproject, subtract the
    grid; invalid (no depth, behind the camera, outside the image) pixels get flow 0.
    """
    g = camera.pixel_grid()
    p0 = camera.unproject(g, depth_z)
    p1 = p0 @ cam1_from_cam0[:3, :3].T + cam1_from_cam0[:3, 3]
    uv1, z1 = camera.project(p1)
    flow = uv1 - g
    valid = (depth_z > 0) & (z1 > 1e-6) & np.isfinite(flow).all(-1)
    valid &= (uv1[..., 0] >= -0.5) & (uv1[..., 0] <= camera.width - 0.5)
    valid &= (uv1[..., 1] >= -0.5) & (uv1[..., 1] <= camera.height - 0.5)
    flow = np.where(valid[..., None], flow, 0.0)
    return flow.astype(np.float32), valid


def toy_motion_sampler(rot_std_rad: float = 0.01, trans_std_m: float = 0.1, forward_m: tuple[float, float] = (0.0, 1.0)):
    """A simple motion model: euler ~ N(0, rot_std), t_x, t_y ~ N(0, trans_std), t_z ~ -U(forward_m).

    Returns ``sample(n, rng) -> (n, 6) float64`` paper vectors of cam1_from_cam0 (the camera moves
    forward, so scene points move towards it: t_z of cam1_from_cam0 is negative).
    """

    def sample(n: int, rng: np.random.Generator) -> np.ndarray:
        out = np.empty((n, 6))
        out[:, :3] = rng.normal(0.0, rot_std_rad, (n, 3))
        out[:, 3:5] = rng.normal(0.0, trans_std_m, (n, 2))
        out[:, 5] = -rng.uniform(*forward_m, n)
        return out

    return sample


def toy_plane_samples(n: int, camera: PinholeCamera, rng: np.random.Generator,
                      sample_motion: Callable[[int, np.random.Generator], np.ndarray] | None = None,
                      camera_height_m: tuple[float, float] = (1.5, 1.8), tilt_std_rad: float = 0.03) -> dict[str, np.ndarray]:
    """``n`` samples of flow over a ground plane (a car's view of a flat road) for random motions.

    The plane lies ``camera_height_m`` below the camera (a narrow range, so that the flow fixes the
    metric scale, as the road does for a car), its normal tilted by ``tilt_std_rad``; the pixels
    above the horizon see nothing (flow 0, invalid).

    Args:
        n: number of samples.
        camera: the network-resolution camera (flows are computed at its size directly).
        rng: the generator all randomness comes from.
        sample_motion: ``(n, rng) -> (n, 6)`` paper vectors of cam1_from_cam0; :func:`toy_motion_sampler` by default.

    Returns dict of numpy arrays: ``flow`` (n, 2, H, W) float32 px, ``valid`` (n, H, W) bool,
    ``intrinsics`` (n, 4) float32, ``target`` (n, 6) float32.
    """
    sample_motion = sample_motion or toy_motion_sampler()
    vec6 = sample_motion(n, rng)
    motions = se3.from_euler6(vec6)
    flows = np.zeros((n, 2, camera.height, camera.width), np.float32)
    valid = np.zeros((n, camera.height, camera.width), bool)
    for i in range(n):
        normal = np.array([rng.normal(0, tilt_std_rad), 1.0, rng.normal(0, tilt_std_rad)])
        normal /= np.linalg.norm(normal)
        depth = plane_depth(camera, normal, rng.uniform(*camera_height_m))
        depth[depth > 200.0] = 0.0  # near the horizon: too far to matter
        f, v = flow_from_depth_np(camera, depth, motions[i])
        flows[i] = f.transpose(2, 0, 1)
        valid[i] = v
    k = camera.intrinsics(np.float32)
    return {"flow": flows, "valid": valid, "intrinsics": np.tile(k, (n, 1)), "target": vec6.astype(np.float32)}
