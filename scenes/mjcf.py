"""MJCF (MuJoCo XML) for a :class:`scenes.spec.Scene`.

One mesh geom per body (the static scene is one mesh), all sharing one material with the scene's
texture atlas; rigid movers are mocap bodies; flags are meshes whose vertices the simulator
rewrites each frame; a camera rig (a mocap body) carries the left camera and, optionally, the right
one at ``+baseline`` along the rig's x axis. The rig frame IS the left camera's OpenGL frame
(x right, y up, z backward), as MuJoCo cameras look along their -z axis.

Lighting is baked into the atlas, so the model renders unlit: the headlight is pure ambient
(1, 1, 1) and the material has no specular or reflection; a texel renders as its atlas colour.
The atlas is declared as a flat builtin texture of the right size and filled in after compiling
(``sim.render_mujoco.compile_model``: this package does not import MuJoCo), which is much faster
than encoding it; :func:`write_mjcf` writes a stand-alone folder (XML + atlas.png) for inspection
in MuJoCo's viewer.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from deepslam.core import atomic, se3
from deepslam.scenes.spec import RIGID, Scene

RIG_BODY = "camera_rig"
LEFT_CAMERA = "left"
RIGHT_CAMERA = "right"
OFFSCREEN_SAMPLES = 4
"""Multisampling of the offscreen buffer (the colour pass's antialiasing; 0: none)."""


def _floats(a) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(a))


def _ints(a) -> str:
    return " ".join(str(int(x)) for x in np.ravel(a))


def mesh_name(i: int) -> str:
    return f"mesh{i}"


def geom_name(i: int) -> str:
    return f"geom{i}"


def scene_xml(scene: Scene, width: int, height: int, fov_y_deg: float, baseline_m: float | None,
              atlas_file: str | None = None) -> str:
    """The MJCF text. ``width``/``height`` size the offscreen buffer; ``fov_y_deg`` is the vertical
    field of view of both cameras; ``baseline_m`` adds the right camera (None: mono). With
    ``atlas_file`` the atlas texture is read from that file, else it is a flat placeholder of the
    atlas' size to be filled by ``sim.render_mujoco.compile_model``."""
    extent = float(scene.zfar_m)
    ah, aw = scene.atlas.shape[:2]
    sky = " ".join(f"{c / 255.0:.6f}" for c in scene.sky_rgb)
    tex = (f'<texture name="atlas" type="2d" file="{atlas_file}"/>' if atlas_file else
           f'<texture name="atlas" type="2d" builtin="flat" width="{aw}" height="{ah}" rgb1="0 0 0" rgb2="0 0 0"/>')
    out = [
        f'<mujoco model="{scene.name}">',
        '  <compiler angle="radian" balanceinertia="true" boundmass="1e-4" boundinertia="1e-8"/>',
        '  <visual>',
        f'    <global offwidth="{int(width)}" offheight="{int(height)}"/>',
        f'    <quality shadowsize="0" offsamples="{OFFSCREEN_SAMPLES}"/>',
        '    <headlight active="1" ambient="1 1 1" diffuse="0 0 0" specular="0 0 0"/>',
        f'    <map znear="{scene.znear_m / extent!r}" zfar="{scene.zfar_m / extent!r}"/>',
        '  </visual>',
        f'  <statistic extent="{extent!r}" center="{_floats((scene.bounds[0] + scene.bounds[1]) / 2)}"/>',
        '  <asset>',
        f'    {tex}',
        f'    <texture name="sky" type="skybox" builtin="flat" rgb1="{sky}" rgb2="{sky}" width="8" height="8"/>',
        '    <material name="atlas" texture="atlas" specular="0" shininess="0" reflectance="0" emission="0"/>',
    ]
    for i, b in enumerate(scene.bodies):
        m = b.mesh
        # MuJoCo reads texcoords with t counted from the image's first row, as the scene does.
        out.append(f'    <mesh name="{mesh_name(i)}" inertia="shell" vertex="{_floats(m.vertices)}" '
                   f'normal="{_floats(m.normals)}" texcoord="{_floats(m.texcoords)}" face="{_ints(m.faces)}"/>')
    out += ['  </asset>', '  <worldbody>']
    for i, b in enumerate(scene.bodies):
        attrs = f'name="{geom_name(i)}" type="mesh" mesh="{mesh_name(i)}" material="atlas" contype="0" conaffinity="0"'
        pose = b.motion.world_from_body(0.0)[0]
        if b.kind == RIGID:
            out.append(f'    <body name="{b.name}" mocap="true" pos="{_floats(pose[:3, 3])}"><geom {attrs}/></body>')
        else:  # static (also deforming flags): a world geom at its fixed pose
            out.append(f'    <geom {attrs} pos="{_floats(pose[:3, 3])}" quat="{_floats(se3.to_quat_wxyz(pose))}"/>')
    cams = [f'<camera name="{LEFT_CAMERA}" pos="0 0 0" quat="1 0 0 0" fovy="{float(fov_y_deg)!r}"/>']
    if baseline_m:
        cams.append(f'<camera name="{RIGHT_CAMERA}" pos="{float(baseline_m)!r} 0 0" quat="1 0 0 0" fovy="{float(fov_y_deg)!r}"/>')
    out.append(f'    <body name="{RIG_BODY}" mocap="true">{"".join(cams)}</body>')
    out += ['  </worldbody>', '</mujoco>']
    return "\n".join(out) + "\n"


def write_mjcf(scene: Scene, folder: str | Path, width: int = 640, height: int = 480, fov_y_deg: float = 45.0,
               baseline_m: float | None = None) -> Path:
    """Write ``<folder>/<scene>.xml`` and ``atlas.png`` (a model MuJoCo's viewer opens)."""
    folder = Path(folder)
    atomic.write_png(folder / "atlas.png", scene.atlas)
    path = folder / f"{scene.name}.xml"
    atomic.write_text(path, scene_xml(scene, width, height, fov_y_deg, baseline_m, atlas_file="atlas.png"))
    return path
