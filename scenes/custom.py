"""Your own meshes in a scene: a scene file names a base scene and adds OBJ / GLB / PLY meshes (read with
trimesh) as static or moving bodies, with the same exact ground truth as the built-in bodies.

A scene file (YAML or JSON; paths relative to the file)::

    scene: street            # the base scene: street or room
    seed: 4                  # its seed (``deepslam render --seed`` overrides it when given)
    meshes:
      - file: bunny.ply      # anything trimesh loads as a triangle mesh (scenes are merged)
        scale: 2.0           # metres per mesh unit (default 1)
        rgb: [200, 120, 80]  # its colour (default: the mesh's own mean colour, else grey)
        xyz: [20.0, -4.0, 0.0]   # where its origin stands, world frame, metres (z up)
        yaw_deg: 30          # turned about z (default 0)
      - file: cart.glb
        path:                # a mover: drives round the closed polyline through these points
          waypoints: [[0, -2], [40, -2], [40, 2], [0, 2]]
          speed_mps: 4.0
          z_m: 0.0

Static meshes join the scene as bodies of their own (mask id 0, like the built-in static scene); a
mesh with a ``path`` is a rigid mover (its own instance id in ``mask/``, its pose in every frame
record, exact flow) and, like the street's cars, starts where the camera sees it
(:func:`sim.world.separate_movers`). Faces are flat-shaded from a fixed sun into a strip of colour
patches appended to the scene's texture atlas (the other bodies' texture coordinates are rescaled
to the taller atlas, so their texels do not change).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.textio import loads_yaml, read_text, short
from deepslam.scenes.geometry import MeshData, PeriodicPath
from deepslam.scenes.spec import RIGID, STATIC, Body, PathFollower, PathProgress, StaticPose, speed_profile

SHADE_LEVELS = 8
"""Shades of each mesh's colour (flat shading by the face normal)."""
PATCH_PX = 8
SUN = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
AMBIENT = 0.55
BASE_SCENES = ("street", "room")


@dataclasses.dataclass(frozen=True)
class UserMesh:
    """One mesh of a scene file (see the module docstring for the fields)."""

    file: Path
    """The mesh file (absolute)."""
    scale: float = 1.0
    """Metres per mesh unit."""
    rgb: tuple[int, int, int] | None = None
    """Colour, or None for the mesh's own mean colour (grey without one)."""
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Position of a static mesh's origin, world frame, metres."""
    yaw_deg: float = 0.0
    """Turn of a static mesh about the world z axis, degrees."""
    waypoints: tuple[tuple[float, float], ...] | None = None
    """A mover's closed polyline (x, y), metres; None: static."""
    speed_mps: float = 3.0
    """A mover's cruise speed, m/s."""
    z_m: float = 0.0
    """A mover's height of its origin, metres."""


@dataclasses.dataclass(frozen=True)
class SceneFile:
    """A parsed scene file."""

    path: Path
    """The file."""
    base: str
    """The base scene: street or room."""
    seed: int | None
    """The base scene's seed, or None (the command's)."""
    meshes: tuple[UserMesh, ...]
    """The meshes to add."""


def is_scene_file(name: str) -> bool:
    """Whether a ``--scene`` value names a scene file (by its extension) rather than a built-in scene."""
    return str(name).lower().endswith((".yaml", ".yml", ".json"))


def _numbers(v, n: int | None, what: str, path: Path) -> tuple[float, ...]:
    try:
        out = tuple(float(x) for x in v)
    except (TypeError, ValueError):
        raise InputError(path, f"{what} must be a list of numbers, got {short(v)}") from None
    if (n is not None and len(out) != n) or not np.isfinite(out).all():
        raise InputError(path, f"{what} must be {n or 'some'} finite numbers, got {short(v)}")
    return out


def load_scene_file(path: str | Path) -> SceneFile:
    """Parse and check a scene file; InputError naming the file (and the mesh entry) when it is wrong."""
    path = Path(path).resolve()
    text = read_text(path, "scene file")
    # bounded YAML (JSON is read as YAML too): aliases limited, no duplicate keys, at most 1 MB (core.textio)
    doc = loads_yaml(text, path, "scene file (YAML/JSON)")
    if not isinstance(doc, dict):
        raise InputError(path, "a scene file holds a mapping (scene, seed, meshes)")
    unknown = sorted(short(str(k), 40) for k in doc if k not in ("scene", "seed", "meshes"))
    if unknown:
        raise InputError(path, f"unknown key(s) {short(', '.join(unknown[:8]), 200)} (scene, seed, meshes)")
    base = doc.get("scene", "street")
    if not isinstance(base, str) or base not in BASE_SCENES:
        raise InputError(path, f"scene must be one of {', '.join(BASE_SCENES)}, got {short(base)}")
    seed = doc.get("seed")
    if seed is not None and (not isinstance(seed, int) or seed < 0):
        raise InputError(path, f"seed must be a non-negative integer, got {short(seed)}")
    entries = doc.get("meshes") or []
    if not isinstance(entries, list):
        raise InputError(path, "meshes must be a list")
    meshes = []
    for k, e in enumerate(entries):
        where = f"meshes[{k}]"
        if not isinstance(e, dict) or "file" not in e:
            raise InputError(path, f"{where} must be a mapping with a file")
        bad = sorted(short(str(x), 40) for x in e if x not in ("file", "scale", "rgb", "xyz", "yaw_deg", "path"))
        if bad:
            raise InputError(path, f"{where}: unknown key(s) {short(', '.join(bad[:8]), 200)}")
        f = (path.parent / str(e["file"])).resolve()
        if not f.is_file():
            raise InputError(path, f"{where}: mesh file {f} does not exist")
        scale = float(_numbers([e.get("scale", 1.0)], 1, f"{where}.scale", path)[0])
        if not 1e-6 <= scale <= 1e6:
            raise InputError(path, f"{where}.scale must be in [1e-6, 1e6], got {scale}")
        rgb = None
        if e.get("rgb") is not None:
            c = _numbers(e["rgb"], 3, f"{where}.rgb", path)
            if not all(0 <= x <= 255 for x in c):
                raise InputError(path, f"{where}.rgb must be three numbers in 0..255")
            rgb = tuple(int(round(x)) for x in c)
        kw = dict(file=f, scale=scale, rgb=rgb, xyz=_numbers(e.get("xyz", (0, 0, 0)), 3, f"{where}.xyz", path),
                  yaw_deg=float(_numbers([e.get("yaw_deg", 0.0)], 1, f"{where}.yaw_deg", path)[0]))
        if e.get("path") is not None:
            p = e["path"]
            if not isinstance(p, dict) or "waypoints" not in p:
                raise InputError(path, f"{where}.path must be a mapping with waypoints")
            pts = [_numbers(w, 2, f"{where}.path.waypoints", path) for w in p["waypoints"]]
            if len(pts) < 3:
                raise InputError(path, f"{where}.path.waypoints needs at least 3 points (a closed loop)")
            speed = float(_numbers([p.get("speed_mps", 3.0)], 1, f"{where}.path.speed_mps", path)[0])
            if not 0.1 <= speed <= 60:
                raise InputError(path, f"{where}.path.speed_mps must be in [0.1, 60], got {speed}")
            kw.update(waypoints=tuple(pts), speed_mps=speed,
                      z_m=float(_numbers([p.get("z_m", 0.0)], 1, f"{where}.path.z_m", path)[0]))
        meshes.append(UserMesh(**kw))
    return SceneFile(path, base, seed, tuple(meshes))


def _load_mesh(m: UserMesh, source: Path):
    """(vertices (V, 3) float64 m, faces (F, 3) int, colour (3,) float) of a mesh file, scaled."""
    import trimesh  # deferred: trimesh is the [sim] extra, needed only for a scene file's own meshes

    try:
        mesh = trimesh.load(m.file, force="mesh", process=False)
    except Exception as e:  # noqa: BLE001 - trimesh raises many kinds
        raise InputError(source, f"cannot read mesh {m.file} ({type(e).__name__}: {e})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(source, f"mesh {m.file} has no triangles")
    if len(mesh.faces) > 2_000_000:
        raise InputError(source, f"mesh {m.file} has {len(mesh.faces)} triangles (at most 2,000,000)")
    v = np.asarray(mesh.vertices, np.float64) * m.scale
    if not np.isfinite(v).all():
        raise InputError(source, f"mesh {m.file} has non-finite vertices")
    colour = np.array(m.rgb, np.float64) if m.rgb is not None else None
    if colour is None:
        try:
            fc = np.asarray(mesh.visual.to_color().face_colors, np.float64)[:, :3]
            colour = fc.mean(0) if len(fc) else None
        except Exception:  # noqa: BLE001 - no usable colour in the file
            colour = None
    if colour is None:
        colour = np.array([150.0, 150.0, 150.0])
    return v, np.asarray(mesh.faces, np.int64), colour


def add_user_meshes(scene, spec: SceneFile):
    """A new Scene: ``scene`` (built from the file's base) with the file's meshes added as bodies."""
    if not spec.meshes:
        return scene
    loaded = [_load_mesh(m, spec.path) for m in spec.meshes]
    atlas = scene.atlas
    ah, aw = atlas.shape[:2]
    per_row = max(1, aw // PATCH_PX)
    n_patches = len(loaded) * SHADE_LEVELS
    rows = -(-n_patches // per_row)
    strip = np.zeros((rows * PATCH_PX, aw, 3), np.uint8)
    centres = np.zeros((n_patches, 2))
    for k, (_, _, colour) in enumerate(loaded):
        for lvl in range(SHADE_LEVELS):
            p = k * SHADE_LEVELS + lvl
            r, c = divmod(p, per_row)
            shade = AMBIENT + (1.0 - AMBIENT) * lvl / (SHADE_LEVELS - 1)
            strip[r * PATCH_PX:(r + 1) * PATCH_PX, c * PATCH_PX:(c + 1) * PATCH_PX] = np.clip(colour * shade, 0, 255)
            centres[p] = ((c + 0.5) * PATCH_PX, ah + (r + 0.5) * PATCH_PX)
    new_h = ah + strip.shape[0]
    new_atlas = np.concatenate([atlas, strip], axis=0)
    squeeze = ah / new_h

    def rescaled(mesh: MeshData) -> MeshData:
        tc = mesh.texcoords.copy()
        tc[:, 1] *= squeeze
        return MeshData(mesh.vertices, mesh.faces, mesh.normals, tc)

    bodies = [dataclasses.replace(b, mesh=rescaled(b.mesh)) for b in scene.bodies]
    next_id = max([b.instance_id for b in bodies] + [0]) + 1
    for k, (m, (v, f, _)) in enumerate(zip(spec.meshes, loaded)):
        tri = v[f]                                           # (F, 3, 3) flat-shaded: vertices per face
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.where(norm > 0, n / np.maximum(norm, 1e-300), np.array([0.0, 0.0, 1.0]))
        if m.waypoints is None:
            yaw = np.radians(m.yaw_deg)
            rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]])
            n_world = n @ rot.T
        else:
            n_world = n  # a mover: shaded as in its body frame, like the street's cars
        lvl = np.clip(np.rint(np.maximum(n_world @ SUN, 0.0) * (SHADE_LEVELS - 1)), 0, SHADE_LEVELS - 1).astype(int)
        uv = centres[k * SHADE_LEVELS + lvl] / np.array([aw, new_h])
        mesh = MeshData(tri.reshape(-1, 3), np.arange(len(f) * 3, dtype=np.int32).reshape(-1, 3),
                        np.repeat(n, 3, axis=0), np.repeat(uv, 3, axis=0))
        name = f"user{k}_{m.file.stem}"[:60]
        if m.waypoints is None:
            pose = se3.from_rt(rot, np.asarray(m.xyz, np.float64))
            bodies.append(Body(name, mesh, STATIC, 0, StaticPose(pose)))
        else:
            pts = np.asarray(m.waypoints, np.float64)
            sides = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
            try:
                if sides.min() < 1e-3:
                    raise ValueError("two consecutive waypoints coincide")
                # fillets of at most 2 m that leave every side a straight part; samples every <= 1 m
                path = PeriodicPath.from_polyline(pts, min(2.0, 0.3 * float(sides.min())),
                                                  step_m=min(1.0, float(sides.sum()) / 200.0))
                prof = speed_profile(path, m.speed_mps, lat_accel_mps2=3.0, long_accel_mps2=1.5)
            except ValueError as e:
                raise InputError(spec.path, f"meshes[{k}].path: not a usable closed path ({e})") from None
            bodies.append(Body(name, mesh, RIGID, next_id, PathFollower(PathProgress(path, prof, 0.0), m.z_m)))
            next_id += 1
    return dataclasses.replace(scene, atlas=new_atlas, bodies=bodies)
