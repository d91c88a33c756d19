"""Depth from a rectified stereo pair: ``depth_z = fx * baseline / disparity``, with a left-right check.

Two disparity estimators, both from OpenCV:

- ``sgbm``: semi-global block matching (``cv2.StereoSGBM``, 3-way mode), the usual choice;
- ``dis``: dense inverse search optical flow (``cv2.DISOpticalFlow``) from left to right, disparity =
  minus the horizontal flow: the "flow network as stereo matcher" alternative the paper used with
  PWC-Net. Matches that move vertically by more than ``max_vertical_px`` (impossible after
  rectification) are dropped.

Left-right consistency: the disparity of the right image is computed too (SGBM on the mirrored pair,
DIS from right to left) and a left pixel is kept only when the right disparity at its match agrees
within ``lr_max_diff_px``. Disparities below ``min_disparity_px`` (farther than ``fx B / min``) are
dropped as well. Unknown depth is 0, as everywhere in the project.

Conventions: images rectified, uint8 grey (H, W) or RGB (H, W, 3); the right camera sits at +baseline
along the left camera's x axis, so a left pixel u matches right pixel u - d with d > 0.
"""
from __future__ import annotations

import contextlib
import dataclasses
from typing import Iterator

import cv2
import numpy as np

from deepslam.core.errors import InputError

METHODS = ("sgbm", "dis")


@dataclasses.dataclass(frozen=True)
class StereoConfig:
    """Settings of :func:`depth_from_stereo`."""

    method: str = "sgbm"
    """``sgbm`` (OpenCV StereoSGBM) or ``dis`` (OpenCV DIS optical flow)."""
    num_disparities: int = 128
    """SGBM search range in pixels (a multiple of 16)."""
    block_size: int = 5
    """SGBM matching block side, pixels (odd)."""
    uniqueness_ratio: int = 10
    """SGBM uniqueness margin, percent."""
    speckle_window: int = 100
    """SGBM speckle filter: largest blob size (pixels) treated as noise; 0 disables."""
    dis_preset: str = "medium"
    """DIS preset: ``ultrafast``, ``fast`` or ``medium``."""
    max_vertical_px: float = 1.0
    """DIS: largest vertical flow (pixels) accepted for a rectified pair."""
    lr_max_diff_px: float = 1.0
    """Left-right check: largest disagreement between left and right disparity, pixels."""
    min_disparity_px: float = 1.0
    """Smallest disparity kept, pixels (sets the largest depth: fx * baseline / this)."""

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"stereo method must be one of {METHODS}, got {self.method!r}")
        if self.num_disparities <= 0 or self.num_disparities % 16:
            raise ValueError(f"num_disparities must be a positive multiple of 16, got {self.num_disparities}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ValueError(f"block_size must be odd, got {self.block_size}")
        if self.dis_preset not in ("ultrafast", "fast", "medium"):
            raise ValueError(f"dis_preset must be ultrafast, fast or medium, got {self.dis_preset!r}")


def _grey(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    if img.dtype != np.uint8:
        raise ValueError(f"stereo images must be uint8, got {img.dtype}")
    if img.ndim == 3:
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(img)


@contextlib.contextmanager
def opencv_threads(n: int) -> Iterator[None]:
    """Run OpenCV with ``n`` threads inside the block (fixed thread counts give bit-identical output)."""
    old = cv2.getNumThreads()
    cv2.setNumThreads(n)
    try:
        yield
    finally:
        cv2.setNumThreads(old)


def _sgbm(left: np.ndarray, right: np.ndarray, cfg: StereoConfig) -> np.ndarray:
    cn = 1
    matcher = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=cfg.num_disparities, blockSize=cfg.block_size,
        P1=8 * cn * cfg.block_size ** 2, P2=32 * cn * cfg.block_size ** 2, disp12MaxDiff=-1,
        preFilterCap=63, uniquenessRatio=cfg.uniqueness_ratio, speckleWindowSize=cfg.speckle_window,
        speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    disp = matcher.compute(left, right).astype(np.float32) / 16.0   # fixed point, 4 fractional bits
    disp[disp <= 0] = np.nan                                       # -1: no match
    return disp


def _dis(a: np.ndarray, b: np.ndarray, cfg: StereoConfig) -> np.ndarray:
    preset = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
              "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}[cfg.dis_preset]
    dis = cv2.DISOpticalFlow_create(preset)
    return dis.calc(a, b, None)


def disparity(left: np.ndarray, right: np.ndarray, config: StereoConfig = StereoConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Left disparity with the left-right check.

    Args:
        left, right: rectified uint8 images (H, W) grey or (H, W, 3) RGB.
        config: method and thresholds.

    Returns:
        (disparity (H, W) float32 pixels, 0 where not valid; valid (H, W) bool).
    """
    lg, rg = _grey(left), _grey(right)
    if lg.shape != rg.shape:
        raise ValueError(f"left {lg.shape} and right {rg.shape} images differ in size")
    h, w = lg.shape
    if config.method == "sgbm":
        d_left = _sgbm(lg, rg, config)
        # Right disparity: SGBM on the mirrored pair (mirrored right image plays the left one).
        d_right = _sgbm(np.ascontiguousarray(rg[:, ::-1]), np.ascontiguousarray(lg[:, ::-1]), config)[:, ::-1]
        ok_left = np.isfinite(d_left)
    else:
        f_lr = _dis(lg, rg, config)
        f_rl = _dis(rg, lg, config)
        d_left = -f_lr[..., 0]
        d_right = f_rl[..., 0]
        ok_left = (np.abs(f_lr[..., 1]) <= config.max_vertical_px) & (d_left > 0)
        d_right = np.where((np.abs(f_rl[..., 1]) <= config.max_vertical_px) & (d_right > 0), d_right, np.nan)
    uu = np.arange(w, dtype=np.float32)[None, :]
    with np.errstate(invalid="ignore"):
        match = np.round(uu - np.nan_to_num(d_left, nan=0.0)).astype(np.int64)
    inside = (match >= 0) & (match < w)
    rows = np.arange(h)[:, None]
    d_back = d_right[rows, np.clip(match, 0, w - 1)]
    with np.errstate(invalid="ignore"):
        valid = ok_left & inside & (np.abs(d_left - d_back) <= config.lr_max_diff_px) & (d_left >= config.min_disparity_px)
    disp = np.where(valid, d_left, 0.0).astype(np.float32)
    return disp, valid


def depth_from_disparity(disp: np.ndarray, valid: np.ndarray, fx: float, baseline_m: float) -> np.ndarray:
    """(H, W) float32 depth_z = fx * baseline / disparity (metres), 0 where not valid."""
    if not baseline_m > 0:
        raise ValueError(f"baseline must be positive, got {baseline_m}")
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(valid & (disp > 0), fx * baseline_m / disp, 0.0)
    return z.astype(np.float32)


def depth_from_stereo(left: np.ndarray, right: np.ndarray, fx: float, baseline_m: float,
                      config: StereoConfig = StereoConfig()) -> np.ndarray:
    """(H, W) float32 depth_z of the left camera in metres (0 = unknown) from a rectified pair.

    Args:
        left, right: rectified uint8 images, grey or RGB.
        fx: focal length of the rectified pair, pixels.
        baseline_m: distance between the two camera centres, metres (right at +x).
        config: method (``sgbm`` / ``dis``) and thresholds.
    """
    disp, valid = disparity(left, right, config)
    return depth_from_disparity(disp, valid, fx, baseline_m)


def sequence_depth(seq, i: int, config: StereoConfig = StereoConfig()) -> np.ndarray:
    """Depth of frame i of a stereo :class:`core.sequence.Sequence` (needs right images and a baseline)."""
    if not seq.has_stereo:
        raise InputError(seq.root, "sequence has no stereo pair (right images and baseline) to compute depth from")
    return depth_from_stereo(seq.image(i), seq.image_right(i), seq.camera.fx, seq.baseline_m, config)
