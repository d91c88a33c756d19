"""Depth as a structured-light sensor (Kinect v1 / PrimeSense, as in TUM RGB-D) would report it.

:func:`kinect_depth` turns an exact rendered depth_z map into sensor-like depth, following the error
models of Khoshelham & Elberink (2012) and Nguyen, Izadi & Lovell (2012):

1. range: no reading nearer than 0.5 m or farther than 4.5 m (0 = no reading, as TUM's PNGs);
2. axial noise, Gaussian with sigma_z(z) = 0.0012 + b (z - 0.4)^2 metres (Nguyen et al.'s form; b fitted
   to TUM's depth, see :class:`KinectModel`);
3. quantisation of the disparity the sensor measures: d = f_ir b / z with f_ir = 580 px and b = 0.075 m
   between projector and IR camera, in steps of 1/8 px, so the depth steps grow as z^2 (about 3 mm at
   1 m, 2.4 cm at 3 m);
4. missing readings where the projected pattern is not seen: at depth discontinuities (a band of
   ``edge_px`` pixels on the far side of a jump of more than 5 % of the depth: the projector's shadow
   and mixed pixels), on surfaces seen at grazing angles (more than ``max_incidence_deg`` from the
   ray), and a sparse speckle of single-pixel drop-outs.

The result is deterministic for a given ``rng``. The ground truth stays exact: the simulator computes
flow and poses from the exact depth and writes that depth beside the sensor's (``depth_exact/``).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage

from deepslam.core.camera import PinholeCamera


@dataclasses.dataclass(frozen=True)
class KinectModel:
    """Parameters of the structured-light error model (defaults: Kinect v1)."""

    min_range_m: float = 0.5
    """No reading nearer than this, metres."""
    max_range_m: float = 4.5
    """No reading farther than this, metres."""
    sigma_a_m: float = 0.0012
    """Axial noise sigma_z = sigma_a + sigma_b (z - z0)^2: constant part, metres."""
    sigma_b_per_m: float = 0.0011
    """... quadratic coefficient, 1/m. Nguyen et al. give 0.0019 for a raw Kinect; TUM's registered
    depth is smoother: 0.0011 matches the teddy slice's plane-fit residuals (6.7 mm at 2-3 m, 14 mm at
    3-4.5 m; 0.0019 gave 1.3-1.7 times those)."""
    sigma_z0_m: float = 0.4
    """... the depth where the quadratic part vanishes, metres."""
    focal_ir_px: float = 580.0
    """Focal length of the IR camera that measures disparity, pixels."""
    baseline_m: float = 0.075
    """Projector-to-IR-camera baseline, metres."""
    disparity_step_px: float = 0.125
    """Disparity resolution (1/8 px)."""
    edge_px: int = 2
    """Width of the band without readings on the far side of a depth discontinuity, pixels."""
    edge_rel_jump: float = 0.05
    """A neighbour more than this fraction nearer makes a discontinuity."""
    max_incidence_deg: float = 78.0
    """No reading where the surface normal is farther than this from the viewing ray, degrees."""
    speckle_fraction: float = 0.003
    """Fraction of single-pixel drop-outs."""


def _normals_incidence(depth_z: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """(H, W) cosine between each pixel's viewing ray and its surface normal (from depth gradients)."""
    h, w = depth_z.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    z = depth_z.astype(np.float64)
    p = np.stack([(u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z], axis=-1)
    du = np.zeros_like(p)
    dv = np.zeros_like(p)
    du[:, 1:-1] = p[:, 2:] - p[:, :-2]
    dv[1:-1] = p[2:] - p[:-2]
    n = np.cross(du, dv)
    n_norm = np.linalg.norm(n, axis=-1)
    r_norm = np.linalg.norm(p, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(np.sum(n * p, axis=-1)) / (n_norm * r_norm)
    return np.nan_to_num(cos, nan=1.0)


def kinect_depth(depth_z: np.ndarray, camera: PinholeCamera, rng: np.random.Generator,
                 model: KinectModel = KinectModel()) -> np.ndarray:
    """Sensor-like depth_z (H, W) float32 metres, 0 = no reading, from an exact render's depth_z.

    Args:
        depth_z: (H, W) float32 exact depth_z, metres (0 = nothing hit).
        camera: the intrinsics of the image (for surface normals).
        rng: the noise's generator (pass one seeded from the frame for determinism).
        model: the error model's parameters.
    """
    z = np.asarray(depth_z, dtype=np.float64)
    valid = np.isfinite(z) & (z >= model.min_range_m) & (z <= model.max_range_m)
    sigma = model.sigma_a_m + model.sigma_b_per_m * (z - model.sigma_z0_m) ** 2
    noisy = z + rng.standard_normal(z.shape) * sigma
    fb = model.focal_ir_px * model.baseline_m
    with np.errstate(divide="ignore", invalid="ignore"):
        disparity = fb / noisy
        disparity = np.round(disparity / model.disparity_step_px) * model.disparity_step_px
        quantised = fb / disparity
    # far side of depth discontinuities: a pixel with a clearly nearer neighbour (4-neighbourhood)
    near_min = ndimage.minimum_filter(np.where(z > 0, z, np.inf), size=3, mode="nearest")
    edge = (z > 0) & (near_min < z * (1.0 - model.edge_rel_jump))
    if model.edge_px > 1:
        edge = ndimage.binary_dilation(edge, iterations=model.edge_px - 1) & (z > 0) & \
            (ndimage.minimum_filter(np.where(z > 0, z, np.inf), size=2 * model.edge_px + 1, mode="nearest")
             < z * (1.0 - model.edge_rel_jump))
    grazing = _normals_incidence(z, camera) < np.cos(np.radians(model.max_incidence_deg))
    speckle = rng.random(z.shape) < model.speckle_fraction
    keep = valid & ~edge & ~grazing & ~speckle & np.isfinite(quantised) & (quantised > 0)
    return np.where(keep, quantised, 0.0).astype(np.float32)


def depth_statistics(depth_z: np.ndarray, patch: int = 7, max_residual_m: float = 0.05) -> dict:
    """What a depth map looks like to a user: the fraction without readings, and the noise of the
    readings against a local plane (least-squares plane z = a u + b v + c over ``patch`` x ``patch``
    windows that are fully valid; residual std per window, binned by depth).

    Returns ``{"hole_fraction", "plane_residual_std_m": {bin label: median std}}`` with bins
    0.5-1, 1-1.5, 1.5-2, 2-3, 3-4.5 m.
    """
    z = np.asarray(depth_z, dtype=np.float64)
    h, w = z.shape
    hole = ~(np.isfinite(z) & (z > 0))
    bins = [(0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 3.0), (3.0, 4.5)]
    per_bin: dict[str, list[float]] = {f"{a:g}-{b:g} m": [] for a, b in bins}
    vv, uu = np.mgrid[0:patch, 0:patch].astype(np.float64)
    a_mat = np.stack([uu.ravel(), vv.ravel(), np.ones(patch * patch)], axis=1)
    pinv = np.linalg.pinv(a_mat)
    for r in range(0, h - patch + 1, patch):
        for c in range(0, w - patch + 1, patch):
            win = z[r:r + patch, c:c + patch]
            if hole[r:r + patch, c:c + patch].any():
                continue
            coef = pinv @ win.ravel()
            res = win.ravel() - a_mat @ coef
            if np.abs(res).max() > max_residual_m:  # not a plane (an edge or a curved surface)
                continue
            m = float(win.mean())
            for a, b in bins:
                if a <= m < b:
                    per_bin[f"{a:g}-{b:g} m"].append(float(res.std()))
    return {"hole_fraction": float(hole.mean()),
            "plane_residual_std_m": {k: (float(np.median(v)) if v else None) for k, v in per_bin.items()}}
