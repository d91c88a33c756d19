"""The simulator: perfect ground truth (RGB, depth, flow, poses, dynamic masks) rendered with
MuJoCo or pyrender along scripted car and drone trajectories.

Quick use (in memory)::

    from deepslam.scenes import SceneConfig
    from deepslam.sim import SimConfig, TrajectoryConfig, RenderConfig, Simulator

    cfg = SimConfig(SceneConfig(name="street", seed=0, moving_objects=2, deform_amplitude_m=0.2),
                    TrajectoryConfig(kind="car", frames=100),
                    RenderConfig(backend="mujoco", width=320))      # height follows the aspect
    with Simulator(cfg) as sim:
        f = sim.frame(10)        # SimFrame: rgb, depth_z, flow (to frame 11), mask, world_from_cam,
                                 #           rgb_right, body, instance_poses, camera
        traj = sim.trajectory    # core.trajectory.Trajectory of all frames (OpenCV camera axes)

To disk (our format, KITTI or EuRoC layout, atomic and resumable)::

    from deepslam.sim import render_sequence
    render_sequence(cfg, "out/street00", fmt="kitti", resume=False, progress=True)

Conventions (as everywhere in the project): OpenCV camera axes, world z up, metres, float64 poses,
``depth_z`` float32 along the optical axis (0 = nothing hit), ``flow[v, u] = (du, dv)`` pixels from
frame i to i+1 with pixel centres at integers, uint8 images, uint16 masks (0 = static scene).

What is exact:
- poses: analytic (C2 splines), the same numbers drive both renderers;
- depth_z: the renderer's depth buffer sampled at pixel centres, linearised in float64. MuJoCo
  renders reversed-Z into a float buffer (error ~1e-6 relative, checked against analytic planes);
  pyrender's 24-bit buffer is rendered in two depth slabs to stay below ~0.1 mm at 200 m. The two
  backends agree within 1 mm (99.9 % of pixels within 0.2 mm; only surfaces seen so obliquely that
  depth changes by metres between neighbouring pixels differ more, by < 1/5000 px of sampling);
- flow: from geometry (depth, per-pixel body ids from a segmentation pass, the bodies' rigid
  motions, the flags' barycentric deformation), so unprojecting a pixel with its depth, moving it
  with its surface and projecting lands where the flow says (to float32 rounding);
- pixel convention: pixel centres at integers, principal point ((W-1)/2, (H-1)/2), fx = fy,
  checked per backend against projected geometry (tests/sim/test_sim_render_geometry.py); a principal
  point elsewhere (``RenderConfig.principal_point_px``) is the window of a larger centred render
  (tests/sim/test_sim_principal_point.py).

Custom scenes and motions: ``Simulator(config, scene=my_scene, motion=my_motion)`` where
``my_scene`` is a :class:`scenes.spec.Scene` (see ``scenes.testing``) and ``my_motion`` anything
with ``world_from_cam(t) -> (N, 4, 4)`` and ``rate_hz`` (e.g. :class:`sim.trajectories.KeyframeMotion`).

Both backends can live in one process: each makes its own EGL context current before rendering,
and the pyrender backend frees its context without ``eglTerminate`` (pyrender's own ``delete()``
terminates the process-wide EGL display and breaks every MuJoCo renderer, live or future). Set
``MUJOCO_GL=egl PYOPENGL_PLATFORM=egl`` before importing mujoco/pyrender for headless use
(importing ``sim`` first sets them when they are unset).

Speed (640x480, RGB + depth + flow, mono, 2 CPU cores, llvmpipe): about 20 frames/s per backend on
an idle machine; see bench/bench_render.py.
"""
from __future__ import annotations

import os as _os

# headless rendering by default (must be set before mujoco / pyrender are first imported)
_os.environ.setdefault("MUJOCO_GL", "egl")
_os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa" if _os.environ["MUJOCO_GL"] == "osmesa" else "egl")

from deepslam.scenes import SceneConfig  # noqa: E402
from deepslam.sim.config import BACKENDS, FORMATS, TRAJECTORY_KINDS, RenderConfig, SimConfig, TrajectoryConfig, camera_for
from deepslam.sim.simulator import SimFrame, Simulator
from deepslam.sim.trajectories import CarMotion, DroneMotion, KeyframeMotion, make_motion
from deepslam.sim.writers import render_sequence as _render


def render_sequence(config: SimConfig, out_dir, fmt: str = "ours", resume: bool = False, progress: bool = True,
                    sequence: str = "00"):
    """Render ``config`` into ``out_dir`` in format ``fmt`` ("ours", "kitti", "euroc", "tum"); see
    :func:`sim.writers.render_sequence`. Returns the output path of the sequence."""
    return _render(config, out_dir, fmt=fmt, resume=resume, progress=progress, sequence=sequence)


__all__ = ["SceneConfig", "SimConfig", "TrajectoryConfig", "RenderConfig", "Simulator", "SimFrame", "render_sequence",
           "camera_for", "KeyframeMotion", "CarMotion", "DroneMotion", "make_motion", "BACKENDS", "FORMATS",
           "TRAJECTORY_KINDS"]
