"""``street``: a KITTI-like town: two blocks side by side inside a ring road, facades, parked cars,
lamp poles with signs, trees, bins, and flags on poles.

Layout (world frame, metres, z up; road surface at z = 0, sidewalks and blocks at z = 0.15):
road centrelines at x in {0, BX, 2 BX} and y in {0, BY} (BX in [56, 60], BY in [44, 46] from the
seed, so the road loop around a block is at least 200 m), roads 12 m wide (two 3.5 m lanes around the centreline, 2.5 m parking strips), 3.5 m
sidewalks, buildings from the sidewalk's back edge outwards, so every sightline along a road ends
at a facade (no visible surface farther than about 150 m).

The ego route (for the ``car`` trajectory, right-hand traffic, lane centre 1.75 m right of the
centreline) goes counter-clockwise around block A (a closed loop of about 215 m), then around both
blocks (about 360 m), and repeats: the bottom and left roads of block A are driven twice per lap
in the same direction (a revisited stretch), and the loop around block A closes after about 22 s.
Moving cars (``moving_objects``) drive the other way round in the opposite lane, and every third
drives ahead of the ego on its own route, a little faster; the simulator starts each where the
camera sees it (:func:`sim.world.separate_movers`). Flags hang over the sidewalks on the ego's right,
facing the traffic.
"""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from deepslam.core.camera import PinholeCamera
from deepslam.scenes import textures as tx
from deepslam.scenes.assemble import Assembler, flag_painter
from deepslam.scenes.geometry import MeshBuilder, PeriodicPath, offset_polyline
from deepslam.scenes.lighting import Lighting
from deepslam.scenes.spec import RIGID, FlagDeform, PathFollower, PathProgress, Scene, speed_profile

ROAD_HALF_M = 6.0
SIDEWALK_M = 3.5
LANE_OFFSET_M = 1.75
PARK_OFFSET_M = 4.75
KERB_M = 0.15
CAMERA_HEIGHT_M = 1.65
EGO_CORNER_RADIUS_M = 12.0
MOVER_CORNER_RADIUS_M = 6.0

@dataclasses.dataclass(frozen=True)
class StreetLayout:
    """What lines the road: how far back the facades stand and how densely cars, trees and poles
    crowd the kerb. The defaults are the original town's (wide pavements, every other parking bay
    taken); :meth:`varied` draws a KITTI-residential-like variant from a seed."""

    sidewalk_m: float = SIDEWALK_M
    """Pavement width between the road edge and the facades, metres."""
    park_offset_m: float = PARK_OFFSET_M
    """Distance of the parked cars' centres from the road's centreline, metres (>= 3.8 keeps them
    clear of the cars driving in the lanes)."""
    park_probability: float = 0.55
    """Chance that a parking bay holds a car."""
    park_gap_m: tuple[float, float] = (0.8, 6.0)
    """Range of the extra gap between parked cars, metres (plus the 4.4 m car)."""
    tree_offset_m: float = 1.3
    """Distance of the trees from the road edge, metres."""
    tree_probability: float = 0.7
    """Chance of a tree half-way between two poles."""
    pole_gap_m: tuple[float, float] = (18.0, 30.0)
    """Range of the distance between lamp poles (a tree or bin half-way), metres."""
    ego_lane_offset_m: float = LANE_OFFSET_M
    """Distance of the ego car's path right of the road's centreline, metres (1.75: the lane centre;
    less: nearer the middle of the street, as on KITTI's residential streets with cars parked on both
    sides)."""
    road_half_m: float = ROAD_HALF_M
    """Half the road's width, kerb to kerb, metres."""
    lane_offset_m: float = LANE_OFFSET_M
    """Distance of the moving cars' paths from the road's centreline, metres."""

    @classmethod
    def varied(cls, seed: int) -> "StreetLayout":
        """A narrow, crowded variant (its own random stream: the rest of the town is unchanged)."""
        rng = np.random.default_rng([int(seed), 0x57EE7])
        return cls(sidewalk_m=float(rng.uniform(1.5, 3.5)), park_offset_m=float(rng.uniform(3.8, 4.75)),
                   park_probability=float(rng.uniform(0.7, 0.95)),
                   park_gap_m=(0.5, float(rng.uniform(1.5, 3.0))), tree_offset_m=float(rng.uniform(0.6, 1.3)),
                   tree_probability=float(rng.uniform(0.8, 1.0)), pole_gap_m=(10.0, float(rng.uniform(14.0, 20.0))),
                   ego_lane_offset_m=float(rng.uniform(0.3, 1.75)))

    @classmethod
    def narrow(cls, seed: int) -> "StreetLayout":
        """A narrow residential street (its own random stream): 8-10 m kerb to kerb with cars parked on
        the road along both kerbs, the ego car near the middle, facades 1-2.5 m behind the kerb, trees
        and poles close to it (KITTI 07's roadside is about twice as near on the left as the town's)."""
        rng = np.random.default_rng([int(seed), 0x4A770])
        half = float(rng.uniform(4.0, 5.0))
        return cls(sidewalk_m=float(rng.uniform(1.0, 2.5)), park_offset_m=half - float(rng.uniform(0.9, 1.1)),
                   park_probability=float(rng.uniform(0.75, 0.95)), park_gap_m=(0.5, float(rng.uniform(1.5, 3.0))),
                   tree_offset_m=float(rng.uniform(0.5, 1.0)), tree_probability=float(rng.uniform(0.8, 1.0)),
                   pole_gap_m=(10.0, float(rng.uniform(14.0, 20.0))), ego_lane_offset_m=float(rng.uniform(0.0, 1.0)),
                   road_half_m=half, lane_offset_m=1.1)


KITTI_CAMERA = PinholeCamera(1241, 376, 718.856, 718.856, 620.0, 187.5)
"""KITTI-like default: 1241x376, fx = fy = 718.856 (KITTI 00-02), principal point at the centre."""
KITTI_BASELINE_M = 0.54


def build_street(seed: int, px_per_m: float, moving_objects: int, deform_amplitude_m: float,
                 rng: np.random.Generator, layout: StreetLayout = StreetLayout(), lighting: Lighting | None = None,
                 grainy_road: bool = False) -> Scene:
    bx = float(rng.uniform(56.0, 60.0))
    by = float(rng.uniform(44.0, 46.0))
    sun = (rng.uniform(-0.5, 0.5), rng.uniform(-0.6, -0.2), 0.8)  # drawn either way: the stream stays
    light = lighting or Lighting(sun, 0.6, (1.0, 1.0, 1.0))
    asm = Assembler(px_per_m, rng, sun_dir=light.sun_dir, ambient=light.ambient)
    _roads(asm, bx, by, layout.road_half_m, grainy_road)
    _sidewalks_and_ground(asm, bx, by, layout)
    _buildings(asm, bx, by, rng, layout)
    _parked_cars(asm, bx, by, rng, layout)
    rh = layout.road_half_m
    flag_sites = [((0.62 * bx, -rh - 0.5), (0, -1)), ((bx + rh + 0.5, 0.45 * by), (1, 0)),
                  ((0.38 * bx, by + rh + 0.5), (0, 1)), ((-rh - 0.5, 0.55 * by), (-1, 0)),
                  ((1.5 * bx, -rh - 0.5), (0, -1)), ((2 * bx + rh + 0.5, 0.5 * by), (1, 0))]
    _street_furniture(asm, bx, by, rng, avoid_xy=np.array([p for p, _ in flag_sites]), layout=layout)

    # ego route: loop around block A (counter-clockwise), then around both blocks
    centre_corners = np.array([(0.5 * bx, 0), (bx, 0), (bx, by), (0, by), (0, 0), (2 * bx, 0), (2 * bx, by), (0, by), (0, 0)], float)
    lane = offset_polyline(centre_corners, layout.ego_lane_offset_m)
    lane_path = PeriodicPath.from_polyline(lane, EGO_CORNER_RADIUS_M)

    # flags on poles over the sidewalk on the ego's right, facing the traffic
    flags_on_poles(asm, flag_sites, deform_amplitude_m, rng)

    # movers: oncoming traffic clockwise around block A or around both blocks in the other lane, and
    # (every third) traffic ahead on the ego's own route, a little faster than the ego; where each
    # starts is chosen by the simulator (sim.world.separate_movers: in view, clear of the camera)
    loops = [np.array([(0, 0), (0, by), (2 * bx, by), (2 * bx, 0)], float),
             np.array([(0, 0), (0, by), (bx, by), (bx, 0)], float)]
    paths = [PeriodicPath.from_polyline(offset_polyline(c, layout.lane_offset_m), MOVER_CORNER_RADIUS_M) for c in loops]
    for k in range(moving_objects):
        ahead = k % 3 == 2
        path = lane_path if ahead else paths[k % 2]
        cruise = float(rng.uniform(7.0, 11.0)) + (6.0 if ahead else 0.0)
        prof = speed_profile(path, cruise, lat_accel_mps2=3.6 if ahead else 2.5, long_accel_mps2=1.5)
        c0 = float((k // 2) * path.length / max(1, (moving_objects + 1) // 2) + rng.uniform(0, 20))
        motion = PathFollower(PathProgress(path, prof, c0), z_m=0.0)
        b = asm.dynamic_builder(f"car{k}", RIGID, motion)
        car(asm, b, (0.0, 0.0), 0.0, rng.uniform(20, 235, 3), z0=0.0)

    return street_scene(asm, seed, lane_path, (bx, by))


def street_scene(asm: Assembler, seed: int, lane_path: PeriodicPath, block_m: tuple[float, float], **layout) -> Scene:
    """The :class:`Scene` of a street built in ``asm``: KITTI's camera at 10 Hz, the ego route ``lane_path``,
    the blocks' size ``block_m`` and any further ``layout`` entries."""
    atlas, bodies = asm.finish()
    verts = bodies[0].mesh.vertices  # the static body (world frame)
    bounds = np.stack([verts.min(0), verts.max(0)])
    return Scene(
        name="street", seed=seed, atlas=atlas, bodies=bodies, camera=KITTI_CAMERA,
        stereo_baseline_m=KITTI_BASELINE_M, rate_hz=10.0, znear_m=1.5,
        zfar_m=float(np.linalg.norm(bounds[1] - bounds[0]) + 10.0), sky_rgb=(170, 200, 235), bounds=bounds,
        layout={"lane_path": lane_path, "camera_height_m": CAMERA_HEIGHT_M, "block_m": block_m,
                "mover_clearance_m": 2.2, "mover_mover_clearance_m": 6.0, **layout},
    )


# ----------------------------------------------------------------------------------------------


def all_sides(painter, top: bool = False, bottom: bool = False) -> dict:
    faces = {"+x": painter, "-x": painter, "+y": painter, "-y": painter}
    if top:
        faces["+z"] = painter
    if bottom:
        faces["-z"] = painter
    return faces


def flags_on_poles(asm: Assembler, sites, deform_amplitude_m: float, rng: np.random.Generator) -> None:
    """A pole and a flag at each of ``sites``: ((x, y) of the pole, metres; (dx, dy) unit direction the flag
    points to, away from the road), the flag 2.7-3.7 m up, waving with ``deform_amplitude_m`` (0: static)
    at a wavelength, frequency, phase and tilt drawn from ``rng``."""
    for k, ((px, py), away) in enumerate(sites):
        asm.box((px, py, KERB_M + 2.0), (0.05, 0.05, 2.0), all_sides(tx.metal((150, 150, 150)), top=True))
        x_b = np.array([away[0], away[1], 0.0])
        z_b = np.array([0.0, 0.0, 1.0])
        world_from_flag = np.eye(4)
        world_from_flag[:3, :3] = np.stack([x_b, np.cross(z_b, x_b), z_b], axis=1)
        world_from_flag[:3, 3] = (px + 0.05 * away[0], py + 0.05 * away[1], KERB_M + 2.7)
        deform = FlagDeform(nx=33, nz=17, length_m=1.6, height_m=1.0, amplitude_m=float(deform_amplitude_m),
                            wavelength_m=float(rng.uniform(1.2, 2.2)), freq_hz=float(rng.uniform(0.5, 1.0)),
                            phase=float(rng.uniform(0, 2 * np.pi)), tilt_rad_per_m=float(rng.uniform(0.3, 0.9)))
        asm.flag(f"flag{k}", world_from_flag, deform, flag_painter(rng.spawn(1)[0]), dynamic=deform_amplitude_m > 0)


def road_painter(length_m: float, width_m: float, along_y: bool, junctions: list[tuple[float, float]],
                 grainy: bool = False):
    """Asphalt with lane markings, drawn along the road's length; ``junctions`` are (start, end)
    metres along the road where other roads cross (no markings inside, zebra crossings before);
    ``grainy``: :func:`textures.asphalt_grainy` instead of the near-uniform :func:`textures.asphalt`."""

    def paint(h, w, ppm, rng):
        lh, lw = (w, h) if along_y else (h, w)   # canvas: length along columns
        img = (tx.asphalt_grainy if grainy else tx.asphalt)(lh, lw, ppm, rng)
        sx = lw / length_m
        sy = lh / width_m
        white, yellow = (235, 235, 230), (230, 190, 40)

        def inside_junction(x0, x1):
            return any(x1 > a and x0 < b for a, b in junctions)

        lt = max(1, int(round(0.12 * sy)))
        # centre line (dashed) and parking-strip lines (solid), interrupted at junctions
        x = 0.0
        while x < length_m:
            if not inside_junction(x, x + 3.0):
                x0, x1 = int(x * sx), int(min(length_m, x + 3.0) * sx)
                yc = int(lh / 2)
                img[max(0, yc - lt // 2):yc + lt - lt // 2, x0:x1] = yellow if rng.random() < 0.1 else white
            x += 3.0 + rng.uniform(5.0, 7.0)
        for off in (-3.5, 3.5):
            yc = int((width_m / 2 + off) * sy)
            for xa in np.arange(0.0, length_m, 0.5):
                if not inside_junction(xa, xa + 0.5):
                    img[max(0, yc - lt // 2):yc + lt - lt // 2, int(xa * sx):int((xa + 0.5) * sx)] = white
        # zebra crossings and stop lines before junctions
        for a, b in junctions:
            for edge, sign in ((a, -1), (b, 1)):
                if not (0 < edge < length_m):
                    continue
                z0 = edge + sign * 0.5
                z1 = edge + sign * 3.5
                lo, hi = sorted((z0, z1))
                for yy in np.arange(0.3, width_m - 0.3, 1.0):
                    img[int(yy * sy):int((yy + 0.5) * sy), int(max(0, lo) * sx):int(min(length_m, hi) * sx)] = white
        # painted words, arrows and manhole covers, at random places
        for _ in range(int(rng.integers(2, 6))):
            xm = rng.uniform(5, max(6, length_m - 5))
            if inside_junction(xm - 3, xm + 3):
                continue
            side = rng.choice([-1.75, 1.75])
            yc = (width_m / 2 + side) * sy
            if rng.random() < 0.5:
                r = int(0.35 * min(sx, sy))
                cv2.circle(img, (int(xm * sx), int(yc)), max(1, r), (55, 55, 60), -1, cv2.LINE_AA)
                cv2.circle(img, (int(xm * sx), int(yc)), max(1, r), (30, 30, 30), max(1, r // 6), cv2.LINE_AA)
            else:
                pts = np.array([[xm - 2.0, -0.15], [xm, -0.15], [xm, -0.5], [xm + 1.0, 0.0], [xm, 0.5], [xm, 0.15], [xm - 2.0, 0.15]])
                pts = np.stack([pts[:, 0] * sx, yc + pts[:, 1] * sy], -1)
                cv2.fillPoly(img, [pts.astype(np.int32)], white, cv2.LINE_AA)
        out = np.clip(img, 0, 255).astype(np.uint8)
        return np.ascontiguousarray(np.rot90(out)) if along_y else out

    return paint


def _roads(asm: Assembler, bx: float, by: float, r: float = ROAD_HALF_M, grainy: bool = False) -> None:
    length = 2 * bx + 2 * r
    junctions = [(x - r + r, x + r + r) for x in (0.0, bx, 2 * bx)]  # along-road coordinate from x = -r
    for y in (0.0, by):
        asm.box((bx, y, -0.1), (bx + r, r, 0.1), {"+z": road_painter(length, 2 * r, False, junctions, grainy)}, densities={"+z": 1.25})
    for x in (0.0, bx, 2 * bx):
        seg = by - 2 * r
        asm.box((x, by / 2, -0.1), (r, seg / 2, 0.1), {"+z": road_painter(seg, 2 * r, True, [], grainy)}, densities={"+z": 1.25})


def slab(asm: Assembler, x0, x1, y0, y1, painter, kerb_faces=(), density=1.0) -> None:
    """A raised area from z = 0 to the kerb height with a paved/ground top and kerb faces."""
    faces = {"+z": painter}
    kerb = tx.flat((150, 148, 140), 0.25)
    for f in kerb_faces:
        faces[f] = kerb
    dens = {"+z": density}
    asm.box(((x0 + x1) / 2, (y0 + y1) / 2, KERB_M / 2), ((x1 - x0) / 2, (y1 - y0) / 2, KERB_M / 2), faces, densities=dens)


def _sidewalks_and_ground(asm: Assembler, bx: float, by: float, layout: StreetLayout) -> None:
    r, s = layout.road_half_m, layout.sidewalk_m
    pave = tx.paving()
    ground = tx.grass
    for x0, x1 in ((r, bx - r), (bx + r, 2 * bx - r)):   # block interiors
        y0, y1 = r, by - r
        slab(asm, x0, x1, y0, y0 + s, pave, ("-y", "-x", "+x"), 1.25)
        slab(asm, x0, x1, y1 - s, y1, pave, ("+y", "-x", "+x"), 1.25)
        slab(asm, x0, x0 + s, y0 + s, y1 - s, pave, ("-x",), 1.25)
        slab(asm, x1 - s, x1, y0 + s, y1 - s, pave, ("+x",), 1.25)
        slab(asm, x0 + s, x1 - s, y0 + s, y1 - s, ground, (), 0.1)
    # outside the ring road
    X0, X1, Y0, Y1 = -r, 2 * bx + r, -r, by + r
    slab(asm, X0 - s, X1 + s, Y0 - s, Y0, pave, ("+y",), 1.25)
    slab(asm, X0 - s, X1 + s, Y1, Y1 + s, pave, ("-y",), 1.25)
    slab(asm, X0 - s, X0, Y0, Y1, pave, ("+x",), 1.25)
    slab(asm, X1, X1 + s, Y0, Y1, pave, ("-x",), 1.25)
    m = 40.0
    slab(asm, X0 - m, X1 + m, Y0 - m, Y0 - s, ground, (), 0.05)
    slab(asm, X0 - m, X1 + m, Y1 + s, Y1 + m, ground, (), 0.05)
    slab(asm, X0 - m, X0 - s, Y0 - s, Y1 + s, ground, (), 0.05)
    slab(asm, X1 + s, X1 + m, Y0 - s, Y1 + s, ground, (), 0.05)


def building(asm: Assembler, x0, x1, y0, y1, front: str, rng) -> None:
    """An axis-aligned building on the footprint [x0,x1]x[y0,y1], its main facade on face ``front``."""
    h = float(rng.uniform(7.0, 24.0))
    style = tx.facade(rng.spawn(1)[0])
    faces = {f: style for f in ("+x", "-x", "+y", "-y")}
    faces["+z"] = tx.flat(rng.uniform(60, 140, 3), 0.3)
    back = {"+x": "-x", "-x": "+x", "+y": "-y", "-y": "+y"}[front]
    dens = {f: 0.5 for f in faces}
    dens[front] = 1.0
    dens[back] = 0.1
    dens["+z"] = 0.03
    asm.box(((x0 + x1) / 2, (y0 + y1) / 2, KERB_M + h / 2), ((x1 - x0) / 2, (y1 - y0) / 2, h / 2), faces, densities=dens)


def building_row(asm: Assembler, a0: float, a1: float, frontage: float, depth: float, along_x: bool, outward: float,
         front: str, rng) -> None:
    """Buildings along a frontage line from a0 to a1 (along x or y); they extend ``depth`` metres
    from the frontage in direction ``outward`` (+1/-1, away from the road)."""
    a = a0
    while a < a1 - 1e-6:
        w = float(rng.uniform(7.0, 20.0))
        if a1 - (a + w) < 5.0:
            w = a1 - a
        b0, b1 = sorted((frontage, frontage + outward * depth * rng.uniform(0.8, 1.0)))
        if along_x:
            building(asm, a, a + w, b0, b1, front, rng)
        else:
            building(asm, b0, b1, a, a + w, front, rng)
        a += w
        if rng.random() < 0.3 and a1 - a > 12.0:
            a += float(rng.uniform(2.0, 5.0))   # an alley


def _buildings(asm: Assembler, bx: float, by: float, rng, layout: StreetLayout) -> None:
    f = layout.road_half_m + layout.sidewalk_m
    for x0, x1 in ((f, bx - f), (bx + f, 2 * bx - f)):   # block interiors
        y0, y1 = f, by - f
        d_bot, d_top, d_side = (float(rng.uniform(8.0, 12.0)) for _ in range(3))
        building_row(asm, x0, x1, y0, d_bot, True, +1, "-y", rng)
        building_row(asm, x0, x1, y1, d_top, True, -1, "+y", rng)
        building_row(asm, y0 + d_bot, y1 - d_top, x0, d_side, False, +1, "-x", rng)
        building_row(asm, y0 + d_bot, y1 - d_top, x1, d_side, False, -1, "+x", rng)
    X0, X1, Y0, Y1 = -f, 2 * bx + f, -f, by + f
    dl, dr = float(rng.uniform(10.0, 14.0)), float(rng.uniform(10.0, 14.0))
    building_row(asm, X0 - dl, X1 + dr, Y0, rng.uniform(10.0, 14.0), True, -1, "+y", rng)
    building_row(asm, X0 - dl, X1 + dr, Y1, rng.uniform(10.0, 14.0), True, +1, "-y", rng)
    building_row(asm, Y0, Y1, X0, dl, False, -1, "+x", rng)
    building_row(asm, Y0, Y1, X1, dr, False, +1, "-x", rng)


def car(asm: Assembler, builder: MeshBuilder | None, xy, yaw: float, colour, z0: float) -> None:
    """A car made of boxes, centred at ``xy`` on the ground at height z0, heading ``yaw`` (x forward)."""
    cs, sn = np.cos(yaw), np.sin(yaw)

    def at(dx, dy, dz):
        return (xy[0] + cs * dx - sn * dy, xy[1] + sn * dx + cs * dy, z0 + dz)

    body = tx.car_body(colour)
    paint_top = tx.flat(colour, 0.15)
    asm.box(at(0.0, 0.0, 0.65), (2.1, 0.9, 0.4), {**all_sides(body), "+z": paint_top}, yaw=yaw, builder=builder,
            densities={f: 2.0 for f in ("+x", "-x", "+y", "-y", "+z")})
    asm.box(at(-0.2, 0.0, 1.33), (1.1, 0.78, 0.28), {**all_sides(tx.car_glass), "+z": paint_top}, yaw=yaw, builder=builder,
            densities={f: 2.0 for f in ("+x", "-x", "+y", "-y", "+z")})
    dark = tx.flat((35, 35, 38), 0.3)
    for dx in (-1.35, 1.35):
        for dy in (-0.86, 0.86):
            asm.box(at(dx, dy, 0.31), (0.32, 0.12, 0.31), {"+y": tx.tyre_band, "-y": tx.tyre_band, "+x": dark, "-x": dark, "+z": dark},
                    yaw=yaw, builder=builder, densities={"+y": 2.0, "-y": 2.0})


def _road_segments(bx: float, by: float, r: float = ROAD_HALF_M):
    """(start_xy, end_xy) of each road stretch between junctions (centreline); ``r``: half the road's width."""
    segs = []
    for y in (0.0, by):
        segs += [((r, y), (bx - r, y)), ((bx + r, y), (2 * bx - r, y))]
    for x in (0.0, bx, 2 * bx):
        segs.append(((x, r), (x, by - r)))
    return segs


def _parked_cars(asm: Assembler, bx: float, by: float, rng, layout: StreetLayout) -> None:
    segments = [(a, b, layout.park_offset_m) for a, b in _road_segments(bx, by, layout.road_half_m)]
    parked_cars(asm, segments, rng, layout.park_probability, layout.park_gap_m)


def parked_cars(asm: Assembler, segments, rng, probability: float, gap_m: tuple[float, float]) -> None:
    """Cars parked along both sides of each road stretch ``(start_xy, end_xy, offset_m)`` (centreline,
    metres; ``offset_m``: distance of the cars' centres from it), each bay taken with ``probability``,
    ``gap_m`` the range of the extra gap between cars (plus the 4.4 m car)."""
    for (ax, ay), (bx_, by_), offset in segments:
        d = np.array([bx_ - ax, by_ - ay])
        length = float(np.linalg.norm(d))
        d /= length
        normal = np.array([-d[1], d[0]])
        for side in (-1.0, 1.0):
            s = float(rng.uniform(4.0, 10.0))
            while s < length - 6.0:
                if rng.random() < probability:
                    p = np.array([ax, ay]) + d * s + normal * side * offset
                    yaw = float(np.arctan2(d[1], d[0]) + (0 if side < 0 else np.pi))
                    car(asm, None, p, yaw + float(rng.normal(0, 0.03)), rng.uniform(20, 235, 3), z0=0.0)
                s += 4.4 + float(rng.uniform(*gap_m))


def _street_furniture(asm: Assembler, bx: float, by: float, rng, avoid_xy: np.ndarray,
                      layout: StreetLayout = StreetLayout()) -> None:
    segments = [(a, b, layout.road_half_m) for a, b in _road_segments(bx, by, layout.road_half_m)]
    street_furniture(asm, segments, rng, avoid_xy, layout.pole_gap_m, layout.tree_offset_m, layout.tree_probability)


def street_furniture(asm: Assembler, segments, rng, avoid_xy: np.ndarray, pole_gap_m: tuple[float, float],
                     tree_offset_m: float, tree_probability: float) -> None:
    """Lamp poles (some with signs), trees and bins along both sidewalks of each road stretch
    ``(start_xy, end_xy, road_half_m)`` (centreline, metres), none within 3.5 m of ``avoid_xy`` (N, 2)
    (the flags); poles ``pole_gap_m`` apart, a tree (with ``tree_probability``, ``tree_offset_m`` behind
    the kerb) or a bin half-way."""

    def free(p) -> bool:
        return bool(np.min(np.linalg.norm(avoid_xy - p, axis=1)) > 3.5)

    for (ax, ay), (bx_, by_), r in segments:
        d = np.array([bx_ - ax, by_ - ay])
        length = float(np.linalg.norm(d))
        d /= length
        normal = np.array([-d[1], d[0]])
        for side in (-1.0, 1.0):
            s = float(rng.uniform(3.0, 12.0))
            while s < length - 3.0:
                base = np.array([ax, ay]) + d * s
                pole = base + normal * side * (r + 0.5)
                gap = float(rng.uniform(*pole_gap_m))
                if not free(pole):
                    s += gap
                    continue
                asm.box((pole[0], pole[1], KERB_M + 3.0), (0.08, 0.08, 3.0), all_sides(tx.metal(), top=True))
                arm = base + normal * side * (r - 0.4)
                yaw_arm = float(np.arctan2(normal[1], normal[0]))
                asm.box((arm[0], arm[1], KERB_M + 6.0), (0.9, 0.05, 0.05), all_sides(tx.metal(), top=True, bottom=True), yaw=yaw_arm)
                lamp = base + normal * side * (r - 1.2)
                asm.box((lamp[0], lamp[1], KERB_M + 5.9), (0.3, 0.15, 0.08), all_sides(tx.flat((230, 230, 210)), top=True, bottom=True), yaw=yaw_arm)
                if rng.random() < 0.5:
                    yaw_sign = float(np.arctan2(d[1], d[0]))
                    plate = pole + d * 0.1
                    asm.box((plate[0], plate[1], KERB_M + 2.4), (0.02, 0.35, 0.35), {"+x": tx.sign_face, "-x": tx.sign_face,
                            "+y": tx.metal(), "-y": tx.metal(), "+z": tx.metal()}, yaw=yaw_sign, densities={"+x": 3.0, "-x": 3.0})
                # a tree half-way to the next pole, sometimes a bin
                t = s + gap / 2
                tree = np.array([ax, ay]) + d * t + normal * side * (r + tree_offset_m)
                if not free(tree):
                    pass
                elif t < length - 3.0 and rng.random() < tree_probability:
                    asm.box((tree[0], tree[1], KERB_M + 1.4), (0.14, 0.14, 1.4), all_sides(tx.bark), yaw=float(rng.uniform(0, np.pi)))
                    for _ in range(int(rng.integers(2, 4))):
                        hc = rng.uniform(0.7, 1.4, 3) * [1, 1, 0.8]
                        off = rng.normal(0, 0.4, 2)
                        asm.box((tree[0] + off[0], tree[1] + off[1], KERB_M + 2.6 + hc[2] + rng.uniform(0, 1.0)), hc,
                                all_sides(tx.foliage, top=True, bottom=True), yaw=float(rng.uniform(0, np.pi)))
                elif t < length - 3.0 and rng.random() < 0.6:
                    b = np.array([ax, ay]) + d * t + normal * side * (r + 0.7)
                    asm.box((b[0], b[1], KERB_M + 0.45), (0.3, 0.3, 0.45), all_sides(tx.metal(rng.uniform(30, 200, 3)), top=True))
                s += gap
