"""Plain per-sample NumPy flow synthesis: the paper's four steps written out, in float64.

The reference the tests hold :func:`gen.flow.synthesize` to, and the baseline of ``bench/bench_gen.py``.
Same conventions and validity rules as :mod:`gen.flow` (read its docstring); nothing here is optimised.
"""
from __future__ import annotations

import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.gen.flow import DEFAULT_OCCLUSION_REL_TOL


def _camera(camera, width: int, height: int) -> PinholeCamera:
    if isinstance(camera, PinholeCamera):
        if (camera.width, camera.height) != (width, height):
            raise ValueError(f"camera is {camera.width}x{camera.height} but the depth map is {width}x{height}")
        return camera
    fx, fy, cx, cy = np.asarray(camera, dtype=np.float64).reshape(4)
    return PinholeCamera(width, height, fx, fy, cx, cy)


def synthesize_reference(depth_z: np.ndarray, camera, cam1_from_cam0: np.ndarray, zbuffer: bool = False,
                         occlusion_rel_tol: float = DEFAULT_OCCLUSION_REL_TOL):
    """Flow of one depth map under one motion.

    Args:
        depth_z: (H, W) depth along camera 0's optical axis, metres (0/negative/NaN/inf = none).
        camera: PinholeCamera of size W x H, or (fx, fy, cx, cy).
        cam1_from_cam0: (4, 4) rigid transform, metres, OpenCV axes.
        zbuffer: also invalidate points hidden in frame 1 by a nearer moved point, as
            :func:`gen.flow.visible_after_motion` does (footprint splat, amin, compare at the nearest
            pixel with a relative tolerance), written as plain loops.

    Returns:
        (flow (H, W, 2) float64 pixels (du, dv), 0 where invalid; valid (H, W) bool;
        depth_z1 (H, W) float64 depth in camera 1, 0 where invalid).
    """
    depth = np.asarray(depth_z, dtype=np.float64)
    h, w = depth.shape
    cam = _camera(camera, w, h)
    grid = cam.pixel_grid()                                   # (H, W, 2) u, v
    has_depth = np.isfinite(depth) & (depth > 0)
    z = np.where(has_depth, depth, 1.0)
    p_cam0 = cam.unproject(grid, z)                           # step 1: unproject
    p_cam1 = se3.transform_points(cam1_from_cam0, p_cam0.reshape(-1, 3)).reshape(h, w, 3)  # step 2: move
    uv1, z1 = cam.project(p_cam1)                             # step 3: reproject
    with np.errstate(invalid="ignore"):
        inside = (uv1[..., 0] > -0.5) & (uv1[..., 0] < w - 0.5) & (uv1[..., 1] > -0.5) & (uv1[..., 1] < h - 0.5)
    valid = has_depth & (z1 > 0) & inside
    flow = np.where(valid[..., None], uv1 - grid, 0.0)       # step 4: subtract the pixel grid
    if zbuffer:
        x1 = np.where(valid, uv1[..., 0], np.nan)
        y1 = np.where(valid, uv1[..., 1], np.nan)
        rx = 0.5 * (_min_one_sided_abs_diff(x1, 1) + _min_one_sided_abs_diff(x1, 0))
        ry = 0.5 * (_min_one_sided_abs_diff(y1, 1) + _min_one_sided_abs_diff(y1, 0))
        rx, ry = np.clip(rx, 0.5, 1.5), np.clip(ry, 0.5, 1.5)
        zz = np.where(valid, z1, np.nan)
        slack = _min_one_sided_abs_diff(zz, 1) + _min_one_sided_abs_diff(zz, 0)
        zbuf = np.full((h, w), np.inf)
        vv, uu = np.nonzero(valid)
        for v, u in zip(vv, uu):          # splat each point over its footprint box (3x3 block around it)
            x, y = x1[v, u], y1[v, u]
            xn, yn = int(np.round(x)), int(np.round(y))
            cols = [c for c in (xn - 1, xn, xn + 1) if 0 <= c < w and (c == xn or abs(c - x) <= rx[v, u])]
            rows = [r for r in (yn - 1, yn, yn + 1) if 0 <= r < h and (r == yn or abs(r - y) <= ry[v, u])]
            for r in rows:
                for c in cols:
                    zbuf[r, c] = min(zbuf[r, c], z1[v, u])
        hidden = np.zeros_like(valid)
        for v, u in zip(vv, uu):
            nearest = zbuf[min(max(int(np.round(y1[v, u])), 0), h - 1), min(max(int(np.round(x1[v, u])), 0), w - 1)]
            hidden[v, u] = z1[v, u] - nearest > slack[v, u] + occlusion_rel_tol * z1[v, u]
        valid &= ~hidden
        flow[hidden] = 0.0
    return flow, valid, np.where(valid, z1, 0.0)


def synthesize_reference_batch(depth_z: np.ndarray, camera, cam1_from_cam0: np.ndarray, zbuffer: bool = False):
    """Loop of :func:`synthesize_reference` over a batch: (B, H, W) depths and (B, 4, 4) motions ->
    (flow (B, H, W, 2) float64, valid (B, H, W) bool)."""
    depth = np.asarray(depth_z)
    motions = np.broadcast_to(np.asarray(cam1_from_cam0, dtype=np.float64), (len(depth), 4, 4))
    outs = [synthesize_reference(depth[i], camera, motions[i], zbuffer)[:2] for i in range(len(depth))]
    return np.stack([o[0] for o in outs]), np.stack([o[1] for o in outs])


def _min_one_sided_abs_diff(a: np.ndarray, axis: int) -> np.ndarray:
    """Per pixel, the smaller |forward| or |backward| difference along ``axis``; 1 where both are NaN."""
    d = np.abs(np.diff(a, axis=axis))
    pad_end = [(0, 0)] * a.ndim
    pad_end[axis] = (0, 1)
    pad_start = [(0, 0)] * a.ndim
    pad_start[axis] = (1, 0)
    fwd = np.pad(d, pad_end, constant_values=np.nan)
    bwd = np.pad(d, pad_start, constant_values=np.nan)
    out = np.fmin(fwd, bwd)
    return np.where(np.isnan(out), 1.0, out)
