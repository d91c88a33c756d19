"""Simulator speed: 640x480 RGB + depth + ground-truth flow per frame, on each backend, against the
bare renderer calls that produce the same images, measured in the same run on the same scene.

Harness: ``Simulator.frame(i, right=False)`` (state update, colour pass, segmentation/depth
pass(es), depth linearisation, id decoding, mask, exact flow). Baseline: for MuJoCo, the three
``mujoco.Renderer.render()`` calls a user needs for the same images (RGB, depth, segmentation), on
the same model and state; for pyrender, the two ``pyrender.OffscreenRenderer.render()`` calls (RGB
with ``FLAT``, segmentation with depth) on the same scene, and, like for like, three: the harness
renders the street's depth in two slabs (near and far) so that a 24-bit depth buffer stays within
1 mm out to 100 m, which one pass cannot. Overhead = harness time / baseline time - 1. The three variants (bare, harness with flow, without)
run in turn on every frame and each is summarised by its median time per frame, so that load from
other processes on a shared machine hits all of them alike.
Targets: >= 10 frames/s with flow; overhead <= 20 %.
"""
from __future__ import annotations

import dataclasses
import json
import os
import sys
import time

import numpy as np

from deepslam.core.camera import world_from_cam_gl_from_cv

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])


def _sim(backend: str, frames: int):
    from deepslam.scenes import SceneConfig
    from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig

    cfg = SimConfig(SceneConfig(name="street", seed=0, moving_objects=3, deform_amplitude_m=0.2),
                    TrajectoryConfig(frames=frames + 100), RenderConfig(backend=backend, width=640, height=480, stereo_baseline_m=0))
    return Simulator(cfg)


def _interleaved_times(fns: dict, indices) -> dict[str, np.ndarray]:
    """Seconds of each call, per function ((len(indices) - 1,) float64, in the order of the frames), the
    functions called in turn on every frame (so that load from other processes on a shared machine hits
    all of them alike); the first frame is a warm-up (first upload of textures and meshes), not timed."""
    for fn in fns.values():
        fn(indices[0])
    times = {k: [] for k in fns}
    for n, i in enumerate(indices[1:]):
        keys = list(fns)
        keys = keys[n % len(keys):] + keys[:n % len(keys)]
        for k in keys:
            t0 = time.perf_counter()
            fns[k](i)
            times[k].append(time.perf_counter() - t0)
    return {k: np.asarray(v, np.float64) for k, v in times.items()}


def _interleaved(fns: dict, indices) -> dict:
    """Median seconds per call of each function (:func:`_interleaved_times`)."""
    return {k: float(np.median(v)) for k, v in _interleaved_times(fns, indices).items()}


def _bare_mujoco(sim):
    import mujoco

    be = sim.backend
    r = mujoco.Renderer(be.model, sim.camera.height, sim.camera.width)
    cam = be._cams["left"]

    def frame(i):
        be.set_state(sim.state(i))
        r.disable_depth_rendering()
        r.disable_segmentation_rendering()
        r.update_scene(be.data, cam)
        r.render()
        r.enable_depth_rendering()
        r.update_scene(be.data, cam)
        r.render()
        r.enable_segmentation_rendering()
        r.update_scene(be.data, cam)
        r.render()

    return frame, r.close, None


def _bare_pyrender(sim):
    import pyrender

    be = sim.backend

    def frame(i):
        s = sim.state(i)
        be.set_state(s)
        be.pscene.set_pose(be._cam_node, world_from_cam_gl_from_cv(s.world_from_cam))
        be._renderer.render(be.pscene, flags=pyrender.RenderFlags.FLAT)
        be._renderer.render(be.pscene, flags=pyrender.RenderFlags.SEG, seg_node_map=be._seg_map)

    # the backend reads its framebuffers with its own lean read-back; the bare calls get pyrender's
    pr = be._renderer._renderer
    pr_read, pr_viewport = type(pr)._read_main_framebuffer, type(pr)._configure_forward_pass_viewport

    def bare(i, slabs: bool = False):
        ours = pr._read_main_framebuffer, pr._configure_forward_pass_viewport
        pr._read_main_framebuffer = pr_read.__get__(pr)
        pr._configure_forward_pass_viewport = pr_viewport.__get__(pr)
        try:
            frame(i)
            if slabs:  # the harness's depth precision: a second depth slab (see PyrenderBackend.render)
                be._renderer.render(be.pscene, flags=pyrender.RenderFlags.SEG, seg_node_map=be._seg_map)
        finally:
            pr._read_main_framebuffer, pr._configure_forward_pass_viewport = ours

    return bare, lambda: None, (lambda i: bare(i, slabs=True))


def run(quick: bool) -> list[dict]:
    n = 10 if quick else 60
    indices = list(range(40, 40 + n + 1))
    rows = []
    for backend, bare in (("mujoco", _bare_mujoco), ("pyrender", _bare_pyrender)):
        sim = _sim(backend, 40 + n + 1)
        bare_fn, bare_close, bare_slabs = bare(sim)
        fns = {"bare": bare_fn, "flow": lambda i: sim.frame(i, right=False, flow=True),
               "noflow": lambda i: sim.frame(i, right=False, flow=False)}
        if bare_slabs is not None:
            fns["bare_slabs"] = bare_slabs
        try:
            t = _interleaved(fns, indices)
        finally:
            bare_close()
            sim.close()
        t_bare, t_flow, t_noflow = t["bare"], t["flow"], t["noflow"]
        what = "3x mujoco.Renderer.render() (rgb, depth, seg)" if backend == "mujoco" else \
            "2x pyrender.OffscreenRenderer.render() (FLAT rgb, SEG + depth)"
        fps = 1.0 / t_flow
        rows.append({"name": f"{backend} 640x480 rgb+depth+flow", "value": round(fps, 2), "unit": "frames/s",
                     "baseline": f"bare {what}", "baseline_value": round(1.0 / t_bare, 2), "ratio": round(fps * t_bare, 3),
                     "target": ">= 10 frames/s", "met": bool(fps >= 10.0)})
        overhead = 100.0 * (t_flow / t_bare - 1.0)
        rows.append({"name": f"{backend} harness overhead (with flow)", "value": round(overhead, 1), "unit": "%",
                     "baseline": f"bare {what}", "baseline_value": round(1000 * t_bare, 2), "ratio": round(t_flow / t_bare, 3),
                     "target": "<= 20 %", "met": bool(overhead <= 20.0)})
        if "bare_slabs" in t:
            like = 100.0 * (t_flow / t["bare_slabs"] - 1.0)
            rows.append({"name": f"{backend} harness overhead (with flow), like for like", "value": round(like, 1),
                         "unit": "%", "baseline": "bare 3x pyrender.OffscreenRenderer.render() (FLAT rgb, SEG + depth "
                         "in two slabs: the harness's 1 mm depth precision over the street's range)",
                         "baseline_value": round(1000 * t["bare_slabs"], 2), "ratio": round(t_flow / t["bare_slabs"], 3),
                         "target": "<= 20 %", "met": bool(like <= 20.0)})
        rows.append({"name": f"{backend} flow computation per frame", "value": round(1000 * (t_flow - t_noflow), 2), "unit": "ms",
                     "baseline": "frame without flow", "baseline_value": round(1000 * t_noflow, 2),
                     "ratio": round(t_flow / t_noflow, 3), "target": None, "met": None})
    rows.extend(_options(quick))
    rows.extend(_street_styles(quick))
    return rows


def _street_styles(quick: bool) -> list[dict]:
    """Frames/s of the default KITTI-look street against the town street (same seed, movers and frames,
    interleaved); the target: the default street renders no slower than the town (ratio >= 0.9, the noise).
    And the same street with the segmentation pass drawn MuJoCo's own way (into the multisampled buffer,
    then resolved; ``MujocoBackend.segmentation_in_resolve_buffer``) against the default single-sample
    pass: the same bytes, the target is that the default is faster.

    Each ratio is the median over frames of each frame's baseline time over its default time (the
    variants timed one after the other, so that a slow spell of the machine hits all); its quartiles go
    in the baseline's text. The frames are five stretches of 20 consecutive frames spread over the first
    90 s of the route (narrow streets, stops, the avenue; consecutive, as ``deepslam render`` renders
    them, each frame's depth pass made with the previous frame's occlusion test): the two looks' costs
    differ by view (the five stretches' own medians ranged 0.64-1.01 in one run), so one stretch alone
    does not tell."""
    from deepslam.scenes import SceneConfig
    from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig

    starts, n = ((40,), 4) if quick else ((40, 240, 440, 640, 840), 20)
    kitti = SimConfig(SceneConfig(name="street", seed=0, moving_objects=3, street_style="kitti"),
                      TrajectoryConfig(frames=starts[-1] + n + 2), RenderConfig(width=640, height=480, stereo_baseline_m=0))
    town = dataclasses.replace(kitti, scene=dataclasses.replace(kitti.scene, street_style="town"))
    sims = {"kitti": Simulator(kitti), "town": Simulator(town), "mujoco_seg": Simulator(kitti)}
    sims["mujoco_seg"].backend.segmentation_in_resolve_buffer = False
    try:
        fns = {k: (lambda i, s=s: s.frame(i, right=False)) for k, s in sims.items()}
        parts = [_interleaved_times(fns, list(range(a, a + n + 1))) for a in starts]
        t = {k: np.concatenate([part[k] for part in parts]) for k in fns}
    finally:
        for s in sims.values():
            s.close()

    def per_frame(baseline: str) -> tuple[float, str]:
        r = t[baseline] / t["kitti"]
        q25, q75 = np.percentile(r, [25, 75])
        return float(np.median(r)), f"per-frame ratio, quartiles {q25:.2f}-{q75:.2f}"

    fps = round(1.0 / float(np.median(t["kitti"])), 2)
    styles, styles_q = per_frame("town")
    seg, seg_q = per_frame("mujoco_seg")
    return [{"name": "render 640x480 of the KITTI-look street (the default)", "value": fps, "unit": "frames/s",
             "baseline": f"the town street (--street-style town), same frames ({styles_q})",
             "baseline_value": round(1.0 / float(np.median(t["town"])), 2), "ratio": round(styles, 3),
             "target": ">= 0.9 x the town", "met": bool(styles >= 0.9)},
            {"name": "render 640x480 of the default street, segmentation pass in the single-sample buffer", "value": fps,
             "unit": "frames/s", "baseline": f"MuJoCo's own segmentation path (multisampled buffer + resolve; the same "
             f"bytes), same frames ({seg_q})", "baseline_value": round(1.0 / float(np.median(t["mujoco_seg"])), 2),
             "ratio": round(seg, 3), "target": "> 1 (faster)", "met": bool(seg > 1.0)}]


OPTIONS = {
    "motion blur (--exposure-ms 20, 8 renders)": dict(exposure_ms=20.0, blur_samples=8),
    "rolling shutter (--rolling-shutter-ms 30, 32 bands)": dict(rolling_shutter_ms=30.0, rolling_shutter_bands=32),
    "sensor noise + exposure + white balance": dict(sensor_noise=3.0, exposure_jitter=0.3, white_balance_jitter=0.1),
    "lens distortion (EuRoC-like k1..p2)": dict(distortion=(-0.28, 0.07, 2e-4, 2e-5)),
}
"""Camera options timed against the plain render (same scene, same frames, interleaved)."""


def _options(quick: bool) -> list[dict]:
    """Frames/s of each camera option against the plain MuJoCo render with flow, same run."""
    from deepslam.scenes import SceneConfig
    from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig

    n = 4 if quick else 12
    indices = list(range(40, 40 + n + 1))
    base = SimConfig(SceneConfig(name="street", seed=0, moving_objects=3), TrajectoryConfig(frames=40 + n + 2),
                     RenderConfig(width=640, height=480, stereo_baseline_m=0))
    variants = {"plain": base, **{k: dataclasses.replace(base, render=dataclasses.replace(base.render, **v))
                                  for k, v in OPTIONS.items()},
                "random lighting (--random-lighting)": dataclasses.replace(
                    base, scene=dataclasses.replace(base.scene, random_lighting=True))}
    sims = {k: Simulator(c) for k, c in variants.items()}
    try:
        t = _interleaved({k: (lambda i, s=s: s.frame(i, right=False)) for k, s in sims.items()}, indices)
    finally:
        for s in sims.values():
            s.close()
    rows = []
    for k in variants:
        if k == "plain":
            continue
        rows.append({"name": f"render 640x480 with {k}", "value": round(1.0 / t[k], 2), "unit": "frames/s",
                     "baseline": "plain render with flow (mujoco, same frames)", "baseline_value": round(1.0 / t["plain"], 2),
                     "ratio": round(t["plain"] / t[k], 3), "target": None, "met": None})
    return rows


if __name__ == "__main__":
    print(json.dumps(run(quick="--quick" in sys.argv), indent=1))
