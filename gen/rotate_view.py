"""A frame as a camera rotated about its own centre would have seen it: exact, from the frame alone.

Why: a network that reads metric translation from flow reads it largely from where the ground is in
the image, and that depends on the camera's pitch. The simulated car's camera is level; KITTI's is
pitched down by about one degree (its road, seen by stereo, lies at 1.49-1.54 m below a level
camera at rows 0.7-0.97 of the image, 1.64 m once pitched by 0.95 degrees), so the road is 10-17 %
nearer at the same image rows and a model trained on level renders over-reads KITTI's translation
by about that much even on exact flow (x1.165 on KITTI 06 from stereo depth and ground-truth motion).
Rotating the training frames' cameras by small random angles teaches that the horizon moves.

A pure rotation has no parallax, so the rotated view needs no guessing except where the new view sees
past the old one's border: for ``cam_new_from_cam`` = R (3x3), each new pixel x' looks along the
ray ``d = R^T K^-1 x'`` of the old camera; the old frame is sampled where that ray lands, and the new
depth is ``depth_z_new = depth_z_old / d_z`` (the same point, measured along the new optical axis).
Inverse depth is sampled bilinearly where the four neighbours agree (exact on planes, where it is
affine in the pixel coordinates) and at the nearest pixel across edges and holes; the image bilinearly.
Pixels whose ray leaves the old image get depth 0 (unknown: left out of the synthesis) and the
image's border pixel.
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from deepslam.core.camera import PinholeCamera


def rotation_from_pitch_roll(pitch_rad: float, roll_rad: float) -> np.ndarray:
    """cam_new_from_cam (3, 3) float64 for a camera pitched by ``pitch_rad`` (positive: looks further
    down, about the camera's x axis) and then rolled by ``roll_rad`` (about its z axis), OpenCV axes."""
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    # pitching down by p turns the optical axis towards +y (down) in the old frame: new_from_old = Rx(-p)^T...
    # a point straight ahead and below (y > 0) moves up in the new image: y_new = cp*y - sp*z
    pitch = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    roll = np.array([[cr, -sr, 0.0], [sr, cr, 0.0], [0.0, 0.0, 1.0]])
    return roll @ pitch


def _source_map(camera: PinholeCamera, cam_new_from_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(map_u, map_v, d_z): where each new pixel's ray lands in the old image (float32 (H, W) px) and
    that ray's z in the old camera (float32 (H, W), for ``K^-1 x'`` with unit z in the new camera)."""
    h, w = camera.height, camera.width
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays_new = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
    d = rays_new @ np.asarray(cam_new_from_cam, np.float64)  # row vectors: (R^T r)^T = r^T R
    dz = d[..., 2]
    safe = np.where(dz > 1e-9, dz, np.nan)
    map_u = camera.fx * d[..., 0] / safe + camera.cx
    map_v = camera.fy * d[..., 1] / safe + camera.cy
    return map_u.astype(np.float32), map_v.astype(np.float32), dz.astype(np.float32)


def rotate_depth(depth_z: np.ndarray, camera: PinholeCamera, cam_new_from_cam: np.ndarray,
                 outside: str = "zero") -> np.ndarray:
    """depth_z (H, W) float32 m of the frame seen by the rotated camera. ``depth_z`` (H, W) float32 m in
    the old camera, 0 = unknown.

    ``outside``: what the new pixels whose ray leaves the old image get: ``zero`` (unknown) or
    ``nearest`` (the value of the nearest new pixel that saw the old image, 0 included: the road or the
    sky goes on, as :mod:`gen.novel_view` assumes for what enters the view; for training data, where
    an estimator reports flow there too)."""
    map_u, map_v, dz = _source_map(camera, cam_new_from_cam)
    mu, mv = np.nan_to_num(map_u, nan=-1e6), np.nan_to_num(map_v, nan=-1e6)
    src = np.asarray(depth_z, np.float32)
    known = np.isfinite(src) & (src > 0)
    inv = np.where(known, 1.0 / np.where(known, src, 1.0), 0.0).astype(np.float32)
    const = dict(borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    near = cv2.remap(inv, mu, mv, cv2.INTER_NEAREST, **const)
    lin = cv2.remap(inv, mu, mv, cv2.INTER_LINEAR, **const)
    all_known = cv2.remap(known.astype(np.float32), mu, mv, cv2.INTER_LINEAR, **const) > 1 - 1e-4
    # inverse depth is affine in the pixel coordinates on a plane, so bilinear is exact there; across an
    # object's edge (neighbours disagree) or next to a hole the nearest pixel is taken instead
    smooth = all_known & (np.abs(lin - near) <= 0.05 * near)
    inv_new = np.where(smooth, lin, near)
    inside = (map_u > -0.5) & (map_u < camera.width - 0.5) & (map_v > -0.5) & (map_v < camera.height - 0.5)
    ok = inside & (inv_new > 0)
    out = np.where(ok, 1.0 / np.where(ok, inv_new, 1.0) / np.maximum(dz, 1e-9), 0.0).astype(np.float32)
    if outside == "nearest" and (~inside).any() and inside.any():
        iv, iu = ndimage.distance_transform_edt(~inside, return_distances=False, return_indices=True)
        out = out[iv, iu]
    elif outside not in ("zero", "nearest"):
        raise ValueError(f"outside must be zero or nearest, got {outside!r}")
    return out


def rotate_image(image: np.ndarray, camera: PinholeCamera, cam_new_from_cam: np.ndarray) -> np.ndarray:
    """The image (H, W[, C]) uint8 the rotated camera sees (bilinear; outside the old image: its border
    pixel replicated)."""
    map_u, map_v, _ = _source_map(camera, cam_new_from_cam)
    return cv2.remap(np.ascontiguousarray(image), np.nan_to_num(map_u, nan=-1e6), np.nan_to_num(map_v, nan=-1e6),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def rotate_motion(cam1_from_cam0: np.ndarray, cam_new_from_cam: np.ndarray) -> np.ndarray:
    """The same rigid motion (4, 4) float64 seen from cameras both rotated by ``cam_new_from_cam``:
    ``new1_from_new0 = R cam1_from_cam0 R^T``."""
    r = np.eye(4)
    r[:3, :3] = cam_new_from_cam
    return r @ np.asarray(cam1_from_cam0, np.float64) @ r.T
