"""How much road motion does a flow field show? The camera height it implies for the road, given the
true motion (a diagnostic for sim-to-real).

A road plane ``n . X = h`` (``n`` the unit normal pointing down from the camera, ``h`` the camera's
height above the road, both in camera 0) moves under ``cam1_from_cam0 = [R | t]`` by the homography
``H = R + t n^T / h``. Fit ``1 / h`` and the camera's pitch to the flow on a patch of road in front of
the car (rows from ``row_below_horizon`` x fy below the principal point down to the bottom, columns
``half_width`` x fx either side of it), with the TRUE R and t: a flow that shows the road's motion
gives the camera's real height (1.65 m on KITTI and in the simulated street); a flow that
under-estimates the road's motion implies a road farther below (h too large), one that
over-estimates it a nearer one. The network reads metric scale from flow; the road is the one
surface whose distance is the same in every street, so how faithfully an estimator moves it is what
the scale read can rest on.
"""
from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class RoadFit:
    """The plane fitted to one flow field."""

    height_m: float
    """Implied camera height above the road, metres (the true motion's scale over the flow's)."""
    pitch_deg: float
    """Implied pitch of the road normal about the camera x axis, degrees (positive: the camera looks down)."""
    residual_px: float
    """Median absolute flow residual of the fit on the patch, pixels."""
    pixels: int
    """Pixels of the patch with a finite flow."""


def implied_road_height(flow: np.ndarray, camera, cam1_from_cam0: np.ndarray, *, row_below_horizon: float = 0.15,
                        half_width: float = 0.15, step: int = 3, start_height_m: float = 1.65) -> RoadFit:
    """Fit the road plane's ``1 / h`` and pitch to ``flow`` with the true motion.

    Args:
        flow: (H, W, 2) float32 (du, dv) pixels from frame 0 to frame 1 (NaN = unknown).
        camera: :class:`core.camera.PinholeCamera` of the flow's size.
        cam1_from_cam0: (4, 4) float64 true motion (metres, OpenCV axes); its translation should be well
            above the flow's noise (say >= 0.3 m at KITTI's 10 Hz).
        row_below_horizon, half_width: the patch, as fractions of fy below and fx either side of the
            principal point (0.15, 0.15: about 6-16 m ahead of a 1.65 m high camera, +-2 m across).
        step: sample every ``step``-th row and column.
        start_height_m: the fit's starting point.
    """
    from scipy.optimize import least_squares  # deferred: scipy.optimize (~0.4 s) only when a road fit runs

    h, w = flow.shape[:2]
    v0 = int(np.ceil(camera.cy + row_below_horizon * camera.fy))
    u0 = max(0, int(camera.cx - half_width * camera.fx))
    u1 = min(w, int(camera.cx + half_width * camera.fx) + 1)
    vv, uu = np.mgrid[min(v0, h):h:step, u0:u1:step]
    f = flow[vv, uu]
    ok = np.isfinite(f).all(-1)
    uu, vv, f = uu[ok].astype(np.float64), vv[ok].astype(np.float64), f[ok].astype(np.float64)
    if len(uu) < 10:
        return RoadFit(float("nan"), float("nan"), float("nan"), int(len(uu)))
    k = camera.k
    x0 = np.linalg.inv(k) @ np.stack([uu, vv, np.ones_like(uu)])
    r, t = cam1_from_cam0[:3, :3], cam1_from_cam0[:3, 3]

    def residuals(q: np.ndarray) -> np.ndarray:
        inv_h, pitch = q
        n = np.array([0.0, np.cos(pitch), np.sin(pitch)])  # world down, seen from a camera pitched down by `pitch`
        x1 = k @ (r + np.outer(t, inv_h * n)) @ x0
        return np.concatenate([x1[0] / x1[2] - uu - f[:, 0], x1[1] / x1[2] - vv - f[:, 1]])

    sol = least_squares(residuals, np.array([1.0 / start_height_m, 0.0]), loss="soft_l1", f_scale=0.5)
    inv_h = float(sol.x[0])
    return RoadFit(1.0 / inv_h if inv_h > 0 else float("inf"), float(np.degrees(sol.x[1])),
                   float(np.median(np.abs(sol.fun))), int(len(uu)))
