"""Camera realism options (motion blur, sensor noise, exposure, white balance): the image changes, the
ground truth stays exact."""
import dataclasses

import numpy as np
import pytest

from deepslam.core.errors import InputError
from deepslam.scenes import SceneConfig
from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig
from deepslam.sim.world import world_state

BASE = SimConfig(SceneConfig(name="street", seed=2), TrajectoryConfig(frames=20),
                 RenderConfig(width=160, stereo_baseline_m=0.0))


def _with(**render) -> SimConfig:
    return dataclasses.replace(BASE, render=dataclasses.replace(BASE.render, **render))


@pytest.fixture(scope="module")
def sharp():
    with Simulator(BASE) as sim:
        return sim.frame(12)


def test_motion_blur_is_the_mean_over_an_exposure_centred_on_the_frame(sharp):
    exposure_s = 0.08
    with Simulator(_with(exposure_ms=exposure_s * 1e3, blur_samples=2)) as sim:
        blurred = sim.frame(12)
        # the two renders it averages: a quarter of the exposure before and after the frame time
        parts = []
        for dt in (-exposure_s / 4, exposure_s / 4):
            sim.backend.set_state(world_state(sim.scene, sim.motion, sim.time(12) + dt))
            parts.append(sim.backend.render("left", colour=True, depth=False)["rgb"].astype(np.float32))
    want = np.clip(np.rint((parts[0] + parts[1]) / 2), 0, 255)
    assert np.abs(blurred.rgb.astype(np.float32) - want).max() <= 1
    assert not np.array_equal(blurred.rgb, sharp.rgb)
    # the ground truth is the frame time's (mid-exposure), exactly as without blur
    for name in ("depth_z", "flow", "mask", "world_from_cam", "occlusion"):
        np.testing.assert_array_equal(getattr(blurred, name), getattr(sharp, name))
    # blur removes detail where the image moves
    grad = lambda img: np.abs(np.diff(img.astype(np.float32).mean(-1), axis=1)).mean()  # noqa: E731
    with Simulator(_with(exposure_ms=60.0, blur_samples=6)) as sim:
        assert grad(sim.frame(12).rgb) < 0.95 * grad(sharp.rgb)


def test_noise_exposure_and_white_balance_are_seeded_and_bounded(sharp):
    cfg = _with(sensor_noise=4.0, exposure_jitter=0.3, white_balance_jitter=0.1)
    with Simulator(cfg) as sim:
        a = sim.frame(12)
    with Simulator(cfg) as sim:
        b = sim.frame(12)
    assert np.array_equal(a.rgb, b.rgb)  # same seed, same bytes
    np.testing.assert_array_equal(a.depth_z, sharp.depth_z)
    np.testing.assert_array_equal(a.flow, sharp.flow)
    ok = (sharp.rgb > 20).all(-1) & (sharp.rgb < 180).all(-1)  # no clipping after a gain of at most 1.3 * 1.1
    ratio = a.rgb[ok].astype(np.float64).sum(0) / sharp.rgb[ok].astype(np.float64).sum(0)
    assert ((ratio > 1 / 1.3 * 0.9 - 0.01) & (ratio < 1.3 * 1.1 + 0.01)).all()
    with Simulator(_with(sensor_noise=4.0)) as sim:
        noisy = sim.frame(12).rgb.astype(np.float64)
    resid = (noisy - sharp.rgb)[ok]
    assert 3.4 < resid.std() < 4.6


@pytest.mark.parametrize("field,value", [("exposure_ms", -1.0), ("exposure_ms", float("nan")), ("sensor_noise", 500.0),
                                         ("exposure_jitter", -0.1), ("white_balance_jitter", 1.0), ("blur_samples", 1)])
def test_bad_camera_effects_are_refused(field, value):
    with pytest.raises(InputError):
        RenderConfig(**{field: value}).validate()


@pytest.mark.parametrize("baseline", [0.0, 0.11])
def test_a_distorted_euroc_export_reads_back_to_the_pinhole_render(tmp_path, baseline):
    """The images on disk are distorted (EuRoC-like radial-tangential); the reader undistorts them back to
    the render's pinhole camera, in which depth and flow are."""
    from deepslam.core.readers import open_sequence
    from deepslam.sim.writers import render_sequence

    cfg = SimConfig(SceneConfig(name="room", seed=3), TrajectoryConfig(frames=3), RenderConfig(width=240, stereo_baseline_m=baseline))
    dist = (-0.28, 0.07, 2e-4, 2e-5)  # EuRoC cam0's
    plain = open_sequence(render_sequence(cfg, tmp_path / "plain", fmt="euroc", progress=False))
    bent = open_sequence(render_sequence(_cfg_with(cfg, distortion=dist), tmp_path / "bent", fmt="euroc", progress=False))
    assert bent.camera == plain.camera
    import cv2

    raw0 = cv2.imread(str(bent.image_paths[1]), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    want = plain.image(1).astype(np.float32)
    got = bent.image(1).astype(np.float32)
    h, w = want.shape[:2]
    inner = (slice(h // 6, h - h // 6), slice(w // 6, w - w // 6))
    assert np.abs(raw0 - want)[inner].mean() > 3 * np.abs(got - want)[inner].mean()  # the files are distorted
    assert np.median(np.abs(got - want)[inner]) <= 2.0
    np.testing.assert_array_equal(bent.depth(1), plain.depth(1))
    if baseline:
        assert bent.baseline_m == pytest.approx(plain.baseline_m)
        assert np.median(np.abs(bent.image_right(1).astype(np.float32) - plain.image_right(1).astype(np.float32))[inner]) <= 2.0


def _cfg_with(cfg, **render):
    return dataclasses.replace(cfg, render=dataclasses.replace(cfg.render, **render))


def test_distortion_needs_the_euroc_layout(tmp_path):
    from deepslam.sim.writers import render_sequence

    with pytest.raises(InputError, match="euroc"):
        render_sequence(_with(distortion=(-0.2, 0.05, 0.0, 0.0)), tmp_path / "o", fmt="ours", progress=False)
    assert not (tmp_path / "o").exists()
