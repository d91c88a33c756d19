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
        match = "translation off"
    elif bad == "rotation":
        est[10:] = est[10:] @ se3.from_euler6(np.array([0.0, np.radians(3.0), 0.0, 0.0, 0.0, 0.0]))
        match = r"relative motion 9 -> 10: rotation off by 3 deg"
    else:
        est = est[:-1]
        match = "19 estimated poses for 20"
    with pytest.raises(AssertionError, match=match):
        assert_relative_motion_close(gt, est, trans_m=0.1 if bad != "rotation" else 10.0, rot_deg=1.0)
