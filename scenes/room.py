"""``room``: a EuRoC-like hall (8.5-10 m square, 3.4-4 m high): textured walls with posters, boards
and cables, a marked floor, shelving units full of labelled boxes along the walls, crates in the
corners, floor mats, and a table in the middle with a pole carrying two flags.

Free space for the ``drone`` trajectory: a ring around the room's vertical axis at radius
1.5-2.2 m and height 0.9-2.0 m. Flying boxes (``moving_objects``) orbit in a farther ring (radius
about 3.1 m), so neither the drone nor the boxes ever come closer than about 0.4 m to anything.
"""
from __future__ import annotations

import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.scenes import textures as tx
from deepslam.scenes.assemble import Assembler, flag_painter
from deepslam.scenes.lighting import Lighting
from deepslam.scenes.spec import RIGID, FlagDeform, Orbiter, Scene

EUROC_CAMERA = PinholeCamera(752, 480, 458.0, 458.0, 375.5, 239.5)
"""EuRoC-like default: 752x480, f = 458 px (square pixels), principal point at the centre."""
EUROC_BASELINE_M = 0.11


def _sides(p, top=True, bottom=False):
    f = {"+x": p, "-x": p, "+y": p, "-y": p}
    if top:
        f["+z"] = p
    if bottom:
        f["-z"] = p
    return f


def build_room(seed: int, px_per_m: float, moving_objects: int, deform_amplitude_m: float,
               rng: np.random.Generator, lighting: Lighting | None = None) -> Scene:
    lx, ly = float(rng.uniform(8.5, 10.0)), float(rng.uniform(8.5, 10.0))
    hh = float(rng.uniform(3.4, 4.0))
    light = lighting or Lighting((0.3, 0.2, 1.0), 0.7, (1.0, 1.0, 1.0))
    asm = Assembler(px_per_m, rng, sun_dir=light.sun_dir, ambient=light.ambient)
    hx, hy = lx / 2, ly / 2

    asm.box((0, 0, -0.1), (hx, hy, 0.1), {"+z": tx.floor_mat})
    asm.box((0, 0, hh + 0.1), (hx, hy, 0.1), {"-z": tx.panels((200, 200, 195))}, densities={"-z": 0.4})
    t = 0.15
    for centre, half, face in (((-hx - t, 0, hh / 2), (t, hy + 2 * t, hh / 2), "+x"), ((hx + t, 0, hh / 2), (t, hy + 2 * t, hh / 2), "-x"),
                               ((0, -hy - t, hh / 2), (hx, t, hh / 2), "+y"), ((0, hy + t, hh / 2), (hx, t, hh / 2), "-y")):
        asm.box(centre, half, {face: tx.indoor_wall(rng.spawn(1)[0])})

    # shelving units along each wall (yaw so that the unit's +x faces into the room)
    for wall in range(4):
        yaw = [0.0, np.pi, np.pi / 2, -np.pi / 2][wall]
        length = ly if wall < 2 else lx
        a = -length / 2 + float(rng.uniform(1.3, 1.8))
        while a < length / 2 - 1.3 - 1.2:
            w = float(rng.uniform(1.2, 2.0))
            if a + w > length / 2 - 1.3:
                break
            if rng.random() < 0.8:
                _shelf(asm, wall, a + w / 2, w, hx, hy, yaw, rng)
            a += w + float(rng.uniform(0.2, 1.5))
    # crates in the corners
    for sx in (-1, 1):
        for sy in (-1, 1):
            z_top = 0.0
            cx, cy = sx * (hx - 0.65), sy * (hy - 0.65)
            for k in range(int(rng.integers(1, 4))):
                s = rng.uniform(0.2, 0.4, 3) * [1, 1, 0.8]
                asm.box((cx, cy, z_top + s[2]), s, _sides(tx.cardboard), yaw=float(rng.uniform(0, np.pi / 2)))
                z_top += 2 * s[2]
    # floor mats (thin), never under the table
    for _ in range(int(rng.integers(3, 7))):
        r, th = rng.uniform(1.2, 3.0), rng.uniform(0, 2 * np.pi)
        s = rng.uniform(0.3, 0.8, 2)

        def mat(h, w, ppm, g):
            return np.clip(tx.poster(h, w, g), 0, 255).astype(np.uint8)
        asm.box((r * np.cos(th), r * np.sin(th), 0.003), (s[0], s[1], 0.003), {"+z": mat}, yaw=float(rng.uniform(0, np.pi)))
    # table in the middle with boxes on it
    asm.box((0, 0, 0.735), (0.5, 0.35, 0.015), _sides(tx.wood, bottom=True))
    for lx_, ly_ in ((-0.45, -0.3), (-0.45, 0.3), (0.45, -0.3), (0.45, 0.3)):
        asm.box((lx_, ly_, 0.36), (0.025, 0.025, 0.36), _sides(tx.metal(), top=False))
    for _ in range(int(rng.integers(2, 5))):
        s = rng.uniform(0.05, 0.14, 3)
        px, py = rng.uniform(-0.5 + s.max(), 0.5 - s.max()), rng.uniform(-0.35 + s.max(), 0.35 - s.max())
        if abs(px) < 0.1 + s.max() and abs(py) < 0.1 + s.max():
            continue  # keep the pole free
        asm.box((px, py, 0.75 + s[2]), s, _sides(tx.cardboard), yaw=float(rng.uniform(0, np.pi)))
    asm.box((0, 0, 1.25), (0.03, 0.03, 1.25), _sides(tx.metal((180, 180, 185))))
    for k, (direction, z0) in enumerate((((1.0, 0.0), 1.75), ((-0.6, 0.8), 1.05))):
        x_b = np.array([direction[0], direction[1], 0.0])
        x_b /= np.linalg.norm(x_b)
        z_b = np.array([0, 0, 1.0])
        world_from_flag = np.eye(4)
        world_from_flag[:3, :3] = np.stack([x_b, np.cross(z_b, x_b), z_b], axis=1)
        world_from_flag[:3, 3] = (0.03 * x_b[0], 0.03 * x_b[1], z0)
        deform = FlagDeform(nx=25, nz=13, length_m=0.9, height_m=0.6, amplitude_m=float(deform_amplitude_m),
                            wavelength_m=float(rng.uniform(0.6, 1.2)), freq_hz=float(rng.uniform(0.6, 1.2)),
                            phase=float(rng.uniform(0, 2 * np.pi)), tilt_rad_per_m=float(rng.uniform(0.5, 1.5)))
        asm.flag(f"flag{k}", world_from_flag, deform, flag_painter(rng.spawn(1)[0]), dynamic=deform_amplitude_m > 0)

    # flying boxes
    for k in range(moving_objects):
        half = rng.uniform(0.12, 0.25, 3)
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        rot0 = se3.from_quat_wxyz(q, np.zeros(3))[:3, :3]
        motion = Orbiter(centre=np.zeros(2), r0=3.1, r_amp=0.1, th0=float(2 * np.pi * k / max(1, moving_objects) + rng.uniform(0, 0.5)),
                         th_amp=float(rng.uniform(0.3, 0.8)), z0=float(rng.uniform(1.0, 2.2)), z_amp=float(rng.uniform(0.2, 0.5)),
                         freq_hz=rng.uniform(0.05, 0.25, 3), phase=rng.uniform(0, 2 * np.pi, 3), rot0=rot0,
                         spin_rad_s=rng.uniform(-1.0, 1.0, 2))
        b = asm.dynamic_builder(f"box{k}", RIGID, motion)
        asm.box((0, 0, 0), half, _sides(tx.cardboard, bottom=True), builder=b, densities={f: 2.0 for f in ("+x", "-x", "+y", "-y", "+z", "-z")})

    atlas, bodies = asm.finish()
    bounds = np.array([[-hx - 2 * t, -hy - 2 * t, -0.2], [hx + 2 * t, hy + 2 * t, hh + 0.2]])
    return Scene(
        name="room", seed=seed, atlas=atlas, bodies=bodies, camera=EUROC_CAMERA, stereo_baseline_m=EUROC_BASELINE_M,
        rate_hz=20.0, znear_m=0.1, zfar_m=float(np.linalg.norm(bounds[1] - bounds[0]) + 2.0), sky_rgb=(0, 0, 0), bounds=bounds,
        layout={"centre": np.zeros(2), "radius_m": (1.5, 2.2), "height_m": (0.9, 2.0), "size_m": (lx, ly, hh),
                "mover_clearance_m": 0.4, "mover_mover_clearance_m": 0.0},
    )


def _shelf(asm: Assembler, wall: int, a: float, w: float, hx: float, hy: float, yaw: float, rng) -> None:
    """A shelving unit of width w centred at position a along the wall, 0.45 m deep, with boxes."""
    depth, height = 0.45, float(rng.uniform(1.8, 2.2))
    # unit frame: u along the wall, d into the room
    if wall == 0:
        origin, u, d = np.array([-hx, a]), np.array([0, 1.0]), np.array([1.0, 0])
    elif wall == 1:
        origin, u, d = np.array([hx, a]), np.array([0, -1.0]), np.array([-1.0, 0])
    elif wall == 2:
        origin, u, d = np.array([a, -hy]), np.array([1.0, 0]), np.array([0, 1.0])
    else:
        origin, u, d = np.array([a, hy]), np.array([-1.0, 0]), np.array([0, -1.0])

    def at(du, dd, z):
        p = origin + u * du + d * dd
        return (p[0], p[1], z)

    wood = tx.wood
    for s in (-1, 1):  # side boards
        asm.box(at(s * (w / 2 - 0.015), depth / 2 + 0.01, height / 2), (depth / 2, 0.015, height / 2), _sides(wood), yaw=yaw)
    n_planks = int(rng.integers(4, 6))
    for k in range(n_planks):
        z = 0.08 + k * (height - 0.1) / (n_planks - 1)
        asm.box(at(0, depth / 2 + 0.01, z), (depth / 2, w / 2 - 0.03, 0.015), _sides(wood, bottom=True), yaw=yaw)
        if k == n_planks - 1:
            continue
        gap = (height - 0.1) / (n_planks - 1) - 0.05
        x = -w / 2 + 0.05
        while x < w / 2 - 0.1:
            bw = float(rng.uniform(0.08, 0.35))
            if x + bw > w / 2 - 0.04:
                break
            bh = float(rng.uniform(0.08, max(0.1, gap * 0.9)))
            bd = float(rng.uniform(0.15, depth - 0.05))
            if rng.random() < 0.85:
                asm.box(at(x + bw / 2, 0.02 + bd / 2 + rng.uniform(0, depth - bd - 0.03), z + 0.015 + bh / 2),
                        (bd / 2, bw / 2, bh / 2), _sides(tx.cardboard), yaw=yaw + float(rng.normal(0, 0.05)),
                        densities={f: 1.5 for f in ("+x", "-x", "+y", "-y", "+z")})
            x += bw + float(rng.uniform(0.01, 0.08))
