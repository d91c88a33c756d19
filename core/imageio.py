"""Readers of one frame's files: images (PNG, JPEG) and arrays (.npy), each checked before use."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from deepslam.core.errors import InputError


def read_image(path: str | Path) -> np.ndarray:
    """Read a PNG/JPEG as uint8 (H, W) grey or (H, W, 3) RGB, or uint16 (H, W) for 16-bit PNGs.

    Raises InputError for a missing, empty or truncated file (a decoder that stops early is an error,
    not a partly grey image).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image file is missing")
    data = path.read_bytes()
    if not data:
        raise InputError(path, "image file is empty")
    if data[:8] == b"\x89PNG\r\n\x1a\n" and b"IEND" not in data[-64:]:
        raise InputError(path, "PNG is truncated (no IEND chunk)")
    if data[:2] == b"\xff\xd8" and data.rstrip(b"\0")[-2:] != b"\xff\xd9":
        raise InputError(path, "JPEG is truncated (no end-of-image marker)")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(path, "cannot decode image")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return img


def read_npy(path: str | Path, dtype: np.dtype, ndim: int) -> np.ndarray:
    """Read a .npy written by this project, checking dtype and rank; InputError when it is bad."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file is missing")
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as e:  # numpy raises ValueError/OSError/EOFError for truncated files
        raise InputError(path, f"cannot read .npy ({type(e).__name__}: {e})") from None
    if arr.ndim != ndim:
        raise InputError(path, f"expected a {ndim}-D array, got shape {arr.shape}")
    return arr.astype(dtype, copy=False)
