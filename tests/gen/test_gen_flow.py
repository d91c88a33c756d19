"""Flow synthesis: known answers, the NumPy reference, degenerate input, the z-buffer, determinism."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.gen.flow import denormalize_flow, normalize_flow, synthesize, visible_after_motion
from deepslam.gen.flow_reference import synthesize_reference, synthesize_reference_batch

from gen_scenes import box_scene, ground_scene, random_motions

CAM = PinholeCamera(64, 48, 50.0, 52.0, 31.2, 24.7)
BACKENDS = ["numba", "torch"]


def test_identity_gives_zero_flow_everywhere_with_depth():
    depth = box_scene(CAM)
    flow, valid = synthesize(depth, CAM, np.eye(4))
    assert flow.shape == (48, 64, 2) and valid.shape == (48, 64)
    assert flow.dtype == torch.float32 and valid.dtype == torch.bool
    assert bool(valid.all())
    assert float(flow.abs().max()) < 1e-4


def test_lateral_translation_known_answer():
    """p_cam1 = p_cam0 + (tx, 0, 0): du = fx tx / z, dv = 0, depth by depth."""
    depth = box_scene(CAM, back_m=10.0, box_m=3.0)
    tx = 0.2
    flow, valid = synthesize(depth, CAM, se3.from_rt(np.eye(3), [tx, 0, 0]))
    f = flow.numpy()
    v = valid.numpy()
    expected = CAM.fx * tx / depth
    np.testing.assert_allclose(f[..., 0][v], expected[v], atol=2e-4)
    np.testing.assert_allclose(f[..., 1][v], 0.0, atol=2e-4)
    # Points that move past the right border are invalid: u + du > W - 0.5.
    u = np.arange(CAM.width)[None, :] + expected
    np.testing.assert_array_equal(v, u < CAM.width - 0.5)


def test_pure_rotation_flow_does_not_depend_on_depth():
    rot = se3.from_euler6([0.0, 0.03, 0.01, 0, 0, 0])
    near = np.full((48, 64), 2.0, np.float32)
    far = np.full((48, 64), 200.0, np.float32)
    f1, v1 = synthesize(near, CAM, rot)
    f2, v2 = synthesize(far, CAM, rot)
    assert torch.equal(v1, v2)
    assert float((f1 - f2).abs().max()) < 1e-4


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_numpy_reference(seed, backend):
    rng = np.random.default_rng(seed)
    b = 5
    depth = np.stack([box_scene(CAM, rng.uniform(5, 30), rng.uniform(1, 4)) for _ in range(b)])
    depth[1] = ground_scene(CAM)
    motions = random_motions(rng, b, rot_sigma=0.05, t_sigma=0.5)
    flow, valid = synthesize(torch.from_numpy(depth), CAM, torch.from_numpy(motions), backend=backend)
    ref_flow, ref_valid = synthesize_reference_batch(depth, CAM, motions)
    flow, valid = flow.numpy(), valid.numpy()
    both = valid & ref_valid
    assert both.mean() > 0.3
    assert np.abs(flow - ref_flow)[both].max() < 1e-3
    # Validity agrees except for points within a hair of the image border (float32 vs float64).
    mismatch = valid != ref_valid
    assert mismatch.mean() < 1e-3
    bb, vv, uu = np.nonzero(mismatch)
    for i, v, u in zip(bb, vv, uu):
        p = np.array([u, v], float) + synthesize_reference_uv1_offset(depth[i], motions[i], u, v)
        border = min(abs(p[0] + 0.5), abs(p[0] - (CAM.width - 0.5)), abs(p[1] + 0.5), abs(p[1] - (CAM.height - 0.5)))
        assert border < 1e-3
    # Flow is exactly zero where not valid.
    assert np.all(flow[~valid] == 0)


def synthesize_reference_uv1_offset(depth, motion, u, v):
    """(du, dv) of pixel (u, v) from the camera model directly, valid or not (float64)."""
    p0 = CAM.unproject(np.array([u, v], float), depth[v, u])
    uv1, _ = CAM.project(se3.transform_points(motion, p0[None])[0])
    return uv1 - np.array([u, v], float)


@pytest.mark.parametrize("backend", BACKENDS)
def test_per_sample_intrinsics_and_numpy_inputs(backend):
    rng = np.random.default_rng(3)
    depth = np.stack([box_scene(CAM)] * 3)
    motions = random_motions(rng, 3)
    cams = [CAM, PinholeCamera(64, 48, 40.0, 40.0, 32.0, 20.0), PinholeCamera(64, 48, 80.0, 70.0, 30.0, 25.0)]
    k = np.stack([c.intrinsics() for c in cams])
    flow, valid = synthesize(depth, k, motions, backend=backend)
    for i, c in enumerate(cams):
        ref, ref_valid, _ = synthesize_reference(depth[i], c, motions[i])
        both = valid[i].numpy() & ref_valid
        assert np.abs(flow[i].numpy() - ref)[both].max() < 1e-3
        assert (valid[i].numpy() == ref_valid).mean() > 0.999


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf, -np.inf, 1e-40])
def test_degenerate_depth_is_masked_never_raises(bad, backend):
    depth = np.full((2, 48, 64), 5.0, np.float32)
    depth[:, 10:20, 10:30] = bad
    motions = np.stack([np.eye(4), se3.from_euler6([0.01, 0.02, 0.0, 0.1, 0.0, -0.5])])
    flow, valid = synthesize(depth, CAM, motions, backend=backend)
    assert not bool(valid[:, 10:20, 10:30].any())
    assert bool(valid[0, 30:, 40:].all())
    assert bool(torch.isfinite(flow).all())
    assert float(flow[:, 10:20, 10:30].abs().max()) == 0.0


@pytest.mark.parametrize("backend", BACKENDS)
def test_all_invalid_and_points_behind_camera(backend):
    empty = np.zeros((48, 64), np.float32)
    flow, valid = synthesize(empty, CAM, np.eye(4), zbuffer=True, backend=backend)
    assert not bool(valid.any()) and float(flow.abs().max()) == 0.0
    # Moving the camera 20 m forward past a wall 10 m away: every point ends behind it.
    wall = np.full((48, 64), 10.0, np.float32)
    flow, valid = synthesize(wall, CAM, se3.from_rt(np.eye(3), [0, 0, -20.0]), backend=backend)
    assert not bool(valid.any())
    _, ref_valid, _ = synthesize_reference(wall, CAM, se3.from_rt(np.eye(3), [0, 0, -20.0]))
    assert not ref_valid.any()


def test_zbuffer_hides_background_behind_the_box():
    """A box 3 m away in front of a wall at 10 m; the camera moves sideways: the box slides over
    background that stays put less; those background points are hidden, nothing else is."""
    depth = box_scene(CAM, back_m=10.0, box_m=3.0)
    tx = 0.31
    motion = se3.from_rt(np.eye(3), [tx, 0, 0])
    flow0, valid0 = synthesize(depth, CAM, motion)
    flow, valid = synthesize(depth, CAM, motion, zbuffer=True)
    hidden = valid0.numpy() & ~valid.numpy()
    assert hidden.any()
    # Expected: background points whose nearest pixel in the new view is covered by a moved box
    # pixel (box points land at c + fx tx / 3 and cover the pixel centres within half a pixel).
    box = depth == 3.0
    rows = np.nonzero(box.any(axis=1))[0]
    cols = np.nonzero(box.any(axis=0))[0]
    box_x1 = cols + CAM.fx * tx / 3.0
    covered = np.array([np.min(np.abs(p - box_x1)) <= 0.5 for p in range(CAM.width)])
    x1 = np.arange(CAM.width)[None, :] + CAM.fx * tx / depth
    nearest = np.clip(np.round(x1).astype(int), 0, CAM.width - 1)
    in_rows = (np.arange(CAM.height) >= rows[0]) & (np.arange(CAM.height) <= rows[-1])
    expected = (~box) & valid0.numpy() & covered[nearest] & in_rows[:, None]
    np.testing.assert_array_equal(hidden, expected)
    assert 3 * len(rows) <= hidden.sum() <= 4 * len(rows)  # (5.17 - 1.55) px of background per row
    # Flow is zeroed where hidden; the reference agrees.
    assert float(flow.numpy()[hidden].__abs__().max()) == 0.0
    ref_flow, ref_valid, _ = synthesize_reference(depth, CAM, motion, zbuffer=True)
    np.testing.assert_array_equal(valid.numpy(), ref_valid)


def test_zbuffer_keeps_smooth_surfaces_visible():
    """A road seen at a grazing angle, the camera moving along it or turning: nothing is hidden."""
    cam = PinholeCamera(160, 48, 100.0, 100.0, 79.5, 23.5)
    depth = ground_scene(cam)
    for vec in ([0, 0, 0, 0, 0, -1.0], [0, 0, 0, 0, 0, 1.0], [0, 0.05, 0, 0.1, 0, -1.0]):
        _, valid0 = synthesize(depth, cam, se3.from_euler6(vec))
        _, valid = synthesize(depth, cam, se3.from_euler6(vec), zbuffer=True)
        assert torch.equal(valid0, valid), vec


def test_zbuffer_matches_reference_on_random_scenes():
    rng = np.random.default_rng(7)
    for _ in range(3):
        depth = box_scene(CAM, rng.uniform(5, 20), rng.uniform(1.5, 4))
        motion = random_motions(rng, 1, 0.03, 0.4)[0]
        _, valid = synthesize(depth, CAM, motion, zbuffer=True)
        _, ref_valid, _ = synthesize_reference(depth, CAM, motion, zbuffer=True)
        assert (valid.numpy() != ref_valid).mean() < 2e-3


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("batch", [1, 3])
def test_zbuffer_kernel_is_the_torch_test_bit_for_bit(batch, threads):
    """The compiled z-buffer (chunked per thread, fast paths) decides exactly as visible_after_motion
    on the numba path's own flow: boxes, holes, big sideways and forward motions, points landing on
    the border, one or more samples per thread."""
    rng = np.random.default_rng(11)
    depth = np.stack([box_scene(CAM, rng.uniform(4, 20), rng.uniform(1.0, 3.0)) for _ in range(batch)])
    depth[:, 5:9, 40:44] = 0.0                                   # a hole
    motions = random_motions(rng, batch, 0.08, 1.5)
    old = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        flow0, valid0, z1 = synthesize(depth, CAM, motions, return_depth1=True, backend="numba")
        flow, valid, z1_zb = synthesize(depth, CAM, motions, zbuffer=True, return_depth1=True, backend="numba")
    finally:
        torch.set_num_threads(old)
    expected = visible_after_motion(flow0.permute(0, 3, 1, 2).contiguous(), valid0, z1)
    assert torch.equal(valid, expected)
    assert bool((valid0 & ~valid).any())                          # something was hidden
    hidden = valid0 & ~valid
    assert float(flow[hidden].abs().max()) == 0.0 and float(z1_zb[hidden].abs().max()) == 0.0
    assert torch.equal(flow[valid], flow0[valid]) and torch.equal(z1_zb[valid], z1[valid])


@pytest.mark.parametrize("backend", BACKENDS)
def test_depth1_out_buffers_and_single_input(backend):
    rng = np.random.default_rng(4)
    depth = np.stack([box_scene(CAM)] * 2)
    motions = random_motions(rng, 2)
    flow_buf = torch.empty(2, 2, 48, 64)
    valid_buf = torch.empty(2, 48, 64, dtype=torch.bool)
    flow, valid, z1 = synthesize(depth, CAM, motions, out=(flow_buf, valid_buf), return_depth1=True, backend=backend)
    assert flow.data_ptr() == flow_buf.data_ptr() and valid.data_ptr() == valid_buf.data_ptr()
    assert torch.equal(flow.permute(0, 3, 1, 2), flow_buf)
    _, ref_valid, ref_z1 = synthesize_reference(depth[1], CAM, motions[1])
    both = valid[1].numpy() & ref_valid
    np.testing.assert_allclose(z1[1].numpy()[both], ref_z1[both], rtol=1e-5)
    f1, v1 = synthesize(depth[1], CAM, motions[1], backend=backend)
    assert f1.shape == (48, 64, 2) and torch.equal(f1, flow[1]) and torch.equal(v1, valid[1])
    with pytest.raises(ValueError):
        synthesize(depth, CAM, motions, out=(torch.empty(2, 48, 64, 2), valid_buf), backend=backend)
    with pytest.raises(ValueError):
        synthesize(depth, PinholeCamera(32, 24, 10, 10, 16, 12), motions, backend=backend)


@pytest.mark.parametrize("backend", BACKENDS)
def test_batch_results_do_not_depend_on_batching(backend):
    """Element-wise only: a sample gives the same bits alone or inside a batch of any size."""
    import deepslam.gen.flow as gf

    rng = np.random.default_rng(5)
    depth = np.stack([box_scene(CAM, rng.uniform(5, 30), rng.uniform(1, 4)) for _ in range(7)])
    motions = random_motions(rng, 7)
    flow, valid = synthesize(depth, CAM, motions, backend=backend)
    old = gf.CHUNK_PIXELS
    try:
        gf.CHUNK_PIXELS = 3 * 48 * 64  # chunks of 3 samples
        flow3, valid3 = synthesize(depth, CAM, motions, backend=backend)
    finally:
        gf.CHUNK_PIXELS = old
    assert torch.equal(flow, flow3) and torch.equal(valid, valid3)
    for i in (0, 6):
        fi, vi = synthesize(depth[i:i + 1], CAM, motions[i:i + 1], backend=backend)
        assert torch.equal(fi[0], flow[i]) and torch.equal(vi[0], valid[i])


def test_visible_after_motion_on_empty_and_normalised_flow():
    flow = torch.zeros(1, 2, 4, 5)
    valid = torch.zeros(1, 4, 5, dtype=torch.bool)
    assert not bool(visible_after_motion(flow, valid, torch.ones(1, 4, 5)).any())
    f = np.random.default_rng(0).normal(size=(3, 4, 2)).astype(np.float32)
    n = normalize_flow(f, 320, 96)
    np.testing.assert_allclose(n[..., 0], f[..., 0] / 320, rtol=1e-6)
    np.testing.assert_allclose(n[..., 1], f[..., 1] / 96, rtol=1e-6)
    np.testing.assert_allclose(denormalize_flow(n, 320, 96), f, rtol=1e-6)
    t = torch.from_numpy(f).permute(2, 0, 1)[None]
    nt = normalize_flow(t, 320, 96, channel_axis=1)
    np.testing.assert_allclose(nt[0].permute(1, 2, 0).numpy(), n, rtol=1e-6)


def test_numba_and_torch_backends_agree_and_threads_do_not_change_the_bits():
    rng = np.random.default_rng(11)
    depth = np.stack([box_scene(CAM, rng.uniform(5, 30), rng.uniform(1, 4)) for _ in range(6)])
    depth[2, :5] = np.nan
    depth[3, :5] = 0.0
    motions = random_motions(rng, 6, rot_sigma=0.05, t_sigma=0.5)
    fn, vn, zn = synthesize(depth, CAM, motions, backend="numba", return_depth1=True)
    ft, vt, zt = synthesize(depth, CAM, motions, backend="torch", return_depth1=True)
    assert (vn == vt).float().mean() > 0.999
    both = vn & vt
    assert float((fn - ft).abs()[both].max()) < 1e-3
    assert float(((zn - zt).abs() / zt.clamp_min(1e-6))[both].max()) < 1e-5
    old = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        f1, v1 = synthesize(depth, CAM, motions, backend="numba")
    finally:
        torch.set_num_threads(old)
    assert torch.equal(f1, fn) and torch.equal(v1, vn)
    with pytest.raises(ValueError, match="backend"):
        synthesize(depth, CAM, motions, backend="cuda-magic")
