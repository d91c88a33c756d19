"""Backend-neutral scene description: bodies with textured meshes, their motions and deformations.

A :class:`Scene` is what a builder (``scenes.street``, ``scenes.room``) returns and what both render
backends (``sim``: MuJoCo and pyrender) consume. World frame: metres, z up. Every body has a pose
``world_from_body(t)`` (4x4 float64, a function of time in seconds, vectorised over times); a
deforming body additionally moves its vertices in its own frame (:class:`FlagDeform`).
"""
from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import gaussian_filter1d

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.scenes.geometry import MeshData, PeriodicPath

STATIC, RIGID, DEFORM = "static", "rigid", "deform"


def smoothstep5(x: np.ndarray) -> np.ndarray:
    """Quintic smoothstep: 0 for x <= 0, 1 for x >= 1, C2 everywhere."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


def smoothstep5_d(x: np.ndarray) -> np.ndarray:
    inside = (x > 0.0) & (x < 1.0)
    return np.where(inside, 30.0 * x * x * (x - 1.0) ** 2, 0.0)


# ----------------------------------------------------------------------------------------------
# motions: world_from_body(t) for times (N,) -> (N, 4, 4)
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class StaticPose:
    """A body that never moves."""

    world_from_body_fixed: np.ndarray
    """(4, 4) float64."""

    def world_from_body(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, np.float64))
        return np.broadcast_to(self.world_from_body_fixed, (len(t), 4, 4)).copy()


class PathProgress:
    """Progress ``c(t)`` along a :class:`PeriodicPath` (chord parameter, metres) for a speed profile.

    The motion solves ``dc/dt = ramp(t) * v(c) / |p'(c)|`` exactly, so the true speed is
    ``ramp(t) * v(c)`` (m/s), ``v`` a periodic speed profile ``speed_mps(c)``. Without the ramp the
    motion is periodic in time: ``tau(c) = integral |p'| / v dc`` is integrated once per lap (on a
    periodic cubic spline, analytically) and inverted by a dense C2 spline. The ramp (``ramp_s`` > 0:
    start from standstill with a quintic, C2 speed ramp) enters as a time warp
    ``c(t) = c_steady(tau(t))`` with ``tau(t) = integral_0^t ramp``. Vectorised, any horizon, no ODE.
    """

    def __init__(self, path: PeriodicPath, speed_mps: CubicSpline, c0: float, ramp_s: float = 0.0,
                 step_m: float = 0.05):
        self.path = path
        self.speed = speed_mps
        self.ramp_s = float(ramp_s)
        L = path.length
        n = max(64, int(np.ceil(L / step_m)))
        c = np.linspace(0.0, L, n + 1)
        g = np.linalg.norm(path.derivative(c), axis=-1) / speed_mps(np.mod(c, L))
        g[-1] = g[0]
        big_g = CubicSpline(c, g, bc_type="periodic").antiderivative()
        tau = big_g(c) - big_g(0.0)
        self.period_s = float(tau[-1])
        # inverse c(tau) on one lap, extended by a margin on both sides for smooth wrapping
        m = n // 10 + 4
        tau_ext = np.concatenate([tau[-m - 1:-1] - self.period_s, tau, tau[1:m + 1] + self.period_s])
        c_ext = np.concatenate([c[-m - 1:-1] - L, c, c[1:m + 1] + L])
        self._c_of_tau = CubicSpline(tau_ext, c_ext)
        self._tau0 = float(big_g(np.mod(c0, L)) - big_g(0.0))
        self._c0_lap = float(c0 - np.mod(c0, L))

    def warp(self, t) -> np.ndarray:
        """Warped time ``tau(t) = integral_0^t ramp(t') dt'`` (seconds)."""
        t = np.asarray(t, np.float64)
        if self.ramp_s <= 0:
            return t
        x = np.clip(t / self.ramp_s, 0.0, 1.0)
        s_int = x ** 6 - 3 * x ** 5 + 2.5 * x ** 4  # integral of smoothstep5 from 0 to x
        return np.where(t < self.ramp_s, self.ramp_s * s_int, self.ramp_s * 0.5 + (t - self.ramp_s))

    def c(self, t) -> np.ndarray:
        """Path parameter (metres, growing without bound: take it modulo ``path.length``) at times t."""
        tau = np.atleast_1d(self.warp(t)) + self._tau0
        lap = np.floor(tau / self.period_s)
        return self._c_of_tau(tau - lap * self.period_s) + lap * self.path.length + self._c0_lap

    def speed_at(self, t) -> np.ndarray:
        """True speed (m/s) at times t."""
        t = np.atleast_1d(np.asarray(t, np.float64))
        ramp = smoothstep5(t / self.ramp_s) if self.ramp_s > 0 else np.ones_like(t)
        return ramp * self.speed(np.mod(self.c(t), self.path.length))


class StopGoProgress:
    """Stop-and-go progress ``c(t)`` along a :class:`PeriodicPath` (chord parameter, metres).

    One lap of the path starts standing at ``stops_c[0]`` and ends standing there again; on the way the
    vehicle stops for ``dwell_s[k]`` at each other ``stops_c[k]``. Between stops it drives as fast as
    ``limit_mps(c)`` (m/s, per path position: speed limits of the stretches), the bends
    (``sqrt(lat_accel / curvature)``) and its acceleration ``accel_mps2`` / braking ``decel_mps2``
    allow. The speed over time is then Gaussian-smoothed over ``smooth_s`` seconds (circularly over
    the lap, which keeps the lap's length), so acceleration is continuous (C2 motion), and ``c(t)``
    is a cubic spline of its integral. Laps repeat: ``c(t + period_s) = c(t) + path.length``. Defined
    for any t >= 0; deterministic (no randomness inside).
    """

    def __init__(self, path: PeriodicPath, limit_mps, stops_c, dwell_s, accel_mps2: float = 3.0,
                 decel_mps2: float = 4.0, lat_accel_mps2: float = 3.0, smooth_s: float = 0.6, step_m: float = 0.25,
                 dt_s: float = 0.02):
        self.path = path
        L = path.length
        c_start = float(np.mod(stops_c[0], L))
        n = max(64, int(np.ceil(L / step_m)))
        c = c_start + np.arange(n + 1) * (L / n)                      # one lap from the first stop
        ds = np.linalg.norm(path.derivative(c), axis=-1) * (L / n)    # metres per step
        kappa = np.abs(path.curvature(c))
        v = np.minimum(np.asarray(limit_mps(np.mod(c, L)), np.float64), np.sqrt(lat_accel_mps2 / np.maximum(kappa, 1e-9)))
        at = [int(round(np.mod(s - c_start, L) / (L / n))) for s in stops_c[1:]]   # grid index of each other stop
        v[[0, n, *at]] = 0.0
        for i in range(1, n + 1):                                     # accelerate ...
            v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * accel_mps2 * ds[i - 1]))
        for i in range(n - 1, -1, -1):                                # ... and brake in time
            v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * decel_mps2 * ds[i]))
        # time at each step (constant acceleration between samples), the dwell at each stop
        dt = 2.0 * ds[:-1] / np.maximum(v[:-1] + v[1:], 1e-6)
        dwell = dict(zip(at, dwell_s[1:]))
        t_knots, c_knots, t = [0.0], [c[0]], 0.0
        for i in range(n):
            t += dt[i]
            t_knots.append(t)
            c_knots.append(c[i + 1])
            if i + 1 in dwell:
                t += float(dwell[i + 1])
                t_knots.append(t)
                c_knots.append(c[i + 1])
        t += float(dwell_s[0])
        t_knots.append(t)
        c_knots.append(c[-1])
        period = t
        m = int(np.ceil(period / dt_s))
        grid = np.arange(m + 1) * (period / m)
        c_grid = np.interp(grid, t_knots, c_knots)
        rate = np.diff(c_grid)                                        # chord metres per time step
        rate = gaussian_filter1d(rate, smooth_s / (period / m), mode="wrap")
        c_grid = c_start + np.concatenate([[0.0], np.cumsum(rate)])
        c_grid[-1] = c_start + L
        self.period_s = float(period)
        # periodic part c(t) - L t / T as a periodic spline: c is C2 across laps
        resid = c_grid - c_start - L * grid / period
        resid[-1] = resid[0]
        self._resid = CubicSpline(grid, resid, bc_type="periodic")
        self._c_start = c_start

    def c(self, t) -> np.ndarray:
        """Path parameter (metres, growing without bound: take it modulo ``path.length``) at times t."""
        t = np.atleast_1d(np.asarray(t, np.float64))
        return self._c_start + self.path.length * t / self.period_s + self._resid(np.mod(t, self.period_s))

    def speed_at(self, t) -> np.ndarray:
        """True speed (m/s) at times t."""
        t = np.atleast_1d(np.asarray(t, np.float64))
        dc = self.path.length / self.period_s + self._resid(np.mod(t, self.period_s), 1)
        return dc * np.linalg.norm(self.path.derivative(self.c(t)), axis=-1)


class LeadProgress:
    """A vehicle driving ahead of another in its lane: ``c(t) = leader.c(t + headway_s) + gap_m``
    on the leader's path, so it keeps a time gap while moving, stands ``gap_m`` ahead (centre to
    centre) when both stand, and stops and starts with the leader (whose stops it reaches first).

    Until :meth:`following` binds it to the camera's progress (the simulator does, once the camera's
    motion exists), ``fallback`` (a progress on the same path) leads it."""

    def __init__(self, fallback, headway_s: float, gap_m: float, leader=None):
        self.fallback = fallback
        self.leader = leader
        self.path = fallback.path
        self.headway_s = float(headway_s)
        self.gap_m = float(gap_m)

    def following(self, leader) -> "LeadProgress":
        """The same car ahead of ``leader`` (a progress on the same path: ``.path``, ``.c(t)``)."""
        return LeadProgress(self.fallback, self.headway_s, self.gap_m, leader)

    def c(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, np.float64))
        return (self.leader or self.fallback).c(t + self.headway_s) + self.gap_m


@dataclasses.dataclass(frozen=True, eq=False)
class PathFollower:
    """A vehicle on a closed path: position p(c(t)) at height ``z_m``, yaw along the tangent.

    The body frame has x forward, y left, z up (the body origin is on the path at ``z_m``).
    """

    progress: PathProgress
    z_m: float

    def world_from_body(self, t) -> np.ndarray:
        c = self.progress.c(t)
        xy = self.progress.path.position(c)
        yaw = self.progress.path.heading(c)
        out = se3.identity((len(c),))
        cs, sn = np.cos(yaw), np.sin(yaw)
        out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1] = cs, -sn, sn, cs
        out[:, :2, 3] = xy
        out[:, 2, 3] = self.z_m
        return out


@dataclasses.dataclass(frozen=True, eq=False)
class Orbiter:
    """A flying object around a vertical axis through ``centre``: radius, angle and height each
    oscillate sinusoidally, and the object spins about its z then y axis. C-infinity in t.

    position = centre + (r cos(th), r sin(th), z), with r = r0 + r_amp sin(2 pi f_r t + ph_r),
    th = th0 + th_amp sin(2 pi f_th t + ph_th), z = z0 + z_amp sin(2 pi f_z t + ph_z).
    """

    centre: np.ndarray
    """(2,) metres, the axis."""
    r0: float
    r_amp: float
    th0: float
    th_amp: float
    z0: float
    z_amp: float
    freq_hz: np.ndarray
    """(3,) f_r, f_th, f_z."""
    phase: np.ndarray
    """(3,) radians."""
    rot0: np.ndarray
    """(3, 3) orientation at t = 0."""
    spin_rad_s: np.ndarray
    """(2,) spin rates about the body z then y axis."""

    def world_from_body(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, np.float64))
        w = 2 * np.pi * np.asarray(self.freq_hz)[:, None] * t + np.asarray(self.phase)[:, None]
        r = self.r0 + self.r_amp * np.sin(w[0])
        th = self.th0 + self.th_amp * np.sin(w[1])
        z = self.z0 + self.z_amp * np.sin(w[2])
        pos = np.stack([self.centre[0] + r * np.cos(th), self.centre[1] + r * np.sin(th), z], axis=-1)
        az, ay = self.spin_rad_s[0] * t, self.spin_rad_s[1] * t
        rz = np.zeros((len(t), 3, 3))
        rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = np.cos(az), -np.sin(az), np.sin(az), np.cos(az), 1
        ry = np.zeros((len(t), 3, 3))
        ry[:, 0, 0], ry[:, 0, 2], ry[:, 2, 0], ry[:, 2, 2], ry[:, 1, 1] = np.cos(ay), np.sin(ay), -np.sin(ay), np.cos(ay), 1
        return se3.from_rt(self.rot0 @ rz @ ry, pos)


# ----------------------------------------------------------------------------------------------
# deformation
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class FlagDeform:
    """A waving flag: a grid of ``nx`` x ``nz`` vertices in its body frame, x in [0, length] (from
    the pole), z in [0, height], displaced only along body y:

        y(x, z, t) = amplitude * (x / length) * sin(2 pi (x / wavelength - freq * t) + phase + tilt * z)

    The rendered surface is the piecewise-linear mesh of :meth:`vertices_at`; because vertices move
    only along y, a surface point keeps its (x, z), which gives its triangle and barycentric
    coordinates exactly (:meth:`advance`).
    """

    nx: int
    nz: int
    length_m: float
    height_m: float
    amplitude_m: float
    wavelength_m: float
    freq_hz: float
    phase: float
    tilt_rad_per_m: float

    def grid_xz(self) -> tuple[np.ndarray, np.ndarray]:
        xs = np.linspace(0.0, self.length_m, self.nx)
        zs = np.linspace(0.0, self.height_m, self.nz)
        gx, gz = np.meshgrid(xs, zs, indexing="ij")
        return gx.ravel(), gz.ravel()

    def _y(self, x, z, t):
        return self.amplitude_m * (x / self.length_m) * np.sin(
            2 * np.pi * (x / self.wavelength_m - self.freq_hz * t) + self.phase + self.tilt_rad_per_m * z)

    def vertices_at(self, t: float) -> np.ndarray:
        """(nx*nz, 3) float64 vertex positions in the body frame at time t (vertex i*nz + j)."""
        gx, gz = self.grid_xz()
        return np.stack([gx, self._y(gx, gz, t), gz], axis=-1)

    def advance(self, p_body: np.ndarray, t0: float, t1: float) -> np.ndarray:
        """Move surface points (N, 3) (body frame, on the rendered mesh at time t0) to where the same
        material points are at t1: same triangle, same barycentric coordinates."""
        p = np.asarray(p_body, np.float64)
        dx = self.length_m / (self.nx - 1)
        dz = self.height_m / (self.nz - 1)
        fx = np.clip(p[:, 0] / dx, 0.0, self.nx - 1)
        fz = np.clip(p[:, 2] / dz, 0.0, self.nz - 1)
        i = np.minimum(np.floor(fx).astype(np.int64), self.nx - 2)
        j = np.minimum(np.floor(fz).astype(np.int64), self.nz - 2)
        a, b = fx - i, fz - j
        lower = a >= b  # triangle (v00, v10, v11), else (v00, v11, v01)
        v1 = self.vertices_at(t1)
        y00 = v1[i * self.nz + j, 1]
        y10 = v1[(i + 1) * self.nz + j, 1]
        y11 = v1[(i + 1) * self.nz + j + 1, 1]
        y01 = v1[i * self.nz + j + 1, 1]
        y_lower = (1 - a) * y00 + (a - b) * y10 + b * y11
        y_upper = (1 - b) * y00 + a * y11 + (b - a) * y01
        out = p.copy()
        out[:, 1] = np.where(lower, y_lower, y_upper)
        return out


# ----------------------------------------------------------------------------------------------
# bodies and scenes
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(eq=False)
class Body:
    """One renderable body.

    Attributes:
        name: unique name (MuJoCo body/mesh names derive from it).
        mesh: its textured mesh in the body frame (for a deforming body: the rest shape).
        kind: "static", "rigid" (moves as a whole) or "deform" (vertices move).
        instance_id: 0 for the static scene, else a unique id >= 1 (the mask value of its pixels).
        motion: object with ``world_from_body(t) -> (N, 4, 4)``.
        deform: the vertex animation of a deforming body, else None.
        double_sided: render both faces (flags).
    """

    name: str
    mesh: MeshData
    kind: str
    instance_id: int
    motion: Any
    deform: FlagDeform | None = None
    double_sided: bool = False

    @property
    def dynamic(self) -> bool:
        return self.kind != STATIC


@dataclasses.dataclass(eq=False)
class Scene:
    """A complete scene: atlas, bodies, default camera and what trajectories need to know.

    Attributes:
        name: "street", "room", or a test scene's name.
        seed: the seed it was built from.
        atlas: (H, W, 3) uint8 RGB texture atlas shared by every mesh (lighting is baked in).
        bodies: static bodies first, then movers and flags.
        camera: default camera (KITTI-like for street, EuRoC-like for room).
        stereo_baseline_m: default stereo baseline.
        rate_hz: default frame rate of the scene's trajectory.
        znear_m, zfar_m: clipping distances of the renderers (nothing is nearer than znear_m to the
            camera on the scene's trajectories; zfar_m beyond the farthest visible surface).
        sky_rgb: (3,) uint8 background colour where nothing is hit.
        bounds: (2, 3) world AABB of the scene, metres.
        layout: builder-specific data for trajectories (street: ``lane_path`` and the cruise speed
            range; room: ``centre``, radius and height ranges of the free space).
        config: the SceneConfig it was built from (or None).
    """

    name: str
    seed: int
    atlas: np.ndarray
    bodies: list[Body]
    camera: PinholeCamera
    stereo_baseline_m: float
    rate_hz: float
    znear_m: float
    zfar_m: float
    sky_rgb: tuple[int, int, int]
    bounds: np.ndarray
    layout: dict = dataclasses.field(default_factory=dict)
    config: Any = None

    def body(self, name: str) -> Body:
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(name)

    @property
    def dynamic_bodies(self) -> list[Body]:
        return [b for b in self.bodies if b.dynamic]

    def instance_ids(self) -> dict[str, int]:
        return {b.name: b.instance_id for b in self.bodies if b.instance_id}


def speed_profile(path: PeriodicPath, cruise_mps: float, lat_accel_mps2: float, long_accel_mps2: float,
                  min_mps: float = 1.0, smooth_m: float = 6.0) -> CubicSpline:
    """A periodic speed profile v(c) (m/s) along ``path``: at most ``cruise_mps``, at most
    ``sqrt(lat_accel / curvature)`` in bends, changing by at most ``long_accel`` (m/s^2) between,
    then Gaussian-smoothed over ``smooth_m`` metres so that acceleration is continuous."""
    L = path.length
    n = max(64, int(np.ceil(L / 0.5)))
    c = np.linspace(0.0, L, n, endpoint=False)
    dc = L / n
    kappa = np.abs(path.curvature(c))
    v = np.minimum(cruise_mps, np.sqrt(lat_accel_mps2 / np.maximum(kappa, 1e-9)))
    v = np.maximum(v, min_mps)
    for _ in range(2):  # cyclic forward/backward passes
        for i in range(n):
            v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * long_accel_mps2 * dc))
        for i in range(n - 1, -1, -1):
            v[i] = min(v[i], np.sqrt(v[(i + 1) % n] ** 2 + 2 * long_accel_mps2 * dc))
    v = gaussian_filter1d(v, smooth_m / dc, mode="wrap")
    return CubicSpline(np.append(c, L), np.append(v, v[0]), bc_type="periodic")
