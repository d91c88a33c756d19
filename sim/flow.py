"""Ground-truth forward optical flow from geometry: exact for static, moving and deforming surfaces.

For each pixel (u, v) of frame t with depth_z > 0 and scene body b (from the segmentation pass):

1. unproject: ``p_cam0 = depth_z * ((u - cx) / fx, (v - cy) / fy, 1)``;
2. move it with its surface to time t+1:
   - static body: ``p_cam1 = cam1_from_world @ world_from_cam0 @ p_cam0``;
   - rigid body: ``p_cam1 = cam1_from_world @ world_from_body(t+1) @ body_from_world(t) @ world_from_cam0 @ p_cam0``;
   - deforming body (flag): to its body frame, then :meth:`scenes.spec.FlagDeform.advance` (same
     triangle, same barycentric coordinates at t+1), then into camera t+1;
3. project with the same camera and subtract the pixel grid: ``flow[v, u] = (u1 - u, v1 - v)``.

Pixels where nothing is hit (sky, depth 0) get the flow of a point at infinity in that direction
(rotation only), which is what the background at infinity does. A point that ends up behind the
camera at t+1 has no projection: its flow is NaN. The flow says where the surface point goes,
whether or not it is visible there; :func:`occlusion_mask` says whether it is (the depth of the
moved point against frame t+1's rendered depth). Backward flow is the same computation from frame
t to the state of frame t-1.
"""
from __future__ import annotations

import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.scenes.spec import DEFORM, RIGID, Scene
from deepslam.sim.world import WorldState


class FlowComputer:
    """Precomputes the camera rays once; :meth:`flow` then costs a few vector operations per pixel."""

    def __init__(self, camera: PinholeCamera):
        self.camera = camera
        g = camera.pixel_grid()
        self._u = g[..., 0]
        self._v = g[..., 1]
        self._rx = (self._u - camera.cx) / camera.fx
        self._ry = (self._v - camera.cy) / camera.fy
        # (3, H*W) rays with z = 1 (planar layout: one fast matrix product per frame). The bulk of the
        # per-pixel arithmetic is float32 (relative error 1e-7: < 1e-4 px at these focal lengths);
        # the transforms themselves are float64.
        self._rays = np.stack([self._rx.ravel(), self._ry.ravel(), np.ones(self._rx.size)]).astype(np.float32)
        self._du = (camera.cx - self._u).astype(np.float32)
        self._dv = (camera.cy - self._v).astype(np.float32)

    def points(self, depth_z: np.ndarray) -> np.ndarray:
        """(H, W, 3) float64 points in the camera frame (OpenCV axes) from depth_z (H, W)."""
        z = depth_z.astype(np.float64)
        return np.stack([self._rx * z, self._ry * z, z], axis=-1)

    def flow(self, scene: Scene, depth_z: np.ndarray, body: np.ndarray, s0: WorldState, s1: WorldState) -> np.ndarray:
        """(H, W, 2) float32 forward flow (du, dv) px from the state s0 to s1.

        Args:
            depth_z: (H, W) float32 metres, 0 = nothing hit.
            body: (H, W) int scene-body index per pixel, -1 = nothing hit.
        """
        return self.flow_and_depth(scene, depth_z, body, s0, s1)[0]

    def flow_and_depth(self, scene: Scene, depth_z: np.ndarray, body: np.ndarray, s0: WorldState,
                       s1: WorldState) -> tuple[np.ndarray, np.ndarray]:
        """(flow, z1): the flow of :meth:`flow` (s1 may be earlier than s0: backward flow) and z1 (H, W)
        float32, the depth_z in camera s1 of each pixel's moved surface point (inf where nothing is
        hit: the point at infinity; NaN where it is behind camera s1)."""
        cam = self.camera
        h, w = depth_z.shape
        cam1_from_world = se3.inverse(s1.world_from_cam)
        cam1_from_cam0 = cam1_from_world @ s0.world_from_cam
        z = depth_z.reshape(-1).astype(np.float32)
        hit = z > 0
        # static scene and the background at infinity: p1 = R (ray z) + t, or R ray where nothing is hit
        p1 = np.einsum("ij,jn->in", cam1_from_cam0[:3, :3].astype(np.float32), self._rays)  # (steadier than BLAS)
        p1 *= np.where(hit, z, np.float32(1.0))
        p1 += cam1_from_cam0[:3, 3:4].astype(np.float32) * hit
        # dynamic bodies present in this image
        flat_body = body.reshape(-1)
        present = np.flatnonzero(np.bincount(flat_body + 1, minlength=len(scene.bodies) + 1)[1:])
        for b in present:
            kind = scene.bodies[b].kind
            if kind not in (RIGID, DEFORM):
                continue
            m = np.flatnonzero(flat_body == b)
            p0 = (self._rays[:, m] * z[m]).T.astype(np.float64)
            if kind == RIGID:
                tr = cam1_from_world @ s1.world_from_body[b] @ se3.inverse(s0.world_from_body[b]) @ s0.world_from_cam
                p1[:, m] = se3.transform_points(tr, p0).T
            else:
                body_from_cam0 = se3.inverse(s0.world_from_body[b]) @ s0.world_from_cam
                p_body1 = scene.bodies[b].deform.advance(se3.transform_points(body_from_cam0, p0), s0.t, s1.t)
                p1[:, m] = se3.transform_points(cam1_from_world @ s1.world_from_body[b], p_body1).T
        zc = p1[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.float32(1.0) / np.where(zc > 1e-9, zc, np.float32(np.nan))
        flow = np.empty((h, w, 2), np.float32)
        flow[..., 0] = (p1[0] * inv).reshape(h, w) * np.float32(cam.fx) + self._du
        flow[..., 1] = (p1[1] * inv).reshape(h, w) * np.float32(cam.fy) + self._dv
        z1 = np.where(hit, np.where(zc > 1e-9, zc, np.nan), np.inf).astype(np.float32).reshape(h, w)
        return flow, z1


_OCC_KERNEL = None


def _occlusion_kernel():
    """:func:`occlusion_mask_reference` compiled (numba, one pass over the pixels; None without numba)."""
    global _OCC_KERNEL
    if _OCC_KERNEL is None:
        try:
            import numba  # deferred: numba (~0.2 s) loads only when a kernel is first compiled
        except ImportError:  # pragma: no cover - numba is a dependency
            _OCC_KERNEL = False
            return None
        # a fork-safe threading layer, as gen.flow's kernels take (GNU OpenMP breaks fork())
        if numba.config.THREADING_LAYER == "default":
            numba.config.THREADING_LAYER = "forksafe"

        @numba.njit
        def kernel(flow, z1, depth1, rel_tol, abs_tol, out):  # pragma: no cover - compiled
            h, w = z1.shape
            for v in range(h):
                for u in range(w):
                    u1 = np.float32(u) + flow[v, u, 0]
                    v1 = np.float32(v) + flow[v, u, 1]
                    z = z1[v, u]
                    visible = False
                    if (np.isfinite(u1) and np.isfinite(v1) and not np.isnan(z) and u1 > -0.5 and u1 < w - 0.5
                            and v1 > -0.5 and v1 < h - 0.5):
                        sky = np.isinf(z)
                        zok = np.float32(0.0) if sky else z  # float32, as the reference's arithmetic
                        u0, v0 = int(np.floor(u1)), int(np.floor(v1))
                        for du in (0, 1):
                            for dv in (0, 1):
                                uu = min(max(u0 + du, 0), w - 1)
                                vv = min(max(v0 + dv, 0), h - 1)
                                d1 = depth1[vv, uu]
                                if sky:
                                    ok = d1 <= 0
                                else:
                                    ok = d1 > 0 and d1 >= zok - (np.float32(rel_tol) * zok + np.float32(abs_tol))
                                visible = visible or ok
                    out[v, u] = not visible

        _OCC_KERNEL = kernel
    return _OCC_KERNEL or None


def occlusion_mask(flow: np.ndarray, z1: np.ndarray, depth1: np.ndarray, rel_tol: float = 0.02,
                   abs_tol_m: float = 0.02) -> np.ndarray:
    """(H, W) bool: True where the surface seen at a pixel of frame t is NOT visible in frame t+1:
    :func:`occlusion_mask_reference` compiled with numba (the same decisions, tested; a few times
    faster), or the reference where numba is missing."""
    kernel = _occlusion_kernel()
    if kernel is None:  # pragma: no cover
        return occlusion_mask_reference(flow, z1, depth1, rel_tol, abs_tol_m)
    out = np.empty(z1.shape, bool)
    kernel(np.ascontiguousarray(flow, np.float32), np.ascontiguousarray(z1, np.float32),
           np.ascontiguousarray(depth1, np.float32), float(rel_tol), float(abs_tol_m), out)
    return out


def occlusion_mask_reference(flow: np.ndarray, z1: np.ndarray, depth1: np.ndarray, rel_tol: float = 0.02,
                             abs_tol_m: float = 0.02) -> np.ndarray:
    """(H, W) bool: True where the surface seen at a pixel of frame t is NOT visible in frame t+1.

    A pixel's point moved to t+1 (``flow`` (H, W, 2) px, ``z1`` its depth_z in camera t+1 from
    :meth:`FlowComputer.flow_and_depth`) is visible when it lands inside the image and, at one of the
    (up to) four pixels around where it lands, frame t+1's rendered depth ``depth1`` is not nearer than
    ``z1`` (within ``rel_tol`` x z1 + ``abs_tol_m``). A point at infinity (sky) is visible where t+1
    sees nothing (depth 0) there. A point behind camera t+1, or whose flow is not finite, is hidden.
    """
    h, w = z1.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    u1, v1 = u + flow[..., 0], v + flow[..., 1]
    finite = np.isfinite(u1) & np.isfinite(v1) & ~np.isnan(z1)
    inside = finite & (u1 > -0.5) & (u1 < w - 0.5) & (v1 > -0.5) & (v1 < h - 0.5)
    visible = np.zeros((h, w), bool)
    u0 = np.floor(np.where(inside, u1, 0)).astype(np.int64)
    v0 = np.floor(np.where(inside, v1, 0)).astype(np.int64)
    sky = np.isinf(z1)
    z_ok = np.where(sky, 0.0, z1)  # no surface to compare for the point at infinity
    for du in (0, 1):
        for dv in (0, 1):
            uu, vv = np.clip(u0 + du, 0, w - 1), np.clip(v0 + dv, 0, h - 1)
            d1 = depth1[vv, uu]
            surface_ok = ~sky & (d1 > 0) & (d1 >= z_ok - (rel_tol * z_ok + abs_tol_m))
            sky_ok = sky & (d1 <= 0)
            visible |= inside & (surface_ok | sky_ok)
    return ~visible
