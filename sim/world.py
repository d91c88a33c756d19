"""The world at a time t: camera poses, body poses, flag vertices; and keeping movers clear of the camera."""
from __future__ import annotations

import dataclasses

import numpy as np

from deepslam.scenes.spec import DEFORM, RIGID, Body, PathFollower, PathProgress, Scene


@dataclasses.dataclass(eq=False)
class WorldState:
    """Everything the renderers and the flow need at one instant.

    Attributes:
        t: time in seconds.
        world_from_cam: (4, 4) float64 left camera pose, OpenCV axes.
        world_from_body: (B, 4, 4) float64 pose of every scene body (same order as scene.bodies).
        flag_vertices: {body index: (V, 3) float64 vertices in the body frame} for deforming bodies.
    """

    t: float
    world_from_cam: np.ndarray
    world_from_body: np.ndarray
    flag_vertices: dict[int, np.ndarray]


def world_state(scene: Scene, motion, t: float) -> WorldState:
    poses = np.stack([b.motion.world_from_body(t)[0] for b in scene.bodies])
    verts = {i: b.deform.vertices_at(t) for i, b in enumerate(scene.bodies) if b.kind == DEFORM}
    return WorldState(float(t), motion.world_from_cam(t)[0], poses, verts)


def separate_movers(scene: Scene, motion, duration_s: float, rng: np.random.Generator) -> Scene:
    """Shift the start of path-following movers (cars) until, within [0, duration_s], the camera
    stays ``layout['mover_clearance_m']`` away from every mover's footprint (its bounding box in the
    ground plane) and mover centres stay ``layout['mover_mover_clearance_m']`` apart, or else keeps
    the best of 40 tries (with many cars on long sequences the clearances are not always all met);
    returns a new Scene (the input is not modified). Movers that do not follow a path (flying boxes) are left
    alone (their space is separated by construction)."""
    cam_clear = float(scene.layout.get("mover_clearance_m", 0.0))
    pair_clear = float(scene.layout.get("mover_mover_clearance_m", 0.0))
    rate = 4.0 * float(getattr(motion, "rate_hz", 10.0))
    times = np.arange(0.0, duration_s + 1.0 / rate, 1.0 / rate)
    cam_xy = motion.world_from_cam(times)[:, :2, 3]

    def footprint_distance(body: Body, poses: np.ndarray) -> float:
        v = body.mesh.vertices[:, :2]
        lo, hi = v.min(axis=0), v.max(axis=0)
        rel = cam_xy - poses[:, :2, 3]
        p = np.einsum("nji,nj->ni", poses[:, :2, :2], rel)   # camera in the body frame (xy)
        gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)
        return float(np.min(np.linalg.norm(gap, axis=1)))
    bodies = list(scene.bodies)
    placed: list[np.ndarray] = []
    changed = False
    for i, b in enumerate(bodies):
        if b.kind != RIGID or not isinstance(b.motion, PathFollower):
            continue
        prog = b.motion.progress
        best, best_score = b, -np.inf
        c0 = float(prog.c(0.0)[0])
        for attempt in range(40):
            cand = b if attempt == 0 else dataclasses.replace(
                b, motion=PathFollower(_shifted(prog, c0 + float(rng.uniform(5.0, prog.path.length - 5.0))), b.motion.z_m))
            poses = cand.motion.world_from_body(times)
            xy = poses[:, :2, 3]
            d_cam = footprint_distance(cand, poses) - cam_clear
            d_pair = min([np.min(np.linalg.norm(xy - p, axis=1)) - pair_clear for p in placed], default=np.inf)
            score = min(d_cam, d_pair)
            if score > best_score:
                best, best_score = cand, score
            if score >= 0:
                break
        if best is not b:
            changed = True
        bodies[i] = best
        placed.append(best.motion.world_from_body(times)[:, :2, 3])
    return dataclasses.replace(scene, bodies=bodies) if changed else scene


def _shifted(prog: PathProgress, c0: float) -> PathProgress:
    return PathProgress(prog.path, prog.speed, c0=c0, ramp_s=prog.ramp_s)


__all__ = ["WorldState", "world_state", "separate_movers", "Body"]
