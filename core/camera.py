"""Pinhole camera in OpenCV axes (x right, y down, z forward) and the one OpenGL<->OpenCV conversion.

Pixel centres are at integer coordinates: pixel (u, v) = (column, row) covers [u-0.5, u+0.5].
"""
from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from deepslam.core.errors import InputError

# The single place where OpenGL camera axes (x right, y up, z backward; MuJoCo, pyrender) meet
# OpenCV's (x right, y down, z forward). Both matrices are their own inverse.
GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])
CV_FROM_GL = GL_FROM_CV


def world_from_cam_cv_from_gl(world_from_cam_gl: np.ndarray) -> np.ndarray:
    """Camera pose in OpenCV axes from the same camera's pose in OpenGL axes, (..., 4, 4)."""
    return np.asarray(world_from_cam_gl, dtype=np.float64) @ GL_FROM_CV


def world_from_cam_gl_from_cv(world_from_cam_cv: np.ndarray) -> np.ndarray:
    """Camera pose in OpenGL axes from the same camera's pose in OpenCV axes, (..., 4, 4)."""
    return np.asarray(world_from_cam_cv, dtype=np.float64) @ CV_FROM_GL


MIN_FLOW_WIDTH_PX = 32
"""Narrowest image the odometry reads: OpenCV's DIS flow refuses smaller pyramids (a 24 x 7 render fails)."""
MIN_FLOW_HEIGHT_PX = 10
"""Lowest image the odometry reads (a 32 x 10 render is the smallest the tests run ``vo`` on)."""


def check_flow_size(width: int, height: int, where=None) -> None:
    """InputError naming ``where`` (a file or folder, or None for an option) when a ``width`` x ``height``
    image is too small for optical flow (:data:`MIN_FLOW_WIDTH_PX` x :data:`MIN_FLOW_HEIGHT_PX`)."""
    if width < MIN_FLOW_WIDTH_PX or height < MIN_FLOW_HEIGHT_PX:
        raise InputError(where, f"images of {width}x{height} px are too small for optical flow; at least "
                                f"{MIN_FLOW_WIDTH_PX}x{MIN_FLOW_HEIGHT_PX} px")


PLAUSIBLE_MEDIAN_DEPTH_M = (0.05, 500.0)
"""Range of the median depth of a frame (metres) that a depth sensor, stereo or a render gives; outside it
the depth is in other units (whole metres in a millimetre format, millimetres read as metres)."""


def check_depth_units(depth_m: np.ndarray, where, scale_note: str = "") -> None:
    """InputError naming ``where`` when the median of the known depths of ``depth_m`` (H, W) float metres
    (0, NaN or inf: unknown) lies outside :data:`PLAUSIBLE_MEDIAN_DEPTH_M`, or no pixel has a depth: the
    depth is plausibly stored in other units than the reader assumes (``scale_note`` says how it read them)."""
    d = np.asarray(depth_m, dtype=np.float64)
    known = d[np.isfinite(d) & (d > 0)]
    how = f" (read with {scale_note})" if scale_note else ""
    if known.size == 0:
        raise InputError(where, f"no pixel has a depth{how}")
    lo, hi = PLAUSIBLE_MEDIAN_DEPTH_M
    med = float(np.median(known))
    if not lo <= med <= hi:
        raise InputError(where, f"the median depth is {med:.3g} m{how}, outside the plausible {lo:g}-{hi:g} m: the "
                                "depth is in other units (whole metres, millimetres?); fix the files or the scale")


MIN_IMAGE_KEPT_BY_UNDISTORTION = 0.5
"""Least share of an undistorted image whose pixels come from inside the recorded frame."""


def check_distortion(k: np.ndarray, dist, width: int, height: int, where=None) -> None:
    """InputError naming ``where`` (the calibration file) when radial-tangential coefficients ``dist``
    (k1, k2, p1, p2[, k3]) with the intrinsics ``k`` (3, 3) px would leave most of the undistorted
    ``width`` x ``height`` image without a source pixel (every image would read black): each pixel of a
    16 x 12 grid of the pinhole image is distorted (:func:`cv2.projectPoints`) and must land inside the
    recorded frame for at least :data:`MIN_IMAGE_KEPT_BY_UNDISTORTION` of the grid."""
    dist = np.asarray(dist, dtype=np.float64).ravel()
    if not np.any(dist):
        return
    k = np.asarray(k, dtype=np.float64)
    u, v = np.meshgrid(np.linspace(0, width - 1, 16), np.linspace(0, height - 1, 12))
    rays = np.stack([(u.ravel() - k[0, 2]) / k[0, 0], (v.ravel() - k[1, 2]) / k[1, 1], np.ones(u.size)], axis=1)
    with np.errstate(all="ignore"):
        uv, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k, dist)
    uv = uv.reshape(-1, 2)
    inside = np.isfinite(uv).all(axis=1) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= width - 0.5) \
        & (uv[:, 1] >= -0.5) & (uv[:, 1] <= height - 0.5)
    if inside.mean() < MIN_IMAGE_KEPT_BY_UNDISTORTION:
        raise InputError(where, f"distortion coefficients {[float(f'{x:.3g}') for x in dist]} map "
                                f"{100 * (1 - inside.mean()):.0f} % of the undistorted image outside the recorded "
                                "frame (every image would read mostly black); check their values and order")


@dataclasses.dataclass(frozen=True)
class PinholeCamera:
    """An undistorted pinhole camera.

    Attributes are in pixels; ``width`` x ``height`` is the image size.
    """

    width: int
    """Image width in pixels (number of columns)."""
    height: int
    """Image height in pixels (number of rows)."""
    fx: float
    """Focal length along x, pixels."""
    fy: float
    """Focal length along y, pixels."""
    cx: float
    """Principal point column, pixels (pixel centres at integers)."""
    cy: float
    """Principal point row, pixels."""

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0 and math.isfinite(self.fx) and math.isfinite(self.fy)):
            raise ValueError(f"focal lengths must be positive and finite, got fx={self.fx}, fy={self.fy}")
        if not (math.isfinite(self.cx) and math.isfinite(self.cy)):
            raise ValueError(f"principal point must be finite, got cx={self.cx}, cy={self.cy}")

    def intrinsics(self, dtype=np.float64) -> np.ndarray:
        """(4,) ``dtype`` vector (fx, fy, cx, cy) in pixels: the networks' and the flow synthesis' intrinsics."""
        return np.array([self.fx, self.fy, self.cx, self.cy], dtype=dtype)

    @classmethod
    def from_k(cls, k: np.ndarray, width: int, height: int) -> "PinholeCamera":
        k = np.asarray(k, dtype=np.float64)
        return cls(int(width), int(height), float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]))

    @classmethod
    def from_fov_y(cls, width: int, height: int, fov_y_deg: float) -> "PinholeCamera":
        """Square pixels, principal point at the image centre ((W-1)/2, (H-1)/2)."""
        f = 0.5 * height / np.tan(np.deg2rad(fov_y_deg) / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @property
    def k(self) -> np.ndarray:
        """3x3 intrinsic matrix, float64."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def principal_point_offset(self) -> tuple[float, float]:
        """(dx, dy) px of the principal point from the image's centre ``((W - 1) / 2, (H - 1) / 2)``: (0, 0) for a
        centred camera (the simulator's default), about (-10.6, -1.4) for KITTI 04-12's."""
        return self.cx - (self.width - 1) / 2.0, self.cy - (self.height - 1) / 2.0

    @property
    def fov_y_deg(self) -> float:
        return float(np.rad2deg(2.0 * np.arctan(0.5 * self.height / self.fy)))

    def scaled(self, width: int, height: int) -> "PinholeCamera":
        """The same camera resampled to ``width`` x ``height`` (pixel-centre convention kept)."""
        sx, sy = width / self.width, height / self.height
        return PinholeCamera(
            width, height, self.fx * sx, self.fy * sy,
            (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5,
        )

    def mirrored(self) -> "PinholeCamera":
        """The camera of the image flipped left-right (column u -> width - 1 - u): the principal point's
        column becomes ``width - 1 - cx``; a point (x, y, z) of the original camera is seen at (-x, y, z)."""
        return PinholeCamera(self.width, self.height, self.fx, self.fy, self.width - 1 - self.cx, self.cy)

    def pixel_grid(self) -> np.ndarray:
        """(H, W, 2) float64 array of (u, v) pixel centres."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        return np.stack([u, v], axis=-1)

    def project(self, p_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project points (..., 3) in camera frame (OpenCV axes, metres).

        Returns ``(uv, depth_z)``: pixels (..., 2) and depth along the optical axis (...,).
        Points with z <= 0 give non-finite uv; check depth_z > 0.
        """
        p = np.asarray(p_cam, dtype=np.float64)
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * p[..., 0] / z + self.cx
            v = self.fy * p[..., 1] / z + self.cy
        return np.stack([u, v], axis=-1), z

    def unproject(self, uv: np.ndarray, depth_z: np.ndarray) -> np.ndarray:
        """Points (..., 3) in camera frame from pixels (..., 2) and depth along the optical axis (...,)."""
        uv = np.asarray(uv, dtype=np.float64)
        z = np.asarray(depth_z, dtype=np.float64)
        x = (uv[..., 0] - self.cx) / self.fx * z
        y = (uv[..., 1] - self.cy) / self.fy * z
        return np.stack([x, y, z], axis=-1)

    def ray_depth_from_z(self, depth_z: np.ndarray) -> np.ndarray:
        """``depth_ray`` (distance to the camera centre) from ``depth_z``, both (H, W)."""
        g = self.pixel_grid()
        x = (g[..., 0] - self.cx) / self.fx
        y = (g[..., 1] - self.cy) / self.fy
        return np.asarray(depth_z) * np.sqrt(1.0 + x * x + y * y)

    def z_from_ray_depth(self, depth_ray: np.ndarray) -> np.ndarray:
        """``depth_z`` from ``depth_ray``, both (H, W)."""
        g = self.pixel_grid()
        x = (g[..., 0] - self.cx) / self.fx
        y = (g[..., 1] - self.cy) / self.fy
        return np.asarray(depth_ray) / np.sqrt(1.0 + x * x + y * y)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "PinholeCamera":
        return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]))


KITTI_00_CAMERA = PinholeCamera(1241, 376, 718.856, 718.856, 607.1928, 185.2157)
"""The left grey camera of KITTI odometry sequences 00-02 (``P0`` of their calib.txt): 1241 x 376 px; the
camera of ``deepslam train --toy`` samples, of tests and of benchmarks that need a street camera's shape."""
