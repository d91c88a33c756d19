"""False colours for looking at ground truth: flow on the Middlebury colour wheel, depth with near bright,
instance masks with one colour per id.

Shared by the contact sheet (:mod:`deepslam.core.preview`) and the 3-D viewer (:mod:`deepslam.view`), so a
flow looks the same in both. Every function returns uint8 (H, W, 3) RGB.
"""
from __future__ import annotations

import cv2
import numpy as np


def _colour_wheel() -> np.ndarray:
    """(55, 3) float64 RGB in [0, 1]: the Middlebury flow colour wheel (Baker et al., "A Database and Evaluation
    Methodology for Optical Flow", 2011): red, yellow, green, cyan, blue, magenta in 15/6/4/11/13/6 steps."""
    steps = [(15, (1, 0, 0), (1, 1, 0)), (6, (1, 1, 0), (0, 1, 0)), (4, (0, 1, 0), (0, 1, 1)),
             (11, (0, 1, 1), (0, 0, 1)), (13, (0, 0, 1), (1, 0, 1)), (6, (1, 0, 1), (1, 0, 0))]
    rows = []
    for n, a, b in steps:
        f = np.floor(255 * np.arange(n) / n)[:, None] / 255.0
        rows.append(np.asarray(a, float) * (1 - f) + np.asarray(b, float) * f)
    return np.concatenate(rows)


WHEEL = _colour_wheel()
"""(55, 3) float64 RGB in [0, 1], the Middlebury colour wheel (hue = flow direction)."""


FLOW_PERCENTILE = 90.0
"""A flow is drawn fully saturated at this percentile of its lengths by default: a near moving car does not
wash out the static scene's flow."""
MIN_FLOW_SCALE_PX = 1.0
"""Smallest default saturation length, pixels: a camera at rest stays white instead of showing sub-pixel noise."""


def flow_magnitude_scale(flow: np.ndarray, percentile: float = FLOW_PERCENTILE,
                         min_px: float = MIN_FLOW_SCALE_PX) -> float:
    """The length in pixels that :func:`flow_to_rgb` draws fully saturated by default: the ``percentile`` of
    the lengths of the finite vectors of ``flow`` (H, W, 2), at least ``min_px``."""
    mag = np.hypot(flow[..., 0], flow[..., 1])
    mag = mag[np.isfinite(mag)]
    m = float(np.percentile(mag, percentile)) if mag.size else 0.0
    return max(m, min_px, 1e-9)


def flow_to_rgb(flow: np.ndarray, max_px: float | None = None) -> np.ndarray:
    """Flow as colour, as the Middlebury benchmark's figures draw it: hue is the direction (right red, down
    yellow, left cyan, up violet), saturation the length up to ``max_px`` (white = no motion; longer vectors
    are drawn darker).

    Args:
        flow: (H, W, 2) float (du, dv) pixels; NaN = unknown.
        max_px: the length drawn fully saturated; None: :func:`flow_magnitude_scale` of ``flow``.

    Returns:
        (H, W, 3) uint8 RGB; unknown flow is black.
    """
    flow = np.asarray(flow, dtype=np.float64)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must be (H, W, 2), got {flow.shape}")
    scale = flow_magnitude_scale(flow) if max_px is None else float(max_px)
    unknown = ~np.isfinite(flow).all(axis=2)
    u = np.where(unknown, 0.0, flow[..., 0]) / scale
    v = np.where(unknown, 0.0, flow[..., 1]) / scale
    rad = np.hypot(u, v)
    n = len(WHEEL)
    fk = (np.arctan2(-v, -u) / np.pi + 1.0) / 2.0 * (n - 1)
    k0 = np.floor(fk).astype(np.int64) % n
    k1 = (k0 + 1) % n
    f = (fk - np.floor(fk))[..., None]
    col = (1 - f) * WHEEL[k0] + f * WHEEL[k1]
    inside = (rad <= 1)[..., None]
    col = np.where(inside, 1 - rad[..., None] * (1 - col), col * 0.75)
    out = np.round(255 * np.clip(col, 0, 1)).astype(np.uint8)
    out[unknown] = 0
    return out


def depth_range_m(depth_z: np.ndarray, percentiles: tuple[float, float] = (2.0, 98.0)) -> tuple[float, float]:
    """(near_m, far_m): percentiles of the valid (finite, > 0) depths of ``depth_z`` (any shape, metres), for
    :func:`depth_to_rgb`; (1, 2) when nothing is valid."""
    d = np.asarray(depth_z, dtype=np.float64)
    d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0:
        return 1.0, 2.0
    near, far = (float(x) for x in np.percentile(d, percentiles))
    return near, max(far, near * 1.001 + 1e-6)


def depth_to_rgb(depth_z: np.ndarray, near_m: float | None = None, far_m: float | None = None) -> np.ndarray:
    """Depth as colour, near bright: inverse depth between ``1/far_m`` and ``1/near_m`` on the magma colour map.

    Args:
        depth_z: (H, W) float depth_z in metres; 0 or non-finite = no depth.
        near_m, far_m: the depths drawn brightest and darkest; None: :func:`depth_range_m` of ``depth_z``.

    Returns:
        (H, W, 3) uint8 RGB; pixels without depth are black.
    """
    d = np.asarray(depth_z, dtype=np.float64)
    if d.ndim != 2:
        raise ValueError(f"depth must be (H, W), got {d.shape}")
    if near_m is None or far_m is None:
        auto_near, auto_far = depth_range_m(d)
        near_m = auto_near if near_m is None else near_m
        far_m = auto_far if far_m is None else far_m
    valid = np.isfinite(d) & (d > 0)
    inv = np.zeros_like(d)
    inv[valid] = 1.0 / d[valid]
    lo, hi = 1.0 / far_m, 1.0 / near_m
    t = np.clip((inv - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    grey = np.round(255 * t).astype(np.uint8)
    rgb = cv2.applyColorMap(grey, cv2.COLORMAP_MAGMA)[..., ::-1].copy()
    rgb[~valid] = 0
    return rgb


def instance_colours(ids: np.ndarray) -> np.ndarray:
    """(len(ids), 3) uint8 RGB, one saturated colour per id (hue stepped by the golden ratio, so neighbouring
    ids differ); id 0 is black. The same id always gets the same colour."""
    ids = np.asarray(ids, dtype=np.int64)
    hue = (ids * 0.6180339887498949) % 1.0
    hsv = np.stack([np.round(hue * 179), np.full_like(hue, 220), np.full_like(hue, 255)], axis=-1).astype(np.uint8)
    rgb = cv2.cvtColor(hsv.reshape(-1, 1, 3), cv2.COLOR_HSV2RGB).reshape(-1, 3)
    rgb[ids == 0] = 0
    return rgb


def mask_to_rgb(mask: np.ndarray, image: np.ndarray | None = None, dim: float = 0.35) -> np.ndarray:
    """Instance ids as colour, over a dimmed grey copy of ``image`` where the scene is static.

    Args:
        mask: (H, W) integer instance ids, 0 = static scene.
        image: (H, W) grey or (H, W, 3) RGB uint8 shown dimmed under the static pixels; None: black.
        dim: brightness kept of ``image``.

    Returns:
        (H, W, 3) uint8 RGB.
    """
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must be (H, W), got {mask.shape}")
    if image is None:
        out = np.zeros((*mask.shape, 3), np.uint8)
    else:
        grey = image if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
        out = np.repeat(np.round(grey.astype(np.float64) * dim).astype(np.uint8)[..., None], 3, axis=2)
    ids, inverse = np.unique(mask, return_inverse=True)
    colours = instance_colours(ids)[inverse.reshape(mask.shape)]
    moving = mask != 0
    out[moving] = colours[moving]
    return out
