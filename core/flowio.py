"""Optical flow in the standard exchange formats: Middlebury ``.flo`` and KITTI 2015 flow PNGs.

Both readers and writers use this project's flow convention (``flow[v, u] = (du, dv)`` in pixels,
u = column, from frame t to frame t+1) and mark unknown flow as NaN in memory, as the ``.npy`` files
of a render do (NaN where the point is behind the next camera):

- Middlebury ``.flo`` (Baker et al., 2011): little-endian float32 magic 202021.25 ("PIEH"), int32 width, int32
  height, then ``height * width`` float32 pairs (u, v) row by row. Exact (float32). Unknown flow is
  written as 1e10 (Middlebury's ``UNKNOWN_FLOW``); on reading, any component with magnitude above 1e9
  (``UNKNOWN_FLOW_THRESH``) or NaN makes the pixel unknown.
- KITTI 2015 flow PNG (Menze and Geiger, 2015): 16-bit, 3 channels, ``u = (R - 2^15) / 64``,
  ``v = (G - 2^15) / 64`` pixels, ``B = 1`` where the flow is valid and 0 where not. The values are
  rounded to 1/64 px (error at most 1/128 px) and hold [-512, 512) px; a pixel whose flow is unknown or
  outside that range is written invalid (R = G = B = 0). OpenCV stores PNG channels as BGR: R is
  channel 2 of ``cv2.imread``'s array.

Writers are atomic (:mod:`deepslam.core.atomic`); readers raise :class:`InputError` naming the file.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.core.imageio import read_image

FLO_MAGIC = 202021.25
"""The float32 tag that opens a Middlebury .flo file."""
FLO_UNKNOWN = 1e10
"""Value written for unknown flow in .flo files (Middlebury's UNKNOWN_FLOW)."""
FLO_UNKNOWN_THRESH = 1e9
"""A .flo component with magnitude above this (or NaN) is unknown flow (Middlebury's UNKNOWN_FLOW_THRESH)."""
KITTI_FLOW_SCALE = 64.0
"""KITTI flow PNG units per pixel."""
KITTI_FLOW_OFFSET = 2 ** 15
"""KITTI flow PNG value of zero flow."""


def _check_flow(flow: np.ndarray) -> np.ndarray:
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2 or flow.shape[0] < 1 or flow.shape[1] < 1:
        raise ValueError(f"flow must be an (H, W, 2) array, got shape {flow.shape}")
    return flow.astype(np.float32, copy=False)


def encode_flo(flow: np.ndarray) -> bytes:
    """The bytes of a Middlebury .flo file holding ``flow`` (H, W, 2) float32 px (NaN = unknown)."""
    flow = _check_flow(flow)
    h, w = flow.shape[:2]
    known = np.isfinite(flow).all(axis=2, keepdims=True)
    data = np.where(known, flow, np.float32(FLO_UNKNOWN)).astype("<f4")
    return np.float32(FLO_MAGIC).astype("<f4").tobytes() + np.array([w, h], "<i4").tobytes() + data.tobytes()


def write_flo(path: str | Path, flow: np.ndarray) -> None:
    """Write ``flow`` (H, W, 2) float32 (du, dv) px, NaN or inf = unknown, as a Middlebury .flo file
    (atomically); a pixel with a non-finite component gets 1e10 in both."""
    atomic.write_bytes(path, encode_flo(flow))


def read_flo(path: str | Path) -> np.ndarray:
    """Read a Middlebury .flo file: (H, W, 2) float32 (du, dv) px, NaN where the flow is unknown
    (a component above 1e9 in magnitude, or NaN). InputError for a missing, truncated or foreign file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "flow file is missing")
    size = path.stat().st_size
    with open(path, "rb") as f:  # the header first: its size is checked against the file before the rest is read
        head = f.read(12)
        if len(head) < 12:
            raise InputError(path, f"not a .flo file (only {len(head)} bytes)")
        magic = float(np.frombuffer(head[:4], "<f4")[0])
        if magic != FLO_MAGIC:
            raise InputError(path, f"not a .flo file (magic {magic!r}, expected {FLO_MAGIC})")
        w, h = (int(x) for x in np.frombuffer(head[4:12], "<i4"))
        if w < 1 or h < 1 or w > 100_000 or h > 100_000:
            raise InputError(path, f"bad .flo size {w}x{h}")
        need = 12 + 8 * w * h
        if size != need:
            raise InputError(path, f".flo of {w}x{h} needs {need} bytes, the file has {size}")
        data = head + f.read()
    flow = np.frombuffer(data, "<f4", count=2 * w * h, offset=12).reshape(h, w, 2).astype(np.float32)
    unknown = ~(np.abs(flow) <= FLO_UNKNOWN_THRESH).all(axis=2)
    flow[unknown] = np.nan
    return flow


def encode_kitti_flow_png(flow: np.ndarray) -> np.ndarray:
    """The (H, W, 3) uint16 RGB image of a KITTI 2015 flow PNG for ``flow`` (H, W, 2) px (NaN = unknown):
    R, G = round(64 * (u, v)) + 2^15, B = 1 where valid; all three 0 where the flow is unknown or
    outside [-512, 512) px."""
    flow = _check_flow(flow).astype(np.float64)
    q = np.round(flow * KITTI_FLOW_SCALE) + KITTI_FLOW_OFFSET
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(q).all(axis=2) & (q >= 0).all(axis=2) & (q <= 65535).all(axis=2)
    out = np.zeros(flow.shape[:2] + (3,), np.uint16)
    out[valid, :2] = q[valid].astype(np.uint16)
    out[valid, 2] = 1
    return out


def write_kitti_flow_png(path: str | Path, flow: np.ndarray) -> None:
    """Write ``flow`` (H, W, 2) float32 (du, dv) px, NaN = unknown, as a KITTI 2015 flow PNG (16-bit
    RGB, see the module docstring; written atomically)."""
    atomic.write_png(path, encode_kitti_flow_png(flow))  # write_png takes RGB and stores BGR


def read_kitti_flow_png(path: str | Path) -> np.ndarray:
    """Read a KITTI 2015 flow PNG: (H, W, 2) float32 (du, dv) px, NaN where B = 0 (invalid).
    InputError for a missing or truncated file or one that is not a 16-bit 3-channel PNG."""
    path = Path(path)
    img = read_image(path)  # RGB order
    if img.dtype != np.uint16 or img.ndim != 3 or img.shape[2] != 3:
        raise InputError(path, f"KITTI flow PNG must be 16-bit with 3 channels, got {img.dtype} with shape {img.shape}")
    flow = (img[..., :2].astype(np.float32) - np.float32(KITTI_FLOW_OFFSET)) / np.float32(KITTI_FLOW_SCALE)
    flow[img[..., 2] == 0] = np.nan
    return flow
