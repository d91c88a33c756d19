"""Scenes whose rigid movers are scaled: the same scene, the same placement, bigger or smaller movers.

:class:`scenes.SceneConfig` has no size knob for the moving objects, so a scale factor is applied to the
meshes of the rigid movers (cars in ``street``, flying boxes in ``room``) about their body origins
(:func:`scaled_movers`), after the movers were placed as for the unscaled scene
(:func:`scene_with_scaled_movers`); the flags are not scaled. The simulator computes exact flow for any
mesh, so a scaled scene is as exact as a built one.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from deepslam.scenes import build_scene
from deepslam.scenes.geometry import MeshData
from deepslam.scenes.spec import RIGID, Scene
from deepslam.sim.config import SimConfig
from deepslam.sim.trajectories import make_motion
from deepslam.sim.world import separate_movers


def scaled_movers(scene: Scene, scale: float) -> Scene:
    """A copy of ``scene`` (a :class:`scenes.spec.Scene`, left unchanged) whose rigid movers' meshes
    are scaled by ``scale`` about their body origins (street cars: the origin is on the road under the
    car's centre, so a scaled car still stands on the road; room boxes: the box centre). Flags and the
    static scene are unchanged; texture coordinates are kept (the texture stretches with the mesh)."""
    if scale == 1.0:
        return scene
    bodies = []
    for b in scene.bodies:
        if b.kind == RIGID:
            m = b.mesh
            b = dataclasses.replace(b, mesh=MeshData(m.vertices * float(scale), m.faces, m.normals, m.texcoords))
        bodies.append(b)
    return dataclasses.replace(scene, bodies=bodies)


def scene_with_scaled_movers(cfg: SimConfig, scale: float) -> Scene:
    """The scene of ``cfg`` (a validated :class:`sim.SimConfig`) with its rigid movers scaled by ``scale``.

    With a scale other than 1 the movers are first placed exactly as the simulator places them for
    the unscaled scene (:func:`sim.world.separate_movers` with the simulator's own generator
    ``[trajectory seed, 2]``), then scaled; the placed scene says ``movers_placed`` so that the
    simulator keeps that placement: a scaled scene differs from its unscaled twin in the size of the
    movers only, not in where they drive (bigger cars would otherwise be pushed away from the camera
    by the clearance rule, and a size sweep would measure fewer dynamic pixels for bigger objects).
    Scale 1 gives the built scene itself.
    """
    base = build_scene(cfg.scene)
    if scale == 1.0:
        return base
    tcfg = cfg.trajectory
    tseed = tcfg.seed if tcfg.seed is not None else cfg.scene.seed
    motion = make_motion(base, tcfg.resolved_kind(base.name), np.random.default_rng([tseed, 1]), tcfg.rate_hz,
                         tcfg.camera_ahead_m, tcfg.body_motion, np.random.default_rng([tseed, 3]))
    placed = separate_movers(base, motion, (tcfg.frames + 1) / float(motion.rate_hz), np.random.default_rng([tseed, 2]))
    return scaled_movers(placed, scale)
