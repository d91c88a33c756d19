"""Trajectory metrics: Umeyama alignment, ATE, RPE and the KITTI odometry t_err / r_err.

Conventions (the same as evo's, and the KITTI devkit's for the KITTI numbers):

- ``gt`` and ``est`` are poses ``world_from_cam``: either (N, 4, 4) float64 arrays already matched
  by index, or two :class:`~core.trajectory.Trajectory` objects, which are matched first by
  :func:`match` (timestamps within 0.01 s when both have them, else index).
- Alignment maps the estimate's world onto the ground truth's: ``p_gt ~= s R p_est + t``, found by
  Umeyama (1991) least squares on the positions. ``none``: identity; ``se3``: R, t; ``sim3``: s, R, t
  (for monocular estimates whose scale is unknown). An aligned pose is ``(R R_est, s R t_est + t)``.
- ATE: root mean square of ``|p_gt_i - p_aligned_est_i|`` over all poses, metres.
- RPE over a frame delta d: for pairs (i, j = i + d), the error pose is
  ``E = inv(inv(gt_i) gt_j) (inv(est_i) est_j)`` (evo's definition); the translation error is |t(E)|
  in metres and the rotation error is the angle of R(E) in degrees; both reported as RMSE over pairs.
  Pairs are i = 0, d, 2d, ... as evo does by default (``all_pairs=False``), or every i.
- KITTI odometry errors, exactly as the devkit's ``evaluate_odometry.cpp``: segment lengths
  100, 200, ..., 800 m measured along the ground truth (``trajectoryDistances``); first frames every
  10 frames; the last frame is the first whose distance exceeds the first's by more than the length;
  ``pose_error = inv(inv(est_f) est_l) (inv(gt_f) gt_l)``; rotation error
  ``acos(clip(0.5 (tr R - 1), -1, 1))`` and translation error |t|, each divided by the length; the
  sequence's figures are the plain means over all segments, reported as t_err in % and r_err in
  deg / 100 m. Segments are relative, so a rigid (se3) alignment does not change them.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.trajectory import Trajectory, associate

ALIGN_MODES = ("none", "se3", "sim3")
"""Accepted values of ``align``."""

KITTI_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
"""Segment lengths of the KITTI odometry benchmark, metres."""

KITTI_STEP_FRAMES = 10
"""The devkit's ``step_size``: a segment starts every 10 frames (one second at 10 Hz)."""

KITTI_MIN_GT_LENGTH_M = 100.0
"""KITTI figures are computed only when the ground truth is longer than this (shortest segment)."""

MIN_MATCHES = 3
"""Fewest matched poses :func:`evaluate` accepts (an alignment needs three points)."""


@dataclasses.dataclass(frozen=True)
class Alignment:
    """A similarity ``p_gt = scale * rotation @ p_est + translation`` (est world -> gt world)."""

    rotation: np.ndarray
    """(3, 3) float64 rotation gt_world_from_est_world."""
    translation: np.ndarray
    """(3,) float64 metres, in the gt world."""
    scale: float
    """Scale factor (1.0 unless sim3)."""

    def apply_to_poses(self, world_from_cam: np.ndarray) -> np.ndarray:
        """Poses (N, 4, 4) in the est world moved into the gt world: (R R_i, s R t_i + t)."""
        p = np.asarray(world_from_cam, dtype=np.float64)
        rot = self.rotation @ p[:, :3, :3]
        trans = self.scale * p[:, :3, 3] @ self.rotation.T + self.translation
        return se3.from_rt(rot, trans)

    def apply_to_points(self, p_est: np.ndarray) -> np.ndarray:
        """Points (N, 3) in the est world mapped into the gt world."""
        return self.scale * np.asarray(p_est, dtype=np.float64) @ self.rotation.T + self.translation


def umeyama(p_src: np.ndarray, p_dst: np.ndarray, with_scale: bool) -> Alignment:
    """Least-squares similarity ``p_dst ~= s R p_src + t`` (Umeyama 1991, with the reflection fix).

    Args:
        p_src: (N, 3) float points (the estimate's positions).
        p_dst: (N, 3) float points (the ground truth's), N >= 3 for a unique answer.
        with_scale: estimate s (sim3); else s = 1 (se3).

    Returns:
        Alignment(rotation (3, 3), translation (3,), scale). When the source points do not spread
        (all equal), the scale stays 1 and the rotation the identity.
    """
    x = np.asarray(p_src, dtype=np.float64)
    y = np.asarray(p_dst, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3 or len(x) == 0:
        raise ValueError(f"umeyama needs two (N, 3) arrays of equal N > 0, got {x.shape} and {y.shape}")
    mu_x, mu_y = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mu_x, y - mu_y
    var_x = float((xc * xc).sum(axis=1).mean())
    if var_x < 1e-24:
        return Alignment(np.eye(3), mu_y - mu_x, 1.0)
    cov = yc.T @ xc / len(x)
    u, d, vt = np.linalg.svd(cov)
    s = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s[2] = -1.0
    rot = (u * s) @ vt
    scale = float((d * s).sum() / var_x) if with_scale else 1.0
    return Alignment(rot, mu_y - scale * rot @ mu_x, scale)


def align(gt: np.ndarray, est: np.ndarray, mode: str = "se3") -> tuple[np.ndarray, Alignment]:
    """Align matched poses ``est`` (N, 4, 4) to ``gt`` (N, 4, 4) by their positions.

    Returns (aligned est poses (N, 4, 4) in the gt world, the Alignment used).
    """
    if mode not in ALIGN_MODES:
        raise ValueError(f"align must be one of {ALIGN_MODES}, got {mode!r}")
    gt, est = _poses(gt), _poses(est)
    if mode == "none":
        a = Alignment(np.eye(3), np.zeros(3), 1.0)
    else:
        a = umeyama(est[:, :3, 3], gt[:, :3, 3], with_scale=(mode == "sim3"))
    return a.apply_to_poses(est), a


_align = align  # ate() and evaluate() take a parameter named ``align``


def _poses(x) -> np.ndarray:
    return x.world_from_cam if isinstance(x, Trajectory) else np.asarray(x, dtype=np.float64)


def _pair(gt, est) -> tuple[np.ndarray, np.ndarray]:
    """Matched (M, 4, 4) pose arrays: two Trajectory objects are matched with :func:`match` (by
    timestamp when both have them, else by index); arrays must already be matched (equal length)."""
    if isinstance(gt, Trajectory) and isinstance(est, Trajectory):
        ig, ie, _ = match(gt, est)
        return gt.world_from_cam[ig], est.world_from_cam[ie]
    g, e = _poses(gt), _poses(est)
    if g.shape != e.shape or g.ndim != 3 or g.shape[1:] != (4, 4):
        raise ValueError(f"need matched (N, 4, 4) poses, got {g.shape} and {e.shape}")
    return g, e


def _stats(err: np.ndarray) -> dict:
    if len(err) == 0:
        return {"rmse": float("nan"), "mean": float("nan"), "median": float("nan"), "max": float("nan"), "n": 0}
    return {"rmse": float(np.sqrt(np.mean(err ** 2))), "mean": float(err.mean()),
            "median": float(np.median(err)), "max": float(err.max()), "n": int(len(err))}


def ate(gt, est, align: str = "se3") -> dict:
    """Absolute trajectory error after ``align`` (none | se3 | sim3).

    ``gt``/``est``: two Trajectory objects (matched by timestamp or index) or matched (N, 4, 4) arrays.

    Returns a dict: ``rmse_m``, ``mean_m``, ``median_m``, ``max_m`` (translation error after
    alignment, metres), ``n``, ``alignment`` (Alignment) and ``errors_m`` ((N,) per-pose errors).
    """
    gt, est = _pair(gt, est)
    aligned, a = _align(gt, est, align)
    err = np.linalg.norm(gt[:, :3, 3] - aligned[:, :3, 3], axis=1)
    s = _stats(err)
    return {"rmse_m": s["rmse"], "mean_m": s["mean"], "median_m": s["median"], "max_m": s["max"],
            "n": s["n"], "alignment": a, "errors_m": err}


def ate_parts(gt_poses: np.ndarray, est_aligned_poses: np.ndarray, part: np.ndarray) -> tuple[float | None, float | None]:
    """The ATE of one alignment split in two: the RMS position error over the poses where ``part`` is true and
    over the others (metres; None for an empty side). The two add up to the whole:
    ``n_in in^2 + n_out out^2 = n ate^2``.

    Args:
        gt_poses: (N, 4, 4) float matched ground-truth poses (world_from_cam); est_aligned_poses: (N, 4, 4) float
            the matched estimate after the alignment (:func:`evaluate`'s ``_gt_poses`` / ``_est_aligned_poses``).
        part: (N,) bool.
    """
    err = np.linalg.norm(np.asarray(gt_poses)[:, :3, 3] - np.asarray(est_aligned_poses)[:, :3, 3], axis=1)
    part = np.asarray(part, bool).reshape(-1)
    if part.shape != err.shape:
        raise ValueError(f"part has {part.size} entries for {err.size} poses")

    def rms(e: np.ndarray) -> float | None:
        return float(np.sqrt(np.mean(e ** 2))) if len(e) else None

    return rms(err[part]), rms(err[~part])


def rpe_pairs(n: int, delta: int, all_pairs: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, i + delta) for RPE: i = 0, delta, 2 delta, ... (evo's default) or every i."""
    if delta < 1:
        raise ValueError(f"RPE delta must be >= 1 frame, got {delta}")
    first = np.arange(0, n - delta, 1 if all_pairs else delta)
    return first, first + delta


def rpe(gt, est, delta: int = 1, all_pairs: bool = False) -> dict:
    """Relative pose error over ``delta`` frames of matched poses (arrays or Trajectory objects, as
    :func:`ate`), as evo defines it.

    ``E_ij = inv(inv(gt_i) gt_j) (inv(est_i) est_j)``; translation error |t(E)| (m), rotation error
    angle(R(E)) (deg). Returns ``t_rmse_m``, ``t_mean_m``, ``t_max_m``, ``r_rmse_deg``, ``r_mean_deg``,
    ``r_max_deg``, ``n`` (pairs). The estimate's scale matters: align a monocular estimate (sim3)
    before calling this (see :func:`align`).
    """
    gt, est = _pair(gt, est)
    i, j = rpe_pairs(len(gt), delta, all_pairs)
    return relative_pose_errors(se3.relative(gt[i], gt[j]), se3.relative(est[i], est[j]))


def relative_pose_errors(true_a_from_b: np.ndarray, est_a_from_b: np.ndarray) -> dict:
    """Errors of estimated relative motions (P, 4, 4) against the true ones: ``E = inv(true) est``,
    translation |t(E)| (m), rotation angle(R(E)) (deg). Returns ``t_rmse_m``, ``t_mean_m``, ``t_max_m``,
    ``r_rmse_deg``, ``r_mean_deg``, ``r_max_deg``, ``n``. :func:`rpe` is this over frame pairs."""
    err = se3.inverse(true_a_from_b) @ np.asarray(est_a_from_b, dtype=np.float64)
    t = _stats(np.linalg.norm(err[:, :3, 3], axis=1))
    r = _stats(np.rad2deg(se3.rotation_angle(err)))
    return {"t_rmse_m": t["rmse"], "t_mean_m": t["mean"], "t_max_m": t["max"],
            "r_rmse_deg": r["rmse"], "r_mean_deg": r["mean"], "r_max_deg": r["max"], "n": t["n"]}


def kitti_segments(gt, lengths_m=KITTI_LENGTHS_M, step_frames: int = KITTI_STEP_FRAMES) -> list[tuple[int, int, float]]:
    """The devkit's segments: (first_frame, last_frame, length_m), first frames every ``step_frames``.

    Distances are accumulated along the ground truth positions; ``last_frame`` is the first frame
    whose distance exceeds ``dist[first] + length`` (strictly), segments that run off the end are skipped.
    """
    gt = _poses(gt)
    d = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1)
    dist = np.concatenate([[0.0], np.cumsum(d)])
    out = []
    for first in range(0, len(gt), step_frames):
        for length in lengths_m:
            # first index i >= first with dist[i] > dist[first] + length (dist is non-decreasing)
            last = int(np.searchsorted(dist, dist[first] + length, side="right"))
            if last < len(gt):
                out.append((first, last, float(length)))
    return out


def kitti_errors(gt, est, lengths_m=KITTI_LENGTHS_M, step_frames: int = KITTI_STEP_FRAMES) -> dict | None:
    """KITTI odometry t_err and r_err of matched poses (arrays or Trajectory objects, as :func:`ate`),
    exactly as the devkit computes them.

    Returns None when no segment fits (ground truth shorter than the shortest length). Otherwise a
    dict: ``t_err_pct`` (mean over segments of |t(E)| / length, in %), ``r_err_deg_per_100m`` (mean of
    angle(E) / length, in deg per 100 m), ``n_segments``, and ``per_length``: a list of dicts
    (``length_m``, ``n_segments``, ``t_err_pct``, ``r_err_deg_per_100m``) for each length with segments.
    """
    gt, est = _pair(gt, est)
    segs = kitti_segments(gt, lengths_m, step_frames)
    if not segs:
        return None
    f, l, length = (np.array(c) for c in zip(*segs))
    # Matrix::inv in the devkit is a general inverse; np.linalg.inv keeps it exact to rounding.
    delta_gt = np.linalg.inv(gt[f]) @ gt[l]
    delta_est = np.linalg.inv(est[f]) @ est[l]
    err = np.linalg.inv(delta_est) @ delta_gt
    cos = 0.5 * (err[:, 0, 0] + err[:, 1, 1] + err[:, 2, 2] - 1.0)
    r_err = np.arccos(np.clip(cos, -1.0, 1.0)) / length
    t_err = np.linalg.norm(err[:, :3, 3], axis=1) / length
    to_pct, to_deg100 = 100.0, 180.0 / np.pi * 100.0
    per_length = []
    for ln in lengths_m:
        m = length == ln
        if m.any():
            per_length.append({"length_m": float(ln), "n_segments": int(m.sum()),
                               "t_err_pct": float(t_err[m].mean() * to_pct),
                               "r_err_deg_per_100m": float(r_err[m].mean() * to_deg100)})
    return {"t_err_pct": float(t_err.mean() * to_pct), "r_err_deg_per_100m": float(r_err.mean() * to_deg100),
            "n_segments": int(len(segs)), "per_length": per_length}


def match(gt: Trajectory, est: Trajectory, max_diff_s: float = 0.01,
          gt_path: str | Path | None = None, est_path: str | Path | None = None) -> tuple[np.ndarray, np.ndarray, str]:
    """Pair the poses of two trajectories: by timestamp when both have them, else by index.

    Returns (index array into gt, index array into est, how: "timestamps" or "index").
    Raises InputError (naming both files) when index matching meets unequal lengths or fewer than
    :data:`MIN_MATCHES` poses match in time.
    """
    gname = str(gt_path) if gt_path is not None else "ground truth"
    ename = str(est_path) if est_path is not None else "estimate"
    if gt.timestamps_s is None or est.timestamps_s is None:
        if len(gt) != len(est):
            raise InputError(est_path, f"has {len(est)} poses and {gname} has {len(gt)}; without timestamps on "
                             "both sides poses are matched by index, so the counts must be equal")
        idx = np.arange(len(gt))
        how = "index"
        ig, ie = idx, idx
    else:
        ig, ie = associate(gt, est, max_diff_s)
        how = "timestamps"
    if len(ig) < MIN_MATCHES:
        if how == "timestamps":
            raise InputError(est_path, f"cannot be associated with {gname}: {len(ig)} poses match within "
                             f"{max_diff_s:g} s (estimate times {_span(est)}, ground truth times {_span(gt)}); "
                             f"need at least {MIN_MATCHES}")
        raise InputError(est_path, f"{ename} and {gname} have only {len(ig)} poses; need at least {MIN_MATCHES}")
    return ig, ie, how


def _span(t: Trajectory) -> str:
    return f"{t.timestamps_s[0]:.3f}..{t.timestamps_s[-1]:.3f}" if len(t) else "none"


def drift(gt, est) -> dict:
    """Odometry drift figures of matched poses, with no alignment (both expressed relative to their
    first pose, as an odometry starts at the identity).

    ``gt``/``est``: two Trajectory objects (matched by timestamp or index) or matched (N, 4, 4) arrays.

    Returns a dict: ``path_length_ratio`` (estimated / true path length: the scale read over the whole
    run), ``endpoint_drift_m`` (distance between the last estimated and true positions, metres) and
    ``endpoint_drift_pct`` (that, in percent of the true path length).
    """
    g, e = _pair(gt, est)
    g = se3.inverse(g[0]) @ g
    e = se3.inverse(e[0]) @ e
    g_len = float(np.linalg.norm(np.diff(g[:, :3, 3], axis=0), axis=1).sum())
    e_len = float(np.linalg.norm(np.diff(e[:, :3, 3], axis=0), axis=1).sum())
    end = float(np.linalg.norm(g[-1, :3, 3] - e[-1, :3, 3]))
    return {"path_length_ratio": e_len / g_len if g_len > 0 else float("nan"), "endpoint_drift_m": end,
            "endpoint_drift_pct": 100.0 * end / g_len if g_len > 0 else float("nan")}


def on_covered_frames(seq, world_from_cam: np.ndarray, frames: np.ndarray) -> tuple[Trajectory, Trajectory]:
    """(ground truth, estimate) on the frames of ``frames`` that ``seq``'s ground truth covers, both
    expressed relative to the first of them (an odometry starts at the identity).

    Args:
        seq: a :class:`core.sequence.Sequence` with ground truth (``seq.gt_pose(i)``).
        world_from_cam: (len(frames), 4, 4) estimated poses of those frames.
        frames: (F,) frame indices into ``seq``.

    Raises:
        InputError: the ground truth covers fewer than two of the frames.
    """
    scored = [k for k, f in enumerate(frames) if seq.gt_pose(int(f)) is not None]
    if len(scored) < 2:
        raise InputError(getattr(seq, "root", None), "the ground truth covers fewer than two of the frames")
    gt_poses = np.stack([seq.gt_pose(int(frames[k])) for k in scored])
    times = np.asarray(seq.timestamps_s)[np.asarray(frames)[scored]]
    gt = Trajectory(se3.inverse(gt_poses[0]) @ gt_poses, times)
    est = Trajectory(se3.inverse(world_from_cam[scored[0]]) @ world_from_cam[scored], times)
    return gt, est


def evaluate(gt: Trajectory, est: Trajectory, align: str = "se3", rpe_delta: int = 1, max_diff_s: float = 0.01,
             gt_path: str | Path | None = None, est_path: str | Path | None = None) -> dict:
    """All metrics of an estimate against ground truth.

    Poses are matched by timestamp (both have times; nearest within ``max_diff_s``, one-to-one) or
    by index. ATE and RPE are computed after ``align`` (none | se3 | sim3) of the matched estimate;
    the KITTI figures use the same aligned estimate (identical to the raw one for none/se3; sim3
    corrects the scale first) and are present only when the matched ground truth is longer than 100 m.

    Returns a JSON-ready dict: ``ate_m``, ``ate_mean_m``, ``ate_median_m``, ``ate_max_m``, ``rpe_t_m``,
    ``rpe_r_deg``, ``rpe_delta``, ``rpe_pairs``, ``align``, ``scale``, ``rotation`` and ``translation``
    (alignment), ``n_gt``, ``n_est``, ``n_matched``, ``matched_by``, ``gt_length_m``, the unaligned
    drift figures of :func:`drift` (``path_length_ratio``, ``endpoint_drift_m``, ``endpoint_drift_pct``),
    and, when the
    ground truth is long enough, ``kitti_t_err_pct``, ``kitti_r_err_deg_per_100m``,
    ``kitti_n_segments``, ``kitti_per_length``. Also ``_gt_poses``/``_est_aligned_poses``
    ((M, 4, 4) matched, for plots) and ``_est_index`` ((M,) int64, the estimate's pose of each match; keys
    starting with ``_`` are not for JSON).
    """
    if align not in ALIGN_MODES:
        raise InputError(None, f"unknown alignment {align!r} (one of {', '.join(ALIGN_MODES)})")
    if rpe_delta < 1:
        raise InputError(None, f"RPE delta must be at least 1 frame, got {rpe_delta}")
    ig, ie, how = match(gt, est, max_diff_s, gt_path, est_path)
    g, e = gt.world_from_cam[ig], est.world_from_cam[ie]
    if rpe_delta >= len(g):
        raise InputError(None, f"RPE delta {rpe_delta} frames needs more than {len(g)} matched poses")
    aligned, a = _align(g, e, align)
    a_res = ate(g, aligned, "none")
    r_res = rpe(g, aligned, rpe_delta)
    gt_len = float(np.linalg.norm(np.diff(g[:, :3, 3], axis=0), axis=1).sum())
    out = {
        "ate_m": a_res["rmse_m"], "ate_mean_m": a_res["mean_m"], "ate_median_m": a_res["median_m"],
        "ate_max_m": a_res["max_m"],
        "rpe_t_m": r_res["t_rmse_m"], "rpe_r_deg": r_res["r_rmse_deg"], "rpe_delta": int(rpe_delta),
        "rpe_pairs": r_res["n"],
        "align": align, "scale": a.scale, "rotation": a.rotation.tolist(), "translation": a.translation.tolist(),
        "n_gt": len(gt), "n_est": len(est), "n_matched": int(len(ig)), "matched_by": how,
        "max_diff_s": float(max_diff_s) if how == "timestamps" else None,
        "gt_length_m": gt_len,
        **drift(g, e),
    }
    if gt_len > KITTI_MIN_GT_LENGTH_M:
        k = kitti_errors(g, aligned)
        if k is not None:
            out.update({"kitti_t_err_pct": k["t_err_pct"], "kitti_r_err_deg_per_100m": k["r_err_deg_per_100m"],
                        "kitti_n_segments": k["n_segments"], "kitti_per_length": k["per_length"]})
    out["_gt_poses"] = g
    out["_est_aligned_poses"] = aligned
    out["_est_index"] = ie
    return out

