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
- :class:`HandheldMotion`: a hand-held camera carried round the room's table at a walking pace (top speed
  0.35-0.55 m/s, slower at places; 1.2-1.6 m up, in the drone's free ring), aimed at the table with the hand's sway (pan, tilt and roll
  of a few degrees at 0.3-1.2 Hz); 30 Hz, a Kinect's rate; the walk is a closed loop, so it revisits. Made
  for the RGB-D rows: TUM RGB-D's hand-held sequences move a few centimetres a frame against the drone's
  3-7 at 30 Hz, and turn about a radian per metre (fr3/teddy: 12 mm and 0.87 degrees a frame at the median,
  0.83 m of path per radian of rotation; the drone in the room 29 mm, 0.81 degrees, 1.9 m).
- :class:`KeyframeMotion`: C2 interpolation of given poses (tests, custom paths).
- :class:`BodyMotion`: the car body's pitch and roll on its suspension, added to :class:`CarMotion`'s camera
  (``render --body-motion``).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.scenes.geometry import PeriodicPath
from deepslam.scenes.spec import PathProgress, Scene, StopGoProgress, smoothstep5, speed_profile

CAR_MAX_SPEED_MPS = 15.0
DRONE_MAX_SPEED_MPS = 1.6
DRONE_MAX_RATE_RAD_S = 0.95
HANDHELD_SPEED_MPS = (0.35, 0.55)
"""Range of :class:`HandheldMotion`'s top walking speed, m/s (its loop's fastest point; the pace varies along
the loop, about half of it at the slowest point)."""
HANDHELD_HEIGHT_M = (1.2, 1.6)
"""Range of the hand-held camera's height above the floor, metres."""
HANDHELD_TARGET_Z_M = 0.9
"""Height of the point on the room's table the camera is aimed at, metres (the table top is at 0.75 m,
boxes stand on it)."""
HANDHELD_SWAY_RAD = (0.10, 0.09, 0.05)
"""Amplitude of each of the hand's pan, tilt and roll sinusoids about the aim, radians (three per angle)."""
HANDHELD_SWAY_HZ = (0.3, 1.2)
"""Frequency range of the hand's sway, Hz."""


def cam_from_forward(forward: np.ndarray, up: np.ndarray = np.array([0, 0, 1.0])) -> np.ndarray:
    """(…, 3, 3) world_from_cam rotation (OpenCV axes) looking along ``forward`` with no roll."""
    f = forward / np.linalg.norm(forward, axis=-1, keepdims=True)
    right = np.cross(f, up)
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    down = np.cross(f, right)
    return np.stack([right, down, f], axis=-1)


# body (x forward, y left, z up) -> camera (x right, y down, z forward)
BODY_FROM_CAM_ROT = np.array([[0, 0, 1.0], [-1.0, 0, 0], [0, -1.0, 0]])


KITTI_BODY_RATE_RMS_RAD = (np.radians(0.17), np.radians(0.15))
"""Frame-to-frame pitch and roll of KITTI 00-10's ground truth at 10 Hz, RMS, radians (00-05 and 08-10: 0.177 and
0.154 degrees; 06 and 07: 0.134 and 0.112). Their power lies mostly at 1-2 Hz (pitch) and 0-3 Hz (roll), and the
steps of successive frames correlate (+0.6): a body swaying on its springs, not noise of the ground truth."""
BODY_TERMS = 4
"""Sinusoids summed per angle in :class:`BodyMotion`."""
BODY_BANDS_HZ = ((1.0, 2.0), (0.3, 2.5))
"""Frequency ranges the pitch and roll sinusoids are drawn from, Hz (KITTI's power, see above)."""
KITTI_RATE_HZ = 10.0
BODY_CALIBRATION_S = 60.0
"""Span over which :meth:`BodyMotion.create` sets the frame-to-frame RMS, seconds (a minute of driving)."""


@dataclasses.dataclass(frozen=True, eq=False)
class BodyMotion:
    """Pitch and roll of a car body on its suspension: per angle a sum of :data:`BODY_TERMS` sinusoids,
    ``sum_k a_k sin(2 pi f_k t + phi_k)``, frequencies and phases drawn from a seed and the amplitudes scaled so
    that the frame-to-frame change at KITTI's 10 Hz has ``scale`` x :data:`KITTI_BODY_RATE_RMS_RAD` RMS. The
    camera turns with the body about its own centre (the few millimetres a pivot at the axles would move it
    are left out)."""

    terms: np.ndarray
    """(2, K, 3) float64 per angle (pitch about the camera's x axis, nose down positive; roll about its z axis)
    and sinusoid: amplitude (rad), frequency (Hz), phase (rad)."""

    @staticmethod
    def create(rng: np.random.Generator, scale: float) -> "BodyMotion":
        """Frequencies ``rng.uniform``, one in each of :data:`BODY_TERMS` equal parts of :data:`BODY_BANDS_HZ`
        (no two nearly alike), phases ``rng.uniform(0, 2 pi)``, relative amplitudes ``rng.uniform(0.5, 1)``, then
        scaled so that the frame-to-frame change over the first :data:`BODY_CALIBRATION_S` seconds at 10 Hz has the
        target RMS (measured on the sum itself: two sinusoids of nearly one frequency add or cancel by their
        phases)."""
        t = np.arange(0.0, BODY_CALIBRATION_S, 1.0 / KITTI_RATE_HZ)
        terms = np.zeros((2, BODY_TERMS, 3))
        for i, (lo, hi) in enumerate(BODY_BANDS_HZ):
            terms[i, :, 1] = lo + (hi - lo) * (np.arange(BODY_TERMS) + rng.uniform(0.0, 1.0, BODY_TERMS)) / BODY_TERMS
            terms[i, :, 2] = rng.uniform(0.0, 2 * np.pi, BODY_TERMS)
            terms[i, :, 0] = rng.uniform(0.5, 1.0, BODY_TERMS)
        steps = np.diff(np.stack(BodyMotion(terms).angles(t)), axis=1)
        rms = np.sqrt(np.mean(steps ** 2, axis=1))
        terms[:, :, 0] *= (scale * np.asarray(KITTI_BODY_RATE_RMS_RAD) / rms)[:, None]
        return BodyMotion(terms)

    def angles(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(pitch, roll): (N,) float64 radians at times ``t`` (N,) seconds."""
        a, f, ph = self.terms[..., 0], self.terms[..., 1], self.terms[..., 2]
        x = np.sin(2 * np.pi * f[:, None, :] * np.asarray(t, np.float64)[None, :, None] + ph[:, None, :])
        out = np.sum(a[:, None, :] * x, axis=-1)
        return out[0], out[1]

    def rotation(self, t: np.ndarray) -> np.ndarray:
        """(N, 3, 3) ``cam_road_from_cam``: the camera's attitude against the road's, Rx(-pitch) Rz(roll) (nose down
        for a positive pitch, as :attr:`CarMotion.pitch_rad`)."""
        pitch, roll = self.angles(t)
        return Rotation.from_euler("XZ", np.stack([-pitch, roll], axis=-1)).as_matrix()


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
    body: BodyMotion | None = None
    """The body's pitch and roll on its suspension (None: the camera keeps the road's attitude)."""

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
        if self.body is not None:
            rot = rot @ self.body.rotation(np.atleast_1d(np.asarray(t, np.float64)))
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


def _sinusoids(terms: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Sum of ``a sin(2 pi k u + phase)`` over the rows ``(a, k, phase)`` of ``terms`` (K, 3), at ``u`` (N,)."""
    return sum(a * np.sin(2 * np.pi * k * u + ph) for a, k, ph in terms)


@dataclasses.dataclass(frozen=True, eq=False)
class RingLoop:
    """A closed loop round the room's vertical axis, in its free ring: over one loop u in [0, 1) the position is at
    radius ``r_spline(u)`` from ``centre``, angle ``2 pi u + th_spline(u)`` and height ``z_spline(u)`` (periodic
    splines); time maps to u through a start-from-rest warp of ``ramp_s`` seconds (a field of each subclass) and
    the loop period. What :class:`DroneMotion` and :class:`HandheldMotion` share; each gives its own orientation
    in ``pose_u``."""

    centre: np.ndarray
    r_spline: CubicSpline
    th_spline: CubicSpline
    z_spline: CubicSpline
    period_s: float
    rate_hz: float

    def position_u(self, u: np.ndarray) -> np.ndarray:
        """(N, 3) world position, metres, at loop parameters u (N,) (any real; period 1)."""
        uf = np.mod(u, 1.0)
        th = 2 * np.pi * u + self.th_spline(uf)
        r = self.r_spline(uf)
        return np.stack([self.centre[0] + r * np.cos(th), self.centre[1] + r * np.sin(th), self.z_spline(uf)], -1)

    def pose_u(self, u) -> np.ndarray:
        raise NotImplementedError

    def world_from_cam(self, t) -> np.ndarray:
        return self.pose_u(_time_warp(np.atleast_1d(t), self.ramp_s) / self.period_s)


@dataclasses.dataclass(frozen=True, eq=False)
class DroneMotion(RingLoop):
    """A 6DoF flight (see module docstring); ``pose_u(u)`` gives world_from_cam over one loop."""

    yaw_terms: np.ndarray
    pitch_terms: np.ndarray
    roll_terms: np.ndarray
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
        m = DroneMotion(np.asarray(lay["centre"], np.float64), r_spl, th_spl, z_spl, 1.0, rate_hz,
                        yaw_terms=yaw, pitch_terms=pitch, roll_terms=roll, yaw0=yaw0)
        # time scaling: the fastest point of the loop meets the speed and rotation-rate limits
        du = 1e-4
        p0 = m.pose_u(uu)
        p1 = m.pose_u(uu + du)
        v_u = np.linalg.norm(p1[:, :3, 3] - p0[:, :3, 3], axis=1) / du
        w_u = se3.rotation_angle(se3.relative(p0, p1)) / du
        period = max(v_u.max() / DRONE_MAX_SPEED_MPS, w_u.max() / DRONE_MAX_RATE_RAD_S, 5.0)
        return dataclasses.replace(m, period_s=float(period))

    def pose_u(self, u) -> np.ndarray:
        """world_from_cam (N, 4, 4) at loop parameters u (any real; period 1)."""
        u = np.atleast_1d(np.asarray(u, np.float64))
        yaw = self.yaw0 + _sinusoids(self.yaw_terms, u)
        pitch = 0.05 + _sinusoids(self.pitch_terms, u)
        roll = _sinusoids(self.roll_terms, u)
        world_from_body = Rotation.from_euler("ZYX", np.stack([yaw, pitch, roll], -1)).as_matrix()
        return se3.from_rt(world_from_body @ BODY_FROM_CAM_ROT, self.position_u(u))


@dataclasses.dataclass(frozen=True, eq=False)
class HandheldMotion(RingLoop):
    """A hand-held camera walked round the room's table (see module docstring): the :class:`RingLoop` one way
    round, the pace varying, its period set so that the walk's fastest point is at :attr:`max_speed_mps`. The aim:
    the optical axis from the camera to ``target`` with no roll, then the hand's sway applied in the camera's own
    axes (pan about y, tilt about x, roll about z; OpenCV axes), each a sum of sinusoids of u with integer
    frequencies (so the loop stays closed and the walk revisits every place with the same view)."""

    target: np.ndarray
    """(3,) world point the optical axis is aimed at, metres."""
    sway_terms: np.ndarray
    """(3, K, 3) the hand's pan, tilt and roll: K sinusoids ``(a rad, k cycles per loop, phase)`` each."""
    max_speed_mps: float
    """The walk's top speed, m/s (its loop's fastest point)."""
    ramp_s: float = 0.5
    """Seconds from rest to the walking pace (a person sets off in half a second; the drone takes 2)."""
    name: str = "handheld"

    @staticmethod
    def create(scene: Scene, rng: np.random.Generator, rate_hz: float = 30.0) -> "HandheldMotion":
        lay = scene.layout
        n = 6
        u = np.arange(n) / n
        lo, hi = lay["radius_m"]
        zlo, zhi = (max(HANDHELD_HEIGHT_M[0], lay["height_m"][0]), min(HANDHELD_HEIGHT_M[1], lay["height_m"][1]))
        # knots inside the ring's middle so that the splines' overshoot stays inside the ring
        r_spl = _periodic_spline(u, rng.uniform(lo + 0.15, hi - 0.15, n))
        z_spl = _periodic_spline(u, rng.uniform(zlo + 0.05, zhi - 0.05, n))
        th_spl = _periodic_spline(u, rng.uniform(-0.35, 0.35, n) * (2 * np.pi / n))  # the pace varies
        speed = float(rng.uniform(*HANDHELD_SPEED_MPS))
        centre = np.asarray(lay["centre"], np.float64)
        target = np.array([centre[0], centre[1], HANDHELD_TARGET_Z_M])
        uu = np.linspace(0, 1, 4000, endpoint=False)
        length_per_loop = 2 * np.pi * float(np.mean(r_spl(uu)))
        # sway frequencies in cycles per loop, drawn so that at the walk's pace they fall in HANDHELD_SWAY_HZ
        loop_s = length_per_loop / speed
        k = np.maximum(1, np.round(rng.uniform(*HANDHELD_SWAY_HZ, (3, 3)) * loop_s))
        amp = np.asarray(HANDHELD_SWAY_RAD)[:, None] * rng.uniform(0.5, 1.0, (3, 3))
        sway = np.stack([amp, k, rng.uniform(0, 2 * np.pi, (3, 3))], axis=-1)  # (angle, term, [a, k, phase])
        m = HandheldMotion(centre, r_spl, th_spl, z_spl, 1.0, rate_hz, target=target, sway_terms=sway,
                           max_speed_mps=speed)
        du = 1e-4
        v_u = np.linalg.norm(m.position_u(uu + du) - m.position_u(uu), axis=1) / du
        return dataclasses.replace(m, period_s=float(v_u.max() / speed))

    def pose_u(self, u) -> np.ndarray:
        """world_from_cam (N, 4, 4) at loop parameters u (any real; period 1)."""
        u = np.atleast_1d(np.asarray(u, np.float64))
        pos = self.position_u(u)
        aim = cam_from_forward(self.target - pos)
        pan, tilt, roll = (_sinusoids(terms, u) for terms in self.sway_terms)
        cam_from_swayed = Rotation.from_euler("YXZ", np.stack([pan, tilt, roll], -1)).as_matrix()
        return se3.from_rt(aim @ cam_from_swayed, pos)


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
                camera_ahead_m: float = 0.0, body_motion: float = 0.0, body_rng: np.random.Generator | None = None):
    """The scripted camera motion ``kind`` ("car", "drone" or "handheld") for ``scene``; ``camera_ahead_m``: the car's
    camera that far ahead of its rear axle (:attr:`sim.config.TrajectoryConfig.camera_ahead_m`); ``body_motion``:
    the car body's pitch and roll, a multiple of KITTI's (:class:`BodyMotion`, drawn from ``body_rng``, a
    generator of its own so that the rest of the motion is the same with and without it)."""
    if kind == "car":
        car = CarMotion.create(scene, rng, rate_hz or 10.0, camera_ahead_m)
        if body_motion:
            car = dataclasses.replace(car, body=BodyMotion.create(body_rng, body_motion))
        return car
    if camera_ahead_m:
        raise ValueError("camera_ahead_m is for the car trajectory")
    if body_motion:
        raise ValueError("body_motion is for the car trajectory")
    if kind == "drone":
        if "lane_path" in scene.layout:
            return StreetDroneMotion.create(scene, rng, rate_hz or 20.0)
        return DroneMotion.create(scene, rng, rate_hz or 20.0)
    if kind == "handheld":
        if "radius_m" not in scene.layout:
            raise InputError(None, "the handheld trajectory walks round the room's table: use --scene room")
        return HandheldMotion.create(scene, rng, rate_hz or 30.0)
    raise ValueError(f"unknown trajectory kind {kind!r}")


__all__ = ["BodyMotion", "CarMotion", "DroneMotion", "HandheldMotion", "RingLoop", "StreetDroneMotion", "KeyframeMotion",
           "make_motion", "cam_from_forward",
           "smoothstep5"]
