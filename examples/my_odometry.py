"""A user odometry as a deepslam plug-in: each pixel's depth, carried by the flow, solved as PnP.

For a consecutive pair (i, i+1), pixels with depth in frame i are back-projected (``seq.depth(i)``) and
matched to where the flow says they land in frame i+1 (``seq.flow(i)``); OpenCV's RANSAC PnP gives
``cam_j_from_cam_i``. On a render with exact flow and depth this is exact where nothing moves; movers that
fill much of the view pull it off, which is what ``deepslam stress`` measures.

Use it with any command that takes ``--odometry`` (run from this folder, or put it on ``PYTHONPATH``)::

    PYTHONPATH=examples deepslam vo --sequence out/quick --odometry my_odometry:make --out out/quick_vo.txt
    PYTHONPATH=examples deepslam stress --quick --odometry my_odometry:make --out out/quick_stress
"""
from __future__ import annotations

import cv2
import numpy as np

from deepslam.core import se3


class DepthFlowOdometry:
    """``predict(seq, pairs) -> (mean6, std6)``: the paper's 6-vector of ``cam_j_from_cam_i`` per pair
    (euler x, y, z in rad with R = Rz Ry Rx, then t in m; OpenCV camera axes) and a fixed std."""

    name = "depth-flow"

    def __init__(self, std6=(0.002, 0.002, 0.002, 0.02, 0.02, 0.02)):
        self.std6 = np.asarray(std6, dtype=np.float64)

    def predict(self, seq, pairs):
        out = []
        for i, j in pairs:
            if j != i + 1:
                raise ValueError(f"consecutive pairs only, got ({i}, {j})")
            out.append(se3.to_euler6(self._motion(seq, i)))
        return np.asarray(out).reshape(-1, 6), np.tile(self.std6, (len(out), 1))

    @staticmethod
    def _motion(seq, i: int, n_points: int = 3000) -> np.ndarray:
        """cam_{i+1}_from_cam_i (4, 4) from the flow (H, W, 2 px), depth_z (H, W m) and the intrinsics."""
        cam, flow, z0 = seq.camera, seq.flow(i), seq.depth(i)
        v, u = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
        u1, v1 = u + flow[..., 0], v + flow[..., 1]
        ok = (z0 > 0) & np.isfinite(z0) & np.isfinite(u1) & np.isfinite(v1)
        idx = np.flatnonzero(ok)
        idx = np.random.default_rng(i).choice(idx, min(n_points, len(idx)), replace=False)  # same draw every run
        zz = z0.ravel()[idx]
        p0 = np.stack([(u.ravel()[idx] - cam.cx) / cam.fx * zz, (v.ravel()[idx] - cam.cy) / cam.fy * zz, zz], 1)
        uv1 = np.stack([u1.ravel()[idx], v1.ravel()[idx]], 1)
        k = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])
        found, rvec, tvec, _ = cv2.solvePnPRansac(p0, uv1, k, None, reprojectionError=0.5, iterationsCount=200,
                                                  flags=cv2.SOLVEPNP_ITERATIVE)
        if not found:
            raise ValueError(f"no pose for pair ({i}, {i + 1})")
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
        return out


def make() -> DepthFlowOdometry:
    """The factory ``--odometry my_odometry:make`` calls."""
    return DepthFlowOdometry()
