"""Movers where the camera sees them, and the per-frame dynamic fraction every layout records."""
import numpy as np
import pytest

from deepslam.core.readers import open_sequence
from deepslam.scenes import SceneConfig, build_scene
from deepslam.sim import RenderConfig, SimConfig, TrajectoryConfig
from deepslam.sim.trajectories import make_motion
from deepslam.sim.world import separate_movers, view_fraction
from deepslam.sim.writers import DYNAMIC_FRACTION_FILE, render_sequence


def _cfg(k: int, frames: int = 30, seed: int = 0, street_style: str | None = None) -> SimConfig:
    return SimConfig(SceneConfig(name="street", seed=seed, moving_objects=k, street_style=street_style),
                     TrajectoryConfig(frames=frames),
                     RenderConfig(width=160, stereo_baseline_m=0.0))


@pytest.fixture(scope="module")
def street3(tmp_path_factory):
    return render_sequence(_cfg(3), tmp_path_factory.mktemp("dyn") / "s", progress=False)


def test_street_movers_are_in_view_from_the_first_frames(street3):
    seq = open_sequence(street3)
    frac = np.array([(seq.mask(i) > 0).mean() for i in range(len(seq))])
    assert frac[:5].max() > 0, "no mover in the first five frames"
    assert (frac > 0).mean() >= 0.5
    assert frac.mean() > 0.01  # the old placement: 0.04 % of the pixels, first mover at frame 25


@pytest.mark.parametrize("fmt", ["ours", "kitti", "euroc"])
def test_dynamic_fraction_file_is_the_masks_share(tmp_path, fmt):
    root = render_sequence(_cfg(3, frames=6), tmp_path / fmt, fmt=fmt, progress=False)
    seq = open_sequence(root)
    where = {"ours": root, "kitti": root, "euroc": root / "mav0" / "cam0"}[fmt]
    values = np.loadtxt(where / DYNAMIC_FRACTION_FILE)
    want = np.array([(seq.mask(i) > 0).mean() for i in range(len(seq))])
    assert values.shape == (6,)
    np.testing.assert_allclose(values, want, atol=1e-6)


def test_placement_keeps_the_camera_clear_and_prefers_movers_in_view():
    cfg = _cfg(4, frames=40, street_style="town").validate()
    base = build_scene(cfg.scene)
    motion = make_motion(base, "car", np.random.default_rng([0, 1]), None)
    duration = 4.1
    placed = separate_movers(base, motion, duration, np.random.default_rng([0, 2]))
    t = np.arange(0.0, duration, 0.05)
    cam = motion.world_from_cam(t)
    cam_from_world = np.linalg.inv(cam)
    seen_before = seen_after = 0.0
    for before, after in zip(base.bodies, placed.bodies):
        if before.motion is None or not hasattr(before.motion, "progress"):
            continue
        poses = after.motion.world_from_body(t)
        # the camera stays clear of the mover (its centre at least half a car length plus the clearance away)
        assert np.min(np.linalg.norm(poses[:, :2, 3] - cam[:, :2, 3], axis=1)) > 2.2 + 0.8
        seen_after += view_fraction(after, poses, cam_from_world, base.camera).mean()
        seen_before += view_fraction(before, before.motion.world_from_body(t), cam_from_world, base.camera).mean()
    assert seen_after > 3 * seen_before
