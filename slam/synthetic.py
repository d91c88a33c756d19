"""Synthetic trajectories with loops and synthetic revisit images, for tests and benchmarks.

- :func:`circle_trajectory`: a camera driving laps of a circle (OpenCV axes, y down, yaw about y),
  so frames i and i + frames_per_lap are revisits of the same place.
- :func:`random_texture` and :func:`plane_homography`: a textured plane seen by a camera that moved a
  little, i.e. the image a camera would see when it comes back to a place with a small offset.
- :func:`write_loop_sequence`: a sequence in our format (rgb + poses) whose image at frame i shows the
  texture of its place on the circle, warped by the homography of a small per-frame camera motion;
  revisits show the same texture, other places unrelated textures.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.ours import OursWriter, read_ours
from deepslam.core.trajectory import Trajectory
from deepslam.slam.odometry import GroundTruthOdometry, NoiseConfig
from deepslam.slam.posegraph import Edges


def circle_trajectory(n_frames: int, radius_m: float = 20.0, laps: float = 2.0, lap_offset_m: float = 0.0,
                      height_amp_m: float = 0.0) -> np.ndarray:
    """(N, 4, 4) world_from_cam along ``laps`` turns of a circle, starting at the origin facing +z.

    Position ``((r)(1 - cos th), h sin(3 th), r sin th)`` with th in [0, 2 pi laps) sampled uniformly
    (``n_frames / laps`` frames per lap, so frame i and i + n_frames / laps are the same place),
    camera z along the direction of travel, y down (world y is "down"), R = Ry(th).
    ``lap_offset_m`` widens the radius by that much per lap (revisits are then slightly offset).
    """
    th = np.arange(n_frames) * (2.0 * np.pi * laps / n_frames)
    r = radius_m + lap_offset_m * th / (2.0 * np.pi)
    pos = np.stack([radius_m - r * np.cos(th), height_amp_m * np.sin(3.0 * th), r * np.sin(th)], axis=1)
    c, s = np.cos(th), np.sin(th)
    rot = np.zeros((n_frames, 3, 3))
    rot[:, 0, 0], rot[:, 0, 2] = c, s
    rot[:, 1, 1] = 1.0
    rot[:, 2, 0], rot[:, 2, 2] = -s, c
    return se3.from_rt(rot, pos)


def random_texture(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """(H, W) uint8 blob texture: white noise blurred at several scales, contrast-stretched."""
    img = np.zeros((height, width), np.float32)
    for sigma, amp in ((1.5, 0.6), (3.0, 1.0), (6.0, 1.0)):
        n = rng.standard_normal((height, width)).astype(np.float32)
        b = cv2.GaussianBlur(n, (0, 0), sigma)
        img += amp * b / (b.std() + 1e-6)
    lo, hi = np.percentile(img, [1, 99])
    return np.clip((img - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8)


def plane_homography(camera_k: np.ndarray, cam_from_ref: np.ndarray, normal_ref=(0.0, 0.0, 1.0),
                     distance_m: float = 5.0) -> np.ndarray:
    """(3, 3) H mapping pixels of the reference camera to the moved camera for the plane n.X = d.

    ``H = K (R + t n^T / d) K^-1`` with (R, t) of ``cam_from_ref`` and the plane in the reference frame.
    """
    k = np.asarray(camera_k, np.float64)
    r, t = cam_from_ref[:3, :3], cam_from_ref[:3, 3]
    h = k @ (r + np.outer(t, np.asarray(normal_ref, np.float64)) / distance_m) @ np.linalg.inv(k)
    return h / h[2, 2]


def small_motion(rng: np.random.Generator, rot_std_rad: float = 0.03, t_std_m: float = 0.15) -> np.ndarray:
    """(4, 4) random cam_from_ref with small rotation and translation."""
    return se3.from_euler6(np.concatenate([rng.normal(0, rot_std_rad, 3), rng.normal(0, t_std_m, 3)]))


def revisit_image(texture: np.ndarray, camera_k: np.ndarray, cam_from_ref: np.ndarray,
                  distance_m: float = 5.0) -> np.ndarray:
    """The texture (a fronto-parallel plane at ``distance_m`` in the reference view) seen after cam_from_ref."""
    h = plane_homography(camera_k, cam_from_ref, distance_m=distance_m)
    return cv2.warpPerspective(texture, h, (texture.shape[1], texture.shape[0]), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REFLECT)


def write_loop_sequence(root: str | Path, n_frames: int = 120, laps: float = 2.0, width: int = 160, height: int = 120,
                        radius_m: float = 10.0, lap_offset_m: float = 0.0, rate_hz: float = 10.0, seed: int = 0):
    """Write a sequence in our format with revisits every ``n_frames / laps`` frames; returns it opened.

    Images: frame i shows the texture of place ``i mod frames_per_lap`` (seeded by (seed, place)) warped
    by a small random camera motion seeded by (seed, i). Poses: :func:`circle_trajectory`. The images are
    not rendered from the poses: they only carry the revisit structure the relocalization needs.
    """
    camera = PinholeCamera.from_fov_y(width, height, 60.0)
    poses = circle_trajectory(n_frames, radius_m, laps, lap_offset_m)
    per_lap = n_frames / laps
    header = {"num_frames": n_frames, "rate_hz": rate_hz, "camera": camera.to_dict(), "stereo_baseline_m": None,
              "scene": "synthetic-revisits", "trajectory": "circle", "seed": seed, "backend": "slam.synthetic",
              "config": {"laps": laps, "radius_m": radius_m, "lap_offset_m": lap_offset_m},
              "has": {"rgb_right": False, "depth": False, "flow": False, "mask": False}}
    w = OursWriter(root, header)
    for i in range(n_frames):
        place = int(round(i % per_lap)) % int(round(per_lap))
        tex = random_texture(np.random.default_rng([seed, 1, place]), height, width)
        img = revisit_image(tex, camera.k, small_motion(np.random.default_rng([seed, 2, i])))
        w.write_frame(i, i / rate_hz, poses[i], np.repeat(img[..., None], 3, axis=2))
    w.finish()
    return read_ours(root)


def synthetic_trajectory(n_frames: int, laps: float, radius_m: float = 50.0, rate_hz: float = 10.0) -> Trajectory:
    """:func:`circle_trajectory` as a Trajectory with timestamps i / rate_hz."""
    return Trajectory(circle_trajectory(n_frames, radius_m, laps, height_amp_m=0.5), np.arange(n_frames) / rate_hz)


def loop_graph(n_frames: int = 400, laps: float = 2.0, radius_m: float = 50.0, loop_every: int = 4,
               cons_noise=None, loop_noise=None, n_false: int = 0, false_min_gap: int = 20, seed: int = 0):
    """A pose-graph problem with known answer: ground truth, noisy consecutive and loop edges.

    Consecutive edges come from :class:`slam.odometry.GroundTruthOdometry` with ``cons_noise`` (by
    default a yaw bias of 2 mrad per frame plus noise: drift), loop edges every ``loop_every`` frames
    between the revisits (i, i + n_frames / laps) with ``loop_noise``. False loops: ``n_false`` random
    pairs at least ``false_min_gap`` apart that are NOT revisits, measured as a small random motion
    with the loop std (what a loop network says about two unrelated images).

    Returns:
        dict with ``gt`` (Trajectory), ``cons``, ``loops``, ``false_loops`` (slam.posegraph.Edges).
    """
    cons_noise = cons_noise or NoiseConfig(std6=(0.001, 0.001, 0.001, 0.02, 0.02, 0.02),
                                           bias6=(0.0, 0.002, 0.0, 0.0, 0.0, 0.0), seed=seed)
    loop_noise = loop_noise or NoiseConfig(std6=(0.003, 0.003, 0.003, 0.05, 0.05, 0.05), seed=seed + 1)
    gt = synthetic_trajectory(n_frames, laps, radius_m)
    pairs = [(i, i + 1) for i in range(n_frames - 1)]
    m, s = GroundTruthOdometry(cons_noise, gt=gt).predict(None, pairs)
    cons = Edges(np.array(pairs), m, s)
    per = int(round(n_frames / laps))
    lp = [(i, i + per) for i in range(0, n_frames - per, loop_every)]
    m, s = GroundTruthOdometry(loop_noise, gt=gt).predict(None, lp)
    loops = Edges(np.array(lp, dtype=np.int64).reshape(-1, 2), m, s)
    rng = np.random.default_rng([seed, 99])
    fp = []
    while len(fp) < n_false:
        i, j = sorted(rng.integers(0, n_frames, 2).tolist())
        if j - i < false_min_gap or abs((j - i) % per) < 10 or per - (j - i) % per < 10:
            continue
        fp.append((i, j))
    std = np.asarray(loop_noise.std6)
    fm = np.concatenate([rng.normal(0, 0.05, (n_false, 3)), rng.normal(0, 1.0, (n_false, 3))], axis=1)
    false_loops = Edges(np.array(fp, dtype=np.int64).reshape(-1, 2), fm, np.tile(std, (n_false, 1)))
    return {"gt": gt, "cons": cons, "loops": loops, "false_loops": false_loops}
