"""The in-memory simulator: a scene, a camera motion and a render backend; frames on demand."""
from __future__ import annotations

import dataclasses

import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.trajectory import Trajectory
from deepslam.scenes import SceneConfig, build_scene
from deepslam.scenes.spec import Scene
from deepslam.sim.config import SimConfig, camera_for
from deepslam.sim.flow import FlowComputer, occlusion_mask
from deepslam.sim.trajectories import make_motion
from deepslam.sim.world import WorldState, separate_movers, world_state


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

    @property
    def world_from_cam_right(self) -> np.ndarray | None:
        """(4, 4) pose of the right camera, or None."""
        if not self.baseline_m:
            return None
        return self.world_from_cam @ se3.from_rt(np.eye(3), [self.baseline_m, 0.0, 0.0])


def make_backend(name: str, scene: Scene, camera: PinholeCamera, baseline_m: float | None):
    if name == "mujoco":
        from deepslam.sim.render_mujoco import MujocoBackend

        return MujocoBackend(scene, camera, baseline_m)
    if name == "pyrender":
        from deepslam.sim.render_pyrender import PyrenderBackend

        return PyrenderBackend(scene, camera, baseline_m)
    raise ValueError(f"unknown backend {name!r}")


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
            motion = make_motion(base, tcfg.resolved_kind(base.name), np.random.default_rng([tseed, 1]), tcfg.rate_hz)
        self.motion = motion
        self.rate_hz = float(motion.rate_hz)
        self.num_frames = int(tcfg.frames)
        self.timestamps_s = np.arange(self.num_frames, dtype=np.float64) / self.rate_hz
        duration = (self.num_frames + 1) / self.rate_hz
        self.scene = separate_movers(base, motion, duration, np.random.default_rng([tseed, 2]))
        rcfg = config.render
        self.camera = camera_for(self.scene.camera, rcfg.width, rcfg.height, rcfg.focal_px)
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
        self.backend = make_backend(rcfg.backend, self.scene, self.camera, self.baseline_m)
        self._flow = FlowComputer(self.camera)
        self._distort_maps: tuple[np.ndarray, np.ndarray] | None = None  # made on the first distorted frame
        self._inst = np.zeros(len(self.scene.bodies) + 1, np.uint16)  # body index + 1 -> instance id
        for i, body in enumerate(self.scene.bodies):
            self._inst[i + 1] = body.instance_id

    # ------------------------------------------------------------------------------------------

    def time(self, i: int) -> float:
        return float(i) / self.rate_hz

    def state(self, i: int) -> WorldState:
        """The world at frame i (any i >= 0, also beyond num_frames)."""
        return world_state(self.scene, self.motion, self.time(i))

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
        self.backend.set_state(s0)
        left = self.backend.render("left", colour=True, depth=True)
        r = self.backend.render("right", colour=True, depth=depth_right) if right else {}
        fl = occ = back = None
        if flow:
            fl, z1 = self._flow.flow_and_depth(self.scene, left["depth_z"], left["body"], s0, self.state(i + 1))
            if occlusion is None or occlusion:
                self.backend.set_state(self.state(i + 1))
                depth1 = self.backend.render("left", colour=False, depth=True)["depth_z"]
                occ = occlusion_mask(fl, z1, depth1)
        if (self.config.render.flow if backward is None else backward) and i > 0:
            back = self._flow.flow(self.scene, left["depth_z"], left["body"], s0, self.state(i - 1))
        sensor = None
        if self.config.render.depth_noise == "kinect":
            from deepslam.sim.sensor import kinect_depth

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
                        back, occ, sensor)

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
        import cv2

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
