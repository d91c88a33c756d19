"""Training-pair augmentation of the flow network: the same random crop of two frames and a shared
photometric draw (used by the supervised renders and the unsupervised real pairs alike)."""
from __future__ import annotations

import numpy as np

from deepslam.core.errors import InputError


def crop_pair(rng: np.random.Generator, g0: np.ndarray, g1: np.ndarray, crop: tuple[int, int],
              what: str) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """The same random ``crop`` (height, width) of two grey uint8 images (H, W), as float32 in [0, 1],
    and its top-left (y, x); InputError naming ``what`` when the images are smaller than the crop."""
    ch, cw = crop
    h, w = g0.shape
    if h < ch or w < cw:
        raise InputError(None, f"{what} {h}x{w} are smaller than the crop {ch}x{cw}")
    y, x = int(rng.integers(0, h - ch + 1)), int(rng.integers(0, w - cw + 1))
    return (g0[y:y + ch, x:x + cw].astype(np.float32) / 255.0, g1[y:y + ch, x:x + cw].astype(np.float32) / 255.0,
            (y, x))


def photometric_pair(a: np.ndarray, b: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The same brightness x[0.7, 1.3], contrast x[0.7, 1.3] and gamma [0.7, 1.5] for both images; in one
    pair of five, an extra gain x[0.9, 1.1] per image (exposure changing between frames); Gaussian
    noise std [0, 0.02] per image. (Drawing everything per image stopped the network from learning to
    match at all in its first thousands of steps.)"""
    gain, contrast, gamma = rng.uniform(0.7, 1.3), rng.uniform(0.7, 1.3), rng.uniform(0.7, 1.5)
    extra = rng.uniform(0.9, 1.1, 2) if rng.random() < 0.2 else np.ones(2)
    out = []
    for img, e in zip((a, b), extra):
        x = img * gain * e
        m = x.mean()
        x = np.clip((x - m) * contrast + m, 0.0, 1.0) ** gamma
        x = x + rng.normal(0.0, rng.uniform(0.0, 0.02), x.shape)
        out.append(np.ascontiguousarray(np.clip(x, 0.0, 1.0), dtype=np.float32))
    return out[0], out[1]
