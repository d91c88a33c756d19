"""Flow estimators: DIS recovers known motion, ground-truth flow and chaining, resizing with rescaled values."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.flow import estimators as fe, registry


def _texture(h, w, seed=0):
    import cv2

    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, (h // 4, w // 4)).astype(np.float32)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)


@pytest.mark.parametrize("preset", ["ultrafast", "fast", "medium"])
def test_dis_recovers_a_translation(preset):
    img = _texture(120, 160)
    shifted = np.roll(img, (2, 3), axis=(0, 1))  # content moves +3 px in u, +2 px in v
    flow = registry.make("dis", preset=preset).estimate(img, shifted)
    assert flow.shape == (120, 160, 2) and flow.dtype == np.float32
    inner = flow[20:-20, 20:-20]
    np.testing.assert_allclose(np.median(inner.reshape(-1, 2), axis=0), [3.0, 2.0], atol=0.25)


def test_dis_accepts_rgb_and_rejects_unknown_preset():
    img = _texture(60, 80)
    rgb = np.repeat(img[..., None], 3, axis=2)
    assert fe.DISFlow().estimate(rgb, rgb).shape == (60, 80, 2)
    with pytest.raises(InputError):
        registry.make("dis", preset="slowest")
    with pytest.raises(InputError, match="unknown flow estimator"):
        registry.make("raft-not-registered")


def test_texture_strength_is_the_structure_tensors_smaller_eigenvalue():
    """Against the definition computed by hand: a flat image has none, a single straight edge (the
    aperture problem) none, a ramp in both directions none (one gradient direction); random texture a lot,
    and the value of a pixel is the smaller eigenvalue of its 7x7 mean of (gx, gy)(gx, gy)^T."""
    flat = np.full((40, 50), 128, np.uint8)
    assert np.abs(fe.texture_strength(flat)).max() < 1e-6
    edge = np.zeros((40, 50), np.uint8)
    edge[:, 25:] = 200
    assert np.abs(fe.texture_strength(edge)).max() < 1e-3
    ramp = (np.add.outer(np.arange(40), np.arange(50)) * 2).astype(np.uint8)  # 2 grey levels per px along u and v
    assert np.abs(fe.texture_strength(ramp)[5:-5, 5:-5]).max() < 1e-3
    img = _texture(40, 50).astype(np.float64)
    t = fe.texture_strength(img.astype(np.uint8))
    gx, gy = np.zeros_like(img), np.zeros_like(img)
    gx[:, 1:-1] = (img[:, 2:] - img[:, :-2]) / 2
    gy[1:-1] = (img[2:] - img[:-2]) / 2
    gx[1:-1] = (gx[:-2] + 2 * gx[1:-1] + gx[2:]) / 4  # Sobel = central difference smoothed 1-2-1 across
    gy[:, 1:-1] = (gy[:, :-2] + 2 * gy[:, 1:-1] + gy[:, 2:]) / 4
    v, u = 20, 24
    win = (slice(v - 3, v + 4), slice(u - 3, u + 4))
    tensor = np.array([[np.mean(gx[win] ** 2), np.mean(gx[win] * gy[win])],
                       [np.mean(gx[win] * gy[win]), np.mean(gy[win] ** 2)]])
    assert t.dtype == np.float32 and t.shape == (40, 50)
    assert t[v, u] == pytest.approx(np.linalg.eigvalsh(tensor)[0], rel=1e-4)
    assert t[v, u] > 1.0


@pytest.mark.parametrize("min_texture", [0.0, 0.5, 1e9])
def test_dis_min_texture_marks_textureless_pixels_unknown(min_texture):
    """Half the image textured, half a flat wall: with a threshold the wall's flow is NaN and the
    textured half's is DIS's own; the name records the threshold; a bad threshold is refused."""
    img = _texture(96, 128)
    img[:, 64:] = 90
    shifted = np.roll(img, 2, axis=1)
    plain = registry.make("dis", preset="medium").estimate(img, shifted)
    dis = registry.make("dis", **registry.estimator_options("dis", "medium", min_texture))
    flow = dis.estimate(img, shifted)
    unknown = np.isnan(flow).any(axis=2)
    assert np.array_equal(unknown, fe.texture_strength(img) < min_texture)
    np.testing.assert_array_equal(flow[~unknown], plain[~unknown])
    if min_texture == 0.0:
        assert dis.name == "dis-medium" and not unknown.any()
    elif min_texture == 0.5:
        assert dis.name == "dis-medium-tex0.5"
        assert unknown[10:-10, 80:-10].all() and not unknown[10:-10, 10:50].any()
    else:
        assert unknown.all()
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(InputError, match="min_texture"):
            fe.DISFlow("medium", bad)
    assert registry.estimator_options("learned", "fast", 0.0) == registry.estimator_options("gt", None, None) == {}
    with pytest.raises(InputError, match="DIS flow only"):
        registry.estimator_options("learned", "fast", 3.0)


def test_registry_takes_new_estimators():
    @registry.register("zero-test")
    class Zero:
        name = "zero-test"

        def estimate(self, a, b):
            return np.zeros((*a.shape[:2], 2), np.float32)

    assert "zero-test" in registry.names()
    assert registry.make("zero-test").estimate(np.zeros((4, 5), np.uint8), None).shape == (4, 5, 2)


def test_resize_flow_rescales_values():
    flow = np.zeros((40, 120, 2), np.float32)
    flow[..., 0], flow[..., 1] = 6.0, -4.0
    small = fe.resize_flow(flow, 30, 20)
    assert small.shape == (20, 30, 2)
    np.testing.assert_allclose(small[..., 0], 6.0 * 30 / 120, rtol=1e-6)
    np.testing.assert_allclose(small[..., 1], -4.0 * 20 / 40, rtol=1e-6)
    big = fe.resize_flow(flow, 240, 80)
    np.testing.assert_allclose(big[..., 0], 12.0, rtol=1e-6)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("size", [(120, 40), (30, 20)])
def test_resize_flow_reads_non_finite_values_as_zero(bad, size):
    flow = np.full((40, 120, 2), 3.0, np.float32)
    flow[5:9, 10:20] = bad
    before = flow.copy()
    got = fe.resize_flow(flow, *size)
    clean = np.where(np.isfinite(flow), flow, 0.0).astype(np.float32)
    np.testing.assert_array_equal(got, fe.resize_flow(clean, *size))
    assert np.isfinite(got).all()
    np.testing.assert_array_equal(flow, before)  # the caller's array is left alone


def test_resized_flow_matches_flow_computed_at_the_small_resolution():
    """A smooth (planar) flow field computed at full size and resized equals the one computed with the
    scaled camera, so the network sees the same numbers whichever way the flow was made."""
    from deepslam.core.camera import PinholeCamera
    from deepslam.vo.data.toy import flow_from_depth_np, plane_depth

    cam = PinholeCamera(320, 96, 250.0, 250.0, 159.5, 47.5)
    motion = se3.from_euler6(np.array([0.0, 0.01, 0.0, 0.05, 0.0, -0.3]))
    wall = np.array([0.1, 0.0, 1.0]) / np.linalg.norm([0.1, 0.0, 1.0])
    full, full_valid = flow_from_depth_np(cam, plane_depth(cam, wall, 8.0), motion)
    small_cam = cam.scaled(80, 24)
    small, valid = flow_from_depth_np(small_cam, plane_depth(small_cam, wall, 8.0), motion)
    resized = fe.resize_flow(full, 80, 24)
    # blocks whose 4x4 full-resolution pixels are all valid (points leaving the image get flow 0)
    block_ok = full_valid.reshape(24, 4, 80, 4).all(axis=(1, 3)) & valid
    assert block_ok.mean() > 0.8
    np.testing.assert_allclose(resized[block_ok], small[block_ok], atol=0.01)


def test_to_network_input_shapes_and_intrinsics():
    from deepslam.core.camera import PinholeCamera

    cam = PinholeCamera(160, 48, 100.0, 100.0, 79.5, 23.5)
    flow = np.ones((48, 160, 2), np.float32)
    chw, k = fe.to_network_input(flow, cam, 80, 24)
    assert chw.shape == (2, 24, 80) and k.dtype == np.float32
    np.testing.assert_allclose(k, [50.0, 50.0, 39.5, 11.5])
    np.testing.assert_allclose(chw, 0.5)


def test_chain_flows_of_constant_fields_adds_them():
    a = np.zeros((10, 12, 2), np.float32)
    a[..., 0] = 1.5
    b = np.zeros((10, 12, 2), np.float32)
    b[..., 1] = -2.0
    np.testing.assert_allclose(fe.chain_flows([a, b]), np.stack([np.full((10, 12), 1.5), np.full((10, 12), -2.0)], -1))


def test_ground_truth_flow_reads_and_chains(plane_sequence):
    from deepslam.vo.data.toy import flow_from_depth_np

    seq = open_sequence(plane_sequence)
    gt = registry.make("gt")
    np.testing.assert_array_equal(gt.pair_flow(seq, 3, 4), seq.flow(3))
    # chained 3 -> 5 vs the flow computed directly from depth and the relative pose
    direct, valid = flow_from_depth_np(seq.camera, seq.depth(3), se3.relative(seq.gt.world_from_cam[5], seq.gt.world_from_cam[3]))
    chained = gt.pair_flow(seq, 3, 5)
    # where both steps stay inside the image and on the ground
    ok = valid & (seq.depth(3) > 0) & (seq.depth(3) < 30)
    err = np.linalg.norm(chained - direct, axis=-1)[ok]
    assert np.median(err) < 0.05 and np.percentile(err, 90) < 0.3
    with pytest.raises(InputError):
        gt.pair_flow(seq, 5, 3)
    with pytest.raises(InputError):
        gt.estimate(seq.image(0), seq.image(1))


def test_dis_on_rendered_sequence_matches_ground_truth(plane_sequence):
    seq = open_sequence(plane_sequence)
    dis = registry.make("dis", preset="medium")
    est = dis.pair_flow(seq, 2, 3)
    gt = seq.flow(2)
    ground = (seq.depth(2) > 0) & (seq.depth(2) < 25) & (np.abs(gt).sum(-1) > 0)  # lands inside frame 3
    ground[:, :16] = ground[:, -16:] = False
    err = np.linalg.norm(est - gt, axis=-1)[ground]
    assert ground.sum() > 2000
    # much closer to the truth than no flow at all (flows here reach 20 px; DIS is coarse on 256 x 80)
    assert np.median(err) < 1.0
    assert np.median(err) < 0.25 * np.median(np.linalg.norm(gt, axis=-1)[ground])


@pytest.fixture(scope="module")
def street_with_movers(tmp_path_factory):
    """5 frames of the simulated street with 32 moving cars (rigid movers with recorded poses; one is in view)."""
    pytest.importorskip("mujoco")
    from deepslam.scenes import SceneConfig
    from deepslam.sim.config import RenderConfig, SimConfig, TrajectoryConfig
    from deepslam.sim.writers import render_sequence

    cfg = SimConfig(SceneConfig(name="street", seed=0, moving_objects=32),
                    TrajectoryConfig(frames=5), RenderConfig(width=320, height=97)).validate()
    return render_sequence(cfg, tmp_path_factory.mktemp("movers") / "street", fmt="ours", progress=False)


def test_exact_pair_flow_equals_the_simulators_flow_on_static_and_moving_pixels(street_with_movers):
    """Geometry (depth + ground-truth motion + the movers' own poses) reproduces the simulator's
    rendered flow, on the static scene and on the moving cars, to 0.01 px."""
    seq = open_sequence(street_with_movers)
    from deepslam.core.ours import read_instance_poses

    assert read_instance_poses(seq.root, 0), "the fixture should have rigid movers"
    for i in range(3):
        flow = fe.exact_pair_flow(seq, i, i + 1)
        err = np.linalg.norm(flow - seq.flow(i), axis=-1)
        hit, mask = seq.depth(i) > 0, seq.mask(i)
        assert (hit & (mask > 0)).sum() > 20
        assert err[hit & (mask == 0)].mean() < 0.01
        assert err[hit & (mask > 0)].mean() < 0.01
        assert err[~hit].mean() < 0.01  # sky: points at infinity, rotation-only flow


def test_gt_pairs_far_apart_use_geometry_not_a_chain(street_with_movers):
    seq = open_sequence(street_with_movers)
    got = registry.make("gt").pair_flow(seq, 0, 4)
    np.testing.assert_array_equal(got, fe.exact_pair_flow(seq, 0, 4))
    # the chain of the four stored flows agrees where nothing is occluded or leaves the view
    chained = fe.chain_flows([seq.flow(k) for k in range(4)])
    err = np.linalg.norm(chained - got, axis=-1)[seq.depth(0) > 0]
    assert np.median(err) < 0.05


def test_dis_pair_flow_reuses_decoded_images_but_never_across_sequences(plane_sequence, tmp_path):
    """Consecutive pairs share a decoded image; a second sequence at the same index is read afresh."""
    import shutil

    seq = open_sequence(plane_sequence)
    dis = registry.make("dis", preset="ultrafast")
    np.testing.assert_array_equal(dis.pair_flow(seq, 2, 3), registry.make("dis", preset="ultrafast").estimate(seq.image(2), seq.image(3)))
    other = tmp_path / "other"
    shutil.copytree(plane_sequence, other)
    imgs = sorted((other / "rgb").glob("*.png"))
    shutil.copy(imgs[4], imgs[2])  # frame 2 of the copy shows frame 4
    seq2 = open_sequence(other)
    np.testing.assert_array_equal(dis.pair_flow(seq2, 2, 3), registry.make("dis", preset="ultrafast").estimate(seq2.image(2), seq2.image(3)))


@pytest.mark.parametrize("size", [(120, 40), (30, 20), (24, 8), (240, 80)])
def test_resize_flow_nan_mode_averages_known_pixels_only(size):
    """unknown="nan": a flow with no unknown pixel resizes as before; a network pixel that covers some
    unknown pixels is the mean of its known ones (not pulled toward 0), and NaN (both components) where
    it covers none."""
    rng = np.random.default_rng(0)
    flow = rng.normal(0, 3, (40, 120, 2)).astype(np.float32)
    np.testing.assert_array_equal(fe.resize_flow(flow, *size, unknown="nan"), fe.resize_flow(flow, *size))
    const = np.full((40, 120, 2), (6.0, -4.0), np.float32)
    const[:, :55] = np.nan  # the left columns unknown, the boundary inside network pixels at every size
    const[0:2, 100:120, 1] = np.inf  # one bad component makes the whole vector unknown
    before = const.copy()
    got = fe.resize_flow(const, *size, unknown="nan")
    w, h = size
    known = np.isfinite(got).all(axis=2)
    assert known.any() and not known.all()
    np.testing.assert_allclose(got[known], np.broadcast_to([6.0 * w / 120, -4.0 * h / 40], got[known].shape), rtol=1e-5)
    assert np.isnan(got[~known]).all()
    if w <= 120:  # downsampling: unknown exactly where the network pixel covers only unknown pixels
        np.testing.assert_array_equal(known[:, : int(55 * w / 120)], False)
    np.testing.assert_array_equal(const, before)  # the caller's array is left alone (NaN == NaN here)
    zero = fe.resize_flow(const, *size)  # the old reading: unknown = 0, averaged in
    assert np.isfinite(zero).all() and np.abs(zero[..., 0]).min() < 6.0 * w / 120 * 0.99
    with pytest.raises(ValueError, match="unknown must be one of"):
        fe.resize_flow(flow, *size, unknown="drop")


def _occluder_pair() -> tuple[np.ndarray, np.ndarray]:
    """A textured scene that moves 4 px right between the images, and a square (new texture) that covers
    part of it in the second image only: the first image's pixels under it are occluded."""
    import cv2

    rng = np.random.default_rng(0)

    def texture(h, w):
        t = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 2.0)
        return cv2.normalize(t, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)

    bg = texture(140, 200)
    img0, img1 = bg[10:130, 10:190].copy(), bg[10:130, 6:186].copy()
    img1[40:80, 70:110] = texture(40, 40)
    return img0, img1


def test_forward_backward_error_of_consistent_inconsistent_and_leaving_flow():
    f = np.zeros((20, 30, 2), np.float32)
    f[..., 0] = 2.0
    b = -f
    err = fe.forward_backward_error(f, b)
    assert np.allclose(err[:, :28], 0.0) and np.isnan(err[:, 28:]).all()  # x + 2 beyond the last column: unknown
    b2 = b.copy()
    b2[5, 12] = (1.0, 3.0)  # the backward flow where (5, 10) lands disagrees
    err2 = fe.forward_backward_error(f, b2)
    assert np.isclose(err2[5, 10], np.hypot(3.0, 3.0)) and err2[5, 9] == err2[5, 11] == 0  # landing on (5, 11), (5, 13)
    f[3, 4] = np.nan
    assert np.isnan(fe.forward_backward_error(f, b)[3, 4])


@pytest.mark.parametrize("fb", [0.0, 0.5, 1.0])
def test_dis_forward_backward_check_leaves_occlusions_out(fb):
    img0, img1 = _occluder_pair()
    dis = fe.DISFlow("medium", 0.0, fb)
    flow = dis.estimate(img0, img1)
    unknown = np.isnan(flow[..., 0])
    occluded, open_ = unknown[40:80, 66:106], unknown[5:30, 20:170]
    assert not open_.any() and np.allclose(flow[5:30, 20:170, 0], 4.0, atol=0.05)  # the seen scene stays, right
    if fb == 0:
        assert dis.name == "dis-medium" and not unknown.any()
    else:
        assert dis.name == f"dis-medium-fb{fb:g}"
        assert occluded.mean() > 0.3 and unknown[:, -2:].all()  # hidden by the square; leaving the view
    assert np.array_equal(np.isnan(fe.DISFlow("medium", 0.0, fb).estimate(img0, img1)[..., 0]), unknown)  # deterministic


def test_fb_check_options_and_refusals():
    assert registry.estimator_options("dis", "medium", 0.5) == {"preset": "medium", "min_texture": 0.5}  # as old records
    assert registry.estimator_options("dis", "medium", 0.5, 0.0)["fb_max_px"] == 0.0  # given: overrides a model's record
    assert registry.estimator_options("dis", "medium", 0.5, 0.5)["fb_max_px"] == 0.5
    for bad in (-1.0, float("nan"), "x"):
        with pytest.raises(InputError, match="fb_max_px"):
            fe.DISFlow("medium", 0.0, bad)
    with pytest.raises(InputError, match="--dis-fb-check applies to DIS flow only"):
        registry.estimator_options("learned", None, None, 1.0)


@pytest.mark.parametrize("max_width", [0, 80, 160, 400])
def test_dis_max_width_gives_full_size_flow_in_full_size_pixels(max_width):
    """DIS on images wider than the limit runs downscaled; the flow comes back at the images' size with its
    vectors in full-size pixels (a 6 px shift reads about 6, not 6 x the scale); at or under the limit the
    flow is DIS's own, bit for bit."""
    img = _texture(120, 320)
    shifted = np.roll(img, (2, 6), axis=(0, 1))  # content moves +6 px in u, +2 px in v
    dis = fe.DISFlow("medium", max_width=max_width)
    flow = dis.estimate(img, shifted)
    assert flow.shape == (120, 320, 2) and flow.dtype == np.float32 and np.isfinite(flow).all()
    np.testing.assert_allclose(np.median(flow[24:-24, 24:-24].reshape(-1, 2), axis=0), [6.0, 2.0], atol=0.3)
    assert dis.name == ("dis-medium" if max_width == 0 else f"dis-medium-w{max_width}")
    full = fe.DISFlow("medium").estimate(img, shifted)
    assert np.array_equal(flow, full) == (max_width in (0, 400))


def test_dis_max_width_with_a_start_flow_and_the_fb_check():
    """The start flow is scaled down with the images, and the forward-backward check runs at the reduced size:
    the seen scene stays known, pixels leaving the view go unknown, a tighter threshold leaves more out."""
    img0, img1 = _occluder_pair()
    h, w = img0.shape[:2]
    start = np.zeros((h, w, 2), np.float32)
    start[..., 0] = 4.0
    small = fe.DISFlow("medium", max_width=w // 2)
    flow = small.estimate(img0, img1, start=start)
    assert flow.shape == (h, w, 2) and np.allclose(np.median(flow[5:30, 20:170, 0]), 4.0, atol=0.2)
    share = []
    for fb in (0.25, 3.0):
        unknown = np.isnan(fe.DISFlow("medium", fb_max_px=fb, max_width=w // 2).estimate(img0, img1)[..., 0])
        assert not unknown[5:30, 20:170].any() and unknown[:, -2:].all()
        share.append(unknown.mean())
    assert share[0] > share[1] > 0


@pytest.mark.parametrize("bad", [-1, 8, 15, 12.5, float("nan"), "x"])
def test_dis_max_width_refuses_bad_values(bad):
    with pytest.raises(InputError, match="max_width"):
        fe.DISFlow("medium", max_width=bad)


def test_dis_max_width_options():
    assert "max_width" not in registry.estimator_options("dis", "medium", 0.0)  # not given: as old records
    assert registry.estimator_options("dis", "medium", 0.0, None, 640)["max_width"] == 640
    assert registry.estimator_options("dis", "medium", 0.0, None, 0)["max_width"] == 0  # given: overrides a model's record
    with pytest.raises(InputError, match="--dis-max-width applies to DIS flow only"):
        registry.estimator_options("learned", None, None, None, 640)


@pytest.mark.parametrize("stride", [0, 3, 4, 6])
def test_dis_patch_stride_keeps_the_motion_and_names_itself(stride):
    """Fewer patches still read a shift; 0 and the preset's own stride (medium: 3) are the same DIS, bit for bit;
    a replica (another thread's estimator) keeps the stride."""
    img = _texture(120, 320)
    shifted = np.roll(img, (2, 6), axis=(0, 1))
    dis = fe.DISFlow("medium", patch_stride=stride)
    flow = dis.estimate(img, shifted)
    assert flow.shape == (120, 320, 2) and flow.dtype == np.float32 and np.isfinite(flow).all()
    np.testing.assert_allclose(np.median(flow[24:-24, 24:-24].reshape(-1, 2), axis=0), [6.0, 2.0], atol=0.3)
    assert dis.name == ("dis-medium" if stride == 0 else f"dis-medium-s{stride}")
    medium = fe.DISFlow("medium").estimate(img, shifted)
    assert np.array_equal(flow, medium) == (stride in (0, 3))
    assert np.array_equal(dis.replica().estimate(img, shifted), flow)


@pytest.mark.parametrize("bad", [-1, 9, 2.5, float("nan"), "x"])
def test_dis_patch_stride_refuses_bad_values(bad):
    with pytest.raises(InputError, match="patch_stride"):
        fe.DISFlow("medium", patch_stride=bad)


def test_dis_patch_stride_options():
    assert "patch_stride" not in registry.estimator_options("dis", "medium", 0.0)  # not given: as old records
    assert registry.estimator_options("dis", "medium", 0.0, dis_patch_stride=4)["patch_stride"] == 4
    with pytest.raises(InputError, match="--dis-patch-stride applies to DIS flow only"):
        registry.estimator_options("learned", None, None, dis_patch_stride=4)


@pytest.mark.parametrize("given, expected", [
    ({}, {}),  # nothing on the command line (vo, slam): the model's record alone
    ({"dis_preset": "medium", "dis_min_texture": 0.0}, {"preset": "medium", "min_texture": 0.0}),  # train's defaults
    ({"dis_patch_stride": 4, "dis_max_width": None}, {"patch_stride": 4}),
])
def test_the_dis_flags_read_into_typed_options(given, expected):
    from types import SimpleNamespace

    from deepslam.commands import _dis_flags

    assert dict(_dis_flags.given_options("dis", SimpleNamespace(**given))) == expected
    assert _dis_flags.given_options("learned", SimpleNamespace()) == ()
    with pytest.raises(InputError, match="--dis-patch-stride applies to DIS flow only"):
        _dis_flags.given_options("learned", SimpleNamespace(dis_patch_stride=4))


def _plane_flow(cam, cam1_from_cam0: np.ndarray) -> np.ndarray:
    """(H, W, 2) exact flow of ``cam`` over the plane 8 / z = 1 - 0.3 x/z + 0.1 y/z (camera 0's frame, metres)
    under the 4x4 motion ``cam1_from_cam0``: the same 3-D surface whatever the principal point."""
    g = cam.pixel_grid()
    x, y = (g[..., 0] - cam.cx) / cam.fx, (g[..., 1] - cam.cy) / cam.fy
    p0 = cam.unproject(g, 8.0 / (1.0 - 0.3 * x + 0.1 * y))
    p1 = p0 @ cam1_from_cam0[:3, :3].T + cam1_from_cam0[:3, 3]
    return (cam.project(p1)[0] - g).astype(np.float32)


def test_centred_flow_is_what_the_centred_camera_sees():
    from deepslam.core import se3
    from deepslam.core.camera import PinholeCamera

    # KITTI 04-10's camera at 1/8 scale: the principal point 1.3 px left of and 0.2 px above the centre
    off = PinholeCamera(153, 46, 88.4, 88.4, 75.2, 22.3)
    centred = PinholeCamera(153, 46, 88.4, 88.4, 76.0, 22.5)
    cam1_from_cam0 = se3.from_euler6(np.array([0.002, 0.01, -0.003, 0.05, -0.01, -0.9]))
    got, cam = fe.centre_principal_point(_plane_flow(off, cam1_from_cam0), off)
    assert cam == centred
    want = _plane_flow(centred, cam1_from_cam0)
    inner = (slice(2, -2), slice(2, -2))
    assert np.abs(want[inner]).max() > 2.0  # a flow worth moving
    np.testing.assert_allclose(got[inner], want[inner], atol=0.02)
    # uncentred, the same flow differs by the shift: the test can fail
    assert np.abs(_plane_flow(off, cam1_from_cam0)[inner] - want[inner]).max() > 0.05


def test_centring_a_centred_camera_returns_its_flow_and_keeps_unknown_local():
    from deepslam.core.camera import PinholeCamera

    flow = np.random.default_rng(0).normal(size=(20, 30, 2)).astype(np.float32)
    cam = PinholeCamera(30, 20, 40.0, 40.0, 14.5, 9.5)
    got, same = fe.centre_principal_point(flow, cam)
    assert got is flow and same == cam
    flow[10, 15] = np.nan
    off = PinholeCamera(30, 20, 40.0, 40.0, 14.0, 9.5)  # half a pixel left of the centre
    got, _ = fe.centre_principal_point(flow, off)
    assert np.isnan(got[10, 15:17]).all()  # the output pixels that read the unknown one
    got[9:12, 14:18] = 0.0  # OpenCV's bilinear reads the neighbours at weight 0 too: one pixel around, no further
    assert np.isfinite(got).all()
    chw, k = fe.to_network_input(flow, off, 15, 10, "nan", centre=True)
    np.testing.assert_allclose(k, [20.0, 20.0, 7.0, 4.5])
