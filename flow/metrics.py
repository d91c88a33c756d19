"""How far an estimated flow is from the true one (end-point error, KITTI's Fl-all)."""
from __future__ import annotations

import numpy as np


def endpoint_error(pred: np.ndarray, gt: np.ndarray) -> dict:
    """EPE (mean, px) and Fl-all (KITTI 2015: share of pixels with EPE > 3 px and > 5 % of |gt|) over
    pixels with a finite label; ``pred``, ``gt`` (H, W, 2) float px."""
    ok = np.isfinite(gt).all(-1)
    e = np.linalg.norm(pred[ok] - gt[ok], axis=-1)
    mag = np.linalg.norm(gt[ok], axis=-1)
    return {"epe": float(e.mean()), "fl_all": float(np.mean((e > 3.0) & (e > 0.05 * mag))), "pixels": int(ok.sum())}
