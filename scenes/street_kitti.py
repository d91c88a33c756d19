"""``street`` in its KITTI look (the default): a residential block of narrow streets beside a long
avenue, grainy asphalt, cars parked along both kerbs, trees, poles and facades at KITTI's distances,
the camera 1.65 m up and pitched about 1 degree down.

Layout (world frame, metres, z up; road surface at z = 0, sidewalks and blocks at z = 0.15): road
centrelines at x in {0, A, A + B} and y in {0, D} (:class:`KittiTown`: A the residential block's
length, B the avenue's, D the blocks' depth). The block between x = 0 and x = A is bounded by narrow
streets (8-10 m kerb to kerb, cars parked on the road along both kerbs); the avenue (the long roads
y = 0 and y = D between x = A and A + B, and the road x = A + B) is 14-16 m wide. Facades stand behind
2-3.5 m sidewalks. Long roads are built in stretches of at most :data:`ROAD_PIECE_M` so their
texture keeps its density.

The ego route (for the ``car`` trajectory, right-hand traffic, lane centre 1.75 m right of the
centreline) starts at the junction (0, 0) heading +x, goes round the residential block (about 160 m:
its first stretch is driven again, a loop closure after about 22 s), then along the avenue and back
(the fast stretch) and round again. :func:`sim.trajectories.CarMotion.create` drives it stop-and-go:
a stop at the route's start and at some junctions, up to about 10 m/s in the narrow streets and up to
:attr:`KittiTown.avenue_mps` on the avenue. Moving cars (``moving_objects``): every third one drives
ahead of the ego car in its lane (:class:`scenes.spec.LeadProgress`: the ego's own progress a
headway ahead, so it stays in view, stopping and starting with it); the others are oncoming traffic
round the residential block or the whole town, placed by the simulator where the camera sees them
(:func:`sim.world.separate_movers`).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from deepslam.scenes import textures as tx
from deepslam.scenes.assemble import Assembler
from deepslam.scenes.geometry import PeriodicPath, offset_polyline
from deepslam.scenes.lighting import Lighting
from deepslam.scenes.spec import RIGID, LeadProgress, PathFollower, PathProgress, Scene, speed_profile
from deepslam.scenes.street import (EGO_CORNER_RADIUS_M, LANE_OFFSET_M, MOVER_CORNER_RADIUS_M, building_row, car,
                                    flags_on_poles, parked_cars, road_painter, slab, street_furniture, street_scene)

ROAD_PIECE_M = 60.0
"""Longest road box, metres (a longer one would exceed the atlas's largest region at full density)."""


@dataclasses.dataclass(frozen=True)
class KittiTown:
    """Proportions and traffic of the KITTI-look street (ranges are drawn from the scene's seed)."""

    block_m: tuple[float, float] = (45.0, 55.0)
    """Length along x of the residential block, metres."""
    avenue_m: tuple[float, float] = (270.0, 300.0)
    """Length along x of the avenue's block, metres (long enough to reach 30 m/s and brake again)."""
    depth_m: tuple[float, float] = (36.0, 42.0)
    """Depth along y of both blocks, metres."""
    narrow_half_m: tuple[float, float] = (4.8, 5.2)
    """Half width, kerb to kerb, of the residential streets, metres."""
    wide_half_m: tuple[float, float] = (7.0, 8.0)
    """Half width of the avenue, metres."""
    sidewalk_m: tuple[float, float] = (2.0, 3.5)
    """Sidewalk width between kerb and facades, metres (drawn once per town)."""
    park_probability: float = 0.85
    """Chance that a parking bay along a residential kerb holds a car."""
    avenue_park_probability: float = 0.35
    """Chance that a parking bay along the avenue holds a car."""
    park_gap_m: tuple[float, float] = (0.5, 3.0)
    """Range of the extra gap between parked cars, metres."""
    camera_pitch_deg: float = 1.0
    """Downward pitch of the car's camera, degrees (KITTI's cameras look slightly down)."""
    residential_mps: tuple[float, float] = (8.0, 10.5)
    """Range of the ego car's cruise speed in the residential streets, m/s."""
    avenue_mps: float = 30.0
    """The ego car's top speed on the avenue, m/s."""
    headway_s: tuple[float, float] = (1.2, 2.0)
    """Range of the time gap of a car driving ahead of the ego car, seconds."""
    standstill_gap_m: tuple[float, float] = (7.0, 9.0)
    """Range of the distance (centre to centre) of a car ahead when both stand, metres."""


def build_kitti_street(seed: int, px_per_m: float, moving_objects: int, deform_amplitude_m: float,
                       rng: np.random.Generator, lighting: Lighting | None = None, town: KittiTown = KittiTown(),
                       route_name: str = "default") -> Scene:
    """The KITTI-look street from ``rng`` (see the module docstring) with the ego route ``route_name`` (one of
    :data:`ROUTES`, :func:`ego_route`); returns a :class:`Scene`. The town is the same for every route."""
    a = float(rng.uniform(*town.block_m))
    b = float(rng.uniform(*town.avenue_m))
    d = float(rng.uniform(*town.depth_m))
    xs = (0.0, a, a + b)
    ys = (0.0, d)
    narrow = [float(rng.uniform(*town.narrow_half_m)) for _ in range(4)]
    wide = [float(rng.uniform(*town.wide_half_m)) for _ in range(3)]
    h_rows = [[narrow[0], wide[0]], [narrow[1], wide[1]]]     # half widths of the x-roads: [y][block]
    h_cols = [narrow[2], narrow[3], wide[2]]                  # half widths of the y-roads: [x]
    sidewalk = float(rng.uniform(*town.sidewalk_m))
    sun = (rng.uniform(-0.5, 0.5), rng.uniform(-0.6, -0.2), 0.8)
    light = lighting or Lighting(sun, 0.6, (1.0, 1.0, 1.0))
    asm = Assembler(px_per_m, rng, sun_dir=light.sun_dir, ambient=light.ambient)

    _ground(asm, xs, ys)
    _roads(asm, xs, ys, h_rows, h_cols)
    _blocks(asm, xs, ys, h_rows, h_cols, sidewalk, rng)
    _outside(asm, xs, ys, h_rows, h_cols, sidewalk, rng)
    segments = _segments(xs, ys, h_rows, h_cols)
    wide_min = town.wide_half_m[0]
    parked_cars(asm, [(p, q, h - 1.0) for p, q, h in segments if h < wide_min], rng, town.park_probability,
                town.park_gap_m)
    parked_cars(asm, [(p, q, h - 1.1) for p, q, h in segments if h >= wide_min], rng, town.avenue_park_probability,
                (1.0, 8.0))
    flag_sites = [((0.5 * a, -h_rows[0][0] - 0.5), (0, -1)), ((a + 0.3 * b, -h_rows[0][1] - 0.5), (0, -1)),
                  ((a + 0.7 * b, d + h_rows[1][1] + 0.5), (0, 1)), ((-h_cols[0] - 0.5, 0.5 * d), (-1, 0))]
    street_furniture(asm, segments, rng, np.array([p for p, _ in flag_sites]), (12.0, 20.0), 0.8, 0.9)
    flags_on_poles(asm, flag_sites, deform_amplitude_m, rng)

    route, fast_legs, stop_before = ego_route(route_name, a, b, d)
    lane = offset_polyline(route, LANE_OFFSET_M)
    lane_path = PeriodicPath.from_polyline(lane, EGO_CORNER_RADIUS_M)
    # the route's stretches (path parameter ranges) and speed limits, for the stop-and-go drive
    c_of = _arc_positions(lane_path, lane)
    avenue = [(c_of[i], c_of[j]) for i, j in fast_legs]
    stops = [c_of[0] + EGO_CORNER_RADIUS_M] + [c_of[i] - 8.0 for i in stop_before]

    loops = [np.array([(0, 0), (0, d), (a + b, d), (a + b, 0)], float),
             np.array([(0, 0), (0, d), (a, d), (a, 0)], float)]
    paths = [PeriodicPath.from_polyline(offset_polyline(c, LANE_OFFSET_M), MOVER_CORNER_RADIUS_M) for c in loops]
    for k in range(moving_objects):
        ahead = k % 3 == 0
        if ahead:
            rank = k // 3
            headway = float(rng.uniform(*town.headway_s)) * (rank + 1)
            gap = float(rng.uniform(*town.standstill_gap_m)) * (rank + 1)
            fallback = PathProgress(lane_path, speed_profile(lane_path, 9.0, 2.5, 1.5), c0=gap)
            progress = LeadProgress(fallback, headway_s=headway, gap_m=gap)
        else:
            path = paths[k % 2]
            prof = speed_profile(path, float(rng.uniform(7.0, 11.0)), lat_accel_mps2=2.5, long_accel_mps2=1.5)
            c0 = float((k // 2) * path.length / max(1, (moving_objects + 1) // 2) + rng.uniform(0, 20))
            progress = PathProgress(path, prof, c0)
        b_ = asm.dynamic_builder(f"car{k}", RIGID, PathFollower(progress, z_m=0.0))
        car(asm, b_, (0.0, 0.0), 0.0, rng.uniform(20, 235, 3), z0=0.0)

    return street_scene(asm, seed, lane_path, (a, d), camera_pitch_rad=float(np.deg2rad(town.camera_pitch_deg)),
                        road_segments=[(tuple(p), tuple(q), h) for p, q, h in segments],
                        stop_and_go={"stops_c": stops, "fast_c": avenue, "fast_mps": town.avenue_mps,
                                     "cruise_mps": town.residential_mps})


ROUTES = ("default", "laps")
"""The ego car's routes through the town (:func:`ego_route`)."""


def ego_route(name: str, a: float, b: float, d: float) -> tuple[np.ndarray, list, list]:
    """(route, fast legs, stop corners) of route ``name`` in the town of block length ``a``, avenue length
    ``b`` and depth ``d`` (metres): ``route`` (N, 2) float64 the road centreline's corners in driving order
    (closed: the last corner leads back to the first, the car starts at the first heading to the second),
    ``fast legs`` (i, j) pairs of corner indices between which the avenue's speed applies, ``stop corners`` the
    indices of the corners the car stops 8 m before (besides the start).

    ``default``: round the residential block (its first stretch driven again after about 160 m, one loop
    closure), then along the avenue and back.
    ``laps``: a lap of the residential block, then every road of the town once in each direction: through the
    two T-junctions from three sides, along each road the other way, the block's lap driven again the same
    way. Same-direction revisits after about 180 m and after the whole route (about 4a + 4b + 6d + 2a + 2d,
    1.75 km for the middle town), opposite-direction ones on every road; KITTI 00 and 05 revisit both ways.
    """
    if name == "default":
        route = [(0, 0), (a, 0), (a, d), (0, d), (0, 0), (a, 0), (a + b, 0), (a + b, d), (a, d), (0, d)]
        return np.array(route, float), [(5, 6), (7, 8)], [8, 9]
    if name == "laps":
        route = [(0, 0), (a, 0), (a, d), (0, d),                                   # the block, counter-clockwise
                 (0, 0), (a, 0), (a, d), (a + b, d), (a + b, 0), (a, 0),           # up the middle road, the avenue
                 (0, 0), (0, d), (a, d), (a, 0),                                   # the block, clockwise
                 (a + b, 0), (a + b, d), (a, d), (0, d)]                           # the avenue the other way
        return np.array(route, float), [(6, 9), (13, 16)], [9, 12, 16]
    raise ValueError(f"unknown route {name!r} (one of {', '.join(ROUTES)})")


# ----------------------------------------------------------------------------------------------


def _arc_positions(path: PeriodicPath, corners_xy: np.ndarray) -> list[float]:
    """Path parameter (metres, in [0, length)) of the point of ``path`` nearest to each corner, in
    route order: each corner is searched in the stretch after the previous one (the path starts at
    the first corner's bend), so a corner passed twice gets each visit."""
    c = np.arange(0.0, path.length, 0.25)
    xy = path.position(c)
    out, prev = [], -20.0
    for k, p in enumerate(corners_xy):
        reach = 30.0 + (float(np.linalg.norm(p - corners_xy[k - 1])) if k else 0.0)
        window = np.mod(c - prev, path.length) <= reach
        idx = np.nonzero(window)[0]
        i = idx[np.argmin(np.linalg.norm(xy[idx] - p, axis=1))]
        out.append(float(c[i]))
        prev = float(c[i])
    return out


def _segments(xs, ys, h_rows, h_cols) -> list:
    """(start_xy, end_xy, half_width_m) of each road stretch between junction squares (centreline)."""
    segs = []
    for j, y in enumerate(ys):
        for i in range(2):
            segs.append(((xs[i] + h_cols[i], y), (xs[i + 1] - h_cols[i + 1], y), h_rows[j][i]))
    for i, x in enumerate(xs):
        hy0 = max(h_rows[0][max(0, i - 1)], h_rows[0][min(1, i)])
        hy1 = max(h_rows[1][max(0, i - 1)], h_rows[1][min(1, i)])
        segs.append(((x, ys[0] + hy0), (x, ys[1] - hy1), h_cols[i]))
    return segs


def _ground(asm: Assembler, xs, ys) -> None:
    """Grass under everything, 5 cm below the road (seen only in gaps between lots)."""
    m = 60.0
    x0, x1, y0, y1 = xs[0] - m, xs[-1] + m, ys[0] - m, ys[-1] + m
    asm.box(((x0 + x1) / 2, (y0 + y1) / 2, -0.15), ((x1 - x0) / 2, (y1 - y0) / 2, 0.1), {"+z": tx.grass},
            densities={"+z": 0.05})


def _road_box(asm: Assembler, start, end, half_w: float, junction_ends: bool) -> None:
    """A road from ``start`` to ``end`` (centreline, axis-aligned) ``half_w`` wide, in pieces of at
    most :data:`ROAD_PIECE_M` metres; ``junction_ends``: plain asphalt (a junction square)."""
    (ax, ay), (bx, by) = start, end
    along_y = abs(bx - ax) < 1e-9
    length = abs(by - ay) if along_y else abs(bx - ax)
    if length <= 1e-6:
        return
    n = max(1, int(np.ceil(length / ROAD_PIECE_M)))
    for k in range(n):
        f0, f1 = k / n, (k + 1) / n
        piece = length / n
        cx, cy = ax + (bx - ax) * (f0 + f1) / 2, ay + (by - ay) * (f0 + f1) / 2
        half = (half_w, piece / 2, 0.1) if along_y else (piece / 2, half_w, 0.1)
        junctions = [(-1.0, piece + 1.0)] if junction_ends else []
        painter = road_painter(piece, 2 * half_w, along_y, junctions, grainy=True)
        asm.box((cx, cy, -0.1), half, {"+z": painter}, densities={"+z": 1.25})


def _roads(asm: Assembler, xs, ys, h_rows, h_cols) -> None:
    for j, y in enumerate(ys):      # junction squares
        for i, x in enumerate(xs):
            hy = max(h_rows[j][max(0, i - 1)], h_rows[j][min(1, i)])
            _road_box(asm, (x - h_cols[i], y), (x + h_cols[i], y), hy, junction_ends=True)
    for start, end, h in _segments(xs, ys, h_rows, h_cols):
        _road_box(asm, start, end, h, junction_ends=False)


def _blocks(asm: Assembler, xs, ys, h_rows, h_cols, s: float, rng) -> None:
    """Each block: a sidewalk ring behind the kerbs, grass inside, facades along the sidewalks."""
    pave = tx.paving()
    for i in range(2):
        x0, x1 = xs[i] + h_cols[i], xs[i + 1] - h_cols[i + 1]
        y0, y1 = ys[0] + h_rows[0][i], ys[1] - h_rows[1][i]
        slab(asm, x0, x1, y0, y0 + s, pave, ("-y", "-x", "+x"), 1.25)
        slab(asm, x0, x1, y1 - s, y1, pave, ("+y", "-x", "+x"), 1.25)
        slab(asm, x0, x0 + s, y0 + s, y1 - s, pave, ("-x",), 1.25)
        slab(asm, x1 - s, x1, y0 + s, y1 - s, pave, ("+x",), 1.25)
        slab(asm, x0 + s, x1 - s, y0 + s, y1 - s, tx.grass, (), 0.1)
        f0x, f1x, f0y, f1y = x0 + s, x1 - s, y0 + s, y1 - s
        d_bot, d_top, d_side = (float(rng.uniform(8.0, 12.0)) for _ in range(3))
        d_bot, d_top = min(d_bot, (f1y - f0y) / 2), min(d_top, (f1y - f0y) / 2)
        building_row(asm, f0x, f1x, f0y, d_bot, True, +1, "-y", rng)
        building_row(asm, f0x, f1x, f1y, d_top, True, -1, "+y", rng)
        if f1y - d_top - (f0y + d_bot) > 5.0:
            building_row(asm, f0y + d_bot, f1y - d_top, f0x, d_side, False, +1, "-x", rng)
            building_row(asm, f0y + d_bot, f1y - d_top, f1x, d_side, False, -1, "+x", rng)


def _outside(asm: Assembler, xs, ys, h_rows, h_cols, s: float, rng) -> None:
    """Sidewalks and facades along the outer side of the ring of roads."""
    pave = tx.paving()
    left, right = xs[0] - h_cols[0], xs[-1] + h_cols[-1]
    bottom = [ys[0] - h for h in h_rows[0]]
    top = [ys[1] + h for h in h_rows[1]]
    cuts = [left - s, xs[1], right + s]   # x where the outer strips of the two blocks meet
    for i in range(2):
        slab(asm, cuts[i], cuts[i + 1], bottom[i] - s, bottom[i], pave, ("+y",), 1.25)
        slab(asm, cuts[i], cuts[i + 1], top[i], top[i] + s, pave, ("-y",), 1.25)
    slab(asm, left - s, left, bottom[0], top[0], pave, ("+x",), 1.25)
    slab(asm, right, right + s, bottom[1], top[1], pave, ("-x",), 1.25)
    dl, dr = float(rng.uniform(10.0, 14.0)), float(rng.uniform(10.0, 14.0))
    for i in range(2):
        a0 = cuts[i] - (dl if i == 0 else 0.0)
        a1 = cuts[i + 1] + (dr if i == 1 else 0.0)
        building_row(asm, a0, a1, bottom[i] - s, rng.uniform(10.0, 14.0), True, -1, "+y", rng)
        building_row(asm, a0, a1, top[i] + s, rng.uniform(10.0, 14.0), True, +1, "-y", rng)
    building_row(asm, bottom[0], top[0], left - s, dl, False, -1, "+x", rng)
    building_row(asm, bottom[1], top[1], right + s, dr, False, +1, "-x", rng)
