"""Shared fixtures. Rendering is headless (EGL); real data lives in ../shared/data. The vo and flow tests
share a tiny rendered sequence of a textured ground plane in our format (``plane_sequence``)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.ours import OursWriter

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = (REPO_ROOT / ".." / "shared" / "data").resolve()


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path to ../shared/data (real KITTI and EuRoC slices); skips the test when it is absent."""
    if not (SHARED_DATA / "README.md").is_file():
        pytest.skip(f"real data not found at {SHARED_DATA} (../shared/data beside the repository)")
    return SHARED_DATA


CAMERA_HEIGHT_M = 1.6


def ground_texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """A float32 (size, size) texture with detail at several scales, values in [0, 255]."""
    import cv2

    tex = np.zeros((size, size), np.float32)
    for cell, amp in ((64, 90.0), (16, 60.0), (4, 50.0)):
        small = rng.uniform(-1, 1, (size // cell, size // cell)).astype(np.float32)
        tex += amp * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    return np.clip(128 + tex, 0, 255)


def render_ground(camera: PinholeCamera, world_from_cam: np.ndarray, texture: np.ndarray,
                  metres_per_texel: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """(RGB uint8 (H, W, 3), depth_z float32 (H, W)) of the plane world y = CAMERA_HEIGHT_M (y down)."""
    import cv2

    g = camera.pixel_grid()
    rays_cam = np.stack([(g[..., 0] - camera.cx) / camera.fx, (g[..., 1] - camera.cy) / camera.fy,
                         np.ones(g.shape[:2])], axis=-1)
    rays_w = rays_cam @ world_from_cam[:3, :3].T
    origin = world_from_cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (CAMERA_HEIGHT_M - origin[1]) / rays_w[..., 1]
    hit = (rays_w[..., 1] > 1e-6) & (s > 0) & (s < 80.0)
    p = origin + np.where(hit, s, 0.0)[..., None] * rays_w
    size = texture.shape[0]
    mu = (p[..., 0] / metres_per_texel) % size
    mv = (p[..., 2] / metres_per_texel) % size
    val = cv2.remap(texture, mu.astype(np.float32), mv.astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    sky = 200.0 - 40.0 * g[..., 1] / camera.height
    img = np.where(hit, val, sky).astype(np.uint8)
    depth = np.where(hit, s, 0.0).astype(np.float32)  # rays_cam z = 1, so the ray parameter is depth_z
    return np.repeat(img[..., None], 3, axis=2), depth


def drive(n: int, speed_m: float = 0.8, yaw_rate_rad: float = 0.02) -> np.ndarray:
    """(n, 4, 4) world_from_cam of a camera driving forward (+z) and turning slowly, height 0."""
    poses = [np.eye(4)]
    step = se3.from_euler6(np.array([0.0, yaw_rate_rad, 0.0, 0.0, 0.0, speed_m]))
    for _ in range(n - 1):
        poses.append(poses[-1] @ step)
    return np.stack(poses)


def write_plane_sequence(root: Path, n: int = 12, width: int = 256, height: int = 80, seed: int = 0) -> Path:
    from deepslam.vo.data.toy import flow_from_depth_np

    camera = PinholeCamera(width, height, 0.58 * width, 0.58 * width, (width - 1) / 2, (height - 1) / 2 - 0.15 * height)
    tex = ground_texture(np.random.default_rng(seed))
    poses = drive(n)
    header = {"num_frames": n, "rate_hz": 10.0, "camera": camera.to_dict(), "stereo_baseline_m": None,
              "scene": "test-street-plane", "trajectory": "drive", "seed": seed, "backend": "numpy", "config": {},
              "has": {"rgb_right": False, "depth": True, "flow": True, "mask": False}}
    w = OursWriter(root, header)
    frames = [render_ground(camera, p, tex) for p in poses]
    for i in range(n):
        flow = None
        if i + 1 < n:
            flow, _ = flow_from_depth_np(camera, frames[i][1], se3.relative(poses[i + 1], poses[i]))
        w.write_frame(i, i / 10.0, poses[i], frames[i][0], depth=frames[i][1], flow=flow)
    w.finish()
    return root


@pytest.fixture(scope="session")
def plane_sequence(tmp_path_factory) -> Path:
    """A 12-frame sequence (256 x 80) of a textured ground plane, camera driving forward 0.8 m/frame."""
    return write_plane_sequence(tmp_path_factory.mktemp("plane") / "seq")


def drive_noisy(n: int, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) world_from_cam of a car-like drive with noisy speed and turns (for motion-model fits)."""
    rng = np.random.default_rng(seed)
    poses = [np.eye(4)]
    for _ in range(n - 1):
        step = np.array([rng.normal(0, 0.002), rng.normal(0, 0.01), rng.normal(0, 0.002),
                         rng.normal(0, 0.02), rng.normal(0, 0.01), rng.uniform(0.5, 1.2)])
        poses.append(poses[-1] @ se3.from_euler6(step))
    return np.stack(poses)


@pytest.fixture(scope="session")
def motion_json(tmp_path_factory) -> Path:
    """A gen.motion model (stride 1) fitted to a noisy car-like drive of 120 frames."""
    from deepslam.core.trajectory import Trajectory
    from deepslam.gen.motion import fit_motion

    path = tmp_path_factory.mktemp("motion") / "motion.json"
    model, _, _ = fit_motion([Trajectory(drive_noisy(120))], stride=1)
    model.save(path)
    return path


@pytest.fixture(scope="session")
def street_model(plane_sequence, tmp_path_factory) -> Path:
    """A tiny model trained on ground-plane flows seen by the test sequence's camera."""
    from deepslam.core.readers import open_sequence
    from deepslam.vo.data.samples import TensorSamples
    from deepslam.vo.data.toy import toy_motion_sampler, toy_plane_samples
    from deepslam.vo.net import NetConfig
    from deepslam.vo.train import TrainConfig, train

    seq = open_sequence(plane_sequence)
    cam = seq.camera.scaled(80, 24)
    sampler = toy_motion_sampler(rot_std_rad=0.02, trans_std_m=0.05, forward_m=(0.3, 1.2))
    s = toy_plane_samples(800, cam, np.random.default_rng(0), sampler)
    tr, ho = TensorSamples(s["flow"], s["intrinsics"], s["target"], seed=0).split(0.1, 0)
    cfg = TrainConfig(net=NetConfig(24, 80, filters=16, hidden_units=64, flow_scale=10.0), batch_size=16, lr_max=3e-3,
                      max_epochs=8, nll_epochs=3, bf16=False, channels_last=False, threads=1)
    return train(cfg, tr, ho, tmp_path_factory.mktemp("model"), progress=False).model_path
