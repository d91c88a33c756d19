"""The in-memory simulator: a scene, a camera motion and a render backend; frames on demand."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera, check_flow_size
from deepslam.core.errors import InputError
from deepslam.core.trajectory import Trajectory
from deepslam.scenes import SceneConfig, build_scene
from deepslam.scenes.spec import Scene
from deepslam.sim.config import SimConfig, camera_for, off_centre
from deepslam.sim.flow import FlowComputer, occlusion_mask
from deepslam.sim.render_mujoco import MujocoBackend
from deepslam.sim.render_pyrender import PyrenderBackend
from deepslam.sim.sensor import kinect_depth
from deepslam.sim.trajectories import make_motion
from deepslam.sim.world import WorldState, follow_camera, separate_movers, world_state


@dataclasses.dataclass(eq=False)
class SimFrame:
    """One rendered frame with perfect ground truth.

    Attributes:
        index: frame number (0-based).
        timestamp_s: ``index / rate_hz`` seconds.
        camera: intrinsics of every image here (pixel centres at integers).
        world_from_cam: (4, 4) float64 pose of the left camera, OpenCV axes (x right, y down, z
            forward), world frame z up, metres.
        rgb: (H, W, 3) uint8 left image.
        depth_z: (H, W) float32 metres along the optical axis, 0 where nothing is hit (sky).
        flow: (H, W, 2) float32 (du, dv) pixels from this frame to frame index + 1 (forward flow of
            each pixel's surface point; rotation-only flow of the point at infinity where
            depth_z = 0; NaN where the point is behind the camera at index + 1), or None.
        mask: (H, W) uint16 instance id of the dynamic surface seen in each pixel, 0 = static scene
            or nothing (moving objects and, with deformation, flags have ids >= 1).
        body: (H, W) int32 index into ``Simulator.scene.bodies`` of the surface seen, -1 = nothing.
        rgb_right: (H, W, 3) uint8 right image (camera at +baseline along x), or None.
        depth_right: (H, W) float32 depth_z of the right image, or None (only when asked for).
        baseline_m: the stereo baseline, or None.
        instance_poses: {instance id: (4, 4) world_from_body at this frame} of the rigid movers.
        flow_backward: (H, W, 2) float32 (du, dv) pixels from this frame to frame index - 1 (the
            same exact computation backwards in time), or None (frame 0, or not asked for).
        occlusion: (H, W) bool, True where the surface seen at a pixel is not visible in frame
            index + 1 (hidden by something nearer, outside the image, or behind the camera), or None.
        depth_sensor: (H, W) float32 depth_z as a sensor would report it (config ``depth_noise``; 0 =
            no reading), or None.
        row_poses: (H, 4, 4) float64 world_from_cam of the left camera at each image row's capture
            time under a rolling shutter (config ``rolling_shutter_ms``), or None (global shutter:
            every row is seen from ``world_from_cam``). The image, depth, masks and flow of row v are
            those seen from ``row_poses[v]``; ``world_from_cam`` stays the pose at the frame time.
    """

    index: int
    timestamp_s: float
    camera: PinholeCamera
    world_from_cam: np.ndarray
    rgb: np.ndarray
    depth_z: np.ndarray
    flow: np.ndarray | None
    mask: np.ndarray
    body: np.ndarray
    rgb_right: np.ndarray | None = None
    depth_right: np.ndarray | None = None
    baseline_m: float | None = None
    instance_poses: dict = dataclasses.field(default_factory=dict)
    flow_backward: np.ndarray | None = None
    occlusion: np.ndarray | None = None
    depth_sensor: np.ndarray | None = None
    row_poses: np.ndarray | None = None

    @property
    def world_from_cam_right(self) -> np.ndarray | None:
        """(4, 4) pose of the right camera, or None."""
        if not self.baseline_m:
            return None
        return self.world_from_cam @ se3.from_rt(np.eye(3), [self.baseline_m, 0.0, 0.0])


def rolling_shutter_bands(height: int, readout_s: float, bands: int) -> list[tuple[int, int, float]]:
    """The bands of rows a rolling shutter renders at one time each: ``(first row, end row, capture
    time minus the frame time in seconds)``, top to bottom. Row v's continuous capture time is
    ``(v / (H - 1) - 1/2) * readout_s``; a band takes its middle row's. ``min(bands, height)`` bands of
    (nearly) equal height."""
    k = max(1, min(int(bands), int(height)))
    edges = np.rint(np.linspace(0, height, k + 1)).astype(int)
    out = []
    for r0, r1 in zip(edges[:-1], edges[1:]):
        mid = (r0 + r1 - 1) / 2.0
        out.append((int(r0), int(r1), float((mid / (height - 1) - 0.5) * readout_s) if height > 1 else 0.0))
    return out


def make_backend(name: str, scene: Scene, camera: PinholeCamera, baseline_m: float | None):
    if name == "mujoco":
        return MujocoBackend(scene, camera, baseline_m)
    if name == "pyrender":
        return PyrenderBackend(scene, camera, baseline_m)
    raise ValueError(f"unknown backend {name!r}")


class WindowBackend:
    """A backend that renders a centred canvas and returns a window of it: the images of a camera whose
    principal point is off the centre (:func:`sim.config.off_centre`). Same ``set_state`` / ``render`` /
    ``close`` as the backend it wraps; every array ``render`` returns is the (height, width) window whose
    first row and column are ``top`` and ``left`` of the canvas."""

    def __init__(self, inner, top: int, left: int, height: int, width: int):
        self.inner = inner
        self._rows, self._cols = slice(top, top + height), slice(left, left + width)

    def set_state(self, state: WorldState) -> None:
        self.inner.set_state(state)

    def render(self, side: str = "left", colour: bool = True, depth: bool = True) -> dict:
        return {k: np.ascontiguousarray(v[self._rows, self._cols])
                for k, v in self.inner.render(side, colour=colour, depth=depth).items()}

    def close(self) -> None:
        self.inner.close()


class Simulator:
    """Renders frames of a scene along a scripted camera motion, with exact ground truth.

    Args:
        config: what to render (validated; bad values raise core.errors.InputError).
        scene: use this scene instead of building ``config.scene`` (tests, custom scenes).
        motion: use this camera motion (anything with ``world_from_cam(t)`` and ``rate_hz``)
            instead of the trajectory of ``config.trajectory``.

    Use as a context manager (or call :meth:`close`) to free the GL context.
    """

    def __init__(self, config: SimConfig | None = None, *, scene: Scene | None = None, motion=None):
        config = config or SimConfig()
        if scene is None:
            config = config.validate()
        else:
            config.trajectory.validate()
            config.render.validate()
        self.config = config
        base = scene if scene is not None else build_scene(config.scene)
        tcfg = config.trajectory
        tseed = tcfg.seed if tcfg.seed is not None else (config.scene.seed if scene is None else base.seed)
        # seed of the per-frame image and sensor effects (noise, exposure, Kinect depth): the trajectory's, else the scene config's
        self._effects_seed = int(tcfg.seed if tcfg.seed is not None else config.scene.seed)
        if motion is None:
            kind = tcfg.resolved_kind(base.name)
            if tcfg.camera_ahead_m and kind != "car":
                raise InputError(None, f"a camera ahead of the rear axle is for the car trajectory, not the {base.name}'s {kind}")
            if tcfg.body_motion and kind != "car":
                raise InputError(None, f"body motion is for the car trajectory, not the {base.name}'s {kind}")
            motion = make_motion(base, kind, np.random.default_rng([tseed, 1]), tcfg.rate_hz, tcfg.camera_ahead_m,
                                 tcfg.body_motion, np.random.default_rng([tseed, 3]))
        self.motion = motion
        self.rate_hz = float(motion.rate_hz)
        self.num_frames = int(tcfg.frames)
        self.timestamps_s = np.arange(self.num_frames, dtype=np.float64) / self.rate_hz
        duration = (self.num_frames + 1) / self.rate_hz
        self.scene = separate_movers(follow_camera(base, motion), motion, duration, np.random.default_rng([tseed, 2]))
        rcfg = config.render
        self.camera = camera_for(self.scene.camera, rcfg.width, rcfg.height, rcfg.focal_px)
        canvas = window = None  # a principal point off the centre: a larger centred render, cut
        if rcfg.principal_point_px is not None:
            self.camera, canvas, window = off_centre(self.camera, rcfg.principal_point_px)
        check_flow_size(self.camera.width, self.camera.height)  # a render the odometry could not read
        b = self.scene.stereo_baseline_m if rcfg.stereo_baseline_m is None else rcfg.stereo_baseline_m
        self.baseline_m = float(b) if b else None
        self.backend_name = rcfg.backend
        self.resolved_config = dataclasses.replace(
            config,
            scene=(dataclasses.replace(config.scene, texture_px_per_m=config.scene.px_per_m) if scene is None
                   else scene.config if isinstance(scene.config, SceneConfig) else config.scene),
            trajectory=dataclasses.replace(tcfg, kind=getattr(motion, "name", tcfg.kind), rate_hz=self.rate_hz, seed=tseed),
            render=dataclasses.replace(rcfg, width=self.camera.width, height=self.camera.height,
                                       stereo_baseline_m=float(self.baseline_m or 0.0)))
        """The config with every default filled in (image size, baseline, rate, trajectory kind and seed)."""
        self.backend = make_backend(rcfg.backend, self.scene, canvas or self.camera, self.baseline_m)
        if window is not None:
            self.backend = WindowBackend(self.backend, *window, self.camera.height, self.camera.width)
        self._flow = FlowComputer(self.camera)
        self._distort_maps: tuple[np.ndarray, np.ndarray] | None = None  # made on the first distorted frame
        self._bands = rolling_shutter_bands(self.camera.height, rcfg.rolling_shutter_ms * 1e-3,
                                            rcfg.rolling_shutter_bands) if rcfg.rolling_shutter else []
        self._band_flow = [FlowComputer(PinholeCamera(self.camera.width, r1 - r0, self.camera.fx, self.camera.fy,
                                                      self.camera.cx, self.camera.cy - r0)) for r0, r1, _ in self._bands]
        self._states: dict[int, WorldState] = {}  # the last few of :meth:`state`, oldest first
        self._next_depth: dict[int, dict] = {}  # {frame: its depth pass} kept from the previous frame's occlusion test
        self._inst = np.zeros(len(self.scene.bodies) + 1, np.uint16)  # body index + 1 -> instance id
        for i, body in enumerate(self.scene.bodies):
            self._inst[i + 1] = body.instance_id

    # ------------------------------------------------------------------------------------------

    def time(self, i: int) -> float:
        return float(i) / self.rate_hz

    def state(self, i: int) -> WorldState:
        """The world at frame i (any i >= 0, also beyond num_frames); the last few are kept (a frame
        needs frames i - 1, i and i + 1, and the next frame the same again). Treat it as read-only."""
        st = self._states.get(i)
        if st is None:
            st = world_state(self.scene, self.motion, self.time(i))
            if len(self._states) >= 4:
                self._states.pop(next(iter(self._states)))  # the oldest
            self._states[i] = st
        return st

    @property
    def trajectory(self) -> Trajectory:
        """Ground-truth world_from_cam of the left camera at the frame times (OpenCV axes)."""
        return Trajectory(self.motion.world_from_cam(self.timestamps_s), self.timestamps_s.copy())

    def frame(self, i: int, *, right: bool | None = None, flow: bool | None = None, depth_right: bool = False,
              backward: bool | None = None, occlusion: bool | None = None) -> SimFrame:
        """Render frame i (0 <= i; frames past ``num_frames`` are allowed too).

        Args:
            right: render the right image (default: when the baseline is set).
            flow: compute the flow to frame i+1 (default: ``config.render.flow``).
            depth_right: also render the right camera's depth.
            backward: compute the backward flow to frame i-1 (default: with the config's flow, i > 0).
            occlusion: compute the occlusion mask against frame i+1 (default: when the forward flow is
                computed; costs one depth-only render of frame i+1).
        """
        if i < 0:
            raise IndexError(f"frame {i} < 0")
        right = bool(self.baseline_m) if right is None else right
        flow = self.config.render.flow if flow is None else flow
        s0 = self.state(i)
        cached = self._next_depth.pop(i, None)  # frame i's depth pass, made for frame i - 1's occlusion test
        left, r = self._render(i, right, depth=cached is None, depth_right=depth_right)
        if cached is not None:
            left.update(cached)
        fl = occ = back = None
        if flow:
            fl, z1 = self._flow_between(i, i + 1, left["depth_z"], left["body"])
            if occlusion is None or occlusion:
                nxt = self._render(i + 1, False, colour=False)[0]
                self._next_depth = {i + 1: nxt}  # the next frame in order reuses this pass
                occ = occlusion_mask(fl, z1, nxt["depth_z"])
        if (self.config.render.flow if backward is None else backward) and i > 0:
            back = self._flow_between(i, i - 1, left["depth_z"], left["body"])[0]
        sensor = None
        if self.config.render.depth_noise == "kinect":
            sensor = kinect_depth(left["depth_z"], self.camera, np.random.default_rng([self._effects_seed, 0x5E75, int(i)]))
        mask = self._inst[left["body"] + 1]
        poses = {b.instance_id: s0.world_from_body[k] for k, b in enumerate(self.scene.bodies) if b.kind == "rigid"}
        rgb, rgb_right = left["rgb"], r.get("rgb")
        rcfg = self.config.render
        if rcfg.exposure_ms > 0:
            rgb, rgb_right = self._motion_blur(i, right)
        if rcfg.photometric:
            rgb, rgb_right = self._photometric(i, rgb, rgb_right)
        if rcfg.distorted:
            rgb = self._distort(rgb)
            rgb_right = None if rgb_right is None else self._distort(rgb_right)
        return SimFrame(i, self.time(i), self.camera, s0.world_from_cam, rgb, left["depth_z"], fl, mask,
                        left["body"], rgb_right, r.get("depth_z"), self.baseline_m if right else None, poses,
                        back, occ, sensor, self.row_poses(i) if self._bands else None)

    def _render(self, i: int, right: bool, colour: bool = True, depth: bool = True,
                depth_right: bool = False) -> tuple[dict, dict]:
        """Frame i's left (and right) renders, the backend's ``render`` dicts (right: {} if not), under
        the global or the rolling shutter."""
        if self._bands:
            return self._render_rolling(i, right, colour, depth_right, depth)
        self.backend.set_state(self.state(i))
        left = self.backend.render("left", colour=colour, depth=depth)
        return left, (self.backend.render("right", colour=True, depth=depth_right) if right else {})

    def _flow_between(self, i: int, j: int, depth_z: np.ndarray, body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(flow, z1) of frame i's pixels to frame j (:meth:`FlowComputer.flow_and_depth`), under the
        global or the rolling shutter."""
        if self._bands:
            return self._rolling_flow(i, j, depth_z, body)
        return self._flow.flow_and_depth(self.scene, depth_z, body, self.state(i), self.state(j))

    # ------------------------------------------------------------------------------ rolling shutter

    @property
    def shutter_bands(self) -> list[tuple[int, int, float]]:
        """The rolling shutter's bands (:func:`rolling_shutter_bands`); [] with a global shutter."""
        return list(self._bands)

    @property
    def row_time_offsets_s(self) -> np.ndarray | None:
        """(H,) float64 capture time of each image row minus the frame time, seconds, under a rolling
        shutter (each row its band's time); None with a global shutter."""
        if not self._bands:
            return None
        out = np.empty(self.camera.height, np.float64)
        for r0, r1, dt in self._bands:
            out[r0:r1] = dt
        return out

    def row_poses(self, i: int) -> np.ndarray:
        """(H, 4, 4) float64 world_from_cam of the left camera at each row's capture time of frame i."""
        offsets = self.row_time_offsets_s
        if offsets is None:
            return np.repeat(self.state(i).world_from_cam[None], self.camera.height, axis=0)
        return self.motion.world_from_cam(self.time(i) + offsets)

    def _render_rolling(self, i: int, right: bool, colour: bool, depth_right: bool = False,
                        depth: bool = True) -> tuple[dict, dict]:
        """Frame i under the rolling shutter: each band of rows cut from a render of the world at the
        band's time. Returns the left and right dicts of the backend's ``render`` (right: {} if not)."""
        h, w = self.camera.height, self.camera.width
        left: dict = {"depth_z": np.empty((h, w), np.float32), "body": np.empty((h, w), np.int32)} if depth else {}
        r: dict = {}
        if colour:
            left["rgb"] = np.empty((h, w, 3), np.uint8)
        if right:
            r = {"rgb": np.empty((h, w, 3), np.uint8)}
            if depth_right:
                r["depth_z"] = np.empty((h, w), np.float32)
        for r0, r1, dt in self._bands:
            self.backend.set_state(world_state(self.scene, self.motion, self.time(i) + dt))
            band = self.backend.render("left", colour=colour, depth=depth)
            for key in left:
                left[key][r0:r1] = band[key][r0:r1]
            if right:
                band = self.backend.render("right", colour=True, depth=depth_right)
                for key in r:
                    r[key][r0:r1] = band[key][r0:r1]
        return left, r

    def _rolling_flow(self, i: int, j: int, depth_z: np.ndarray, body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(flow, z1) from rolling-shutter frame i to frame j (j = i + 1: forward, i - 1: backward), as
        :meth:`FlowComputer.flow_and_depth` gives them for a global shutter.

        A pixel of row v shows its surface point at row v's time. Where it appears in frame j depends
        on when frame j captures the row it lands in: the landing row r solves r = row of the point
        projected at the capture time of r's band. Each band's pixels start from the band with the
        same rows and move to the band of their landing row until nothing changes (at most 8 rounds;
        a point that lands outside the image takes the nearest band's time).
        """
        h, w = depth_z.shape
        flow = np.empty((h, w, 2), np.float32)
        z1 = np.empty((h, w), np.float32)
        band_of_row = np.empty(h, np.int64)
        for k, (r0, r1, _) in enumerate(self._bands):
            band_of_row[r0:r1] = k
        target: dict[int, WorldState] = {}

        def state_j(k: int) -> WorldState:
            if k not in target:
                target[k] = world_state(self.scene, self.motion, self.time(j) + self._bands[k][2])
            return target[k]

        for b, (r0, r1, dt) in enumerate(self._bands):
            s0 = world_state(self.scene, self.motion, self.time(i) + dt)
            d, bd = depth_z[r0:r1], body[r0:r1]
            cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
            choice = np.full((r1 - r0, w), b, np.int64)
            rows = np.arange(r0, r1, dtype=np.float64)[:, None]
            for _ in range(8):
                fl = np.empty((r1 - r0, w, 2), np.float32)
                zz = np.empty((r1 - r0, w), np.float32)
                for k in np.unique(choice):
                    if k not in cache:
                        cache[k] = self._band_flow[b].flow_and_depth(self.scene, d, bd, s0, state_j(int(k)))
                    m = choice == k
                    fl[m], zz[m] = cache[k][0][m], cache[k][1][m]
                land = rows + fl[..., 1]
                ok = np.isfinite(land)
                new = np.where(ok, band_of_row[np.clip(np.rint(np.where(ok, land, 0.0)), 0, h - 1).astype(np.int64)], choice)
                if np.array_equal(new, choice):
                    break
                choice = new
            flow[r0:r1], z1[r0:r1] = fl, zz
        return flow, z1

    def _motion_blur(self, i: int, right: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """The left (and right) image averaged over the exposure, centred on frame i's time."""
        rcfg = self.config.render
        n = rcfg.blur_samples
        exposure_s = rcfg.exposure_ms * 1e-3
        acc = {"left": None, "right": None}
        for k in range(n):
            t = self.time(i) + ((k + 0.5) / n - 0.5) * exposure_s
            self.backend.set_state(world_state(self.scene, self.motion, t))
            for side in ("left", "right") if right else ("left",):
                img = self.backend.render(side, colour=True, depth=False)["rgb"].astype(np.float32)
                acc[side] = img if acc[side] is None else acc[side] + img
        out = {k: None if v is None else np.clip(np.rint(v / n), 0, 255).astype(np.uint8) for k, v in acc.items()}
        return out["left"], out["right"]

    def _distort(self, img: np.ndarray) -> np.ndarray:
        """The image a lens with ``render.distortion`` would give: pixel x_d of the distorted image shows
        what the pinhole render shows at undistort(x_d) (OpenCV's model, iterative inverse; bilinear)."""
        if self._distort_maps is None:
            cam = self.camera
            u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
            pts = np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2)
            und = cv2.undistortPointsIter(pts, cam.k, np.asarray(self.config.render.distortion, np.float64), None, cam.k,
                                          (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-6))
            und = und.reshape(cam.height, cam.width, 2).astype(np.float32)
            self._distort_maps = (und[..., 0].copy(), und[..., 1].copy())
        return cv2.remap(img, *self._distort_maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def _photometric(self, i: int, rgb: np.ndarray, rgb_right: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """Exposure gain, white balance (the same for both cameras of a frame) and sensor noise, from the
        trajectory seed and the frame index (same seed, same bytes)."""
        rcfg = self.config.render
        rng = np.random.default_rng([self._effects_seed, 0xC0102, int(i)])
        j = np.log1p(rcfg.exposure_jitter)
        gain = float(np.exp(rng.uniform(-j, j)))
        wb = 1.0 + rng.uniform(-rcfg.white_balance_jitter, rcfg.white_balance_jitter, 3)
        out = []
        for img in (rgb, rgb_right):
            if img is None:
                out.append(None)
                continue
            x = img.astype(np.float32) * (gain * wb).astype(np.float32)
            if rcfg.sensor_noise > 0:
                x += rng.normal(0.0, rcfg.sensor_noise, x.shape).astype(np.float32)
            out.append(np.clip(np.rint(x), 0, 255).astype(np.uint8))
        return out[0], out[1]

    def close(self) -> None:
        if getattr(self, "backend", None) is not None:
            self.backend.close()
            self.backend = None

    def __enter__(self) -> "Simulator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
