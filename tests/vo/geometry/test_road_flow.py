"""The distance travelled read from the road (``deepslam vo --scale road``): exact on an exact road
flow, the camera's pitch from the direction of travel, untrusted fits left to the network."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.vo.geometry.road_flow import (ROAD_BANDS, RoadScaleConfig, path_leaves_band, road_distances, road_parallel, scan_road, travel_pitch_deg, yaw_rad)

CAM = PinholeCamera(620, 188, 359.4, 359.4, 309.5, 93.5)


def _pitched(pitch_deg: float) -> np.ndarray:
    """(3, 3) world-level-from-camera rotation of a camera pitched down by ``pitch_deg`` (OpenCV axes)."""
    p = np.radians(pitch_deg)
    return np.array([[1, 0, 0], [0, np.cos(p), np.sin(p)], [0, -np.sin(p), np.cos(p)]], float)


def _road_flow(distance_m: float, pitch_deg: float, yaw_deg: float = 0.0, height_m: float = 1.65):
    """Exact flow of a flat road ``height_m`` below a camera pitched ``pitch_deg`` down that drives
    ``distance_m`` forward (turning ``yaw_deg``); NaN above the horizon. Returns (flow, cam1_from_cam0)."""
    level_from_cam = _pitched(pitch_deg)
    # motion in the level frame (x right, y down, z forward): forward, a small turn
    yaw = np.radians(yaw_deg)
    r_level = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    level1_from_level0 = se3.from_rt(r_level.T, -r_level.T @ np.array([0.0, 0.0, distance_m]))
    to_level = se3.from_rt(level_from_cam, np.zeros(3))
    cam1_from_cam0 = se3.inverse(to_level) @ level1_from_level0 @ to_level
    v, u = np.mgrid[0:CAM.height, 0:CAM.width].astype(np.float64)
    rays = np.linalg.inv(CAM.k) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    down = level_from_cam[1] @ rays                       # the ray's downward component in the level frame
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(down > 1e-3, height_m / down, np.nan)
    pts = rays * depth
    p1 = cam1_from_cam0[:3, :3] @ pts + cam1_from_cam0[:3, 3:4]
    uv = CAM.k @ p1
    flow = np.stack([uv[0] / uv[2] - u.ravel(), uv[1] / uv[2] - v.ravel()], -1).reshape(CAM.height, CAM.width, 2)
    return flow.astype(np.float32), cam1_from_cam0


@pytest.mark.parametrize("distance_m,pitch_deg", [(0.4, 1.0), (1.2, 0.0), (3.0, 1.5), (6.0, 1.0)])
def test_an_exact_road_flow_gives_the_distance_travelled(distance_m, pitch_deg):
    scans, rots, dirs = [], [], []
    for yaw in (0.0, 0.5, -0.3):
        flow, m = _road_flow(distance_m, pitch_deg, yaw)
        d = m[:3, 3] / np.linalg.norm(m[:3, 3])
        scans.append(scan_road(flow, CAM, m[:3, :3], d))
        rots.append(m[:3, :3])
        dirs.append(d)
    pitch = travel_pitch_deg(rots, dirs)
    assert pitch == pytest.approx(pitch_deg, abs=1e-6)
    dist = road_distances(scans, pitch, RoadScaleConfig(max_flow_frac=1.0))
    np.testing.assert_allclose(dist, distance_m, rtol=0.01)


@pytest.mark.parametrize("straight,corners,expected_deg", [
    (12, 30, 1.0),    # enough straight pairs: the corners' motion, read 0.3 deg up, is left out
    (9, 30, 1.3),     # too few: every pair counts, and the corners pull the median up
    (0, 5, 1.3),
])
def test_the_travel_pitch_comes_from_pairs_that_do_not_turn(straight, corners, expected_deg):
    rots, dirs = [], []
    for k in range(straight + corners):
        yaw = 0.2 if k < straight else 6.0
        _, m = _road_flow(1.5, 1.0, yaw)
        d = m[:3, 3] / np.linalg.norm(m[:3, 3])
        if k >= straight:   # the corner's fit: the motion read 0.3 deg upwards (about the camera's x axis)
            lift = np.radians(0.3)
            up = np.array([[1, 0, 0], [0, np.cos(lift), -np.sin(lift)], [0, np.sin(lift), np.cos(lift)]])
            d = -m[:3, :3] @ (up @ (-m[:3, :3].T @ d))
        rots.append(m[:3, :3])
        dirs.append(d)
    assert travel_pitch_deg(rots, dirs) == pytest.approx(expected_deg, abs=0.01)


def test_a_flow_that_is_not_a_road_is_left_to_the_network():
    flow, m = _road_flow(1.0, 1.0)
    rng = np.random.default_rng(0)
    noisy = flow + rng.normal(0, 20.0, flow.shape).astype(np.float32)
    d = m[:3, 3] / np.linalg.norm(m[:3, 3])
    dist = road_distances([scan_road(noisy, CAM, m[:3, :3], d), None], 1.0)
    assert np.isnan(dist).all()
    assert np.isnan(road_distances([scan_road(flow, CAM, m[:3, :3], d)], float("nan"))).all()


def test_a_road_flow_too_large_for_the_near_rows_is_read_on_farther_rows():
    flow, m = _road_flow(4.0, 1.0)
    d = m[:3, 3] / np.linalg.norm(m[:3, 3])
    scan = scan_road(flow, CAM, m[:3, :3], d)
    assert scan.flow90_px[1].max() > 0.02 * CAM.width   # the near band moves more than the limit
    np.testing.assert_allclose(road_distances([scan], 1.0), 4.0, rtol=0.01)


@pytest.mark.parametrize("pitch_deg", [-3.0, -1.5, 0.1, 1.0, 1.125, 3.5, 9.0])
def test_a_scan_at_a_pitch_is_its_tables_interpolated_and_fits_only_that_pitchs_neighbours(pitch_deg):
    """RoadScan fits a pitch when asked: at_pitch gives what the whole tables interpolated give (clipped to the
    scanned pitches), having fitted only the two pitches either side (of 21), each band."""
    from deepslam.vo.geometry.road_flow import PITCHES_DEG

    flow, m = _road_flow(1.5, 1.0, 0.4)
    d = m[:3, 3] / np.linalg.norm(m[:3, 3])
    lazy, whole = scan_road(flow, CAM, m[:3, :3], d), scan_road(flow, CAM, m[:3, :3], d)
    got = lazy.at_pitch(pitch_deg)
    assert len(lazy._fits) == 2 * len(ROAD_BANDS)
    x = np.clip(pitch_deg, PITCHES_DEG[0], PITCHES_DEG[-1])
    for value, table in zip(got, (whole.q, whole.cost_px, whole.flow90_px)):
        expected = [np.interp(x, PITCHES_DEG, row) for row in table]
        np.testing.assert_allclose(value, expected, rtol=1e-12, atol=1e-12)
    assert np.isfinite(got[0]).all() and lazy.width == CAM.width


@pytest.mark.parametrize("yaw_deg", [3.0, -2.0, 0.0])
def test_yaw_is_the_turn_about_the_vertical_axis(yaw_deg):
    _, m = _road_flow(0.5, 1.0, yaw_deg)
    assert np.degrees(yaw_rad(m[:3, :3])) == pytest.approx(yaw_deg, abs=0.01)


def _level_motion(yaw_deg: float, pitch_deg: float, level_motion: np.ndarray) -> np.ndarray:
    """(4, 4) cam1_from_cam0 of a camera pitched ``pitch_deg`` down that turns ``yaw_deg`` about the level
    vertical while moving by ``level_motion`` (3,) in camera 0's level axes (x right, y down, z forward)."""
    yaw = np.radians(yaw_deg)
    r_level = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    to_level = se3.from_rt(_pitched(pitch_deg), np.zeros(3))
    return se3.inverse(to_level) @ se3.inverse(se3.from_rt(r_level, level_motion)) @ to_level


@pytest.mark.parametrize("yaw_deg,pitch_deg,motion", [
    (0.0, 1.0, (0.0, 0.0, 3.0)),      # straight ahead
    (9.0, 1.0, (0.2, 0.0, 1.5)),      # a corner's chord
    (9.0, 1.0, (0.45, 0.0, 1.5)),     # the same with a camera 0.84 m ahead of the axle: slides sideways
    (-4.0, 0.0, (-0.3, 0.0, 2.0)),
    (3.0, 2.5, (0.1, 0.0, -1.0)),     # reversing
])
def test_a_direction_in_the_roads_plane_keeps_its_heading_and_one_off_it_returns_to_it(yaw_deg, pitch_deg, motion):
    """Only the part along the road's normal is removed: any heading, a lever arm's slide included, stays."""
    m_level = np.array(motion, float)
    cam1_from_cam0 = _level_motion(yaw_deg, pitch_deg, m_level)
    r, t = cam1_from_cam0[:3, :3], cam1_from_cam0[:3, 3]
    d = t / np.linalg.norm(t)
    np.testing.assert_allclose(road_parallel(r, d, pitch_deg), d, atol=1e-12)
    # tilted 0.5 deg out of the road's plane (as the fit reads it at speed): back to the in-plane direction
    off = np.radians(0.5) * np.linalg.norm(m_level)
    t_off = -r @ (_pitched(pitch_deg).T @ (m_level - np.array([0.0, off, 0.0])))   # camera 1 a little higher
    d_off = t_off / np.linalg.norm(t_off)
    assert np.degrees(np.arccos(np.clip(d_off @ d, -1, 1))) > 0.4
    got = road_parallel(r, d_off, pitch_deg)
    np.testing.assert_allclose(got, d, atol=1e-12)
    assert np.linalg.norm(got) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("curvature,ahead_m,leaves", [
    (0.0, 13.75, False), (0.005, 13.75, False), (-0.005, 13.75, False),   # straight, a gentle bend: in the band
    (0.02, 13.75, True), (-0.02, 13.75, True),                           # 0.2 x 13.75 / 2: beyond 0.1 x 13.75
    (0.1, 13.75, True),                                                  # a 10 m radius never gets 13.75 m ahead
    (0.02, 6.0, False),                                                  # nearer rows are still on its road
])
def test_a_tight_turn_leaves_the_band_straight_ahead(curvature, ahead_m, leaves):
    assert path_leaves_band(curvature, ahead_m) is leaves


def _far_band_on_the_roadside(distance_m: float, yaw_deg: float):
    """A road flow whose far band's rows move like a surface 0.9 m below the camera instead of 1.65 m (the
    kerb, parked cars and walls straight ahead in a turn read ~1.8x), and its scan."""
    flow, m = _road_flow(distance_m, 1.0, yaw_deg)
    near_things, _ = _road_flow(distance_m, 1.0, yaw_deg, height_m=0.9)
    v0, v1 = int(np.ceil(CAM.cy + ROAD_BANDS[0][0] * CAM.fy)), int(CAM.cy + ROAD_BANDS[0][1] * CAM.fy) + 1
    flow[v0:v1] = near_things[v0:v1]
    d = m[:3, 3] / np.linalg.norm(m[:3, 3])
    return scan_road(flow, CAM, m[:3, :3], d), m


def test_in_a_tight_turn_the_near_band_is_read_not_the_roadside_ahead():
    scan, m = _far_band_on_the_roadside(0.45, 3.0)
    assert road_distances([scan], 1.0)[0] == pytest.approx(0.45 * 1.65 / 0.9, rel=0.03)    # judged by the far band
    assert road_distances([scan], 1.0, yaws_rad=[yaw_rad(m[:3, :3])])[0] == pytest.approx(0.45, rel=0.02)


def test_on_a_straight_road_the_yaw_changes_nothing():
    scan, m = _far_band_on_the_roadside(0.45, 0.1)
    assert road_distances([scan], 1.0, yaws_rad=[yaw_rad(m[:3, :3])])[0] == road_distances([scan], 1.0)[0]
