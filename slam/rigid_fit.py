"""The rigid-fit odometry: relative motion by a least-squares rigid fit of flow + depth over all pixels.

The plainest form of the rigid-scene assumption a flow -> motion network makes: no robust loss, no
outlier rejection. Exact on a rigid scene with exact flow, so whatever error it makes on ground-truth flow
is the rigid assumption failing, directly (the stress study's fallback and control, ``--odometry rigid-fit``).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from deepslam.core import se3
from deepslam.core.errors import InputError


class RigidFitOdometry:
    """Relative motion by a least-squares rigid fit of flow + depth over all pixels (slam Odometry protocol).

    For a pair (i, j): every pixel of frame i with a positive finite depth and a finite flow (at most
    ``max_points`` of them, evenly spread in raster order) is unprojected with its depth to ``p_cam_i``
    and its flow target ``uv_j = uv_i + flow[v, u]`` is taken as its observation in frame j; then
    ``cam_j_from_cam_i`` minimises the sum of squared reprojection errors (OpenCV ``solvePnP``,
    Levenberg-Marquardt from the identity and, for pairs more than one frame apart, also from the
    DLT solution; the lower cost wins). No robust loss, no outlier rejection: every moving and deforming
    pixel pulls on the fit as a static one would, which is the rigid-scene assumption of a flow->motion
    network in its plainest form.

    The reported std is the Gauss-Newton one, ``sigma^2 (J^T J)^-1`` with ``sigma`` the residual RMS,
    rotation-vector std taken as the Euler-angle std (equal to first order), floored at ``min_std``.

    Args:
        flow_estimator: anything with ``name`` and ``pair_flow(seq, i, j) -> (H, W, 2)`` (flow.estimators).
        max_points: most pixels used per pair.
        min_std: floor of the std (rad for rotations, m for translations).
    """

    def __init__(self, flow_estimator, max_points: int = 2000, min_std: tuple[float, float] = (1e-4, 1e-3)):
        self.flow_estimator = flow_estimator
        self.max_points = int(max_points)
        self.min_std = min_std
        self.name = f"rigid-fit+{getattr(flow_estimator, 'name', 'flow')}"

    def fit(self, depth_z: np.ndarray, flow: np.ndarray, camera, dlt_start: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(mean6, std6) of cam_j_from_cam_i from depth (H, W) float32 m and flow (H, W, 2) float32 px;
        ``dlt_start``: also start from the DLT solution (for wide motions), not only from the identity."""
        depth = np.asarray(depth_z, np.float64)
        flow = np.asarray(flow, np.float64)
        ok = np.isfinite(depth) & (depth > 0) & np.isfinite(flow).all(axis=-1)
        vv, uu = np.nonzero(ok)
        big = np.array([1.0, 1.0, 1.0, 100.0, 100.0, 100.0])
        if len(vv) < 12:
            return np.zeros(6), big
        step = max(1, int(math.ceil(len(vv) / self.max_points)))
        vv, uu = vv[::step], uu[::step]
        uv = np.stack([uu, vv], axis=1).astype(np.float64)
        p_cam_i = camera.unproject(uv, depth[vv, uu])
        uv_j = uv + flow[vv, uu]
        k = camera.k.astype(np.float64)
        obj = np.ascontiguousarray(p_cam_i.reshape(-1, 1, 3))
        img = np.ascontiguousarray(uv_j.reshape(-1, 1, 2))
        best = None
        for guess in ((True, False) if dlt_start else (True,)):
            r0, t0 = np.zeros((3, 1)), np.zeros((3, 1))
            try:
                ok_, rvec, tvec = cv2.solvePnP(obj, img, k, None, r0, t0, useExtrinsicGuess=guess,
                                               flags=cv2.SOLVEPNP_ITERATIVE)
            except cv2.error:
                continue
            if not ok_ or not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
                continue
            proj, jac = cv2.projectPoints(obj, rvec, tvec, k, None)
            res = (proj.reshape(-1, 2) - uv_j).ravel()
            cost = float(res @ res)
            if best is None or cost < best[0]:
                best = (cost, rvec, tvec, res, jac[:, :6])
        if best is None:
            return np.zeros(6), big
        cost, rvec, tvec, res, jac = best
        rot, _ = cv2.Rodrigues(rvec)
        mean6 = se3.to_euler6(se3.from_rt(rot, tvec.ravel()))
        dof = max(1, len(res) - 6)
        sigma2 = cost / dof
        try:
            cov = sigma2 * np.linalg.inv(jac.T @ jac)
            std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        except np.linalg.LinAlgError:
            std = big.copy()
        floor = np.array([self.min_std[0]] * 3 + [self.min_std[1]] * 3)
        return mean6, np.maximum(std, floor)

    def predict(self, seq, pairs) -> tuple[np.ndarray, np.ndarray]:
        means, stds = [], []
        for i, j in pairs:
            depth = seq.depth(int(i))
            if depth is None:
                raise InputError(getattr(seq, "root", None), "the rigid-fit odometry needs a sequence with depth")
            m, s = self.fit(depth, self.flow_estimator.pair_flow(seq, int(i), int(j)), seq.camera,
                            dlt_start=abs(int(j) - int(i)) > 1)
            means.append(m)
            stds.append(s)
        if not means:
            return np.zeros((0, 6)), np.zeros((0, 6))
        return np.array(means), np.array(stds)
