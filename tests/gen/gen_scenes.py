"""Helpers of the gen tests: analytic depth scenes, random motions, a tiny depth sequence in our format."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.ours import OursWriter


def box_scene(camera: PinholeCamera, back_m: float = 10.0, box_m: float = 3.0) -> np.ndarray:
    """(H, W) float32 depth: a fronto-parallel wall at ``back_m`` with a nearer square at ``box_m``."""
    h, w = camera.height, camera.width
    d = np.full((h, w), back_m, np.float32)
    d[h // 4: 3 * h // 4, w // 3: 2 * w // 3] = box_m
    return d


def ground_scene(camera: PinholeCamera, height_m: float = 1.65, sky_rows: int = 2) -> np.ndarray:
    """(H, W) float32 depth of a flat road ``height_m`` below the camera; 0 (no depth) above the horizon."""
    v = np.arange(camera.height, dtype=np.float64)[:, None] - camera.cy
    with np.errstate(divide="ignore"):
        z = np.where(v > sky_rows, camera.fy * height_m / np.maximum(v, 1e-9), 0.0)
    return np.broadcast_to(z, (camera.height, camera.width)).astype(np.float32).copy()


def random_motions(rng: np.random.Generator, n: int, rot_sigma: float = 0.02, t_sigma: float = 0.3) -> np.ndarray:
    """(n, 4, 4) cam1_from_cam0 with small random rotations and translations."""
    return se3.from_euler6(np.concatenate([rng.normal(0, rot_sigma, (n, 3)), rng.normal(0, t_sigma, (n, 3))], axis=1))


def write_depth_sequence(root: Path, n: int = 6, width: int = 40, height: int = 30, seed: int = 0) -> Path:
    """A sequence in our format with depth only (random tilted planes + boxes), no flow: a gen source."""
    rng = np.random.default_rng(seed)
    cam = PinholeCamera.from_fov_y(width, height, 60.0)
    header = {"num_frames": n, "rate_hz": 10.0, "camera": cam.to_dict(), "stereo_baseline_m": None,
              "has": {"rgb_right": False, "depth": True, "flow": False, "mask": False}}
    w = OursWriter(root, header)
    for i in range(n):
        depth = box_scene(cam, back_m=float(rng.uniform(6, 20)), box_m=float(rng.uniform(2, 5)))
        depth *= (1.0 + 0.02 * np.arange(width, dtype=np.float32)[None, :] / width)
        depth[0, :3] = 0.0  # a few pixels without depth
        pose = se3.from_euler6([0, 0, 0, 0, 0, float(i)])
        w.write_frame(i, i / 10.0, pose, np.zeros((height, width, 3), np.uint8), depth=depth)
    w.finish()
    return root


