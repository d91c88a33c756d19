"""End-to-end geometry check: flow synthesized from frame t's depth + the ground-truth relative pose vs.
the simulator's true flow.

For a rendered sequence the synthesized flow of a STATIC surface must equal the simulator's true flow
up to float32 rounding (target: mean end-point error below 0.01 px). Where the scene moves or deforms
(instance mask > 0) the method's rigid-scene assumption breaks; the error there is reported
separately and quantifies that failure case.

Which pixels are compared (per frame t, motion cam_{t+1}_from_cam_t from the ground-truth poses):

- *comparable*: depth_z(t) is a positive finite number, the synthesized point lands inside frame t+1
  in front of the camera (``valid`` of :func:`gen.flow.synthesize`), and the true flow is finite (the
  simulator writes NaN where a point goes behind the camera, and rotation-only flow on the sky, which
  has no depth and is therefore excluded);
- *static visible* (the headline set): comparable, instance mask 0, and VISIBLE at t+1: the moved
  point is not hidden by another surface in frame t+1. With the next frame's rendered depth
  available, visibility is the depth test "at least one of the 2x2 pixels around (u1, v1) in frame
  t+1 has depth >= depth_z1 (1 - tol)", i.e. the surface the camera sees there is not clearly nearer
  than the moved point (this catches occlusion by static geometry and by moving objects alike);
  without it, the z-buffer of frame t's own moved points (:func:`gen.flow.visible_after_motion`) is
  used. Pixels whose point lands on a different surface at t+1 have no observable optical flow, so
  a flow network could never be trained or tested on them;
- *static occluded*: comparable, static, not visible. The simulator's flow is geometric (where the
  surface point goes, visible or not), so these agree as well; they are reported separately;
- *moving*: comparable with instance mask > 0 (moving and deforming surfaces), also per instance id.

The z-buffer visibility, which training data must rely on (it has no next frame), is also compared
with the next-depth test on static pixels (``zbuffer_vs_next_depth``).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import torch

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.core.progress import progress as progress_bar
from deepslam.gen.flow import synthesize, visible_after_motion

TARGET_EPE_PX = 0.01
"""Largest accepted mean end-point error on static visible pixels, pixels."""


@dataclasses.dataclass(frozen=True)
class ValidationConfig:
    """Thresholds of :func:`compare_frame`."""

    next_depth_rel_tol: float = 0.02
    """Depth test: the point is hidden when every pixel around it in frame t+1 is nearer than
    depth_z1 (1 - tol)."""
    occlusion_rel_tol: float = 0.02
    """Relative margin of the z-buffer test (see :func:`gen.flow.visible_after_motion`)."""
    target_epe_px: float = TARGET_EPE_PX
    """Pass/fail threshold on the mean EPE of static visible pixels, pixels."""


@dataclasses.dataclass
class FrameComparison:
    """Per-pixel result for one frame: (H, W) arrays."""

    epe: np.ndarray
    """float64 end-point error |synthesized - true| in pixels (NaN where not comparable)."""
    comparable: np.ndarray
    """bool, see the module docstring."""
    static_visible: np.ndarray
    """bool."""
    static_occluded: np.ndarray
    """bool."""
    moving: np.ndarray
    """bool (mask > 0 and comparable)."""
    mask: np.ndarray
    """uint16 instance ids (zeros when the sequence has none)."""
    zbuffer_visible: np.ndarray
    """bool, the z-buffer's visibility (comparable pixels)."""
    next_depth_visible: np.ndarray | None
    """bool, the depth test's visibility, or None without the next depth."""
    counts: dict
    """Excluded pixel counts: no_depth, outside_or_behind, true_flow_not_finite."""


def next_depth_visible(flow: np.ndarray, valid: np.ndarray, depth_z1: np.ndarray, depth_next: np.ndarray,
                       rel_tol: float) -> np.ndarray:
    """(H, W) bool: the moved point is not clearly behind what frame t+1 sees around where it lands.

    Args:
        flow: (H, W, 2) synthesized flow, pixels.
        valid: (H, W) bool points landing inside frame t+1 in front of the camera.
        depth_z1: (H, W) depth of the moved points in camera t+1, metres.
        depth_next: (H, W) rendered depth_z of frame t+1, metres (0 = nothing).
        rel_tol: relative tolerance.
    """
    h, w = valid.shape
    vv, uu = np.nonzero(valid)
    x = uu + flow[vv, uu, 0].astype(np.float64)
    y = vv + flow[vv, uu, 1].astype(np.float64)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    best = np.zeros(len(vv))
    for dx in (0, 1):
        for dy in (0, 1):
            d = depth_next[np.clip(y0 + dy, 0, h - 1), np.clip(x0 + dx, 0, w - 1)].astype(np.float64)
            best = np.maximum(best, np.where(np.isfinite(d), d, 0.0))
    out = np.zeros((h, w), dtype=bool)
    out[vv, uu] = (best > 0) & (best >= depth_z1[vv, uu] * (1.0 - rel_tol))
    return out


def compare_frame(depth_z: np.ndarray, flow_true: np.ndarray, camera: PinholeCamera, cam1_from_cam0: np.ndarray,
                  mask: np.ndarray | None = None, depth_next: np.ndarray | None = None,
                  config: ValidationConfig = ValidationConfig()) -> FrameComparison:
    """Compare the flow synthesized for one frame with its true flow.

    Args:
        depth_z: (H, W) float32 depth of frame t, metres (0 = none).
        flow_true: (H, W, 2) float32 true flow t -> t+1, pixels (NaN allowed).
        camera: the sequence's PinholeCamera.
        cam1_from_cam0: (4, 4) float64 ground-truth ``cam_{t+1}_from_cam_t``.
        mask: (H, W) instance ids of frame t (0 = static), or None (everything static).
        depth_next: (H, W) depth of frame t+1 for the visibility test, or None (z-buffer instead).
        config: tolerances.
    """
    depth = np.asarray(depth_z, dtype=np.float32)
    h, w = depth.shape
    flow_t, valid_t, z1_t = synthesize(torch.from_numpy(depth), camera, cam1_from_cam0, return_depth1=True)
    flow = flow_t.numpy()
    valid = valid_t.numpy()
    z1 = z1_t.numpy()
    zb = visible_after_motion(flow_t.permute(2, 0, 1)[None].contiguous(), valid_t[None], z1_t[None],
                              config.occlusion_rel_tol)[0].numpy()
    flow_true = np.asarray(flow_true, dtype=np.float64)
    true_ok = np.isfinite(flow_true).all(axis=-1)
    has_depth = np.isfinite(depth) & (depth > 0)
    comparable = valid & true_ok
    mask = np.zeros((h, w), np.uint16) if mask is None else np.asarray(mask)
    static = mask == 0
    nd = None
    if depth_next is not None:
        nd = next_depth_visible(flow, valid, z1, np.asarray(depth_next), config.next_depth_rel_tol)
        visible = nd
    else:
        visible = zb
    epe = np.full((h, w), np.nan)
    diff = flow.astype(np.float64) - flow_true
    epe[comparable] = np.hypot(diff[comparable, 0], diff[comparable, 1])
    counts = {"no_depth": int((~has_depth).sum()), "outside_or_behind": int((has_depth & ~valid).sum()),
              "true_flow_not_finite": int((valid & ~true_ok).sum())}
    return FrameComparison(epe, comparable, comparable & static & visible, comparable & static & ~visible,
                           comparable & ~static, mask, zb & comparable, None if nd is None else nd & comparable, counts)


def summarize(values: np.ndarray) -> dict:
    """{pixels, epe_mean_px, epe_median_px, epe_p95_px, epe_max_px} of EPE values (None when empty)."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return {"pixels": 0, "epe_mean_px": None, "epe_median_px": None, "epe_p95_px": None, "epe_max_px": None}
    return {"pixels": int(v.size), "epe_mean_px": float(v.mean()), "epe_median_px": float(np.median(v)),
            "epe_p95_px": float(np.quantile(v, 0.95)), "epe_max_px": float(v.max())}


def validate_sequence(seq, frames: range | None = None, config: ValidationConfig = ValidationConfig(),
                      progress: bool | None = None) -> dict:
    """Compare synthesized and true flow over a rendered sequence (ours format with depth and flow).

    Args:
        seq: a :class:`core.sequence.Sequence` with depth, flow and ground truth (mask optional).
        frames: frame indices t to compare (flow t -> t+1); default all but the last.
        config: tolerances and the pass threshold.
        progress: progress bar (None: the project's default policy).

    Returns:
        A JSON-able report: ``static_visible`` / ``static_occluded`` / ``moving`` summaries (pixels,
        EPE mean/median/p95/max in px), ``per_instance``, ``per_frame``, excluded pixel counts,
        ``zbuffer_vs_next_depth`` and ``met`` (static visible mean EPE < target).
    """
    if not seq.has_depth:
        raise InputError(seq.root, "sequence has no depth (validate-flow needs a rendered sequence with depth/ and flow/)")
    if seq.flow_paths is None:
        raise InputError(seq.root, "sequence has no flow (validate-flow needs a rendered sequence with depth/ and flow/)")
    if seq.gt is None:
        raise InputError(seq.root, "sequence has no ground-truth poses")
    n = len(seq)
    frames = range(n - 1) if frames is None else frames
    if len(frames) == 0:
        raise InputError(seq.root, "need at least two frames to compare flow")
    sv, so, mv = [], [], []
    per_instance: dict[int, list] = {}
    per_frame = []
    counts = {"no_depth": 0, "outside_or_behind": 0, "true_flow_not_finite": 0}
    zb_agree = zb_total = zb_hidden = nd_hidden = 0
    opts = {} if progress is None else {"disable": not progress}
    for t in progress_bar(frames, desc="validate-flow", unit="frame", **opts):
        if not 0 <= t < n - 1:
            raise InputError(seq.root, f"frame {t} has no next frame (sequence has {n} frames)")
        flow_true = seq.flow(t)
        if flow_true is None:
            raise InputError(seq.root, f"frame {t} has no flow file")
        depth = seq.depth(t)
        depth_next = seq.depth(t + 1)
        mask = seq.mask(t) if seq.mask_paths is not None else None
        motion = _relative(seq.gt.world_from_cam, t)
        c = compare_frame(depth, flow_true, seq.camera, motion, mask, depth_next, config)
        sv.append(c.epe[c.static_visible])
        so.append(c.epe[c.static_occluded])
        mv.append(c.epe[c.moving])
        for inst in np.unique(c.mask[c.moving]):
            per_instance.setdefault(int(inst), []).append(c.epe[c.moving & (c.mask == inst)])
        for k in counts:
            counts[k] += c.counts[k]
        stat = c.comparable & (c.mask == 0)
        zb_agree += int((c.zbuffer_visible[stat] == c.next_depth_visible[stat]).sum())
        zb_total += int(stat.sum())
        zb_hidden += int((stat & ~c.zbuffer_visible).sum())
        nd_hidden += int((stat & ~c.next_depth_visible).sum())
        per_frame.append({"frame": int(t),
                          "static_visible_epe_mean_px": summarize(c.epe[c.static_visible])["epe_mean_px"],
                          "moving_epe_mean_px": summarize(c.epe[c.moving])["epe_mean_px"],
                          "moving_pixels": int(c.moving.sum())})
    static_visible = summarize(np.concatenate(sv))
    report = {
        "sequence": seq.name, "frames_compared": len(frames), "image_size_wh": [seq.camera.width, seq.camera.height],
        "static_visible": static_visible,
        "static_occluded": summarize(np.concatenate(so)),
        "moving": summarize(np.concatenate(mv)),
        "per_instance": {str(k): summarize(np.concatenate(v)) for k, v in sorted(per_instance.items())},
        "excluded": counts,
        "zbuffer_vs_next_depth": {"static_pixels": zb_total, "agreement": (zb_agree / zb_total) if zb_total else None,
                                  "zbuffer_hidden": zb_hidden, "next_depth_hidden": nd_hidden},
        "target_epe_px": config.target_epe_px,
        "met": bool(static_visible["epe_mean_px"] is not None and static_visible["epe_mean_px"] < config.target_epe_px),
        "per_frame": per_frame,
    }
    return report


def _relative(world_from_cam: np.ndarray, t: int) -> np.ndarray:
    """cam_{t+1}_from_cam_t = inverse(world_from_cam[t+1]) @ world_from_cam[t]."""
    return se3.relative(world_from_cam[t + 1], world_from_cam[t])
