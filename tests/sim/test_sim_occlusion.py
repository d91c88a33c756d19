"""Backward flow and occlusion ground truth: exact for static and moving surfaces, in every layout."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from deepslam.core.readers import open_sequence


@pytest.fixture(scope="module")
def busy_street(tmp_path_factory):
    from deepslam.cli import main

    out = tmp_path_factory.mktemp("occ")
    for fmt in ("ours", "kitti", "euroc"):
        assert main(["render", "--scene", "street", "--frames", "26", "--width", "192", "--moving-objects", "8",
                     "--format", fmt, "--stereo-baseline", "0", "--out", str(out / fmt), "--quiet"]) == 0
    return out


def _seq(busy_street, fmt):
    root = busy_street / fmt
    if fmt == "kitti":
        root = root / "sequences" / "00"
    return open_sequence(root)


@pytest.mark.parametrize("fmt", ["ours", "kitti", "euroc"])
def test_every_layout_holds_backward_flow_and_occlusion_with_the_documented_numbering(busy_street, fmt):
    seq = _seq(busy_street, fmt)
    n = len(seq)
    assert seq.flow_backward(0) is None and seq.occlusion(n - 1) is None
    b, o = seq.flow_backward(5), seq.occlusion(5)
    assert b.shape == (seq.camera.height, seq.camera.width, 2) and b.dtype == np.float32
    assert o.shape == (seq.camera.height, seq.camera.width) and o.dtype == bool


def test_forward_and_backward_flow_agree_where_visible_and_occlusion_marks_the_rest(busy_street):
    seq = _seq(busy_street, "ours")
    h, w = seq.camera.height, seq.camera.width
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    moved = 0
    for t in (18, 22):
        f, back, occ = seq.flow(t), seq.flow_backward(t + 1), seq.occlusion(t)
        b_at = cv2.remap(back, u + f[..., 0], v + f[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=np.nan)
        err = np.linalg.norm(f + b_at, axis=-1)
        vis = ~occ & np.isfinite(err)
        assert vis.mean() > 0.5
        # where the backward flow is smooth around the landing point, its bilinear reading is exact
        # enough to compare (across a depth edge it blends two surfaces: near parked cars, many pixels)
        jump = np.maximum(np.abs(np.diff(back, axis=0, append=back[-1:])).max(-1),
                          np.abs(np.diff(back, axis=1, append=back[:, -1:])).max(-1))
        smooth = vis & (cv2.remap(jump, u + f[..., 0], v + f[..., 1], cv2.INTER_NEAREST) < 0.5)
        assert smooth.mean() > 0.4
        assert np.percentile(err[smooth], 95) < 0.05  # forward then backward returns to the pixel
        assert np.percentile(err[vis], 80) < 0.05
        # a pixel that flows out of the image is occluded
        out = (u + f[..., 0] < -1) | (u + f[..., 0] > w) | (v + f[..., 1] < -1) | (v + f[..., 1] > h)
        assert occ[out].all()
        moved += int((seq.mask(t) > 0).sum())
    assert moved > 0  # the movers were in view (the check above includes their pixels)


def test_occlusion_of_a_point_hidden_by_a_nearer_surface():
    """Unit: two pixels whose points land on the same pixel of t+1: the nearer is visible, the farther not."""
    from deepslam.sim.flow import occlusion_mask

    flow = np.zeros((4, 4, 2), np.float32)
    flow[1, 1] = (1.0, 0.0)  # lands on (1, 2)
    z1 = np.full((4, 4), 5.0, np.float32)
    z1[1, 1] = 9.0           # but farther than what t+1 sees there
    depth1 = np.full((4, 4), 5.0, np.float32)
    occ = occlusion_mask(flow, z1, depth1)
    assert occ[1, 1] and not occ[0, 0] and not occ[1, 2]
    flow[2, 2] = (5.0, 0.0)  # leaves the image
    assert occlusion_mask(flow, z1, depth1)[2, 2]
    z1[3, 3] = np.inf        # sky: visible where t+1 sees sky, hidden where a surface moved in front
    assert occlusion_mask(flow, z1, depth1)[3, 3]
    depth1[3, 3] = 0.0
    flow[3, 3] = (0.0, 0.0)
    assert not occlusion_mask(flow, z1, depth1)[3, 3]


def test_compiled_occlusion_mask_decides_as_the_reference():
    """Random flows, depths with holes, sky and NaN (behind the camera), points leaving the image."""
    from deepslam.sim.flow import occlusion_mask, occlusion_mask_reference

    rng = np.random.default_rng(3)
    for _ in range(5):
        h, w = 37, 53
        flow = rng.normal(0, 6, (h, w, 2)).astype(np.float32)
        z1 = rng.uniform(1, 30, (h, w)).astype(np.float32)
        z1[rng.random((h, w)) < 0.05] = np.inf
        z1[rng.random((h, w)) < 0.02] = np.nan
        flow[rng.random((h, w)) < 0.02] = np.nan
        depth1 = (z1 * rng.uniform(0.9, 1.1, (h, w))).astype(np.float32)
        depth1[~np.isfinite(depth1) | (rng.random((h, w)) < 0.05)] = 0.0
        np.testing.assert_array_equal(occlusion_mask(flow, z1, depth1), occlusion_mask_reference(flow, z1, depth1))


@pytest.mark.parametrize("backend", ["mujoco", "pyrender"])
def test_frames_in_order_reuse_the_occlusion_depth_pass_and_equal_fresh_renders(backend):
    """Frame i's occlusion test renders frame i+1's depth; frame i+1 then reuses it (one pass fewer): the
    frames are the same bytes as frames rendered alone."""
    from deepslam.scenes import SceneConfig
    from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig

    cfg = SimConfig(SceneConfig(name="street", seed=2, moving_objects=3, deform_amplitude_m=0.2),
                    TrajectoryConfig(frames=6), RenderConfig(backend=backend, width=160))
    with Simulator(cfg) as sim:
        in_order = [sim.frame(i) for i in range(3)]
        assert set(sim._next_depth) == {3}
    for i in (1, 2):
        with Simulator(cfg) as sim:
            alone = sim.frame(i)
        for name in ("rgb", "depth_z", "body", "mask", "flow", "occlusion", "flow_backward"):
            np.testing.assert_array_equal(getattr(alone, name), getattr(in_order[i], name), err_msg=name)
