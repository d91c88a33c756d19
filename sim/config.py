"""Frozen configuration dataclasses of the simulator, one per stage (scene, trajectory, render)."""
from __future__ import annotations

import dataclasses

import numpy as np

from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.scenes import SceneConfig

TRAJECTORY_KINDS = ("auto", "car", "drone", "handheld")
BACKENDS = ("mujoco", "pyrender")
FORMATS = ("ours", "kitti", "euroc", "tum")
FLOW_FORMATS = ("npy", "flo", "png")
"""Flow file formats of a render: ``npy`` (float32 HxWx2, always written), ``flo`` (Middlebury) and
``png`` (KITTI 2015 flow PNG); see :mod:`deepslam.core.flowio`."""
MAX_SIDE_PX = 4096


@dataclasses.dataclass(frozen=True)
class TrajectoryConfig:
    """The scripted camera motion."""

    kind: str = "auto"
    """"car" (planar, 1.65 m above the road, street only), "drone" (6DoF), "handheld" (a camera walked round the
    room's table at a walking pace, top speed 0.35-0.55 m/s, aimed at it, with the hand's sway; room only) or "auto" (street: car, room:
    drone)."""
    frames: int = 300
    """Number of frames to render."""
    rate_hz: float | None = None
    """Frame rate in Hz (None: 10 for car, 20 for drone, 30 for handheld)."""
    seed: int | None = None
    """Seed of the trajectory's random choices (speeds, waypoints); None: the scene's seed."""
    camera_ahead_m: float = 0.0
    """Car only: how far the camera sits ahead of the car's rear axle, metres, along the car's heading. The
    route is the rear axle's path; 0: the camera rides on it, moving along its own optical axis. A camera
    ahead of the axle slides sideways in a turn, as KITTI's does: a fit of KITTI's ground truth 00-10 (the
    sideways motion a pair = psi d / 2 + L psi, psi its turn, d its length) gives L = 0.84 m, 0.68-0.97 m by
    city sequence (docs/experiments/2026-12-05_vo_drift_sources.md)."""
    body_motion: float = 0.0
    """Car only: the car body's pitch and roll on its suspension, as a multiple of KITTI's (0: none, the camera
    keeps the road's attitude; 1: frame-to-frame pitch and roll of 0.17 and 0.15 degrees RMS at 10 Hz, KITTI
    00-10's ground truth, mostly at 1-2 Hz). :class:`sim.trajectories.BodyMotion`."""

    def resolved_kind(self, scene_name: str) -> str:
        if self.kind != "auto":
            return self.kind
        return "car" if scene_name == "street" else "drone"

    def validate(self) -> "TrajectoryConfig":
        if self.kind not in TRAJECTORY_KINDS:
            raise InputError(None, f"unknown trajectory {self.kind!r} (choose from {', '.join(TRAJECTORY_KINDS)})")
        if not isinstance(self.frames, int) or self.frames < 1 or self.frames > 1_000_000:
            raise InputError(None, f"frames must be an integer in 1..1000000, got {self.frames}")
        if self.rate_hz is not None and not (np.isfinite(self.rate_hz) and 0.1 <= self.rate_hz <= 1000):
            raise InputError(None, f"rate must be in [0.1, 1000] Hz, got {self.rate_hz}")
        if self.seed is not None and (not isinstance(self.seed, int) or self.seed < 0):
            raise InputError(None, f"trajectory seed must be a non-negative integer, got {self.seed}")
        if not (np.isfinite(self.camera_ahead_m) and 0.0 <= self.camera_ahead_m <= 5.0):
            raise InputError(None, f"camera distance ahead of the rear axle must be in [0, 5] m, got {self.camera_ahead_m}")
        if not (np.isfinite(self.body_motion) and 0.0 <= self.body_motion <= 5.0):
            raise InputError(None, f"body motion must be in [0, 5] (a multiple of KITTI's), got {self.body_motion}")
        return self


@dataclasses.dataclass(frozen=True)
class RenderConfig:
    """How to render."""

    backend: str = "mujoco"
    """"mujoco" (mujoco.Renderer's GL pipeline) or "pyrender" (pyrender2's OffscreenRenderer)."""
    width: int | None = None
    """Image width in pixels (None: the scene camera's, or from height keeping its aspect ratio)."""
    height: int | None = None
    """Image height in pixels (None: the scene camera's, or from width keeping its aspect ratio)."""
    stereo_baseline_m: float | None = None
    """Right camera at +baseline along the camera x axis, metres (None: the scene's default; 0: mono)."""
    focal_px: float | None = None
    """Focal length fx = fy in pixels (e.g. a Kinect's 537 at 640x480); None keeps the scene camera's
    vertical field of view. The renderers take square pixels."""
    principal_point_px: tuple[float, float] | None = None
    """(cx, cy) of the images, pixels at the output size (pixel centres at integers); None: the image's
    centre ``((W - 1) / 2, (H - 1) / 2)``. A real camera's is rarely there (KITTI 04-12's lies 10.6 px
    left of its centre, 0.87 % of the width): the frame is rendered centred on a canvas wider and taller
    by twice the offset, at the same focal length, and cut to the requested window
    (:func:`off_centre`), so every image, depth, flow and mask is the one such a camera would give. Its
    offset from the centre must be a multiple of 0.5 px."""
    flow: bool = True
    """Compute the forward ground-truth optical flow."""
    depth_noise: str | None = None
    """None: the depth written is exact. "kinect": a structured-light sensor's errors
    (:func:`sim.sensor.kinect_depth`: range, depth-dependent noise, disparity quantisation, missing
    readings at edges and grazing angles) are applied to the depth written to ``depth/``; the exact
    depth goes to ``depth_exact/`` and every other ground truth stays exact."""
    exposure_ms: float = 0.0
    """Exposure time in milliseconds for motion blur (0: a sharp image). The image is the mean of
    ``blur_samples`` renders spread evenly over the exposure, centred on the frame time, so the
    frame's pose, depth, flow and masks (all at the frame time) are those of mid-exposure."""
    blur_samples: int = 8
    """Renders averaged per image when ``exposure_ms`` > 0."""
    sensor_noise: float = 0.0
    """Std of Gaussian noise added to every image channel, grey levels (0: none)."""
    exposure_jitter: float = 0.0
    """Per-frame brightness gain drawn log-uniformly in [1 / (1 + j), 1 + j] (0: none), as auto-exposure
    does between frames."""
    white_balance_jitter: float = 0.0
    """Per-frame gain of each colour channel drawn uniformly in [1 - w, 1 + w] (0: none)."""
    rolling_shutter_ms: float = 0.0
    """Rolling-shutter readout time, milliseconds, from the first image row to the last (0: a global
    shutter). Row v is captured at ``t_i + (v / (H - 1) - 1/2) * readout`` (the middle row at the frame
    time); rows are rendered in ``rolling_shutter_bands`` bands, each at the time of its middle row.
    Depth, masks, flow, occlusion and the per-row poses are those of the rows as rendered (exact)."""
    rolling_shutter_bands: int = 32
    """Bands of rows rendered at one time each under a rolling shutter (at most the image height:
    then every row has its own time)."""
    distortion: tuple[float, float, float, float] | None = None
    """Lens distortion (k1, k2, p1, p2), OpenCV's radial-tangential model, applied to the images only
    (EuRoC layout: written to sensor.yaml, and the readers undistort back to the render's pinhole
    camera, in which depth, flow and masks stay exact); None: a pinhole image."""
    flow_formats: tuple[str, ...] = ("npy",)
    """Files written per flow field (``flow/``, ``flow_backward/``), from :data:`FLOW_FORMATS`:
    ``NNNNNN.npy`` (float32, the one the readers read) is always written; ``"flo"`` adds a Middlebury
    ``NNNNNN.flo`` (float32, unknown = 1e10) and ``"png"`` a KITTI 2015 flow ``NNNNNN.png`` (16-bit,
    1/64 px, invalid where unknown) beside it (:mod:`deepslam.core.flowio`)."""

    def __post_init__(self):
        # a list (from JSON) or a comma-separated string becomes a tuple, so configs compare and hash
        fmts = () if self.flow_formats is None else self.flow_formats
        if isinstance(fmts, str):
            fmts = [f.strip() for f in fmts.split(",")]
        object.__setattr__(self, "flow_formats", tuple(fmts))
        if self.principal_point_px is not None:
            object.__setattr__(self, "principal_point_px", tuple(self.principal_point_px))

    @property
    def distorted(self) -> bool:
        """Whether the images get a lens distortion (``distortion`` set and not all zero)."""
        return self.distortion is not None and any(self.distortion)

    @property
    def rolling_shutter(self) -> bool:
        """Whether the rows are captured at different times (``rolling_shutter_ms`` > 0)."""
        return self.rolling_shutter_ms > 0

    @property
    def photometric(self) -> bool:
        """Whether any image-only effect (noise, exposure, white balance) is on."""
        return self.sensor_noise > 0 or self.exposure_jitter > 0 or self.white_balance_jitter > 0

    def validate(self) -> "RenderConfig":
        if self.backend not in BACKENDS:
            raise InputError(None, f"unknown backend {self.backend!r} (choose from {', '.join(BACKENDS)})")
        for name, v in (("width", self.width), ("height", self.height)):
            if v is not None and (not isinstance(v, int) or v < 1 or v > MAX_SIDE_PX):
                raise InputError(None, f"{name} must be an integer in 1..{MAX_SIDE_PX}, got {v}")
        if self.depth_noise not in (None, "kinect"):
            raise InputError(None, f"unknown depth noise model {self.depth_noise!r} (kinect, or none)")
        if self.focal_px is not None and not (np.isfinite(self.focal_px) and 1.0 <= self.focal_px <= 100_000.0):
            raise InputError(None, f"focal length must be in [1, 100000] px, got {self.focal_px}")
        if self.principal_point_px is not None and (len(self.principal_point_px) != 2
                                                     or not np.isfinite(self.principal_point_px).all()):
            raise InputError(None, f"principal point must be two finite numbers CX,CY, got {list(self.principal_point_px)}")
        if self.stereo_baseline_m is not None and not (np.isfinite(self.stereo_baseline_m) and 0 <= self.stereo_baseline_m <= 10):
            raise InputError(None, f"stereo baseline must be in [0, 10] m, got {self.stereo_baseline_m}")
        for name, v, hi in (("exposure (ms)", self.exposure_ms, 1000.0), ("sensor noise", self.sensor_noise, 100.0),
                            ("exposure jitter", self.exposure_jitter, 4.0), ("white-balance jitter", self.white_balance_jitter, 0.9)):
            if not (np.isfinite(v) and 0.0 <= v <= hi):
                raise InputError(None, f"{name} must be in [0, {hi:g}], got {v}")
        if self.distortion is not None:
            d = tuple(self.distortion)
            if len(d) != 4 or not np.isfinite(d).all() or abs(d[0]) > 1 or abs(d[1]) > 1 or max(abs(d[2]), abs(d[3])) > 0.05:
                raise InputError(None, f"distortion must be k1 k2 p1 p2 with |k| <= 1 and |p| <= 0.05, got {list(d)}")
        if not (np.isfinite(self.rolling_shutter_ms) and 0.0 <= self.rolling_shutter_ms <= 1000.0):
            raise InputError(None, f"rolling-shutter readout must be in [0, 1000] ms, got {self.rolling_shutter_ms}")
        if not isinstance(self.rolling_shutter_bands, int) or not 1 <= self.rolling_shutter_bands <= MAX_SIDE_PX:
            raise InputError(None, f"rolling-shutter bands must be an integer in [1, {MAX_SIDE_PX}], got {self.rolling_shutter_bands}")
        if self.rolling_shutter_ms > 0 and self.exposure_ms > 0:
            raise InputError(None, "rolling shutter and motion blur (exposure) cannot be combined yet: choose one")
        if not isinstance(self.blur_samples, int) or not 2 <= self.blur_samples <= 64:
            raise InputError(None, f"blur samples must be an integer in [2, 64], got {self.blur_samples}")
        unknown = [f for f in self.flow_formats if f not in FLOW_FORMATS]
        if unknown or not self.flow_formats:
            raise InputError(None, f"unknown flow format {(unknown or [''])[0]!r} (choose from {', '.join(FLOW_FORMATS)}, "
                                   f"comma-separated)")
        if not self.flow and any(f != "npy" for f in self.flow_formats):
            raise InputError(None, "flow formats other than npy need the flow: drop --no-flow or the --flow-format")
        return self


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Everything that determines a rendered sequence (same config, same bytes)."""

    scene: SceneConfig = SceneConfig()
    """What to render."""
    trajectory: TrajectoryConfig = TrajectoryConfig()
    """Along which camera path."""
    render: RenderConfig = RenderConfig()
    """With which renderer, image size and stereo baseline."""

    def validate(self) -> "SimConfig":
        self.scene.validate()
        self.trajectory.validate()
        self.render.validate()
        kind = self.trajectory.resolved_kind(self.scene.name)
        if kind == "car" and self.scene.name != "street":
            raise InputError(None, f"trajectory 'car' needs roads: use it with scene 'street', not {self.scene.name!r}")
        return self

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "SimConfig":
        # a record that names no street style describes the town street
        scene = {"street_style": "town", **d["scene"]}
        return SimConfig(SceneConfig(**scene), TrajectoryConfig(**d["trajectory"]), RenderConfig(**d["render"]))


def camera_for(default: PinholeCamera, width: int | None, height: int | None,
               focal_px: float | None = None) -> PinholeCamera:
    """The scene camera at another image size, with square pixels and the principal point at the
    centre, as MuJoCo renders it: the vertical field of view is kept (``fy`` scales with the height),
    ``fx = fy``, ``cx = (W - 1) / 2``, ``cy = (H - 1) / 2``. A missing side follows the default's aspect
    ratio. With the default's aspect ratio this equals ``default.scaled(width, height)`` up to the
    rounding of the size. ``focal_px`` sets fx = fy instead of keeping the field of view."""
    if width is None and height is None and focal_px is None:
        return default
    if width is None and height is None:
        width, height = default.width, default.height
    if width is None:
        width = max(1, int(round(height * default.width / default.height)))
    if height is None:
        height = max(1, int(round(width * default.height / default.width)))
    f = float(focal_px) if focal_px is not None else default.fy * height / default.height
    return PinholeCamera(int(width), int(height), f, f, (width - 1) / 2.0, (height - 1) / 2.0)


def off_centre(camera: PinholeCamera, principal_point_px: tuple[float, float]
               ) -> tuple[PinholeCamera, PinholeCamera, tuple[int, int]]:
    """``camera`` (centred, as :func:`camera_for` gives it) with its principal point moved to
    ``principal_point_px`` = (cx, cy) px, and how to render it with a centred renderer.

    Returns ``(output, canvas, (top, left))``: ``output`` the camera of the written images (same size and
    focal length, the principal point moved); ``canvas`` the centred camera to render (each side larger by
    twice the offset along it, same focal length, so its field of view covers the output's); ``(top,
    left)`` the output window's first row and column in the canvas. A pixel (u, v) of the output is pixel
    (u + left, v + top) of the canvas, so ``output.cx = canvas.cx - left``. Raises InputError when the point
    lies outside the image or its offset from the centre is not a multiple of 0.5 px (the window must fall
    on the canvas's pixels)."""
    cx, cy = (float(x) for x in principal_point_px)
    if not (0.0 <= cx <= camera.width - 1 and 0.0 <= cy <= camera.height - 1):
        raise InputError(None, f"principal point ({cx:g}, {cy:g}) lies outside the {camera.width}x{camera.height} image")
    twice = (2.0 * (cx - camera.cx), 2.0 * (cy - camera.cy))
    if any(abs(t - round(t)) > 1e-9 for t in twice):
        raise InputError(None, f"principal point ({cx:g}, {cy:g}) must lie a multiple of 0.5 px from the image centre "
                               f"({camera.cx:g}, {camera.cy:g})")
    dx2, dy2 = (int(round(t)) for t in twice)  # twice the offset, signed, px
    canvas = PinholeCamera(camera.width + abs(dx2), camera.height + abs(dy2), camera.fx, camera.fy,
                           (camera.width + abs(dx2) - 1) / 2.0, (camera.height + abs(dy2) - 1) / 2.0)
    top, left = (abs(dy2) - dy2) // 2, (abs(dx2) - dx2) // 2
    output = PinholeCamera(camera.width, camera.height, camera.fx, camera.fy, canvas.cx - left, canvas.cy - top)
    return output, canvas, (top, left)
