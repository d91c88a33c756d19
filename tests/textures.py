"""Test data shared by the flow network's and the training runner's tests: block texture shifted by a known flow."""
from __future__ import annotations

import numpy as np
import torch


def shifted_texture_batch(rng: np.random.Generator, n: int, crop: tuple[int, int], max_shift_px: int) -> dict:
    """``n`` pairs of random 4x4-block texture, the second shifted by a whole (du, dv) in
    [-max_shift_px, max_shift_px] each: ``img0``, ``img1`` (n, 1, H, W) float32 in [0, 1) and ``flow`` (n, 2, H, W)
    float32 px, constant per pair (``img1(x - d) = img0(x)``: the flow is ``-d``), ``crop`` = (H, W)."""
    h, w = crop
    i0, i1, fl = [], [], []
    for _ in range(n):
        big = np.kron(rng.random((h // 4 + 4, w // 4 + 4)).astype(np.float32), np.ones((4, 4), np.float32))
        du, dv = (int(rng.integers(-max_shift_px, max_shift_px + 1)) for _ in range(2))
        i0.append(big[8:8 + h, 8:8 + w])
        i1.append(big[8 + dv:8 + dv + h, 8 + du:8 + du + w])
        fl.append(np.stack([np.full((h, w), -du, np.float32), np.full((h, w), -dv, np.float32)]))
    return {"img0": torch.from_numpy(np.stack(i0)[:, None]), "img1": torch.from_numpy(np.stack(i1)[:, None]),
            "flow": torch.from_numpy(np.stack(fl))}
