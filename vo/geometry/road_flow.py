"""Distance travelled from the road in a dense flow (``deepslam vo --scale road``).

A road plane ``n . X = h`` in front of the car moves under ``cam1_from_cam0 = [R | t]`` by the homography
``H = R + t n^T / h``. With R and the direction of ``t`` known from the epipolar geometry
(:mod:`vo.geometry.epipolar`), :func:`scan_road` fits ``q = |t| / h`` per band of image rows below the
horizon at each scanned camera pitch; :func:`travel_pitch_deg` reads the camera's pitch from the
sequence's straight pairs and :func:`road_distances` turns the scans into metres at the camera height.
Rows, columns and pitches: :data:`ROAD_BANDS`, :data:`ROAD_HALF_WIDTH`, :data:`PITCHES_DEG`.
"""
from __future__ import annotations

import dataclasses

import numpy as np


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


def band_box(camera, r0: float, r1: float) -> tuple[int, int, int, int]:
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
    v0, v1, u0, u1 = band_box(camera, *ROAD_BANDS[b])
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
