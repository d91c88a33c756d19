"""A frame seen by a camera rotated about its centre (gen.rotate_view) and the training tilt built on it."""
import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.gen.rotate_view import rotate_depth, rotate_image, rotate_motion, rotation_from_pitch_roll
from deepslam.vo.data.frames import Frames
from deepslam.vo.data.motion import CameraTilt
from deepslam.vo.data.synthetic import SyntheticSource
from deepslam.vo.data.toy import flow_from_depth_np, plane_depth

CAM = PinholeCamera(320, 96, 185.0, 185.0, 159.5, 47.5)


@pytest.mark.parametrize("pitch_deg,roll_deg", [(1.0, 0.0), (-2.0, 0.0), (3.0, 1.5), (0.5, -4.0)])
def test_rotated_ground_is_the_ground_seen_by_the_rotated_camera(pitch_deg, roll_deg):
    rot = rotation_from_pitch_roll(np.radians(pitch_deg), np.radians(roll_deg))
    floor = np.array([0.0, 1.0, 0.0])  # a level camera 1.65 m above a flat road
    got = rotate_depth(plane_depth(CAM, floor, 1.65), CAM, rot)
    want = plane_depth(CAM, rot @ floor, 1.65)
    both = (got > 0) & (want > 0) & (want < 30)  # away from the horizon, where depth changes fast per row
    assert both.mean() > 0.3
    rel = np.abs(got[both] - want[both]) / want[both]
    assert np.median(rel) < 0.01 and np.percentile(rel, 95) < 0.05


def test_pitching_down_moves_the_horizon_up():
    rot = rotation_from_pitch_roll(np.radians(2.0), 0.0)
    p_far = rot @ np.array([0.0, 0.0, 1000.0])  # a point far along the level camera's axis
    v = CAM.fy * p_far[1] / p_far[2] + CAM.cy
    assert v < CAM.cy - 0.9 * CAM.fy * np.tan(np.radians(2.0))


def test_exact_flow_after_rotation_is_the_old_flow_mapped_by_the_homography():
    """Rotating the frame and the motion describes the same scene and the same drive: the flow of
    the rotated frame is the original flow carried through H = K R K^-1."""
    rot = rotation_from_pitch_roll(np.radians(2.0), np.radians(1.0))
    depth = plane_depth(CAM, np.array([0.0, 1.0, 0.2]) / np.hypot(1, 0.2), 1.65)
    motion = se3.from_euler6(np.array([0.002, -0.01, 0.001, 0.05, 0.01, -1.0]))
    new_depth = rotate_depth(depth, CAM, rot)
    flow_new, valid_new = flow_from_depth_np(CAM, new_depth, rotate_motion(motion, rot))
    k = CAM.k
    h = k @ rot @ np.linalg.inv(k)
    v, u = np.nonzero(valid_new)
    x_new = np.stack([u, v, np.ones_like(u)], 0).astype(np.float64)
    x_old = np.linalg.inv(h) @ x_new
    x_old = x_old[:2] / x_old[2]
    z_old = depth[np.clip(np.rint(x_old[1]).astype(int), 0, CAM.height - 1), np.clip(np.rint(x_old[0]).astype(int), 0, CAM.width - 1)]
    p_old = np.stack([(x_old[0] - CAM.cx) / CAM.fx, (x_old[1] - CAM.cy) / CAM.fy, np.ones_like(x_old[0])]) * z_old
    # exact depth of the plane along that ray, not the nearest pixel's
    n = np.array([0.0, 1.0, 0.2]) / np.hypot(1, 0.2)
    p_old = p_old / (n @ p_old) * 1.65
    p1 = motion[:3, :3] @ p_old + motion[:3, 3:4]
    x1_new = h @ (k @ p1)
    x1_new = x1_new[:2] / x1_new[2]
    want = (x1_new - x_new[:2]).T
    err = np.linalg.norm(flow_new[v, u] - want, axis=1)
    assert np.median(err) < 0.05 and np.percentile(err, 99) < 1.0


def test_identity_rotation_changes_nothing_and_outside_strip_filled_on_request():
    depth = plane_depth(CAM, np.array([0.0, 1.0, 0.0]), 1.65)
    np.testing.assert_allclose(rotate_depth(depth, CAM, np.eye(3)), depth, rtol=1e-6)
    img = (np.arange(96 * 320) % 251).astype(np.uint8).reshape(96, 320)
    assert np.array_equal(rotate_image(img, CAM, np.eye(3)), img)
    rot = rotation_from_pitch_roll(np.radians(3.0), 0.0)  # looks down: the bottom rows are new
    zero = rotate_depth(depth, CAM, rot)
    near = rotate_depth(depth, CAM, rot, outside="nearest")
    assert (zero[-3:] == 0).all() and (near[-3:] > 0).all()
    assert np.array_equal(near[zero > 0], zero[zero > 0])


@pytest.mark.parametrize("text", ["1", "a:b", "3:1", "-40:1", "0:1:-2", "0:1:2:3", "nan:1"])
def test_bad_tilt_flags_are_refused(text):
    with pytest.raises(InputError):
        CameraTilt.parse(text)


def test_tilted_synthetic_source_is_seeded_and_zero_tilt_matches_none():
    depth = np.stack([plane_depth(CAM, np.array([0.0, 1.0, 0.0]), 1.65)] * 3)
    frames = Frames(depth, np.zeros(3, np.int64), [CAM], ["a:0", "a:1", "a:2"])

    def sample(n, rng):
        return np.column_stack([rng.normal(0, 0.01, (n, 3)), rng.normal(0, 0.05, (n, 2)), -rng.uniform(0.5, 1.5, n)])

    tilt = CameraTilt((-1.0, 3.0), 1.0)
    a = SyntheticSource(frames, sample, 8, seed=3, tilt=tilt).make_batch(np.random.default_rng(0), 8)
    b = SyntheticSource(frames, sample, 8, seed=3, tilt=tilt).make_batch(np.random.default_rng(0), 8)
    assert all(np.array_equal(a[k].numpy(), b[k].numpy()) for k in a)
    plain = SyntheticSource(frames, sample, 8, seed=3).make_batch(np.random.default_rng(0), 8)
    zero = SyntheticSource(frames, sample, 8, seed=3, tilt=CameraTilt((0.0, 0.0))).make_batch(np.random.default_rng(0), 8)
    np.testing.assert_allclose(zero["target"].numpy(), plain["target"].numpy(), atol=1e-6)
    np.testing.assert_allclose(zero["flow"].numpy(), plain["flow"].numpy(), atol=1e-3)
    # a tilted sample's target is the drive seen from the tilted camera: forward gains a vertical part
    assert not np.allclose(a["target"].numpy()[:, 4], plain["target"].numpy()[:, 4], atol=1e-3)


@pytest.mark.parametrize("flag,what", [("--camera-tilt-deg=5:1", "bad camera tilt"),
                                       ("--camera-tilt-deg=1:3", "needs --mode synthetic with --source")])
def test_train_refuses_a_bad_or_unusable_tilt_before_writing(tmp_path, flag, what):
    """A tilt is validated up front, and refused where nothing would be tilted (toy samples)."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "deepslam", "train", "--mode", "synthetic", "--toy", "50", flag,
                        "--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert r.returncode == 2 and what in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()
