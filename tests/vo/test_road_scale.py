"""The distance travelled read from the road (``deepslam vo --scale road``): exact on an exact road
flow, the camera's pitch from the direction of travel, untrusted fits left to the network."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.vo.road_scale import RoadScaleConfig, road_distances, scan_road, travel_pitch_deg

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
