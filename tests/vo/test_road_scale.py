"""The road-height diagnostic on flow with a known answer."""
import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.gen.flow import synthesize
from deepslam.vo.road_scale import implied_road_height

CAM = PinholeCamera(640, 194, 370.9, 370.9, 319.5, 96.5)


def _road_flow(height_m: float, pitch_deg: float, motion: np.ndarray) -> np.ndarray:
    """Exact flow of a flat road below a camera pitched down by pitch_deg (sky: no depth)."""
    p = np.deg2rad(pitch_deg)
    n = np.array([0.0, np.cos(p), np.sin(p)])                      # world down in the camera frame
    v, u = np.mgrid[0:CAM.height, 0:CAM.width].astype(np.float64)
    rays = np.stack([(u - CAM.cx) / CAM.fx, (v - CAM.cy) / CAM.fy, np.ones_like(u)], -1)
    denom = rays @ n
    depth = np.where(denom > 1e-3, height_m / np.maximum(denom, 1e-3), 0.0).astype(np.float32)
    flow, valid = synthesize(depth, CAM, motion)
    out = flow.numpy().copy()
    out[~valid.numpy()] = np.nan
    return out


@pytest.mark.parametrize("pitch_deg", [-1.0, 0.0, 1.5])
@pytest.mark.parametrize("vec", [[0, 0, 0, 0, 0, -1.0], [0.002, 0.03, 0.0, 0.02, 0.01, -0.6]])
def test_exact_road_flow_gives_the_true_height_and_pitch(pitch_deg, vec):
    motion = se3.from_euler6(vec)
    fit = implied_road_height(_road_flow(1.65, pitch_deg, motion), CAM, motion)
    assert fit.height_m == pytest.approx(1.65, rel=2e-3)
    assert fit.pitch_deg == pytest.approx(pitch_deg, abs=0.05)
    assert fit.residual_px < 1e-2 and fit.pixels > 300


def test_a_flow_that_under_moves_the_road_implies_a_road_farther_below():
    motion = se3.from_euler6([0, 0, 0, 0, 0, -1.0])
    short = implied_road_height(0.8 * _road_flow(1.65, 0.0, motion), CAM, motion)
    assert short.height_m > 1.9
    empty = implied_road_height(np.full((CAM.height, CAM.width, 2), np.nan, np.float32), CAM, motion)
    assert np.isnan(empty.height_m) and empty.pixels == 0
