"""A classical baseline odometry, shipped as a plug-in (entry point ``deepslam.odometry: pnp``).

For each pair (i, j): SIFT keypoints in both images, Lowe-ratio matches, then

- with depth in frame i (rendered or sensor depth): the matched points of i are back-projected with
  their depth_z and ``cv2.solvePnPRansac`` finds ``cam_j_from_cam_i`` in metres;
- without depth: ``cv2.findEssentialMat`` + ``cv2.recoverPose`` give the rotation and the direction
  of travel; the translation gets the length ``unit_translation_m`` (monocular scale is unknown).

The std reported is a fixed, documented guess scaled by the inlier count (fewer inliers, larger
std); a pair with too few matches gets the identity with a very large std, so a pose graph ignores it.
"""
from __future__ import annotations

from typing import Sequence as SequenceT

import cv2
import numpy as np

from deepslam.core import se3

BASE_STD6 = (0.002, 0.002, 0.002, 0.03, 0.03, 0.03)
"""Std at 200 inliers (rad x3, m x3); it grows as sqrt(200 / inliers)."""
FAILED_STD6 = (1.0, 1.0, 1.0, 10.0, 10.0, 10.0)
"""Std of a pair the method could not solve (identity motion)."""


class PnPOdometry:
    """SIFT + PnP-RANSAC with depth (or essential matrix without), as a :class:`deepslam.slam.odometry.Odometry`.

    Args:
        max_features: SIFT keypoints per image.
        ratio: Lowe's ratio test threshold.
        min_inliers: fewer inliers than this is a failed pair.
        unit_translation_m: translation length when there is no depth (monocular).
    """

    name = "pnp-sift"

    def __init__(self, max_features: int = 2000, ratio: float = 0.75, min_inliers: int = 12,
                 unit_translation_m: float = 1.0):
        self.max_features = int(max_features)
        self.ratio = float(ratio)
        self.min_inliers = int(min_inliers)
        self.unit_translation_m = float(unit_translation_m)

    def _features(self, img: np.ndarray):
        grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
        sift = cv2.SIFT_create(nfeatures=self.max_features)
        return sift.detectAndCompute(grey, None)

    def _pair(self, seq, i: int, j: int, cache: dict) -> tuple[np.ndarray, np.ndarray]:
        for k in (i, j):
            if k not in cache:
                cache[k] = self._features(seq.image(k))
        (kp0, d0), (kp1, d1) = cache[i], cache[j]
        failed = (np.zeros(6), np.asarray(FAILED_STD6, dtype=np.float64))
        if d0 is None or d1 is None or len(kp0) < self.min_inliers or len(kp1) < self.min_inliers:
            return failed
        matches = cv2.BFMatcher(cv2.NORM_L2).knnMatch(d0, d1, k=2)
        good = [m for m, *rest in matches if rest and m.distance < self.ratio * rest[0].distance]
        if len(good) < self.min_inliers:
            return failed
        p0 = np.array([kp0[m.queryIdx].pt for m in good], np.float64)
        p1 = np.array([kp1[m.trainIdx].pt for m in good], np.float64)
        cam = seq.camera
        k_mat = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]], np.float64)
        depth = seq.depth(i) if getattr(seq, "has_depth", False) else None
        if depth is not None:
            u, v = np.rint(p0[:, 0]).astype(int), np.rint(p0[:, 1]).astype(int)
            inside = (u >= 0) & (v >= 0) & (u < depth.shape[1]) & (v < depth.shape[0])
            z = np.zeros(len(p0))
            z[inside] = depth[v[inside], u[inside]]
            ok = np.isfinite(z) & (z > 0)
            if ok.sum() >= self.min_inliers:
                pts = np.stack([(p0[ok, 0] - cam.cx) / cam.fx * z[ok], (p0[ok, 1] - cam.cy) / cam.fy * z[ok], z[ok]], 1)
                found, rvec, tvec, inl = cv2.solvePnPRansac(pts, p1[ok], k_mat, None, reprojectionError=2.0,
                                                            iterationsCount=200, flags=cv2.SOLVEPNP_EPNP)
                if found and inl is not None and len(inl) >= self.min_inliers:
                    rvec, tvec = cv2.solvePnPRefineLM(pts[inl[:, 0]], p1[ok][inl[:, 0]], k_mat, None, rvec, tvec)
                    return self._answer(cv2.Rodrigues(rvec)[0], tvec.ravel(), len(inl))
            return failed
        e_mat, mask = cv2.findEssentialMat(p0, p1, k_mat, cv2.RANSAC, 0.999, 1.0)
        if e_mat is None or e_mat.shape != (3, 3):
            return failed
        n_in, r_mat, t_vec, _ = cv2.recoverPose(e_mat, p0, p1, k_mat, mask=mask)
        if n_in < self.min_inliers:
            return failed
        return self._answer(r_mat, self.unit_translation_m * t_vec.ravel() / max(np.linalg.norm(t_vec), 1e-12), n_in)

    @staticmethod
    def _answer(r_mat: np.ndarray, t: np.ndarray, inliers: int) -> tuple[np.ndarray, np.ndarray]:
        cam_j_from_cam_i = se3.from_rt(se3.project_to_so3(r_mat), t)
        std = np.asarray(BASE_STD6, dtype=np.float64) * np.sqrt(200.0 / max(inliers, 1))
        return se3.to_euler6(cam_j_from_cam_i), std

    def predict(self, seq, pairs: SequenceT[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        cache: dict = {}
        out = [self._pair(seq, int(i), int(j), cache) for i, j in np.asarray(pairs, dtype=np.int64).reshape(-1, 2)]
        if not out:
            return np.zeros((0, 6)), np.zeros((0, 6))
        return np.stack([o[0] for o in out]), np.stack([o[1] for o in out])


def make_pnp() -> PnPOdometry:
    """The entry point's factory (``--odometry pnp`` or ``--odometry deepslam.slam.classical:make_pnp``)."""
    return PnPOdometry()
