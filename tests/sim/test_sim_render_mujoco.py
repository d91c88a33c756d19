"""The MuJoCo backend's segmentation pass (drawn into the single-sample resolve buffer) against MuJoCo's
own path: the same bytes, and the colour pass after it unharmed."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.scenes import SceneConfig, mjcf
from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig


def _config(scene: str) -> SimConfig:
    return SimConfig(SceneConfig(name=scene, seed=3, moving_objects=2, deform_amplitude_m=0.2, texture_px_per_m=6),
                     TrajectoryConfig(frames=80), RenderConfig(width=160, stereo_baseline_m=0.5))


@pytest.mark.parametrize("reference", ["mujoco path", "no multisampling"])
@pytest.mark.parametrize("scene", ["street", "room"])
def test_segmentation_pass_matches_mujocos_path(scene, reference, monkeypatch):
    fast = Simulator(_config(scene))
    colour_only = Simulator(_config(scene))   # never runs a segmentation pass
    if reference == "no multisampling":
        monkeypatch.setattr(mjcf, "OFFSCREEN_SAMPLES", 0)
    ref = Simulator(_config(scene))
    ref.backend.segmentation_in_resolve_buffer = reference != "mujoco path"
    try:
        assert fast.backend._con.offFBO_r and bool(ref.backend._con.offFBO_r) == (reference == "mujoco path")
        seen = set()
        for i in (0, 37, 79):
            for sim in (fast, ref, colour_only):
                sim.backend.set_state(sim.state(i))
            for side in ("left", "right"):
                # this colour pass follows the previous view's segmentation pass
                a = fast.backend.render(side, colour=True, depth=True)
                b = ref.backend.render(side, colour=False, depth=True)
                assert np.array_equal(a["body"], b["body"])
                assert np.array_equal(a["depth_z"], b["depth_z"])
                assert (a["body"] >= 0).mean() > 0.5
                seen.update(np.unique(a["body"]).tolist())
                rgb = colour_only.backend.render(side, colour=True, depth=False)["rgb"]
                assert np.array_equal(a["rgb"], rgb) and rgb.std() > 5
        assert len(seen) > 1   # movers or flags in view, not only the static scene
    finally:
        for sim in (fast, ref, colour_only):
            sim.close()
