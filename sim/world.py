"""The world at a time t: camera poses, body poses, flag vertices; and keeping movers clear of the camera."""
from __future__ import annotations

import dataclasses

import numpy as np

from deepslam.scenes.spec import DEFORM, RIGID, Body, LeadProgress, PathFollower, PathProgress, Scene


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


def view_fraction(body: Body, poses: np.ndarray, cam_from_world: np.ndarray, camera) -> np.ndarray:
    """(T,) float64: the share of the image covered by the bounding rectangle of ``body``'s bounding
    box (its mesh's, in the body frame) at ``poses`` (T, 4, 4) world_from_body, seen by the camera at
    ``cam_from_world`` (T, 4, 4), clipped to the image; 0 where any corner is behind 0.5 m (an
    estimate: the renders' masks give the exact per-frame fraction)."""
    v = body.mesh.vertices
    lo, hi = v.min(axis=0), v.max(axis=0)
    corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    cam_from_body = cam_from_world @ poses
    p = np.einsum("tij,kj->tki", cam_from_body, corners)[..., :3]
    z = p[..., 2]
    front = (z > 0.5).all(axis=1)
    zs = np.where(z > 0.5, z, 1.0)
    u = camera.fx * p[..., 0] / zs + camera.cx
    w = camera.fy * p[..., 1] / zs + camera.cy
    du = np.clip(u.max(1), 0, camera.width) - np.clip(u.min(1), 0, camera.width)
    dv = np.clip(w.max(1), 0, camera.height) - np.clip(w.min(1), 0, camera.height)
    return np.where(front, du * dv / float(camera.width * camera.height), 0.0)


def follow_camera(scene: Scene, motion) -> Scene:
    """Bind the scene's cars that drive ahead of the camera (:class:`scenes.spec.LeadProgress`) to the
    camera's own progress along the same path (``motion.progress``), so each keeps its headway in
    front of the camera, stopping and starting with it. A motion without such a progress (a drone
    in a room, keyframes) leaves them on their own path. Returns a new Scene (the input is kept)."""
    leader = getattr(motion, "progress", None)
    bodies = list(scene.bodies)
    changed = False
    for i, b in enumerate(bodies):
        prog = getattr(b.motion, "progress", None)
        if isinstance(prog, LeadProgress) and leader is not None and getattr(leader, "path", None) is prog.path:
            bodies[i] = dataclasses.replace(b, motion=PathFollower(prog.following(leader), b.motion.z_m))
            changed = True
    return dataclasses.replace(scene, bodies=bodies) if changed else scene


def separate_movers(scene: Scene, motion, duration_s: float, rng: np.random.Generator, candidates: int = 64) -> Scene:
    """Place the path-following movers (cars) where the camera sees them, clear of it and of each other.

    For each mover, ``candidates`` start points along its path are tried (its own first, then spread
    evenly round the path with a random jitter); among those that keep, within [0, duration_s], the
    camera ``layout['mover_clearance_m']`` away from the mover's footprint (its bounding box in the
    ground plane) and mover centres ``layout['mover_mover_clearance_m']`` apart, the one the camera
    sees most of is kept (the mean over the sequence of :func:`view_fraction` with the scene's
    camera, the first seconds weighted up to 4x); where none keeps the clearances, the one that comes nearest to keeping them. So movers are
    in view from the first frames on: oncoming cars, cars driving ahead, crossing traffic. Returns a
    new Scene (the input is not modified). Movers that do not follow a path (flying boxes) are left
    alone (their space is separated by construction). A scene whose layout says ``movers_placed`` (what
    this function returns) is returned as it is, so a placement can be made once and kept (the stress
    study's scaled movers)."""
    if scene.layout.get("movers_placed"):
        return scene
    cam_clear = float(scene.layout.get("mover_clearance_m", 0.0))
    pair_clear = float(scene.layout.get("mover_mover_clearance_m", 0.0))
    rate = 4.0 * float(getattr(motion, "rate_hz", 10.0))
    times = np.arange(0.0, duration_s + 1.0 / rate, 1.0 / rate)
    world_from_cam = motion.world_from_cam(times)
    cam_from_world = np.linalg.inv(world_from_cam)  # once: every candidate of every mover is seen from it
    cam_xy = world_from_cam[:, :2, 3]
    weights = 1.0 + 3.0 * np.exp(-times / 2.0)  # the first seconds count more: movers in view from the start

    def footprint_distance(body: Body, poses: np.ndarray) -> float:
        v = body.mesh.vertices[:, :2]
        lo, hi = v.min(axis=0), v.max(axis=0)
        rel = cam_xy - poses[:, :2, 3]
        p = np.einsum("nji,nj->ni", poses[:, :2, :2], rel)   # camera in the body frame (xy)
        gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)
        return float(np.min(np.linalg.norm(gap, axis=1)))
    bodies = list(scene.bodies)
    placed: list[np.ndarray] = []
    for i, b in enumerate(bodies):
        if b.kind != RIGID or not isinstance(b.motion, PathFollower) or isinstance(b.motion.progress, LeadProgress):
            continue  # flying boxes are apart by construction; cars ahead of the camera keep their headway
        prog = b.motion.progress
        c0 = float(prog.c(0.0)[0])
        length = prog.path.length
        best, best_key = b, (-np.inf, -np.inf)
        for attempt in range(candidates):
            shift = (attempt + float(rng.uniform(0.0, 1.0))) * length / candidates
            cand = b if attempt == 0 else dataclasses.replace(
                b, motion=PathFollower(_shifted(prog, c0 + shift), b.motion.z_m))
            poses = cand.motion.world_from_body(times)
            xy = poses[:, :2, 3]
            d_cam = footprint_distance(cand, poses) - cam_clear
            d_pair = min([np.min(np.linalg.norm(xy - p, axis=1)) - pair_clear for p in placed], default=np.inf)
            clear = min(d_cam, d_pair)
            seen = float(np.average(view_fraction(cand, poses, cam_from_world, scene.camera), weights=weights))
            key = (0.0, seen) if clear >= 0 else (clear, seen)
            if key > best_key:
                best, best_key = cand, key
        bodies[i] = best
        placed.append(best.motion.world_from_body(times)[:, :2, 3])
    return dataclasses.replace(scene, bodies=bodies, layout={**scene.layout, "movers_placed": True})


def _shifted(prog: PathProgress, c0: float) -> PathProgress:
    return PathProgress(prog.path, prog.speed, c0=c0, ramp_s=prog.ramp_s)


__all__ = ["WorldState", "world_state", "follow_camera", "separate_movers", "view_fraction", "Body"]
