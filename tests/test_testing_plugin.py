"""The pytest plugin users load (``pytest_plugins = ["deepslam.testing"]``), run as a user's test suite."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.testing import assert_relative_motion_close, assert_trajectory_close

pytest_plugins = ["pytester"]

USER_TEST = '''
import numpy as np
from deepslam.testing import assert_trajectory_close, assert_relative_motion_close

def test_ground_truth_is_what_the_plugin_promises(sim_sequence):
    seq = sim_sequence(scene="street", frames=4, width=160, moving_objects=1, seed=3)
    assert len(seq) == 4
    cam = seq.camera
    assert (cam.width, cam.height) == (160, seq.image(0).shape[0]) and cam.fx > 0 and cam.cy > 0
    assert seq.image(0).dtype == np.uint8 and seq.depth(0).dtype == np.float32
    assert seq.flow(0).shape == (cam.height, cam.width, 2) and seq.mask(0).dtype == np.uint16
    assert seq.gt.world_from_cam.shape == (4, 4, 4) and len(seq.timestamps_s) == 4
    assert sim_sequence(scene="street", frames=4, width=160, moving_objects=1, seed=3) is seq  # rendered once
    assert_trajectory_close(seq.gt.world_from_cam, seq.gt.world_from_cam, ate_m=1e-9)

def test_my_odometry_is_off(sim_sequence):
    seq = sim_sequence(scene="street", frames=4, width=160, moving_objects=1, seed=3)
    est = seq.gt.world_from_cam.copy()
    est[2:, 0, 3] += 0.5
    assert_relative_motion_close(seq.gt.world_from_cam, est, trans_m=0.1, rot_deg=1.0)
'''


@pytest.mark.slow
def test_plugin_in_a_user_suite(pytester):
    pytester.makeconftest('pytest_plugins = ["deepslam.testing"]\n')
    pytester.makepyfile(test_user=USER_TEST)
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    res.assert_outcomes(passed=1, failed=1)
    res.stdout.fnmatch_lines(["*relative motion 1 -> 2: translation off by 0.5 m > 0.1 m*"])


def _drive(n: int = 20) -> np.ndarray:
    step = se3.from_euler6(np.array([0.0, 0.02, 0.0, 0.0, 0.0, 1.0]))
    poses = [np.eye(4)]
    for _ in range(n - 1):
        poses.append(poses[-1] @ step)
    return np.stack(poses)


@pytest.mark.parametrize("align,offset_ok", [("none", False), ("se3", True), ("sim3", True)])
def test_trajectory_assertion_names_alignment_frame_and_amount(align, offset_ok):
    gt = _drive()
    est = gt.copy()
    est[:, :3, 3] += [3.0, 0.0, 0.0]  # a constant offset: removed by se3/sim3 alignment, not by none
    if offset_ok:
        assert assert_trajectory_close(gt, est, ate_m=1e-6, align=align)["rmse_m"] < 1e-6
    else:
        with pytest.raises(AssertionError, match=r"ATE \(none-aligned\) 3 m > 0\.1 m; worst at frame \d+: 3 m off"):
            assert_trajectory_close(gt, est, ate_m=0.1, align=align)


def test_trajectory_assertion_sim3_forgives_scale_and_max_m_catches_one_frame():
    gt = _drive()
    est = gt.copy()
    est[:, :3, 3] *= 2.0
    with pytest.raises(AssertionError, match="se3-aligned"):
        assert_trajectory_close(gt, est, ate_m=0.1, align="se3")
    assert_trajectory_close(gt, est, ate_m=1e-6, align="sim3")
    est = gt.copy()
    est[7, 1, 3] += 0.4
    with pytest.raises(AssertionError, match="frame 7 is 0.4 m off"):
        assert_trajectory_close(gt, est, ate_m=0.2, align="none", max_m=0.1)


@pytest.mark.parametrize("bad", ["nan", "rotation", "length"])
def test_relative_motion_assertion_edge_cases(bad):
    gt = _drive()
    est = gt.copy()
    if bad == "nan":
        est[5, 0, 3] = np.nan
        match = "estimated pose of frame 5 is not finite"
    elif bad == "rotation":
        est[10:] = est[10:] @ se3.from_euler6(np.array([0.0, np.radians(3.0), 0.0, 0.0, 0.0, 0.0]))
        match = r"relative motion 9 -> 10: rotation off by 3 deg"
    else:
        est = est[:-1]
        match = "19 estimated poses for 20"
    with pytest.raises(AssertionError, match=match):
        assert_relative_motion_close(gt, est, trans_m=0.1 if bad != "rotation" else 10.0, rot_deg=1.0)


def _line(n: int) -> np.ndarray:
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 2, 3] = np.arange(n) * 0.5
    return poses


@pytest.mark.parametrize("est,what", [
    (lambda g: g[:3], "no estimated pose for ground-truth frame 3"),
    (lambda g: np.where(np.arange(len(g))[:, None, None] == 7, np.nan, g), "estimated pose of frame 7 is not finite"),
])
def test_trajectory_assertions_check_every_frame(est, what):
    from deepslam.testing import assert_relative_motion_close, assert_trajectory_close

    gt = _line(50)
    with pytest.raises(AssertionError, match=what):
        assert_trajectory_close(gt, est(gt), ate_m=1.0)
    with pytest.raises(AssertionError, match=what):
        assert_relative_motion_close(gt, est(gt), trans_m=1.0, rot_deg=1.0)


def test_trajectories_with_times_must_cover_every_ground_truth_time():
    from deepslam.core.trajectory import Trajectory
    from deepslam.testing import assert_trajectory_close

    gt = Trajectory(_line(50), np.arange(50) * 0.1)
    keep = np.r_[0:20, 21:50]  # frame 20 missing
    est = Trajectory(_line(50)[keep], (np.arange(50) * 0.1)[keep])
    with pytest.raises(AssertionError, match=r"no estimated pose for ground-truth frame 20 \(t = 2.0"):
        assert_trajectory_close(gt, est, ate_m=1.0)
    assert assert_trajectory_close(gt, Trajectory(_line(50), np.arange(50) * 0.1), ate_m=1e-9)["rmse_m"] < 1e-9


@pytest.mark.parametrize("kw", [{"ate_m": float("nan")}, {"ate_m": -1.0}, {"ate_m": 1.0, "max_m": float("inf")}])
def test_nan_or_negative_tolerances_are_refused(kw):
    from deepslam.testing import assert_trajectory_close

    with pytest.raises(ValueError, match="must be a finite number >= 0"):
        assert_trajectory_close(_line(5), _line(5), **kw)
