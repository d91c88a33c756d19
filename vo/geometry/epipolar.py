"""Rotation and direction of travel from the epipolar geometry of a dense flow; distance from the network.

``deepslam vo --pose epipolar`` splits the work the way DF-VO argues for (Zhan et al., "Visual
Odometry Revisited: What Should Be Learnt?", ICRA 2020): a monocular flow fixes the rotation and the
direction of travel by geometry, but not the distance; the network reads the distance (the metric
scale it learned from single frames). The paper's network reads all six DoF from a 48x160 flow, and
there a turning car's sideways slide (a 2-degree shift of the direction of travel) and a street's
left-right layout are read as yaw (measured in ``bench.results_turn``); the essential matrix of the
full-resolution flow tells them apart.

:func:`fit_essential` fits OpenCV's essential matrix (``cv2.findEssentialMat``, USAC: RANSAC with local
optimisation, then ``cv2.recoverPose`` for the cheirality) to flow correspondences on a regular grid; :func:`fuse`
replaces a network motion's rotation and translation direction by the fit's, keeping the network's
translation length. A pair is left to the network where the fit cannot be trusted: too few flow
vectors or inliers, or too little parallax once the rotation is taken out (a car standing still, a
pure rotation: the direction of travel is then undetermined).

Frames and units: every motion is ``cam1_from_cam0`` (a point in camera 0's frame, metres, OpenCV
axes: x right, y down, z forward, mapped into camera 1's), angles in radians, pixels with centres at
integers. OpenCV's USAC and RANSAC draw from a fixed seed: the same flow gives the same fit.

This module does not import torch.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from deepslam.core import se3
from deepslam.vo.geometry.road_flow import (RoadScaleConfig, RoadScan, road_distances, road_parallel, scan_road,
                                           travel_pitch_deg, yaw_rad)
from deepslam.vo.geometry.road_image import image_road_q, turn_curvature
from deepslam.vo.geometry.road_sequence import RoadSequenceConfig, check_and_fill


METHODS = ("usac_default", "usac_accurate", "usac_magsac", "usac_fast", "ransac")
"""Robust estimators :class:`EpipolarConfig` takes (OpenCV's ``cv2.USAC_*`` flags and ``cv2.RANSAC``)."""


@dataclass(frozen=True)
class EpipolarConfig:
    """How the essential matrix is fitted to a flow and when its fit is used."""

    grid_step_px: int = 12
    """Spacing of the flow vectors sampled, pixels of the full-resolution image (12: ~3,000 on KITTI)."""
    max_points: int = 1000
    """At most this many of them go to RANSAC (evenly spaced along the grid, no random draw)."""
    threshold_px: float = 0.5
    """RANSAC inlier threshold: distance to the epipolar line, pixels."""
    method: str = "usac_default"
    """Robust estimator: one of OpenCV's USAC variants (``usac_default``: RANSAC with local optimisation and a
    fixed seed; ``usac_accurate``, ``usac_magsac``, ``usac_fast``) or ``ransac`` (cv2.RANSAC, no local
    optimisation: on KITTI 06's DIS flow a median rotation error of 0.055 deg a pair against 0.022)."""
    confidence: float = 0.999
    """RANSAC's confidence that a sample of inliers was drawn."""
    min_inliers: int = 200
    """Fewer RANSAC inliers than this: the pair is left to the network. (The cheirality check of
    ``recoverPose`` only picks the decomposition; a wrong pick near standing still is caught by
    :attr:`max_rotation_disagreement_deg`.)"""
    min_inlier_fraction: float = 0.2
    """A smaller fraction of the sampled vectors as inliers: the pair is left to the network. (At 6-9 m a pair
    DIS keeps the road and the facades' motion for 25-40 % of the vectors, and a fit on them reads the rotation
    within 0.1 deg: bench/criteria/2026-12-05_road_gaps.md.)"""
    min_parallax_px: float = 1.0
    """Median flow of the inliers once the fitted rotation is taken out, pixels; below it the direction of
    travel is undetermined (standing still, pure rotation) and the pair is left to the network."""
    max_rotation_disagreement_deg: float = 10.0
    """A fit whose rotation differs from the network's by more than this is not used (:func:`fuse`): near
    standing still the essential matrix can decompose into the wrong one of its four poses (a 180-degree
    twist, which then also passes the parallax test). Any bound well under 180 degrees catches the twist; it
    has to exceed the network's error, which reaches 3 degrees where a car turns 9 degrees a pair (a corner at
    3.33 Hz, where the fit is right within 0.1 deg)."""

    road_height_m: float | None = None
    """Height of the camera above a road in front of it, metres (1.65 on KITTI and in the simulated street):
    when set, the distance travelled is read from the road's motion in the flow (:mod:`vo.geometry.road_flow`: the
    road plane's homography with the fit's rotation and direction of travel, the camera's pitch chosen once
    per sequence) instead of from the network, in every pair whose road fits well enough. None: the
    network's distance."""
    road_fill: bool = True
    """With :attr:`road_height_m`: pairs whose flow shows no usable road are read from the images themselves
    (:func:`vo.geometry.road_image.image_road_q`: the fit's rotation and direction where used, else the network's, the
    direction made parallel to the road by :func:`vo.geometry.road_flow.road_parallel`), a
    distance far from its neighbours' is dropped and short gaps are interpolated
    (:func:`vo.geometry.road_sequence.check_and_fill`); the rest keep the network's distance. False: the road's motion in
    the flow only (``deepslam vo --scale road-flow``)."""

    def __post_init__(self) -> None:
        if self.road_height_m is not None and not (0.1 <= self.road_height_m <= 100.0):
            raise ValueError(f"road_height_m must be in [0.1, 100] m, got {self.road_height_m}")
        if self.grid_step_px < 1:
            raise ValueError(f"grid_step_px must be >= 1, got {self.grid_step_px}")
        if self.max_points < 5 or self.min_inliers < 5:
            raise ValueError("max_points and min_inliers must be >= 5 (the five-point solver)")
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if not (self.threshold_px > 0 and 0 < self.confidence < 1 and 0 <= self.min_inlier_fraction <= 1
                and self.min_parallax_px >= 0 and self.max_rotation_disagreement_deg > 0):
            raise ValueError(f"invalid epipolar settings: {self}")


@dataclass(frozen=True, eq=False)
class EpipolarFit:
    """The essential-matrix fit of one flow."""

    ok: bool
    """True when the fit is to be used (enough inliers and parallax)."""
    cam1_from_cam0_rotation: np.ndarray
    """(3, 3) float64 rotation of camera 0's axes into camera 1's (identity when the fit failed)."""
    direction_cam1: np.ndarray
    """(3,) float64 unit translation of ``cam1_from_cam0`` (camera 0's centre seen from camera 1, up to scale;
    zeros when the fit failed)."""
    inliers: int
    """Vectors within ``threshold_px`` of their epipolar line (RANSAC's inliers)."""
    sampled: int
    """Finite flow vectors sampled (landing inside the second image)."""
    parallax_px: float
    """Median inlier flow with the fitted rotation taken out, pixels (NaN when not fitted)."""
    reason: str = ""
    """Why the fit is not used ('' when ``ok``)."""
    road: RoadScan | None = None
    """The road's fit per distance (:func:`vo.geometry.road_flow.scan_road`) when :attr:`EpipolarConfig.road_height_m`
    is set, else None."""

    @property
    def rigid(self) -> bool:
        """Whether the flow fits one rigid motion: the fit is ok, or failed only for want of parallax (its
        inliers passed, and the parallax was measured). False where too few vectors were sampled, too few are
        inliers, or OpenCV found no essential matrix: the flow broke (DIS lost a large turn or distance between
        the frames) and anything read from it, the network's motion included, is suspect."""
        return self.ok or bool(np.isfinite(self.parallax_px))


def _failed(sampled: int, reason: str, inliers: int = 0, parallax: float = float("nan")) -> EpipolarFit:
    return EpipolarFit(False, np.eye(3), np.zeros(3), int(inliers), int(sampled), float(parallax), reason)


def grid_correspondences(flow: np.ndarray, step: int, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Flow vectors on a regular grid as point pairs.

    Args:
        flow: (H, W, 2) float px, ``flow[v, u] = (du, dv)`` from image 0 to image 1 (NaN = unknown).
        step: grid spacing, px; the grid starts at step // 2.
        max_points: at most this many pairs, evenly spaced along the grid order.

    Returns:
        (pts0, pts1): float64 (N, 2) pixel positions (u, v) in image 0 and where they land in image 1;
        only finite vectors that land inside image 1.
    """
    h, w = flow.shape[:2]
    vs, us = np.mgrid[step // 2:h:step, step // 2:w:step]
    f = flow[vs, us].astype(np.float64)
    pts0 = np.stack([us, vs], axis=-1).reshape(-1, 2).astype(np.float64)
    pts1 = pts0 + f.reshape(-1, 2)
    keep = (np.isfinite(pts1).all(axis=1) & (pts1[:, 0] >= -0.5) & (pts1[:, 0] <= w - 0.5)
            & (pts1[:, 1] >= -0.5) & (pts1[:, 1] <= h - 0.5))
    pts0, pts1 = pts0[keep], pts1[keep]
    if len(pts0) > max_points:
        idx = np.linspace(0, len(pts0) - 1, max_points).round().astype(np.int64)
        pts0, pts1 = pts0[idx], pts1[idx]
    return pts0, pts1


def fit_essential(flow: np.ndarray, camera, cfg: EpipolarConfig = EpipolarConfig()) -> EpipolarFit:
    """Fit the essential matrix of one flow (module docstring).

    Args:
        flow: (H, W, 2) float32 px at the full resolution of ``camera`` (NaN = unknown).
        camera: a :class:`core.camera.PinholeCamera` of the images (undistorted).
        cfg: the fit's settings.

    A point set OpenCV refuses (``cv2.error``) is a failed fit, not an exception; a flow of another size
    than the camera's is a ValueError.
    """
    if flow.ndim != 3 or flow.shape[2] != 2 or flow.shape[:2] != (camera.height, camera.width):
        raise ValueError(f"flow must be ({camera.height}, {camera.width}, 2) for this camera, got {flow.shape}")
    pts0, pts1 = grid_correspondences(flow, cfg.grid_step_px, cfg.max_points)
    n = len(pts0)
    if n < cfg.min_inliers:
        return _failed(n, f"{n} flow vectors sampled, fewer than {cfg.min_inliers}")
    k = camera.k
    try:
        e, mask = cv2.findEssentialMat(pts0, pts1, k, method=getattr(cv2, cfg.method.upper()), prob=cfg.confidence,
                                       threshold=cfg.threshold_px)
        if e is None or e.shape[0] < 3:
            return _failed(n, "no essential matrix found")
        sel = mask.ravel() > 0
        inl = int(sel.sum())
        if inl < cfg.min_inliers or inl < cfg.min_inlier_fraction * n:
            return _failed(n, f"{inl} of {n} vectors are inliers", inl)
        # the decomposition whose triangulated inliers lie in front of both cameras (cheirality); given the
        # inliers alone, as recoverPose counts only the masked points anyway (the same pick, 20 % less time)
        _, rot, t, _ = cv2.recoverPose(e[:3], pts0[sel], pts1[sel], k, mask=mask[sel].copy())
    except cv2.error as err:  # a degenerate point set OpenCV refuses: the pair is left to the network
        last = str(err).strip().splitlines()[-1] if str(err).strip() else "cv2.error"
        return _failed(n, f"OpenCV could not fit it ({last})")
    # the rotation's own flow: where each inlier would land under the rotation alone (infinitely far points)
    rays = np.c_[(pts0[sel, 0] - camera.cx) / camera.fx, (pts0[sel, 1] - camera.cy) / camera.fy, np.ones(int(sel.sum()))]
    r = rays @ rot.T
    ok_z = r[:, 2] > 1e-6
    landed = np.c_[camera.fx * r[ok_z, 0] / r[ok_z, 2] + camera.cx, camera.fy * r[ok_z, 1] / r[ok_z, 2] + camera.cy]
    parallax = float(np.median(np.linalg.norm(pts1[sel][ok_z] - landed, axis=1))) if ok_z.any() else 0.0
    if parallax < cfg.min_parallax_px:
        return _failed(n, f"parallax {parallax:.2f} px below {cfg.min_parallax_px}", inl, parallax)
    d = np.asarray(t, dtype=np.float64).ravel()
    d = d / np.linalg.norm(d)
    rot = np.asarray(rot, dtype=np.float64)
    road = scan_road(flow, camera, rot, d) if cfg.road_height_m is not None else None
    return EpipolarFit(True, rot, d, inl, n, parallax, road=road)


def fit_usable(mean6: np.ndarray, fit: EpipolarFit, cfg: EpipolarConfig = EpipolarConfig()) -> bool:
    """Whether :func:`fuse` takes the fit's rotation and direction for a pair whose network motion is ``mean6``
    ((6,) float, see :func:`fuse`): not where the fit failed, where its rotation is more than
    ``cfg.max_rotation_disagreement_deg`` from the network's, or where its direction of travel points more than
    90 degrees away from the network's (the cheirality sign disagreeing with the network: too little depth
    structure to trust either)."""
    if not fit.ok:
        return False
    m = np.asarray(mean6, dtype=np.float64).reshape(6)
    net = se3.from_euler6(m)
    if se3.rotation_angle(fit.cam1_from_cam0_rotation @ net[:3, :3].T) > np.radians(cfg.max_rotation_disagreement_deg):
        return False
    return not (np.linalg.norm(m[3:]) > 0 and float(fit.direction_cam1 @ m[3:]) < 0)


def fuse(mean6: np.ndarray, fit: EpipolarFit, cfg: EpipolarConfig = EpipolarConfig(),
         distance_m: float = float("nan")) -> tuple[np.ndarray, bool]:
    """One network motion with the fit's rotation and direction of travel (where :func:`fit_usable`), and the
    network's distance, or ``distance_m`` (metres) where finite: the road's (:func:`sequence_road_distances`).

    Args:
        mean6: (6,) float the network's ``cam1_from_cam0`` (euler_x, euler_y, euler_z rad, t_x, t_y, t_z m).
        fit: :func:`fit_essential` of the same pair's flow.
        cfg: the settings (:attr:`EpipolarConfig.max_rotation_disagreement_deg`).

    Returns:
        (mean6, used): the fused (6,) float64 motion, and whether the fit was used. Where it is not, the
        network's motion is kept, its translation stretched to ``distance_m`` where that is finite.
    """
    m = np.asarray(mean6, dtype=np.float64).reshape(6)
    used = fit_usable(m, fit, cfg)
    axes = _rotation_direction(m, fit, used)
    if axes is None or not (used or np.isfinite(distance_m)):
        return m.copy(), False
    length = float(distance_m) if np.isfinite(distance_m) else float(np.linalg.norm(m[3:]))
    return se3.to_euler6(se3.from_rt(axes[0], axes[1] * length)), used


def _rotation_direction(mean6: np.ndarray, fit: EpipolarFit, used: bool,
                        min_length_m: float = 0.0) -> tuple[np.ndarray, np.ndarray] | None:
    """The pair's rotation (3, 3) and unit direction of travel (3,) of ``cam1_from_cam0``: the fit's where
    ``used``, else the network's ``mean6`` (6,); None where the network's translation is no longer than
    ``min_length_m`` (no direction)."""
    if used:
        return fit.cam1_from_cam0_rotation, fit.direction_cam1
    length = float(np.linalg.norm(mean6[3:]))
    if not length > min_length_m:
        return None
    return se3.from_euler6(np.asarray(mean6, np.float64))[:3, :3], np.asarray(mean6[3:], np.float64) / length


def fuse_all(mean6: np.ndarray, fits, cfg: EpipolarConfig = EpipolarConfig(), camera=None, pair_greys=None,
             road_out: list | None = None, chained: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fuse` for (P, 6) motions and their P fits -> ((P, 6) float64 motions, (P,) bool used).

    ``camera`` (:class:`core.camera.PinholeCamera`) and ``pair_greys`` (``f(p) -> (grey0, grey1)``, the
    pair's (H, W) uint8 images at the camera's size): see :func:`sequence_road_distances`; ``road_out``: a list
    the sequence's :class:`RoadDistances` is appended to; ``chained``: the pairs follow each other (see
    :func:`sequence_road_distances`)."""
    mean6 = np.asarray(mean6, dtype=np.float64).reshape(-1, 6)
    fits = list(fits)
    if len(fits) != len(mean6):
        raise ValueError(f"{len(mean6)} motions but {len(fits)} epipolar fits")
    out = np.empty_like(mean6)
    used = np.zeros(len(mean6), bool)
    road = sequence_road_distances(fits, cfg, mean6, camera, pair_greys, chained)
    if road_out is not None:
        road_out.append(road)
    for p, (m, fit) in enumerate(zip(mean6, fits)):
        out[p], used[p] = fuse(m, fit, cfg, road.distances_m[p])
    return out, used


@dataclass(frozen=True, eq=False)
class RoadDistances:
    """The distance travelled in each pair of a sequence as read from the road."""

    distances_m: np.ndarray
    """(P,) float64 metres, NaN where the road cannot tell (the network's distance is kept)."""
    pitch_deg: float
    """The camera's pitch over the road, degrees, from the direction of travel of the usable fits
    (:func:`vo.geometry.road_flow.travel_pitch_deg`); NaN when not asked."""
    source: tuple[str, ...]
    """Per pair: ``flow`` (the road's motion in the flow), ``images`` (the road bands aligned,
    :func:`vo.geometry.road_image.image_road_q`), ``filled`` (interpolated between neighbours) or ``""`` (none)."""

    def counts(self) -> dict[str, int]:
        """Pairs per source (``network``: none read from the road)."""
        return {k: sum(1 for s in self.source if s == v) for k, v in
                (("flow", "flow"), ("images", "images"), ("filled", "filled"), ("network", ""))}


def sequence_road_distances(fits, cfg: EpipolarConfig = EpipolarConfig(), mean6: np.ndarray | None = None,
                            camera=None, pair_greys=None, chained: bool = True) -> RoadDistances:
    """The distance travelled in each of a sequence's P pairs, read from the road (:class:`RoadDistances`).

    Args:
        fits: the P pairs' :class:`EpipolarFit`.
        cfg: the settings; ``cfg.road_height_m`` None: nothing is read (all NaN).
        mean6: (P, 6) float the network's motions (:func:`fuse`): which fits are used, and the rotation and
            direction for the image alignment where the fit is not; None: every fit that is ``ok`` counts.
        camera: :class:`core.camera.PinholeCamera` of the images; pair_greys: ``f(p) -> (grey0, grey1)``
            (H, W) uint8 images of pair p at its size, or their :class:`vo.geometry.road_image.RoadImage`: with
            ``cfg.road_fill`` the pairs the flow cannot read are read from them (either None: not). Called
            from two threads at once (each walking its half of the pairs in order): it must be thread-safe.
        chained: the pairs follow each other (pair p ends where pair p + 1 starts), as ``vo`` and ``slam``
            make them; only then are distances checked against their neighbours and gaps filled.

    The flow's road (:func:`vo.geometry.road_flow.road_distances`) is read in the pairs whose fit is used; with
    ``cfg.road_fill`` the others are read from the images (the pair's rotation, the fit's where used else the
    network's, and its direction made parallel to the road, :func:`vo.geometry.road_flow.road_parallel`; in a sharp turn
    the bands are moved onto the car's path, its curvature from the nearest pair the flow read,
    :func:`vo.geometry.road_image.turn_curvature`), then :func:`vo.geometry.road_sequence.check_and_fill` drops distances far from
    their neighbours' and interpolates short gaps.
    """
    fits = list(fits)
    n = len(fits)
    if cfg.road_height_m is None:
        return RoadDistances(np.full(n, np.nan), float("nan"), ("",) * n)
    usable = [f.ok for f in fits] if mean6 is None else [fit_usable(m, f, cfg) for m, f in zip(mean6, fits)]
    ok = [f for f, u in zip(fits, usable) if u]
    pitch = travel_pitch_deg([f.cam1_from_cam0_rotation for f in ok], [f.direction_cam1 for f in ok])
    dist = road_distances([f.road if u else None for f, u in zip(fits, usable)], pitch,
                          RoadScaleConfig(height_m=cfg.road_height_m),
                          [yaw_rad(f.cam1_from_cam0_rotation) if u else np.nan for f, u in zip(fits, usable)])
    source = np.where(np.isfinite(dist), "flow", "").astype(object)
    if not cfg.road_fill or not np.isfinite(pitch):
        return RoadDistances(dist, pitch, tuple(source))
    if pair_greys is not None and camera is not None:
        tasks = []
        read_from_flow = np.flatnonzero(np.isfinite(dist))
        for p in np.flatnonzero(~np.isfinite(dist)):
            axes = (_rotation_direction(mean6[p] if mean6 is not None else np.zeros(6), fits[p], usable[p],
                                        min_length_m=1e-6))
            if axes is not None:
                # a sharp turn's curvature from a distance known before the alignment: the nearest pair the
                # flow read among chained pairs, up to fill_pairs away (a car's speed changes little in that
                # time), else the network's
                near = read_from_flow[np.argmin(np.abs(read_from_flow - p))] if len(read_from_flow) else -1
                prior = (float(dist[near]) if chained and near >= 0 and abs(near - p) <= RoadSequenceConfig().fill_pairs
                         else float(np.linalg.norm(mean6[p][3:])) if mean6 is not None else float("nan"))
                # a car moves in its road's plane: the far road moves a pixel or two a frame at speed, and the
                # fit's direction, a few tenths of a degree off that plane at 30 m/s, reads it 2 % short
                tasks.append((int(p), (axes[0], road_parallel(axes[0], axes[1], pitch)),
                              turn_curvature(yaw_rad(axes[0]), prior / cfg.road_height_m, camera)))

        def read(part: list) -> list[float]:  # each pair on its own: the order of the parts changes nothing
            return [image_road_q(*pair_greys(p), camera, *axes, pitch, kappa_h=kappa_h) for p, axes, kappa_h in part]

        # two halves in two threads (OpenCV and numpy's large operations release the GIL); each half in the
        # order of the pairs, so consecutive pairs still share a prepared frame. A few pairs: no thread.
        if len(tasks) < 4:
            qs = read(tasks)
        else:
            with ThreadPoolExecutor(2) as pool:
                qs = [q for part in pool.map(read, (tasks[:len(tasks) // 2], tasks[len(tasks) // 2:])) for q in part]
        for (p, _, _), q in zip(tasks, qs):
            if np.isfinite(q):
                dist[p], source[p] = cfg.road_height_m * q, "images"
    if not chained:
        return RoadDistances(dist, pitch, tuple(source))
    filled, dropped = check_and_fill(dist)
    source[dropped] = ""
    source[np.isfinite(filled) & (source == "")] = "filled"
    return RoadDistances(filled, pitch, tuple(source))


class EpipolarFitter:
    """:func:`fit_essential` with fixed settings as a ``f(flow, camera)`` callable (what
    :class:`vo.data.prefetch.PairInputs` applies in its worker thread); equal when the settings are."""

    def __init__(self, cfg: EpipolarConfig = EpipolarConfig()):
        self.cfg = cfg

    def __call__(self, flow: np.ndarray, camera) -> EpipolarFit:
        return fit_essential(flow, camera, self.cfg)

    def __eq__(self, other) -> bool:
        return isinstance(other, EpipolarFitter) and other.cfg == self.cfg

    def __hash__(self) -> int:
        return hash(self.cfg)
