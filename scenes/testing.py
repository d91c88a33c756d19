"""Small scenes with known geometry for tests and examples (fast to build and render).

- :func:`plane_scene`: one textured plane (the front face of a thin box) at a known pose.
- :func:`mini_scene`: a small textured hall with a few boxes, one flying box and one flag.

The camera of both looks along world +y from the origin (use :func:`looking_along_y`).
"""
from __future__ import annotations

import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.scenes import textures as tx
from deepslam.scenes.assemble import Assembler, flag_painter
from deepslam.scenes.geometry import AtlasBuilder, MeshBuilder
from deepslam.scenes.spec import RIGID, STATIC, Body, FlagDeform, Orbiter, Scene, StaticPose

TEST_CAMERA = PinholeCamera(160, 120, 100.0, 100.0, 79.5, 59.5)


def looking_along_y(position=(0.0, 0.0, 0.0)) -> np.ndarray:
    """world_from_cam (OpenCV axes) at ``position`` looking along world +y, z up."""
    rot = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # columns: x_cam = +x, y_cam = -z, z_cam = +y
    return se3.from_rt(rot, np.asarray(position, np.float64))


def plane_scene(distance_m: float = 3.0, rotation: np.ndarray | None = None, half_size_m: float = 30.0,
                px_per_m: float = 40.0, seed: int = 0) -> Scene:
    """A plane facing the camera at the origin: the front face of a 0.1 m thick box whose front
    face's centre is at (0, distance_m, 0) and whose normal is ``rotation @ (0, -1, 0)``."""
    rng = np.random.default_rng(seed)
    rot = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
    atlas = AtlasBuilder(px_per_m, rng, max_texels=4_000_000)
    front = atlas.region(2 * half_size_m, 2 * half_size_m, tx.facade(rng.spawn(1)[0]))
    back = atlas.region(1, 1, tx.flat((100, 100, 100)))
    mb = MeshBuilder()
    centre = np.array([0.0, distance_m, 0.0]) + rot @ np.array([0.0, 0.05, 0.0])
    faces = {"-y": front, "+y": back, "+x": back, "-x": back, "+z": back, "-z": back}
    mb.add_box(se3.from_rt(rot, centre), np.array([half_size_m, 0.05, half_size_m]), faces)
    img = atlas.build()
    bodies = [Body("static", mb.finish(atlas), STATIC, 0, StaticPose(np.eye(4)))]
    r = half_size_m + distance_m + 1
    return Scene("plane", seed, img, bodies, TEST_CAMERA, 0.1, 10.0, 0.05, 4 * r, (0, 0, 0),
                 np.array([[-r, -r, -r], [r, r, r]]))


def marker_scene(camera: PinholeCamera, rect_px: tuple[float, float, float, float], marker_depth_m: float = 2.0,
                 plane_depth_m: float = 4.0, px_per_m: float = 20.0, seed: int = 0) -> Scene:
    """A flat quad facing the camera at the origin (looking along +y) whose corners project exactly
    to the pixel rectangle ``rect_px = (u_left, v_top, u_right, v_bottom)`` of ``camera`` at depth
    ``marker_depth_m``, in front of a plane at ``plane_depth_m``. Body 0 is the plane, body 1 the
    marker (both static)."""
    rng = np.random.default_rng(seed + 1)
    atlas = AtlasBuilder(px_per_m, rng)
    plane_region = atlas.region(1, 1, tx.flat((90, 90, 90)))  # re-texture the plane: one region atlas
    marker_region = atlas.region(1, 1, tx.flat((240, 40, 40), 0.0))
    world_from_cam = looking_along_y()
    ul, vt, ur, vb = rect_px

    def corner(u, v):
        return se3.transform_points(world_from_cam, camera.unproject(np.array([[u, v]]), np.array([marker_depth_m])))[0]

    mb = MeshBuilder()
    mb.add_quad(corner(ul, vb), corner(ur, vb), corner(ur, vt), corner(ul, vt), marker_region)
    pb = MeshBuilder()
    h = 30.0
    pb.add_quad((-h, plane_depth_m, -h), (h, plane_depth_m, -h), (h, plane_depth_m, h), (-h, plane_depth_m, h), plane_region)
    img = atlas.build()
    bodies = [Body("static", pb.finish(atlas), STATIC, 0, StaticPose(np.eye(4))),
              Body("marker", mb.finish(atlas), STATIC, 0, StaticPose(np.eye(4)))]
    bounds = np.array([[-h, -1.0, -h], [h, plane_depth_m + 1.0, h]])
    return Scene("marker", seed, img, bodies, camera, 0.1, 10.0, 0.05, 4 * h, (0, 0, 0), bounds)


def mini_scene(seed: int = 0, moving: bool = True, deform_amplitude_m: float = 0.15, px_per_m: float = 40.0) -> Scene:
    """A 10 m x 10 m x 4 m hall centred at (0, 5, 0) (floor at z = -1.5), textured walls, three boxes,
    a flying box near (0.8, 4, 0) and a flag near (-1, 4.5, 0.5) facing the camera."""
    rng = np.random.default_rng(seed)
    asm = Assembler(px_per_m, rng, sun_dir=(0.3, -0.5, 0.8), ambient=0.6, max_texels=6_000_000)
    cy, fz, h = 5.0, -1.5, 4.0
    asm.box((0, cy, fz - 0.1), (5, 5, 0.1), {"+z": tx.floor_mat})
    asm.box((0, cy + 5.1, fz + h / 2), (5, 0.1, h / 2), {"-y": tx.indoor_wall(rng.spawn(1)[0])})
    asm.box((-5.1, cy, fz + h / 2), (0.1, 5, h / 2), {"+x": tx.indoor_wall(rng.spawn(1)[0])})
    asm.box((5.1, cy, fz + h / 2), (0.1, 5, h / 2), {"-x": tx.indoor_wall(rng.spawn(1)[0])})
    for c, s, yaw in (((-2.0, 7.0, fz + 0.5), (0.5, 0.4, 0.5), 0.3), ((2.2, 6.0, fz + 0.4), (0.4, 0.6, 0.4), -0.5),
                      ((0.5, 8.5, fz + 0.8), (0.8, 0.3, 0.8), 0.1)):
        asm.box(c, s, {f: tx.cardboard for f in ("+x", "-x", "+y", "-y", "+z")}, yaw=yaw)
    deform = FlagDeform(nx=21, nz=11, length_m=1.0, height_m=0.6, amplitude_m=float(deform_amplitude_m), wavelength_m=0.8,
                        freq_hz=0.9, phase=0.3, tilt_rad_per_m=1.0)
    world_from_flag = np.eye(4)
    world_from_flag[:3, 3] = (-1.5, 4.5, 0.2)  # x along world x, z up, waving along world y (towards the camera)
    asm.box((-1.53, 4.5, -0.65), (0.03, 0.03, 0.85), {f: tx.metal() for f in ("+x", "-x", "+y", "-y", "+z")})
    asm.flag("flag", world_from_flag, deform, flag_painter(rng.spawn(1)[0]), dynamic=deform_amplitude_m > 0)
    if moving:
        motion = Orbiter(centre=np.array([0.0, 4.0]), r0=0.8, r_amp=0.1, th0=0.0, th_amp=0.6, z0=0.0, z_amp=0.2,
                         freq_hz=np.array([0.3, 0.25, 0.4]), phase=np.array([0.1, 0.2, 0.3]), rot0=np.eye(3),
                         spin_rad_s=np.array([0.8, 0.5]))
        b = asm.dynamic_builder("box", RIGID, motion)
        asm.box((0, 0, 0), (0.25, 0.2, 0.15), {f: tx.cardboard for f in ("+x", "-x", "+y", "-y", "+z", "-z")}, builder=b)
    atlas, bodies = asm.finish()
    bounds = np.array([[-5.2, -0.2, fz - 0.2], [5.2, cy + 5.2, fz + h]])
    return Scene("mini", seed, atlas, bodies, TEST_CAMERA, 0.1, 10.0, 0.05, 40.0, (0, 0, 0), bounds)
