"""The image a moved camera would see, rendered from ONE frame and its depth (depth-image-based rendering).

Why: the paper trains on flow synthesized from a single frame's depth, i.e. *exact* flow, while at test
time the network sees the flow of an estimator (here OpenCV DIS), whose errors are not noise: on roads
it under-reads the large flow near the camera, and the network, which reads metric scale mostly from
there, under-reads translation (see models/README.md). Rendering the second view from the same single
frame lets the estimator run on the synthetic pair, so a network can be trained on the flow it will
really be given (:class:`vo.data.synthetic.EstimatedFlowSource`) -- still from single frames, still without any
ground-truth pose.

How (:func:`render_novel_view`), for frame 0 (image, depth_z) and ``cam1_from_cam0``:

1. every pixel with depth is unprojected, moved and projected into frame 1; its depth_z1 is splatted
   to the four pixels around where it lands, keeping the nearest (a z-buffer; four pixels so that a
   surface seen closer, i.e. magnified, leaves no cracks);
2. frame-1 pixels nobody landed on are either sky (rotating the ray back into frame 0 hits a pixel
   without depth: a point at infinity) or get the depth of the nearest splatted pixel (the surface
   continues: road entering the view from below, disoccluded background);
3. each frame-1 pixel is unprojected with that depth, moved back into frame 0 and frame 0 is sampled
   there (bilinear, cv2.remap). Content that was outside frame 0 is the border reflected (there is no
   way to know it; any estimator has to guess there, in a real pair too).

The result agrees with the simulator's own rendering of the next frame except at disocclusions and
at the border (tested in tests/gen/test_gen_novel_view.py), and DIS on a rendered pair makes most of
the errors DIS makes on the real pair: on the simulated street's lowest sixth it reads ~0.84 of the
true flow on rendered pairs and ~0.80 on real ones (exact flow: 1.0). Noise on the rendered view
(``EstimatedFlowSource(appearance_noise=)``) stands for the appearance changes a real next frame has.
"""
from __future__ import annotations

import threading

import cv2
import numpy as np

from deepslam.core.camera import PinholeCamera

_KERNELS = None
_KERNELS_LOCK = threading.Lock()


def _kernels():
    """numba kernels (compiled on first use, cached on disk): (splat, classify, back_map)."""
    global _KERNELS
    with _KERNELS_LOCK:
        if _KERNELS is None:
            import numba  # deferred: numba (~0.2 s) loads only when a kernel is first compiled

            @numba.njit(nogil=True)
            def splat(depth_z, m, zbuf):  # pragma: no cover - compiled
                """z-buffer of depth_z1 at the four pixels around where each point of frame 0 lands."""
                h, w = depth_z.shape
                for v in range(h):
                    for u in range(w):
                        z = depth_z[v, u]
                        if not (z > 0.0 and z < np.inf):
                            continue
                        iw = 1.0 / z
                        nu = m[0, 0] * u + m[0, 1] * v + m[0, 2] + m[0, 3] * iw
                        nv = m[1, 0] * u + m[1, 1] * v + m[1, 2] + m[1, 3] * iw
                        d = m[2, 0] * u + m[2, 1] * v + m[2, 2] + m[2, 3] * iw   # depth_z1 / depth_z
                        if d <= 1e-6:
                            continue
                        u1, v1, z1 = nu / d, nv / d, d * z
                        if not (u1 > -1.0 and u1 < w and v1 > -1.0 and v1 < h):
                            continue
                        iu, iv = int(np.floor(u1)), int(np.floor(v1))
                        for dv in range(2):
                            for du in range(2):
                                x, y = iu + du, iv + dv
                                if 0 <= x < w and 0 <= y < h and z1 < zbuf[y, x]:
                                    zbuf[y, x] = z1

            @numba.njit(nogil=True)
            def classify(zbuf, depth_z, h_rot):  # pragma: no cover - compiled
                """0: splatted; 1: sky (the ray rotated back hits a frame-0 pixel without depth); 2: to fill."""
                h, w = zbuf.shape
                out = np.zeros((h, w), np.uint8)
                for v in range(h):
                    for u in range(w):
                        if zbuf[v, u] < np.inf:
                            continue
                        x = h_rot[0, 0] * u + h_rot[0, 1] * v + h_rot[0, 2]
                        y = h_rot[1, 0] * u + h_rot[1, 1] * v + h_rot[1, 2]
                        d = h_rot[2, 0] * u + h_rot[2, 1] * v + h_rot[2, 2]
                        out[v, u] = 2
                        if d > 0.0:
                            u0, v0 = x / d, y / d
                            if u0 > -0.5 and u0 < w - 0.5 and v0 > -0.5 and v0 < h - 0.5:
                                z0 = depth_z[int(np.rint(v0)), int(np.rint(u0))]
                                if not (z0 > 0.0 and z0 < np.inf):
                                    out[v, u] = 1
                return out

            @numba.njit(nogil=True)
            def back_map(zbuf, kind, k, k_inv, r, t, map_u, map_v):  # pragma: no cover - compiled
                """Where each frame-1 pixel comes from in frame 0: R^T (z1 K^-1 p1 - t), or R^T K^-1 p1 for sky."""
                h, w = zbuf.shape
                for v in range(h):
                    for u in range(w):
                        rx = k_inv[0, 0] * u + k_inv[0, 2]
                        ry = k_inv[1, 1] * v + k_inv[1, 2]
                        if kind[v, u] == 1:
                            px, py, pz = rx, ry, 1.0
                        else:
                            z1 = zbuf[v, u]
                            px, py, pz = z1 * rx - t[0], z1 * ry - t[1], z1 - t[2]
                        qx = r[0, 0] * px + r[1, 0] * py + r[2, 0] * pz
                        qy = r[0, 1] * px + r[1, 1] * py + r[2, 1] * pz
                        qz = r[0, 2] * px + r[1, 2] * py + r[2, 2] * pz
                        if qz > 1e-9:
                            map_u[v, u] = k[0, 0] * qx / qz + k[0, 2]
                            map_v[v, u] = k[1, 1] * qy / qz + k[1, 2]
                        else:  # behind camera 0: content from outside the view, like the border
                            map_u[v, u] = -1e4
                            map_v[v, u] = -1e4

            _KERNELS = (splat, classify, back_map)
    return _KERNELS


def _projection(camera: PinholeCamera, cam1_from_cam0: np.ndarray) -> np.ndarray:
    """(3, 4) ``[K R K^-1 | K t]``: ``depth_z1 / depth_z * (u1, v1, 1) = M (u, v, 1, 1 / depth_z)``."""
    k = camera.k
    r, t = cam1_from_cam0[:3, :3], cam1_from_cam0[:3, 3]
    return np.concatenate([k @ r @ np.linalg.inv(k), (k @ t)[:, None]], axis=1)


def depth_after_motion(depth_z: np.ndarray, camera: PinholeCamera, cam1_from_cam0: np.ndarray) -> np.ndarray:
    """Frame 1's depth_z1 (H, W) float64 metres, forward-splatted from frame 0 (inf where nothing landed).

    Args:
        depth_z: (H, W) float32/64 metres of frame 0; 0 or non-finite = no surface (sky).
        camera: the pinhole camera of both frames (H x W).
        cam1_from_cam0: (4, 4) float64, OpenCV axes.
    """
    zbuf = np.full(depth_z.shape, np.inf)
    _kernels()[0](np.ascontiguousarray(depth_z, np.float64), _projection(camera, np.asarray(cam1_from_cam0, np.float64)),
                  zbuf)
    return zbuf


def _fill_nearest(values: np.ndarray, known: np.ndarray, fill: np.ndarray) -> np.ndarray:
    """``values`` with the ``fill`` pixels set to the value of the nearest ``known`` pixel
    (cv2.distanceTransformWithLabels, L2 with a 5x5 mask: each unknown pixel gets the label of its
    nearest known one)."""
    _, labels = cv2.distanceTransformWithLabels((~known).astype(np.uint8), cv2.DIST_L2, 5,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    lut = np.zeros(int(labels.max()) + 1, values.dtype)
    lut[labels[known]] = values[known]
    out = values.copy()
    out[fill] = lut[labels[fill]]
    return out


def render_novel_view(image: np.ndarray, depth_z: np.ndarray, camera: PinholeCamera,
                      cam1_from_cam0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The image camera 1 would see of frame 0's scene (see the module docstring for the method).

    Args:
        image: (H, W) or (H, W, 3) uint8 frame 0.
        depth_z: (H, W) float metres of frame 0 (0 / non-finite: no surface, a point at infinity).
        camera: pinhole camera of both frames, H x W (OpenCV axes).
        cam1_from_cam0: (4, 4) float64 motion of the camera.

    Returns:
        ``(image1, seen)``: image1 like ``image`` (same shape and dtype); seen (H, W) bool, true where
        the pixel shows a surface point of frame 0 (a splatted pixel) or sky that rotates back inside
        frame 0, false where its content was filled in.
    """
    image = np.asarray(image)
    h, w = depth_z.shape
    if image.shape[:2] != (h, w) or (camera.width, camera.height) != (w, h):
        raise ValueError(f"image {image.shape[:2]}, depth {depth_z.shape} and camera {camera.height}x{camera.width} disagree")
    _, classify, back_map = _kernels()
    cam1_from_cam0 = np.asarray(cam1_from_cam0, np.float64)
    r, t = np.ascontiguousarray(cam1_from_cam0[:3, :3]), np.ascontiguousarray(cam1_from_cam0[:3, 3])
    k = camera.k
    k_inv = np.linalg.inv(k)
    depth64 = np.ascontiguousarray(depth_z, np.float64)
    zb = depth_after_motion(depth64, camera, cam1_from_cam0)
    kind = classify(zb, depth64, k @ r.T @ k_inv)            # frame-1 pixel -> frame-0 pixel of the same ray
    seen = kind < 2
    splatted = kind == 0
    fill = kind == 2
    if fill.any():
        if splatted.any():
            zb = _fill_nearest(zb, splatted, fill)
        else:  # nothing landed at all: everything far away
            kind[fill] = 1
    map_u = np.empty((h, w), np.float32)
    map_v = np.empty((h, w), np.float32)
    back_map(zb, kind, k, k_inv, r, t, map_u, map_v)
    out = cv2.remap(image, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT101)
    return out, seen
