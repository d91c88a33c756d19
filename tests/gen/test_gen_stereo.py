"""Depth from stereo: a synthetic pair with known disparity, KITTI 06, and a rendered pair vs rendered depth."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.readers import open_sequence
from deepslam.gen.flow import synthesize
from deepslam.gen.stereo import StereoConfig, depth_from_disparity, depth_from_stereo, disparity


def _textured_pair(disp_px: int, width: int = 160, height: int = 64, seed: int = 0):
    """Left/right grey images of a fronto-parallel textured plane at a constant disparity."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.integers(0, 256, (height, width + disp_px)).astype(np.uint8), (7, 7), 0)
    left = np.ascontiguousarray(tex[:, :width])                    # left pixel u sees texture column u
    right = np.ascontiguousarray(tex[:, disp_px:disp_px + width])  # right pixel u - d sees column u too
    return left, right


@pytest.mark.parametrize("method", ["sgbm", "dis"])
def test_known_constant_disparity(method):
    d = 12
    left, right = _textured_pair(d)
    disp, valid = disparity(left, right, StereoConfig(method=method, num_disparities=32))
    assert valid.mean() > 0.6
    assert np.all(disp[~valid] == 0)
    assert np.median(np.abs(disp[valid] - d)) < 0.25
    z = depth_from_disparity(disp, valid, fx=100.0, baseline_m=0.5)
    np.testing.assert_allclose(np.median(z[valid]), 100.0 * 0.5 / d, rtol=0.02)
    # Columns u < d have no match in the right image: never valid.
    assert not valid[:, : d - 2].any()


def test_left_right_check_rejects_inconsistent_matches():
    """Right image unrelated to the left one: matches are noise and the left-right check drops most."""
    left, _ = _textured_pair(8, seed=1)
    _, right = _textured_pair(8, seed=2)
    for method in ("sgbm", "dis"):
        _, valid = disparity(left, right, StereoConfig(method=method, num_disparities=32))
        assert valid.mean() < 0.25, method
    with pytest.raises(ValueError):
        StereoConfig(method="bm")


@pytest.fixture(scope="module")
def kitti06(shared_data):
    return open_sequence(shared_data / "kitti" / "sequences" / "06")


def test_kitti06_sgbm_and_dis_agree(kitti06):
    seq = kitti06
    depths = {m: depth_from_stereo(seq.image(30), seq.image_right(30), seq.camera.fx, seq.baseline_m,
                                   StereoConfig(method=m)) for m in ("sgbm", "dis")}
    for m, z in depths.items():
        v = z > 0
        assert 0.5 < v.mean() < 0.95, m
        assert 5.0 < np.median(z[v]) < 40.0, m
        assert z[v].max() <= seq.camera.fx * seq.baseline_m / StereoConfig().min_disparity_px + 1e-3
    both = (depths["sgbm"] > 0) & (depths["dis"] > 0)
    rel = np.abs(depths["sgbm"] - depths["dis"])[both] / depths["sgbm"][both]
    assert np.median(rel) < 0.03 and (rel < 0.1).mean() > 0.85


def test_kitti06_stereo_depth_plus_gt_motion_predicts_the_next_frame(kitti06):
    """Flow synthesized from frame 30's stereo depth and the ground-truth motion 30 -> 31 matches the
    optical flow DIS measures between the two left images; the inverse motion does not."""
    seq = kitti06
    z = depth_from_stereo(seq.image(30), seq.image_right(30), seq.camera.fx, seq.baseline_m)
    motion = se3.relative(seq.gt.world_from_cam[31], seq.gt.world_from_cam[30])  # cam31_from_cam30
    flow, valid = synthesize(z, seq.camera, motion)
    measured = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(seq.image(30), seq.image(31), None)
    v = valid.numpy()
    epe = np.linalg.norm(flow.numpy() - measured, axis=-1)[v]
    assert v.mean() > 0.4
    assert np.median(np.linalg.norm(measured, axis=-1)[v]) > 5.0  # the flow is not trivially small
    assert np.median(epe) < 1.5
    wrong, _ = synthesize(z, seq.camera, se3.inverse(motion))
    assert np.median(np.linalg.norm(wrong.numpy() - measured, axis=-1)[v]) > 10 * np.median(epe)


@pytest.mark.parametrize("method", ["sgbm", "dis"])
def test_rendered_stereo_pair_matches_rendered_depth(rendered_sequence, method):
    seq = open_sequence(rendered_sequence)
    assert seq.has_stereo and seq.baseline_m > 0
    for i in (0, 2):
        z = depth_from_stereo(seq.image(i), seq.image_right(i), seq.camera.fx, seq.baseline_m, StereoConfig(method=method))
        gt = seq.depth(i)
        v = (z > 0) & (gt > 0)
        assert v.mean() > 0.4
        rel = np.abs(z[v] - gt[v]) / gt[v]
        assert np.median(rel) < 0.03, (i, np.median(rel))
        assert (rel < 0.05).mean() > 0.7
