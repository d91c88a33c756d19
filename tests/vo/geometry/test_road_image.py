"""The road read from the images where the flow loses it (``deepslam vo --scale road``): the road bands of two
rendered road images aligned through the road plane's homography give the distance at any speed; a
sequence's distances checked against their neighbours, short gaps filled; a pair the fit cannot serve keeps
the network's rotation and direction with the road's distance."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.vo.geometry.epipolar import EpipolarConfig, EpipolarFit, fuse, sequence_road_distances
from deepslam.vo.geometry.road_flow import band_box
from deepslam.vo.geometry.road_image import (IMAGE_BANDS, ImageRoadConfig, _follow_path, image_road_q, road_image, road_rows_top, turn_curvature)
from deepslam.vo.geometry.road_sequence import RoadSequenceConfig, check_and_fill

CAM = PinholeCamera(620, 188, 359.4, 359.4, 309.5, 93.5)
HEIGHT_M = 1.65
_TEXEL_M = 0.02
_TEX_X0, _TEX_Z0 = -25.0, -15.0


def _texture(seed: int = 0) -> np.ndarray:
    """(4000, 2500) float32 asphalt-like noise on the road plane, 2 cm texels, x in [-25, 25] m, z in [-15, 65] m."""
    rng = np.random.default_rng(seed)
    tex = rng.normal(0, 1, (4000, 2500)).astype(np.float32)
    tex = cv2.GaussianBlur(tex, (0, 0), 3.0) * 40 + cv2.GaussianBlur(rng.normal(0, 1, (4000, 2500)).astype(np.float32), (0, 0), 20.0) * 400
    return np.clip(tex + 128, 0, 255).astype(np.float32)


TEX = _texture()


def _pitched(pitch_deg: float) -> np.ndarray:
    """(3, 3) level-from-camera rotation of a camera pitched down by ``pitch_deg`` (OpenCV axes)."""
    p = np.radians(pitch_deg)
    return np.array([[1, 0, 0], [0, np.cos(p), np.sin(p)], [0, -np.sin(p), np.cos(p)]], float)


def _drive(distance_m: float, pitch_deg: float, yaw_deg: float = 0.0,
           texture: np.ndarray | None = None, block: tuple[float, ...] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two uint8 (188, 620) images of a textured flat road ``HEIGHT_M`` below a camera pitched ``pitch_deg``
    down, before and after driving ``distance_m`` forward while turning ``yaw_deg`` (sky: mid grey), and
    cam1_from_cam0 (4, 4). ``texture``: the road's (4000, 2500) texels (default :data:`TEX`). ``block``:
    ``(x0, x1, z0, z1, top_m)``, a textured flat top ``top_m`` below the camera over that footprint (metres,
    camera 0's level frame: x right, z ahead), standing on the road like a parked car's roof."""
    level_from_cam = _pitched(pitch_deg)
    yaw = np.radians(yaw_deg)
    r_level = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    level0_from_level1 = se3.from_rt(r_level, np.array([0.0, 0.0, distance_m]))
    to_level = se3.from_rt(level_from_cam, np.zeros(3))
    cam1_from_cam0 = se3.inverse(to_level) @ se3.inverse(level0_from_level1) @ to_level
    v, u = np.mgrid[0:CAM.height, 0:CAM.width].astype(np.float64)
    rays = level_from_cam @ (np.linalg.inv(CAM.k) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)]))
    images = []
    for level0_from_levelk in (np.eye(4), level0_from_level1):
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(rays[1] > 1e-3, HEIGHT_M / rays[1], np.nan)
        p = level0_from_levelk[:3, :3] @ (rays * depth) + level0_from_levelk[:3, 3:4]
        if block is not None:
            x0, x1, z0, z1, top_m = block
            with np.errstate(divide="ignore", invalid="ignore"):
                top = level0_from_levelk[:3, :3] @ (rays * np.where(rays[1] > 1e-3, top_m / rays[1], np.nan)) \
                    + level0_from_levelk[:3, 3:4]
            on_top = (top[0] >= x0) & (top[0] <= x1) & (top[2] >= z0) & (top[2] <= z1)
            p = np.where(on_top[None], top, p)
        mx = ((p[0] - _TEX_X0) / _TEXEL_M).reshape(CAM.height, CAM.width).astype(np.float32)
        mz = ((p[2] - _TEX_Z0) / _TEXEL_M).reshape(CAM.height, CAM.width).astype(np.float32)
        img = cv2.remap(TEX if texture is None else texture, np.nan_to_num(mx, nan=-1), np.nan_to_num(mz, nan=-1), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=128)
        images.append(np.clip(img, 0, 255).astype(np.uint8))
    return images[0], images[1], cam1_from_cam0


def _rd(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return m[:3, :3], m[:3, 3] / np.linalg.norm(m[:3, 3])


@pytest.mark.parametrize("distance_m,pitch_deg,yaw_deg", [(0.5, 1.0, 0.0), (3.0, 1.0, 0.5), (8.0, 1.0, 0.0),
                                                           (9.0, 1.0, 0.0), (9.0, 1.0, -0.4), (2.0, 2.5, 0.0)])
def test_aligning_the_road_bands_reads_the_distance_at_any_speed(distance_m, pitch_deg, yaw_deg):
    g0, g1, m = _drive(distance_m, pitch_deg, yaw_deg)
    q = image_road_q(g0, g1, CAM, *_rd(m), pitch_deg)
    assert HEIGHT_M * q == pytest.approx(distance_m, rel=0.03)


@pytest.mark.parametrize("distance_m", [8.0, 9.0])
def test_a_level_camera_at_speed_reads_nothing_from_the_radial_derivative_not_a_wrong_distance(distance_m):
    # the bands look 14-28 m ahead of a level camera: the derivatives of a road 1.5x nearer in the second
    # image correlate below min_ncc at the right distance (0.37-0.47); the high-passed images still read it
    g0, g1, m = _drive(distance_m, 0.0, -0.4)
    assert np.isnan(image_road_q(g0, g1, CAM, *_rd(m), 0.0))
    q = image_road_q(g0, g1, CAM, *_rd(m), 0.0, ImageRoadConfig(radial=False))
    assert HEIGHT_M * q == pytest.approx(distance_m, rel=0.03)


@pytest.mark.parametrize("radial", [False, True])
@pytest.mark.parametrize("distance_m,pitch_deg,yaw_deg,rows_above", [
    (3.0, 1.0, 0.5, 0.02),      # the rows prepared hold every sample
    (2.0, 1.0, 0.0, -0.2),      # bands and samples reach above them: those rows computed when needed
])
def test_frames_prepared_once_read_exactly_what_the_images_read(distance_m, pitch_deg, yaw_deg, rows_above, radial):
    g0, g1, m = _drive(distance_m, pitch_deg, yaw_deg)
    cfg = ImageRoadConfig(rows_above=rows_above, radial=radial)
    f0, f1 = road_image(g0, CAM, cfg), road_image(g1, CAM, cfg)
    top = road_rows_top(CAM, cfg)
    assert np.isnan(f0.highpass[:top]).all() and np.isfinite(f0.highpass[top:]).all()
    full = image_road_q(g0, g1, CAM, *_rd(m), pitch_deg, ImageRoadConfig(rows_above=10.0, radial=radial))
    assert image_road_q(f0, f1, CAM, *_rd(m), pitch_deg, cfg) == full
    assert np.isfinite(full)


def _lined(texture: np.ndarray, spacing_m: float = 1.75, width_m: float = 0.16, gain: float = 120.0) -> np.ndarray:
    """``texture`` with bright lines along the road (constant in z) every ``spacing_m`` across it."""
    x = np.arange(texture.shape[1]) * _TEXEL_M + _TEX_X0
    lines = (np.abs(((x + spacing_m / 2) % spacing_m) - spacing_m / 2) < width_m / 2) * np.float32(gain)
    return np.clip(texture - 108 + lines[None, :], 0, 255).astype(np.float32)


LINED = _lined(TEX)


@pytest.mark.parametrize("distance_m,texture", [(5.0, "lined"), (7.0, "lined"), (9.0, "plain")])
def test_lines_along_the_road_fool_the_highpassed_images_not_their_radial_derivative(distance_m, texture):
    # lines along the road map onto themselves at any distance: the high-passed images correlate best at
    # the smallest; their derivative away from the epipole (where the texture's motion is) does not see them
    g0, g1, m = _drive(distance_m, 1.0, texture=LINED if texture == "lined" else None)
    assert HEIGHT_M * image_road_q(g0, g1, CAM, *_rd(m), 1.0, ImageRoadConfig(radial=False)) < 0.1 * distance_m
    q = image_road_q(g0, g1, CAM, *_rd(m), 1.0)
    assert HEIGHT_M * q == pytest.approx(distance_m, rel=0.02)


def test_a_featureless_road_reads_nothing():
    flat = np.full((CAM.height, CAM.width), 90, np.uint8)
    _, _, m = _drive(2.0, 1.0)
    assert np.isnan(image_road_q(flat, flat, CAM, *_rd(m), 1.0))


def test_images_of_another_size_are_refused():
    g0, g1, m = _drive(1.0, 1.0)
    with pytest.raises(ValueError, match="188x620"):
        image_road_q(g0[:, :600], g1, CAM, *_rd(m), 1.0)


@pytest.mark.parametrize("given,expected,dropped", [
    # an isolated reading twice its neighbours' is dropped and interpolated
    ([1.0, 1.0, 2.1, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0, 1.0], [0, 0, 1, 0, 0]),
    # ... on a steady speed-up too, and its neighbours are kept
    ([1.0, 1.1, 1.2, 2.6, 1.4, 1.5, 1.6], [1.0, 1.1, 1.2, 1.3, 1.4, 1.5, 1.6], [0, 0, 0, 1, 0, 0, 0]),
    # a car pulling away from a stop (0.25 m more a pair) is not an outlier
    ([0.0, 0.25, 0.5, 0.75, 1.0, 1.25], [0.0, 0.25, 0.5, 0.75, 1.0, 1.25], [0, 0, 0, 0, 0, 0]),
    # with fill_pairs 2: a gap of two pairs is interpolated, one of three is not
    ([1.0, np.nan, np.nan, 1.6, 1.6, np.nan, np.nan, np.nan, 1.6], [1.0, 1.2, 1.4, 1.6, 1.6, np.nan, np.nan, np.nan, 1.6],
     [0] * 9),
    # a gap at either end takes the nearest distance (up to two pairs)
    ([np.nan, 2.0, 2.0, 2.0, np.nan, np.nan], [2.0, 2.0, 2.0, 2.0, 2.0, 2.0], [0] * 6),
    ([np.nan] * 3 + [2.0], [np.nan] * 3 + [2.0], [0] * 4),
    # small distances differ by less than min_jump_m: kept
    ([0.05, 0.05, 0.2, 0.05, 0.05], [0.05, 0.05, 0.2, 0.05, 0.05], [0] * 5),
    ([], [], []),
])
def test_distances_far_from_their_neighbours_are_dropped_and_short_gaps_filled(given, expected, dropped):
    out, was_dropped = check_and_fill(np.array(given, float), RoadSequenceConfig(fill_pairs=2))
    np.testing.assert_allclose(out, expected, atol=1e-12)
    assert was_dropped.tolist() == [bool(x) for x in dropped]


@pytest.mark.parametrize("gap", [1, 6, 7])
def test_the_default_fills_runs_of_up_to_six_pairs(gap):
    # a car at 30 m/s braking at 3 m/s^2: the readings either side of the run, and the line between them
    speeds = 9.0 - 0.9 * np.arange(gap + 2) / (gap + 1)
    given = np.concatenate([[9.0, speeds[0]], np.full(gap, np.nan), [speeds[-1], speeds[-1]]])
    out, _ = check_and_fill(given)
    if gap <= RoadSequenceConfig().fill_pairs:
        np.testing.assert_allclose(out[2:2 + gap], speeds[1:-1], atol=1e-12)
    else:
        assert np.isnan(out[2:2 + gap]).all()


@pytest.mark.parametrize("distance_m,yaw_deg,turns", [
    (0.6, 3.0, True), (0.6, -3.0, True),     # a corner of 11.5 m radius: the path leaves the band straight ahead
    (0.6, 0.3, False),                       # below MIN_TURN_YAW_DEG: a rotation's noise near a stop is no curve
    (0.6, 0.6, False),                       # a 57 m radius: the nearest rows are still on its road
    (9.0, 3.0, False),                       # the same yaw at 30 m/s: a 172 m radius
    (float("nan"), 3.0, False), (0.0, 3.0, False),   # no distance known: no curve
])
def test_a_sharp_turn_is_told_by_its_yaw_over_a_distance_known_beforehand(distance_m, yaw_deg, turns):
    kappa_h = turn_curvature(np.radians(yaw_deg), distance_m / HEIGHT_M, CAM)
    if turns:
        assert kappa_h == pytest.approx(np.radians(yaw_deg) * HEIGHT_M / distance_m)
    else:
        assert kappa_h == 0.0


@pytest.mark.parametrize("kappa_h", [0.14, -0.14, 0.05])
def test_band_rows_follow_the_path_and_rows_beyond_its_radius_drop_out(kappa_h):
    v0, v1, u0, u1 = band_box(CAM, *IMAGE_BANDS[1])
    vv, uu = np.mgrid[v0:v1, u0:u1]
    u, v = _follow_path(uu.ravel(), vv.ravel(), CAM, np.radians(1.0), kappa_h)
    x0 = np.linalg.inv(CAM.k) @ np.stack([u, v, np.ones_like(u)]).astype(float)
    p = np.radians(1.0)
    depth = 1.0 / (np.cos(p) * x0[1] + np.sin(p) * x0[2])          # flat road, in camera heights
    radius = 1.0 / abs(kappa_h)
    assert len(u) and (depth < radius).all() and (u >= 0).all() and (u <= CAM.width - 1).all()
    # each kept pixel sits within the band's half width (0.1 fx, plus a pixel's rounding) of the path
    path_x = np.sign(kappa_h) * (radius - np.sqrt(radius ** 2 - depth ** 2))
    centre_u = CAM.cx + CAM.fx * path_x / depth
    assert (np.abs(u - centre_u) <= 0.1 * CAM.fx + 1.5).all()
    if abs(kappa_h) > 0.1:       # a radius of 7 camera heights: the band's deeper rows (to 8.3) are gone
        assert len(u) < uu.size


@pytest.mark.parametrize("yaw_deg", [3.0, -3.0])
def test_in_a_corner_the_bands_on_the_path_read_the_road_not_the_kerb_straight_ahead(yaw_deg):
    # a kerb stone's top (0.3 m above the road) fills the band straight ahead, 4-14 m out; the path turns away
    img0, img1, m = _drive(0.6, 1.0, yaw_deg, block=(-1.2, 1.2, 4.0, 14.0, HEIGHT_M - 0.3))
    straight = HEIGHT_M * image_road_q(img0, img1, CAM, *_rd(m), 1.0)
    assert straight > 0.6 * 1.1          # the raised top moves like a nearer road: read long
    kappa_h = turn_curvature(np.radians(yaw_deg), 0.6 / HEIGHT_M, CAM)
    on_path = HEIGHT_M * image_road_q(img0, img1, CAM, *_rd(m), 1.0, kappa_h=kappa_h)
    assert on_path == pytest.approx(0.6, rel=0.03)


def _fit(m: np.ndarray, ok: bool = True) -> EpipolarFit:
    r, d = _rd(m)
    return EpipolarFit(ok, r if ok else np.eye(3), d if ok else np.zeros(3), 500, 800, 5.0, road=None)


def test_pairs_without_a_flow_road_are_read_from_their_images():
    drives = [_drive(dist, 1.0) for dist in (2.0, 2.2, 2.4)]
    fits = [_fit(m) for _, _, m in drives]
    mean6 = np.stack([se3.to_euler6(m) for _, _, m in drives]) * np.array([1, 1, 1, 0.6, 0.6, 0.6])  # the network: 40 % short
    cfg = EpipolarConfig(road_height_m=HEIGHT_M)
    road = sequence_road_distances(fits, cfg, mean6, CAM, lambda p: drives[p][:2])
    np.testing.assert_allclose(road.distances_m, [2.0, 2.2, 2.4], rtol=0.03)
    assert road.source == ("images",) * 3 and road.counts()["images"] == 3
    assert road.pitch_deg == pytest.approx(1.0, abs=1e-6)
    # the flow-only reading (--scale road-flow) leaves them to the network
    flow_only = sequence_road_distances(fits, EpipolarConfig(road_height_m=HEIGHT_M, road_fill=False), mean6, CAM,
                                        lambda p: drives[p][:2])
    assert np.isnan(flow_only.distances_m).all() and flow_only.counts()["network"] == 3


def test_a_pair_the_fit_cannot_serve_keeps_the_networks_rotation_and_direction_with_the_roads_distance():
    _, _, m = _drive(3.0, 1.0, 0.5)
    net = se3.to_euler6(m) * np.array([1, 1, 1, 0.5, 0.5, 0.5])
    fused, used = fuse(net, _fit(m, ok=False), EpipolarConfig(road_height_m=HEIGHT_M), distance_m=3.0)
    assert not used
    np.testing.assert_allclose(fused[:3], net[:3], atol=1e-12)
    np.testing.assert_allclose(fused[3:], net[3:] * 2, rtol=1e-9)
    # no distance: the network's motion unchanged
    same, used = fuse(net, _fit(m, ok=False), EpipolarConfig(road_height_m=HEIGHT_M))
    assert not used and np.array_equal(same, net)


@pytest.mark.parametrize("scale,fill", [(None, True), ("road", True), ("road-flow", False)])
def test_vo_on_kitti_records_where_each_distance_came_from(shared_data, tmp_path, scale, fill):
    """`deepslam vo` on KITTI 07 at stride 3 (the shipped default records the road scale): the record counts
    the pairs read from the flow's road, the images, filled between neighbours and left to the network; the
    flow-only reading never uses the images."""
    import json

    from deepslam.cli import main

    out = tmp_path / "t.txt"
    args = ["vo", "--sequence", str(shared_data / "kitti" / "sequences" / "07"), "--end", "31", "--stride", "3",
            "--out", str(out), "--quiet"] + (["--scale", scale] if scale else [])
    assert main(args) == 0
    cfg = json.loads((tmp_path / "t.config.json").read_text())
    assert cfg["epipolar"]["road_height_m"] == 1.65 and cfg["epipolar"]["road_fill"] is fill
    counts = cfg["road_scale_sources"]
    assert sum(counts.values()) == 10 and cfg["road_scale_pairs_used"] == 10 - counts["network"]
    if not fill:
        assert counts["images"] == counts["filled"] == 0


@pytest.mark.parametrize("distance_m", [3.0, 7.0])
def test_shading_fixed_in_the_image_does_not_pull_the_alignment_to_standing_still(distance_m):
    """Vignetting or a brightness ramp that stays put in the image correlates with itself under a near-identity
    warp: the high-pass keeps only the road's texture."""
    g0, g1, m = _drive(distance_m, 1.0)
    v = np.arange(CAM.height, dtype=np.float32)[:, None]
    u = np.arange(CAM.width, dtype=np.float32)[None, :]
    ramp = 60 * (v / CAM.height) + 40 * np.cos((u - CAM.cx) / CAM.width * np.pi) ** 2
    shaded = [np.clip(g.astype(np.float32) * 0.5 + ramp, 0, 255).astype(np.uint8) for g in (g0, g1)]
    q = image_road_q(*shaded, CAM, *_rd(m), 1.0)
    assert HEIGHT_M * q == pytest.approx(distance_m, rel=0.03)


def test_pairs_that_do_not_follow_each_other_are_not_checked_against_each_other():
    """Loop pairs or a hand-picked list: a neighbour is no prediction of a pair's distance."""
    drives = [_drive(dist, 1.0) for dist in (2.0, 5.0, 2.0)]
    fits = [_fit(m) for _, _, m in drives]
    mean6 = np.stack([se3.to_euler6(m) for _, _, m in drives])
    cfg = EpipolarConfig(road_height_m=HEIGHT_M)
    loose = sequence_road_distances(fits, cfg, mean6, CAM, lambda p: drives[p][:2], chained=False)
    np.testing.assert_allclose(loose.distances_m, [2.0, 5.0, 2.0], rtol=0.03)
    chained = sequence_road_distances(fits, cfg, mean6, CAM, lambda p: drives[p][:2])
    assert chained.source[1] == "filled"                  # as a sequence, 5 m between 2 m pairs is a jump
