"""Scripted camera motions: smooth (C2: continuous acceleration), deterministic from a seed, defined
for any time t >= 0 (so frame i and frame i+1 are always available, for the flow of the last frame).

Every motion has ``world_from_cam(t) -> (N, 4, 4)`` float64, OpenCV camera axes (x right, y down,
z forward), world z up, and ``rate_hz``.

- :class:`CarMotion`: planar, the camera 1.65 m above the road looking forward along the lane of
  the street's route; starts from standstill (quintic speed ramp), cruises at up to 15 m/s, slows
  in bends to a lateral acceleration of about 2.5 m/s^2 (yaw rates about 0.5 rad/s); 10 Hz.
- :class:`DroneMotion`: 6DoF; in the room a closed loop around the hall's centre (polar periodic
  splines for radius, angle and height) with the yaw swinging +-70 degrees about a fixed heading,
  pitch and roll wobbling; time is scaled so speed <= 1.6 m/s and rotation rate <= 0.95 rad/s;
  20 Hz; the loop repeats (period about 10-13 s), so every place is revisited with the same view.
  In the street: a flight along the route 3-5 m up at 1.5 m/s.
- :class:`KeyframeMotion`: C2 interpolation of given poses (tests, custom paths).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from deepslam.core import se3
from deepslam.scenes.geometry import PeriodicPath
from deepslam.scenes.spec import PathProgress, Scene, StopGoProgress, smoothstep5, speed_profile

CAR_MAX_SPEED_MPS = 15.0
DRONE_MAX_SPEED_MPS = 1.6
DRONE_MAX_RATE_RAD_S = 0.95


def cam_from_forward(forward: np.ndarray, up: np.ndarray = np.array([0, 0, 1.0])) -> np.ndarray:
    """(…, 3, 3) world_from_cam rotation (OpenCV axes) looking along ``forward`` with no roll."""
    f = forward / np.linalg.norm(forward, axis=-1, keepdims=True)
    right = np.cross(f, up)
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    down = np.cross(f, right)
    return np.stack([right, down, f], axis=-1)


# body (x forward, y left, z up) -> camera (x right, y down, z forward)
BODY_FROM_CAM_ROT = np.array([[0, 0, 1.0], [-1.0, 0, 0], [0, -1.0, 0]])


@dataclasses.dataclass(frozen=True, eq=False)
class CarMotion:
    """The street's ego car (see module docstring)."""

    progress: PathProgress | StopGoProgress
    height_m: float
    rate_hz: float
    cruise_mps: float
    name: str = "car"
    pitch_rad: float = 0.0
    """Downward pitch of the camera about its x axis, radians (0: looking along the road)."""
    ahead_m: float = 0.0
    """Distance of the camera ahead of the rear axle, whose path the progress follows, metres (0: on it)."""

    @staticmethod
    def create(scene: Scene, rng: np.random.Generator, rate_hz: float = 10.0, ahead_m: float = 0.0) -> "CarMotion":
        path: PeriodicPath = scene.layout["lane_path"]
        cruise = float(rng.uniform(12.5, 14.5))
        pitch = float(scene.layout.get("camera_pitch_rad", 0.0))
        stop_go = scene.layout.get("stop_and_go")
        if stop_go is not None:
            return CarMotion(_stop_and_go(path, stop_go, rng), float(scene.layout["camera_height_m"]), rate_hz,
                             float(stop_go["fast_mps"]), pitch_rad=pitch, ahead_m=ahead_m)
        prof = speed_profile(path, min(cruise, CAR_MAX_SPEED_MPS), lat_accel_mps2=float(rng.uniform(3.0, 3.4)),
                             long_accel_mps2=2.5, smooth_m=5.0)
        # start from standstill in the bend before the route's start (lowest speed there), so the
        # start-up ramp stays gentle; the loop around block A then closes there after about 27 s
        c = np.linspace(path.length - 60.0, path.length, 601)
        c0 = float(c[np.argmin(prof(c))]) - path.length
        return CarMotion(PathProgress(path, prof, c0=c0, ramp_s=3.0), float(scene.layout["camera_height_m"]), rate_hz,
                         cruise, pitch_rad=pitch, ahead_m=ahead_m)

    def world_from_cam(self, t) -> np.ndarray:
        c = self.progress.c(t)
        path = self.progress.path
        xy = path.position(c)
        d = path.derivative(c)
        fwd = np.concatenate([d, np.zeros((len(c), 1))], axis=-1)
        pos = np.concatenate([xy, np.full((len(c), 1), self.height_m)], axis=-1)
        if self.ahead_m:
            pos = pos + self.ahead_m * fwd / np.linalg.norm(fwd, axis=-1, keepdims=True)
        rot = cam_from_forward(fwd)
        if self.pitch_rad:
            s, k = np.sin(self.pitch_rad), np.cos(self.pitch_rad)
            rot = rot @ np.array([[1.0, 0.0, 0.0], [0.0, k, s], [0.0, -s, k]])   # nose down about camera x
        return se3.from_rt(rot, pos)


def _stop_and_go(path: PeriodicPath, spec: dict, rng: np.random.Generator) -> StopGoProgress:
    """The ego car's stop-and-go drive on the street's route (``scene.layout['stop_and_go']``: stop
    positions ``stops_c``, fast stretches ``fast_c`` with top speed ``fast_mps``, the range
    ``cruise_mps`` of the speed elsewhere); the dwell at each stop and the cruise speed from ``rng``."""
    cruise = float(rng.uniform(*spec["cruise_mps"]))
    fast = [(float(a), float(b)) for a, b in spec["fast_c"]]
    top = float(spec["fast_mps"])
    length = path.length

    def limit(c):
        c = np.asarray(c, np.float64)
        v = np.full(c.shape, cruise)
        for a, b in fast:
            v[np.mod(c - a, length) <= np.mod(b - a, length)] = top
        return v

    stops = [float(s) for s in spec["stops_c"]]
    dwell = [float(rng.uniform(1.0, 3.0)) for _ in stops]
    return StopGoProgress(path, limit, stops, dwell, accel_mps2=3.5)


def _periodic_spline(u: np.ndarray, y: np.ndarray) -> CubicSpline:
    return CubicSpline(np.append(u, 1.0), np.append(y, y[:1], axis=0), bc_type="periodic")


def _time_warp(t: np.ndarray, ramp_s: float) -> np.ndarray:
    """integral_0^t smoothstep5(t'/ramp_s) dt' (seconds): start from rest, C2."""
    t = np.asarray(t, np.float64)
    x = np.clip(t / ramp_s, 0.0, 1.0)
    return np.where(t < ramp_s, ramp_s * (x ** 6 - 3 * x ** 5 + 2.5 * x ** 4), ramp_s * 0.5 + (t - ramp_s))


@dataclasses.dataclass(frozen=True, eq=False)
class DroneMotion:
    """A 6DoF flight (see module docstring); ``pose_u(u)`` gives world_from_cam over one loop
    u in [0, 1), and time maps to u through a start-from-rest warp and the loop period."""

    centre: np.ndarray
    r_spline: CubicSpline
    th_spline: CubicSpline
    z_spline: CubicSpline
    yaw_terms: np.ndarray
    pitch_terms: np.ndarray
    roll_terms: np.ndarray
    period_s: float
    rate_hz: float
    yaw0: float = 0.0
    ramp_s: float = 2.0
    name: str = "drone"

    @staticmethod
    def create(scene: Scene, rng: np.random.Generator, rate_hz: float = 20.0) -> "DroneMotion":
        lay = scene.layout
        n = 7
        u = np.arange(n) / n
        r = rng.uniform(*lay["radius_m"], n)
        dth = rng.uniform(-0.25, 0.25, n) * (2 * np.pi / n)
        z = rng.uniform(*lay["height_m"], n)
        # keep cubic overshoot inside the free ring: shrink the radius variation if needed
        lo, hi = lay["radius_m"]
        r_spl = _periodic_spline(u, r)
        uu = np.linspace(0, 1, 4000, endpoint=False)
        rr = r_spl(uu)
        if rr.min() < lo or rr.max() > hi:
            mid = (lo + hi) / 2
            k = min((mid - lo) / max(mid - rr.min(), 1e-9), (hi - mid) / max(rr.max() - mid, 1e-9), 1.0) * 0.98
            r_spl = _periodic_spline(u, mid + k * (r - mid))
        zlo, zhi = lay["height_m"]
        z_spl = _periodic_spline(u, z)
        zz = z_spl(uu)
        if zz.min() < zlo or zz.max() > zhi:
            mid = (zlo + zhi) / 2
            k = min((mid - zlo) / max(mid - zz.min(), 1e-9), (zhi - mid) / max(zz.max() - mid, 1e-9), 1.0) * 0.98
            z_spl = _periodic_spline(u, mid + k * (z - mid))
        th_spl = _periodic_spline(u, dth)
        # yaw swings +-70 degrees about a fixed heading (walls, shelves, the middle of the hall in turn)
        yaw = np.array([[1.2, 1, rng.uniform(0, 2 * np.pi)], [0.2, 2, rng.uniform(0, 2 * np.pi)]])
        pitch = np.array([[0.1, 2, rng.uniform(0, 2 * np.pi)], [0.03, 3, rng.uniform(0, 2 * np.pi)]])
        roll = np.array([[0.06, 1, rng.uniform(0, 2 * np.pi)], [0.02, 3, rng.uniform(0, 2 * np.pi)]])
        yaw0 = float(rng.uniform(0, 2 * np.pi))
        m = DroneMotion(np.asarray(lay["centre"], np.float64), r_spl, th_spl, z_spl, yaw, pitch, roll, 1.0, rate_hz, yaw0)
        # time scaling: the fastest point of the loop meets the speed and rotation-rate limits
        du = 1e-4
        p0 = m.pose_u(uu)
        p1 = m.pose_u(uu + du)
        v_u = np.linalg.norm(p1[:, :3, 3] - p0[:, :3, 3], axis=1) / du
        w_u = se3.rotation_angle(se3.relative(p0, p1)) / du
        period = max(v_u.max() / DRONE_MAX_SPEED_MPS, w_u.max() / DRONE_MAX_RATE_RAD_S, 5.0)
        return dataclasses.replace(m, period_s=float(period))

    @staticmethod
    def _series(terms: np.ndarray, u: np.ndarray) -> np.ndarray:
        return sum(a * np.sin(2 * np.pi * k * u + ph) for a, k, ph in terms)

    def pose_u(self, u) -> np.ndarray:
        """world_from_cam (N, 4, 4) at loop parameters u (any real; period 1)."""
        u = np.atleast_1d(np.asarray(u, np.float64))
        uf = np.mod(u, 1.0)
        th = 2 * np.pi * u + self.th_spline(uf)
        r = self.r_spline(uf)
        pos = np.stack([self.centre[0] + r * np.cos(th), self.centre[1] + r * np.sin(th), self.z_spline(uf)], -1)
        yaw = self.yaw0 + self._series(self.yaw_terms, u)
        pitch = 0.05 + self._series(self.pitch_terms, u)
        roll = self._series(self.roll_terms, u)
        world_from_body = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], -1)).as_matrix()
        return se3.from_rt(world_from_body @ BODY_FROM_CAM_ROT, pos)

    def world_from_cam(self, t) -> np.ndarray:
        return self.pose_u(_time_warp(np.atleast_1d(t), self.ramp_s) / self.period_s)


@dataclasses.dataclass(frozen=True, eq=False)
class StreetDroneMotion:
    """A drone flying along the street route 3-5 m up at 1.5 m/s, yaw and pitch wobbling."""

    progress: PathProgress
    phases: np.ndarray
    rate_hz: float
    name: str = "drone"

    @staticmethod
    def create(scene: Scene, rng: np.random.Generator, rate_hz: float = 20.0) -> "StreetDroneMotion":
        path = scene.layout["lane_path"]
        n = 16
        prof = CubicSpline(np.linspace(0, path.length, n + 1), np.full(n + 1, 1.5), bc_type="periodic")
        return StreetDroneMotion(PathProgress(path, prof, c0=0.0, ramp_s=3.0), rng.uniform(0, 2 * np.pi, 5), rate_hz)

    def world_from_cam(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, np.float64))
        c = self.progress.c(t)
        path = self.progress.path
        ph = self.phases
        xy = path.position(c)
        z = 4.0 + 0.8 * np.sin(2 * np.pi * t / 20.0 + ph[0])
        yaw = path.heading(c) + 0.4 * np.sin(2 * np.pi * t / 11.0 + ph[1])
        pitch = 0.15 + 0.05 * np.sin(2 * np.pi * t / 7.0 + ph[2])
        roll = 0.04 * np.sin(2 * np.pi * t / 5.0 + ph[3])
        world_from_body = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], -1)).as_matrix()
        return se3.from_rt(world_from_body @ BODY_FROM_CAM_ROT, np.concatenate([xy, z[:, None]], -1))


@dataclasses.dataclass(frozen=True, eq=False)
class KeyframeMotion:
    """C2 interpolation of keyframe poses: positions by a cubic spline, orientations by a cubic
    spline of rotation vectors relative to the first keyframe (fine for rotations < pi from it).
    With one keyframe the camera stands still."""

    times_s: np.ndarray
    world_from_cam_keys: np.ndarray
    rate_hz: float
    name: str = "keyframes"

    def world_from_cam(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, np.float64))
        keys = np.asarray(self.world_from_cam_keys, np.float64)
        if len(keys) == 1:
            return np.broadcast_to(keys[0], (len(t), 4, 4)).copy()
        pos = CubicSpline(self.times_s, keys[:, :3, 3])(t)
        rel = se3.inverse(keys[0]) @ keys
        rv = Rotation.from_matrix(rel[:, :3, :3]).as_rotvec()
        rot = keys[0, :3, :3] @ Rotation.from_rotvec(CubicSpline(self.times_s, rv)(t)).as_matrix()
        return se3.from_rt(rot, pos)


def make_motion(scene: Scene, kind: str, rng: np.random.Generator, rate_hz: float | None = None,
                camera_ahead_m: float = 0.0):
    """The scripted camera motion ``kind`` ("car" or "drone") for ``scene``; ``camera_ahead_m``: the car's
    camera that far ahead of its rear axle (:attr:`sim.config.TrajectoryConfig.camera_ahead_m`)."""
    if kind == "car":
        return CarMotion.create(scene, rng, rate_hz or 10.0, camera_ahead_m)
    if camera_ahead_m:
        raise ValueError("camera_ahead_m is for the car trajectory")
    if kind == "drone":
        if "lane_path" in scene.layout:
            return StreetDroneMotion.create(scene, rng, rate_hz or 20.0)
        return DroneMotion.create(scene, rng, rate_hz or 20.0)
    raise ValueError(f"unknown trajectory kind {kind!r}")


__all__ = ["CarMotion", "DroneMotion", "StreetDroneMotion", "KeyframeMotion", "make_motion", "cam_from_forward",
           "smoothstep5"]
