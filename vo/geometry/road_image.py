"""The road read from the images themselves, where the flow loses it (``deepslam vo --scale road``).

The road bands of two frames (:data:`IMAGE_BANDS`, below the principal point) are high-passed
(:func:`road_image`) and aligned over distances ``q`` (metres over the camera height) along the path the
epipolar rotation and direction of travel predict (:func:`image_road_q`): the ``q`` with the best normalised
cross-correlation is the pair's distance over the camera height. Turns bend that path
(:func:`turn_curvature`).
"""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from deepslam.vo.geometry.road_flow import ROAD_BANDS, band_box, path_leaves_band

IMAGE_BANDS = ROAD_BANDS + ((0.03, 0.06),)
"""Bands :func:`image_road_q` compares, tried nearest first (as fractions of fy below the principal point): the
road bands, then one 27-55 m ahead of a 1.65 m high camera for the fastest pairs, when the nearer road leaves
the view or changes scale too much between the frames."""
IMAGE_Q = np.geomspace(0.01, 12.0, 120)
"""Distances over the camera height scanned by :func:`image_road_q` (steps of 6 %, refined by a parabola
through the peak): 1.65 cm to 20 m a pair at a 1.65 m high camera."""
_IMAGE_BAND_POINTS = 3000
"""At most about this many pixels per band are compared (a regular grid)."""


@dataclasses.dataclass(frozen=True)
class ImageRoadConfig:
    """How :func:`image_road_q` aligns the road bands of two images."""

    blur_px: float = 1.5
    """Gaussian blur (sigma, pixels) of both images before they are compared: widens the correlation's peak
    so that the scan's 6 % steps do not step over it."""
    highpass_px: float = 10.0
    """The images compared are the ``blur_px`` blur minus this wider one (sigma, pixels): shading and exposure
    out, the road's texture in (large-scale shading correlates with itself under any warp, a false peak)."""
    min_ncc: float = 0.5
    """A band whose best normalised cross-correlation is below this reads nothing (no road texture)."""
    min_in_view: float = 0.6
    """A distance is scored only where at least this fraction of the band's pixels lands inside image 1."""
    radial: bool = True
    """Compare the high-passed images' derivative along the direction away from each image's epipole (``K c1``
    in image 0, ``K t`` in image 1) instead of the high-passed images: a forward-moving camera moves the road's
    texture that way, while lines along the road (which map onto themselves at any distance, a false peak at the
    smallest, and converge at the epipole) have none of it."""
    rows_above: float = 0.02
    """:class:`RoadImage` high-passes the rows from this fraction of fy above the farthest band down (the road
    and its motion; rows a sample reaches above them are computed when needed)."""


def _blur_radius_px(sigma: float) -> int:
    """Rows either side that OpenCV's Gaussian blur of a float image reads (its kernel is 8 sigma + 1 wide)."""
    return int(np.ceil(4.0 * sigma)) + 1


def road_rows_top(camera, cfg: ImageRoadConfig = ImageRoadConfig()) -> int:
    """First image row of :class:`RoadImage`'s high-passed rows: ``cfg.rows_above`` x fy above the farthest
    band of :data:`IMAGE_BANDS` (clipped to the image)."""
    return max(0, int(np.floor(camera.cy + (min(b[0] for b in IMAGE_BANDS) - cfg.rows_above) * camera.fy)))


@dataclasses.dataclass(frozen=True, eq=False)
class RoadImage:
    """One frame prepared for :func:`image_road_q` (:func:`road_image`): the difference of its two blurs,
    computed only on the rows the road bands and their motion reach. Consecutive pairs share a frame, so a
    sequence prepares each frame once."""

    highpass: np.ndarray
    """(H, W) float32 ``cfg.blur_px`` blur minus ``cfg.highpass_px`` blur of the grey image (grey levels; with
    ``cfg.radial`` (H, W, 2) its x and y derivatives); NaN in the rows above :func:`road_rows_top` (not
    computed)."""
    grey: np.ndarray
    """(H, W) the grey image it was made from (to compute the rows above, should a sample need them)."""
    cfg: ImageRoadConfig
    """The settings of the blurs."""


def _highpass(grey: np.ndarray, cfg: ImageRoadConfig, top: int = 0) -> np.ndarray:
    """(H, W) float32 ``cfg.blur_px`` blur minus ``cfg.highpass_px`` blur of ``grey`` (with ``cfg.radial``:
    (H, W, 2) its x and y derivatives, Sobel 3x3, grey levels per pixel), exact from row ``top`` on (NaN
    above it): the blur is computed on the rows from ``top`` less the blur's reach, so that the rows kept
    see the same neighbourhood, and the same values, as a blur of the whole image."""
    g = np.asarray(grey, np.float32)
    start = max(0, top - _blur_radius_px(max(cfg.blur_px, cfg.highpass_px)) - 1)
    crop = g[start:]
    band = cv2.GaussianBlur(crop, (0, 0), cfg.blur_px) - cv2.GaussianBlur(crop, (0, 0), cfg.highpass_px)
    if cfg.radial:
        band = np.stack([cv2.Sobel(band, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(band, cv2.CV_32F, 0, 1, ksize=3)], -1)
    out = np.full(g.shape + band.shape[2:], np.nan, np.float32)
    out[start:] = band
    out[:top] = np.nan
    return out


def road_image(grey: np.ndarray, camera, cfg: ImageRoadConfig = ImageRoadConfig()) -> RoadImage:
    """:class:`RoadImage` of a (H, W) uint8 or float grey image at ``camera``'s size."""
    return RoadImage(_highpass(grey, cfg, road_rows_top(camera, cfg)), np.asarray(grey), cfg)


def _point(x: np.ndarray, camera) -> tuple[float, float]:
    """Pixel (u, v) of the homogeneous (3,) image point ``x``; the principal point where it lies at infinity."""
    if abs(x[2]) < 1e-9:
        return camera.cx, camera.cy
    return float(x[0] / x[2]), float(x[1] / x[2])


def _along(grad: np.ndarray, u, v, centre: tuple[float, float]) -> np.ndarray:
    """(..., 2) x/y derivatives at pixels (u, v) (arrays of its leading shape) projected on the unit direction
    away from ``centre`` -> (...) float64."""
    du, dv = np.asarray(u, np.float64) - centre[0], np.asarray(v, np.float64) - centre[1]
    n = np.sqrt(du * du + dv * dv) + 1e-9
    return (grad[..., 0] * du + grad[..., 1] * dv) / n


MIN_TURN_YAW_DEG = 0.5
"""A pair turning less than this (degrees) keeps its bands straight ahead whatever its distance: 15 times the
epipolar fit's rotation error on the rendered street (0.03 deg a pair), so that near a stop a rotation's noise
over a tiny distance is no tight curve; corners turn 3-10 degrees a pair at strides 1-3."""


def turn_curvature(yaw: float, q_prior: float, camera) -> float:
    """The path's curvature times the camera height (1 / radius in camera heights, signed: positive turning
    towards +x) where a pair's turn is so sharp that its path leaves the nearest image band by the band's
    nearest visible row (:func:`path_leaves_band`); 0.0 elsewhere (and where ``q_prior`` is not a positive
    number, or the yaw is below :data:`MIN_TURN_YAW_DEG`), so that straight roads and gentle bends keep the
    bands straight ahead.

    Args:
        yaw: the pair's heading change, radians (:func:`yaw_rad`).
        q_prior: a distance of the pair over the camera height known before its images are aligned (a
            neighbour's road reading or the network's): the curvature is ``yaw / q_prior``. Taken from the
            alignment's own scanned distance, a rotation's noise over a small scanned distance would look
            like a tight curve (bench/criteria/2026-12-05_road_image_turns.md).
        camera: :class:`core.camera.PinholeCamera` of the images.
    """
    if not (np.isfinite(yaw) and abs(yaw) >= np.radians(MIN_TURN_YAW_DEG) and np.isfinite(q_prior) and q_prior > 0):
        return 0.0
    r_near = min(max(b[1] for b in IMAGE_BANDS), (camera.height - 1 - camera.cy) / camera.fy)
    kappa_h = float(yaw) / float(q_prior)
    return kappa_h if r_near > 0 and path_leaves_band(kappa_h, 1.0 / r_near) else 0.0


def _follow_path(uu: np.ndarray, vv: np.ndarray, camera, pitch_rad: float, kappa_h: float):
    """Band pixels ``(uu, vv)`` moved sideways onto a path of curvature ``kappa_h`` (1 / radius in camera
    heights, signed): each row's road point at depth ``Z`` (in camera heights, flat road at the pitch) is
    shifted by the path's offset ``X(Z) = r - sqrt(r^2 - Z^2)`` to the side it turns, ``fx X / Z`` pixels;
    rows deeper than the radius (the path never gets that far ahead) and pixels leaving the image drop out."""
    x0 = np.linalg.inv(camera.k) @ np.stack([uu, vv, np.ones_like(uu)]).astype(np.float64)
    nx = np.cos(pitch_rad) * x0[1] + np.sin(pitch_rad) * x0[2]
    radius = 1.0 / abs(kappa_h)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(nx > 1e-9, 1.0 / nx, np.inf)
        offset = np.sign(kappa_h) * (radius - np.sqrt(np.maximum(radius * radius - depth * depth, 0.0)))
        du = np.rint(camera.fx * offset / depth)
    u = uu + np.nan_to_num(du, nan=0.0).astype(np.int64)
    keep = (depth < radius) & (u >= 0) & (u <= camera.width - 1)
    return u[keep], vv[keep]


def image_road_q(grey0, grey1, camera, rotation: np.ndarray, direction: np.ndarray,
                 pitch_deg: float, cfg: ImageRoadConfig = ImageRoadConfig(), kappa_h: float = 0.0) -> float:
    """Distance travelled over the camera's height, ``q = |t| / h``, from the road's appearance in two images.

    With the rotation and the direction of travel known, the road plane moves by the homography
    ``K (R + q d n^T) K^-1`` (``n`` the road's normal at the camera pitch ``pitch_deg``): one unknown. Each
    band of :data:`IMAGE_BANDS` (ego lane, ``ROAD_HALF_WIDTH`` x fx either side of the principal point) of
    image 0 is compared with image 1 sampled through the homography of every ``q`` of :data:`IMAGE_Q`
    (normalised cross-correlation of the high-passed images over the pixels landing inside image 1). The
    nearest band whose correlation peaks inside the scanned range, with both neighbours scored and a peak of
    at least ``cfg.min_ncc``, gives ``q`` (parabola through the peak in log q). Unlike a flow estimator's
    patch search, the homography follows the road's large motion and its change of scale at any speed.

    Args:
        grey0, grey1: (H, W) uint8 or float images of the two frames at the camera's size, or their
            :class:`RoadImage` (prepared once per frame: :func:`road_image`).
        camera: :class:`core.camera.PinholeCamera` of the images (undistorted).
        rotation: (3, 3) rotation of ``cam1_from_cam0``; direction: (3,) its unit translation.
        pitch_deg: the camera's pitch over the road, degrees (positive: looking down).
        kappa_h: the path's curvature times the camera height in a sharp turn (:func:`turn_curvature`); nonzero:
            each band's rows are moved sideways onto the path (:func:`_follow_path`), off the kerb and the cars
            parked along it that the bands straight ahead look at (they stand above the road and read long).

    Returns:
        ``q`` (float, dimensionless), NaN where no band reads.
    """
    h, w = camera.height, camera.width
    shapes = [(i.grey if isinstance(i, RoadImage) else np.asarray(i)).shape[:2] for i in (grey0, grey1)]
    if shapes[0] != (h, w) or shapes[1] != (h, w):
        raise ValueError(f"images must be {h}x{w} for this camera, got {shapes[0]} and {shapes[1]}")
    k = camera.k
    kr = k @ np.asarray(rotation, np.float64)
    kd = k @ np.asarray(direction, np.float64)
    p = np.radians(pitch_deg)
    if int(np.ceil(camera.cy + min(b[0] for b in IMAGE_BANDS) * camera.fy)) >= h:
        return float("nan")

    def prepared(img) -> RoadImage:
        if isinstance(img, RoadImage) and img.cfg == cfg:
            return img
        return road_image(img.grey if isinstance(img, RoadImage) else img, camera, cfg)

    frames = (prepared(grey0), prepared(grey1))
    g0, g1 = frames[0].highpass, frames[1].highpass
    whole: dict[int, np.ndarray] = {}

    def all_rows(i: int) -> np.ndarray:     # a sample above the prepared rows: the frame's every row
        if i not in whole:
            whole[i] = _highpass(frames[i].grey, cfg)
        return whole[i]

    # the points the road's texture moves away from: the epipoles of image 0 (K c1) and image 1 (K t)
    foe = (_point(k @ (-np.asarray(rotation, np.float64).T @ np.asarray(direction, np.float64)), camera),
           _point(kd, camera))
    log_q = np.log(IMAGE_Q)
    for r0, r1 in sorted(IMAGE_BANDS, key=lambda b: -b[0]):     # nearest band first
        v0, v1, u0, u1 = band_box(camera, r0, r1)
        if v1 - v0 < 2 or u1 - u0 < 2:
            continue
        step = max(1, int(np.ceil(np.sqrt((v1 - v0) * (u1 - u0) / _IMAGE_BAND_POINTS))))
        vv, uu = np.mgrid[v0:v1:step, u0:u1:step]
        uu, vv = uu.ravel(), vv.ravel()
        if kappa_h:
            n_band = len(uu)
            uu, vv = _follow_path(uu, vv, camera, p, kappa_h)
            if len(uu) < 0.5 * n_band:      # most of the band's rows lie beyond the turn's radius
                continue
        ref = g0[vv, uu]
        ref = (all_rows(0)[vv, uu] if np.isnan(ref).any() else ref).astype(np.float64)
        if cfg.radial:
            ref = _along(ref, uu, vv, foe[0])
        x0 = np.linalg.inv(k) @ np.stack([uu, vv, np.ones_like(uu)]).astype(np.float64)
        nx = np.cos(p) * x0[1] + np.sin(p) * x0[2]
        x1 = (kr @ x0)[None] + IMAGE_Q[:, None, None] * kd[None, :, None] * nx[None, None, :]   # (Q, 3, N)
        z = x1[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            mu, mv = x1[:, 0] / z, x1[:, 1] / z
        inside = (z > 1e-9) & (mu >= 0) & (mu <= w - 1) & (mv >= 0) & (mv <= h - 1)
        map_u, map_v = np.where(inside, mu, -10).astype(np.float32), np.where(inside, mv, -10).astype(np.float32)
        samples = cv2.remap(g1, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        if np.isnan(samples[inside]).any():
            samples = cv2.remap(all_rows(1), map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                borderValue=0)
        samples = samples.astype(np.float64)
        if cfg.radial:
            samples = _along(samples, mu, mv, foe[1])
        wgt = inside.astype(np.float64)
        cnt = wgt.sum(axis=1)
        scored = cnt >= cfg.min_in_view * len(ref)
        cnt = np.maximum(cnt, 1.0)
        m0 = (wgt * ref[None]).sum(axis=1) / cnt
        m1 = (wgt * samples).sum(axis=1) / cnt
        a0 = wgt * (ref[None] - m0[:, None])
        a1 = wgt * (samples - m1[:, None])
        den = np.sqrt((a0 * a0).sum(axis=1) * (a1 * a1).sum(axis=1))
        ncc = np.where(scored & (den > 1e-9), (a0 * a1).sum(axis=1) / np.maximum(den, 1e-12), np.nan)
        if not np.isfinite(ncc).any():
            continue
        i = int(np.nanargmax(ncc))
        if not (0 < i < len(ncc) - 1 and np.isfinite(ncc[i - 1]) and np.isfinite(ncc[i + 1])) or ncc[i] < cfg.min_ncc:
            continue
        c_l, c_0, c_r = ncc[i - 1], ncc[i], ncc[i + 1]
        curv = c_l - 2 * c_0 + c_r
        shift = 0.5 * (c_l - c_r) / curv if curv < 0 else 0.0
        dq = log_q[1] - log_q[0]
        return float(np.exp(log_q[i] + float(np.clip(shift, -0.5, 0.5)) * dq))
    return float("nan")
