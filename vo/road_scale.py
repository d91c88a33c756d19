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

import cv2
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


# ----------------------------------------------------------------------------------------------
# distance travelled from the road (deepslam vo --scale road)
# ----------------------------------------------------------------------------------------------

ROAD_BANDS = ((0.06, 0.12), (0.12, 0.25))
"""Bands of image rows scanned for the road, far to near, as fractions of fy below the principal point
(for a camera 1.65 m up: about 14-27 m and 7-14 m ahead), each ``ROAD_HALF_WIDTH`` x fx either side of
the principal point (the ego lane, clear of cars parked along the kerbs). Rows nearer the horizon hold
too little of the road's motion (on the rendered street they read 25 % long)."""
ROAD_HALF_WIDTH = 0.1
PITCHES_DEG = np.arange(-1.5, 3.51, 0.25)
"""Camera pitches scanned (degrees, positive: looking down); the sequence's pitch is interpolated between them."""
_Q_COARSE = np.geomspace(0.005, 12.0, 40)
_BAND_POINTS = 600
"""At most about this many pixels per band (a regular grid): the median of the fit needs no more."""


def _band_box(camera, r0: float, r1: float) -> tuple[int, int, int, int]:
    """Pixel box ``(v0, v1, u0, u1)`` (rows ``v0:v1``, columns ``u0:u1``) of the band ``r0``-``r1`` x fy below
    the principal point, ``ROAD_HALF_WIDTH`` x fx either side of it, clipped to the image (``v0`` may lie below
    it)."""
    v0, v1 = int(np.ceil(camera.cy + r0 * camera.fy)), min(camera.height, int(camera.cy + r1 * camera.fy) + 1)
    u0 = max(0, int(camera.cx - ROAD_HALF_WIDTH * camera.fx))
    u1 = min(camera.width, int(camera.cx + ROAD_HALF_WIDTH * camera.fx) + 1)
    return v0, v1, u0, u1


class RoadScan:
    """How well the road's motion in one flow fits each distance, per row band and camera pitch.

    With the rotation and direction of travel known (the epipolar fit), a road plane ``h`` below the camera
    moves by the homography ``R + q d n^T`` with ``q = |t| / h``: one unknown per pitch. For each band of
    :data:`ROAD_BANDS` and pitch of :data:`PITCHES_DEG`, the ``q`` whose homography moves the band's pixels
    most like the flow (smallest median end-point difference) is kept.

    Made by :func:`scan_road`, which keeps the flow at the bands' pixels; a pitch's fit is computed the first
    time it is asked for (:meth:`at_pitch`: the two pitches either side of the sequence's camera pitch, known
    only once every pair is fitted; :attr:`q`, :attr:`cost_px`, :attr:`flow90_px`: all of them), so a sequence
    pays for 2 of the 21 pitches. Not thread-safe: read one scan from one thread at a time.
    """

    def __init__(self, samples: tuple, camera, rotation: np.ndarray, direction: np.ndarray, shape: tuple[int, int]):
        """``samples``: per band of :data:`ROAD_BANDS`, the (N, 2) flow (pixels, NaN = unknown; the flow's dtype) at the
        band's grid of pixels (:func:`_band_grid`); ``camera`` of the flow, ``rotation`` (3, 3) and ``direction``
        (3,) of ``cam1_from_cam0``, ``shape`` the flow's (H, W)."""
        self._samples = samples
        self._camera = camera
        self._rotation = np.asarray(rotation, np.float64)
        self._direction = np.asarray(direction, np.float64)
        self._shape = shape
        self._fits: dict[tuple[int, int], tuple[float, float, float]] = {}

    width = property(lambda self: int(self._shape[1]), doc="Image width of the flow, pixels (limits scale with it).")

    def _fit(self, b: int, p: int) -> tuple[float, float, float]:
        """(q, cost_px, flow90_px) of band ``b`` at pitch ``PITCHES_DEG[p]``; NaN where the band has fewer than 30
        pixels of known flow."""
        if (b, p) not in self._fits:
            self._fits[b, p] = _fit_band(self._samples[b], self._camera, self._rotation, self._direction, self._shape,
                                         b, float(np.radians(PITCHES_DEG)[p]))
        return self._fits[b, p]

    def _table(self, k: int) -> np.ndarray:
        return np.array([[self._fit(b, p)[k] for p in range(len(PITCHES_DEG))] for b in range(len(ROAD_BANDS))])

    q = property(lambda self: self._table(0), doc="(B, P) float64 best ``|t| / h`` (distance travelled over the "
                 "camera's height).")
    cost_px = property(lambda self: self._table(1), doc="(B, P) float64 median end-point difference at that ``q``, "
                       "pixels (NaN: too few pixels in the band).")
    flow90_px = property(lambda self: self._table(2), doc="(B, P) float64 90th percentile of the band's flow due to "
                         "the translation at that ``q``, pixels.")

    def at_pitch(self, pitch_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, cost_px, flow90_px), each (B,) float64, linearly interpolated at ``pitch_deg`` along
        :data:`PITCHES_DEG` (clipped to its range)."""
        i, w = _pitch_index_weight(pitch_deg)
        lo = np.array([self._fit(b, i) for b in range(len(ROAD_BANDS))])
        hi = np.array([self._fit(b, i + 1) for b in range(len(ROAD_BANDS))])
        return tuple((1 - w) * lo[:, k] + w * hi[:, k] for k in range(3))


def _band_grid(camera, b: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) int arrays of band ``b``'s regular grid of at most about ``_BAND_POINTS`` pixels in an image
    ``height`` rows high, row-major."""
    v0, v1, u0, u1 = _band_box(camera, *ROAD_BANDS[b])
    step = max(1, int(np.ceil(np.sqrt(max(v1 - v0, 1) * max(u1 - u0, 1) / _BAND_POINTS))))
    return np.mgrid[min(v0, height):v1:step, u0:u1:step]


def scan_road(flow: np.ndarray, camera, rotation: np.ndarray, direction: np.ndarray) -> RoadScan:
    """:class:`RoadScan` of one flow.

    Args:
        flow: (H, W, 2) float32 (du, dv) pixels from frame 0 to frame 1 at the camera's size (NaN = unknown).
        camera: :class:`core.camera.PinholeCamera` of the flow.
        rotation: (3, 3) rotation of ``cam1_from_cam0``; direction: (3,) unit translation of ``cam1_from_cam0``.

    Each band is sampled on a regular grid of at most about ``_BAND_POINTS`` pixels; only those samples are kept.
    """
    h = flow.shape[0]
    samples = []
    for b in range(len(ROAD_BANDS)):
        vv, uu = _band_grid(camera, b, h)
        samples.append(flow[vv, uu].reshape(-1, 2).copy())
    return RoadScan(tuple(samples), camera, rotation, direction, tuple(flow.shape[:2]))


def _fit_band(samples: np.ndarray, camera, rotation: np.ndarray, direction: np.ndarray, shape: tuple[int, int],
              b: int, pitch: float) -> tuple[float, float, float]:
    """:meth:`RoadScan._fit`: band ``b``'s best ``q`` at ``pitch`` (radians), its cost and flow's 90th percentile."""
    k = camera.k
    kr = k @ rotation
    kd = k @ direction
    vv, uu = _band_grid(camera, b, shape[0])
    f = samples.astype(np.float64)
    uu, vv = uu.ravel().astype(np.float64), vv.ravel().astype(np.float64)
    ok = np.isfinite(f).all(axis=1)
    if ok.sum() < 30:
        return float("nan"), float("nan"), float("nan")
    uu, vv, f = uu[ok], vv[ok], f[ok]
    x0 = np.linalg.inv(k) @ np.stack([uu, vv, np.ones_like(uu)])
    a = kr @ x0                                          # (3, N) the rotation's image of each ray
    rot_uv = np.stack([a[0] / a[2], a[1] / a[2]], -1)
    target = np.stack([uu + f[:, 0], vv + f[:, 1]], -1)
    nx = np.cos(pitch) * x0[1] + np.sin(pitch) * x0[2]   # n . x0 with n = (0, cos, sin): the road's normal

    def costs(qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x1 = a[None] + qs[:, None, None] * kd[None, :, None] * nx[None, None, :]   # (Q, 3, N)
        uv = np.stack([x1[:, 0] / x1[:, 2], x1[:, 1] / x1[:, 2]], -1)            # (Q, N, 2)
        return np.median(np.linalg.norm(uv - target[None], axis=-1), axis=1), uv

    c, _ = costs(_Q_COARSE)
    i = int(np.argmin(c))
    fine = np.geomspace(_Q_COARSE[max(0, i - 1)], _Q_COARSE[min(len(_Q_COARSE) - 1, i + 1)], 25)
    c, uv = costs(fine)
    j = int(np.argmin(c))
    return float(fine[j]), float(c[j]), float(np.percentile(np.linalg.norm(uv[j] - rot_uv, axis=-1), 90))


@dataclasses.dataclass(frozen=True)
class RoadScaleConfig:
    """How the distances of a sequence's pairs are read from their road scans."""

    height_m: float = 1.65
    """Camera height above the road, metres."""
    max_flow_frac: float = 0.02
    """The nearest band is used whose translation flow (90th percentile) stays below this fraction of the
    image width (25 px on KITTI): a flow estimator loses the near road's large motion first."""
    max_cost_frac: float = 0.0012
    """A pair whose band fits the flow worse than this fraction of the image width (1.5 px on KITTI, median
    end-point difference) keeps the network's distance."""


STRAIGHT_TURN_DEG = 1.0
"""Pairs turning less than this (degrees about the camera's vertical, :func:`yaw_rad`) tell the camera's pitch
(:func:`travel_pitch_deg`): in corners the essential-matrix fit reads the motion 0.2-0.3 deg up (the rendered
streets at stride 3: 1.098 deg from all pairs against 1.000; 1.024 from these)."""
STRAIGHT_MIN_PAIRS = 10
"""Fewer straight pairs than this: the pitch is read from all pairs."""


def travel_pitch_deg(rotations, directions) -> float:
    """The camera's pitch over the road (degrees, positive: looking down), from the direction of travel of
    many pairs: a car moves parallel to its road, so its camera sees itself move that far upwards. The
    median over pairs of ``atan2(-m_y, m_z)``, ``m = -R^T d`` the motion in camera 0's axes (OpenCV: y
    down), over the pairs turning less than :data:`STRAIGHT_TURN_DEG` (all pairs where fewer than
    :data:`STRAIGHT_MIN_PAIRS` do); NaN without pairs.

    Args:
        rotations: (P, 3, 3) rotations of ``cam1_from_cam0``; directions: (P, 3) their unit translations.
    """
    rot = np.asarray(rotations, np.float64).reshape(-1, 3, 3)
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    if len(d) == 0:
        return float("nan")
    m = -np.einsum("pji,pj->pi", rot, d)
    angle = np.arctan2(-m[:, 1], m[:, 2])
    straight = np.abs([yaw_rad(r) for r in rot]) < np.radians(STRAIGHT_TURN_DEG)
    if straight.sum() >= STRAIGHT_MIN_PAIRS:
        angle = angle[straight]
    return float(np.degrees(np.median(angle)))


def _pitch_index_weight(pitch_deg: float) -> tuple[int, float]:
    """(i, w): ``pitch_deg`` (clipped to :data:`PITCHES_DEG`' range) lies ``w`` of the way from ``PITCHES_DEG[i]``
    to ``PITCHES_DEG[i + 1]``."""
    x = float(np.clip(pitch_deg, PITCHES_DEG[0], PITCHES_DEG[-1]))
    i = min(int(np.searchsorted(PITCHES_DEG, x, side="right")) - 1, len(PITCHES_DEG) - 2)
    return i, (x - PITCHES_DEG[i]) / (PITCHES_DEG[i + 1] - PITCHES_DEG[i])


def yaw_rad(rotation: np.ndarray) -> float:
    """Heading change of ``cam1_from_cam0`` (its (3, 3) rotation) about the camera's vertical axis, radians
    (positive: turning towards +x, the image's right): the angle of camera 1's optical axis in camera 0's
    x-z plane."""
    r = np.asarray(rotation, np.float64)
    return float(np.arctan2(r[2, 0], r[2, 2]))


def road_parallel(rotation: np.ndarray, direction: np.ndarray, pitch_deg: float) -> np.ndarray:
    """``direction`` made parallel to the road: a car moves in its road's plane, whatever its heading (a camera
    ahead of the rear axle slides sideways in a turn, never off that plane).

    With ``p`` the camera's pitch over the road (degrees, positive: looking down; :func:`travel_pitch_deg`) and
    ``L`` the level-from-camera rotation it gives (OpenCV axes: x right, y down, z forward), the motion in
    camera 0's axes is ``m = -R^T d`` (``R`` = ``rotation`` (3, 3) of ``cam1_from_cam0``, ``d`` = ``direction``
    (3,) its unit translation); its level vertical component ``(L m)_y`` is set to zero and the result mapped
    back, ``-R L^T (L m with y = 0)``, normalised. The heading (the sideways part) is ``direction``'s.

    Returns:
        (3,) float64 unit direction of travel in camera 1's axes; ``direction`` itself (normalised) where the
        motion is along the road's normal (no heading to keep).
    """
    r = np.asarray(rotation, np.float64)
    d = np.asarray(direction, np.float64)
    p = np.radians(pitch_deg)
    level_from_cam = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(p), np.sin(p)], [0.0, -np.sin(p), np.cos(p)]])
    m = level_from_cam @ (-r.T @ d)
    m[1] = 0.0
    norm = float(np.linalg.norm(m))
    if norm < 1e-9:
        return d / np.linalg.norm(d)
    return -r @ (level_from_cam.T @ (m / norm))


def path_leaves_band(curvature_per_m: float, ahead_m: float) -> bool:
    """Whether a path of ``curvature_per_m`` (1/m, either sign) is more than ``ROAD_HALF_WIDTH`` x ``ahead_m`` to
    the side by the time it is ``ahead_m`` metres ahead (or never gets that far ahead): a band of rows that
    far ahead, straight ahead of the camera, does not look at the road the car drives on."""
    k = abs(float(curvature_per_m)) * ahead_m        # sine of the heading change by then
    if k >= 1.0:
        return True
    return k > 0 and bool((1.0 - np.sqrt(1.0 - k * k)) / k > ROAD_HALF_WIDTH)   # sideways over ahead


def road_distances(scans: list[RoadScan | None], pitch_deg: float,
                   cfg: RoadScaleConfig = RoadScaleConfig(), yaws_rad=None) -> np.ndarray:
    """Distance travelled in each pair (metres, NaN where the road cannot tell) from the pairs'
    :class:`RoadScan` (None: no scan) at the camera pitch ``pitch_deg`` (:func:`travel_pitch_deg`). Per pair:
    the distance from the far band gives each band's expected translation flow; the nearest band whose flow
    stays within ``max_flow_frac`` of the width is read (the near road has the finest depth but moves most).

    ``yaws_rad`` ((P,) float, :func:`yaw_rad` of each pair's rotation; NaN or None: not known): in a turn
    whose path (its yaw over the far band's distance) has left the bands before the far band's nearest row
    (:func:`path_leaves_band`), the far band looks at the roadside, not the road: the nearest band whose own
    translation flow stays within ``max_flow_frac`` is read instead, or none."""
    out = np.full(len(scans), np.nan)
    if not np.isfinite(pitch_deg):
        return out
    far_ahead_m = cfg.height_m / ROAD_BANDS[0][1]      # the far band's nearest row, flat road
    for i, s in enumerate(scans):
        if s is None:
            continue
        q, cost, f90 = s.at_pitch(pitch_deg)
        if not np.isfinite(q[0]):
            continue
        limit = cfg.max_flow_frac * s.width
        yaw = float("nan") if yaws_rad is None else float(yaws_rad[i])
        if np.isfinite(yaw) and q[0] > 0 and path_leaves_band(yaw / (cfg.height_m * q[0]), far_ahead_m):
            band = next((b for b in range(len(q) - 1, 0, -1) if np.isfinite(q[b]) and f90[b] <= limit), None)
            if band is not None and cost[band] <= cfg.max_cost_frac * s.width:
                out[i] = cfg.height_m * q[band]
            continue
        band = 0
        for b in range(1, len(q)):
            # the band's translation flow at the far band's distance (flow grows about linearly with q)
            expected = f90[b] * q[0] / max(q[b], 1e-9)
            if np.isfinite(expected) and expected <= limit:
                band = b
        if cost[band] <= cfg.max_cost_frac * s.width:
            out[i] = cfg.height_m * q[band]
    return out


# ----------------------------------------------------------------------------------------------
# the road read from the images themselves, where the flow loses it
# ----------------------------------------------------------------------------------------------

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
        v0, v1, u0, u1 = _band_box(camera, r0, r1)
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


@dataclasses.dataclass(frozen=True)
class RoadSequenceConfig:
    """How a sequence's per-pair road distances are checked against their neighbours and gaps filled."""

    neighbours: int = 2
    """Pairs on each side whose distances predict a pair's (:func:`check_and_fill`)."""
    max_jump_frac: float = 0.3
    """A distance differing from what its neighbours predict by more than this fraction of it ..."""
    min_jump_m: float = 0.2
    """... and by more than this many metres is dropped (a car's speed changes little in a few frames)."""
    fill_pairs: int = 6
    """Runs of at most this many pairs without a distance, between two pairs with one, are interpolated; at
    either end of the sequence, such a run takes the nearest pair's distance. (A car's speed changes by at most
    about 3 m/s a second: across six pairs at 3.33 Hz the line between two readings errs by less than the
    network's distance, a speed prior, does at speed.)"""


def check_and_fill(distances: np.ndarray, cfg: RoadSequenceConfig = RoadSequenceConfig()) -> tuple[np.ndarray, np.ndarray]:
    """A sequence's road distances with outliers dropped and short gaps interpolated.

    Args:
        distances: (P,) float metres per consecutive pair, NaN where none was read.

    Returns:
        ((P,) float64 distances, NaN where still none; (P,) bool: dropped as an outlier). A distance is
        dropped where it differs from what its neighbours predict (the median, over each finite neighbour up
        to ``cfg.neighbours`` pairs before and each after, of the straight line through the two; at least one
        on each side) by more than ``cfg.max_jump_frac`` of that prediction and ``cfg.min_jump_m``; then gaps
        of up to ``cfg.fill_pairs`` pairs are filled (:class:`RoadSequenceConfig`).
    """
    d = np.asarray(distances, np.float64).ravel()
    n = len(d)
    dropped = np.zeros(n, bool)
    finite = np.isfinite(d)
    for i in np.flatnonzero(finite):
        before = [b for b in range(max(0, i - cfg.neighbours), i) if finite[b]]
        after = [a for a in range(i + 1, min(n, i + 1 + cfg.neighbours)) if finite[a]]
        if not (before and after):      # one side only: a speed-up or a slow-down would read as a jump
            continue
        # the distance each (before, after) pair of neighbours predicts by a straight line: a steady
        # speed-up is no jump, and one bad neighbour spoils only the lines through it
        pred = float(np.median([d[b] + (d[a] - d[b]) * (i - b) / (a - b) for b in before for a in after]))
        dropped[i] = abs(d[i] - pred) > max(cfg.max_jump_frac * abs(pred), cfg.min_jump_m)
    out = np.where(dropped, np.nan, d)
    known = np.flatnonzero(np.isfinite(out))
    for a, b in zip(known[:-1], known[1:]):
        if 1 < b - a <= cfg.fill_pairs + 1:
            out[a + 1:b] = np.interp(np.arange(a + 1, b), [a, b], [out[a], out[b]])
    if len(known) and 0 < known[0] <= cfg.fill_pairs:
        out[:known[0]] = out[known[0]]
    if len(known) and 0 < n - 1 - known[-1] <= cfg.fill_pairs:
        out[known[-1] + 1:] = out[known[-1]]
    return out, dropped
