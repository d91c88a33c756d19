"""Fixtures of the gen tests: a tiny depth sequence in our format, a KITTI motion model, a rendered sequence."""
from __future__ import annotations

from pathlib import Path

import pytest

from deepslam.core.ours import OursWriter
from gen_scenes import write_depth_sequence


@pytest.fixture(scope="session")
def depth_sequence(tmp_path_factory) -> Path:
    return write_depth_sequence(tmp_path_factory.mktemp("depthseq") / "seq")


@pytest.fixture(scope="session")
def motion_json(tmp_path_factory) -> Path:
    """A KITTI-like motion model written by hand (no data needed): about 0.9 m forward per frame."""
    from deepslam.gen.motion import MotionModel, SixDof, StudentT

    six = SixDof((StudentT(3.1, 0.0, 0.002, -0.026, 0.022), StudentT(0.73, 0.0, 0.002, -0.074, 0.083),
                  StudentT(2.0, 0.0, 0.0016, -0.02, 0.019), StudentT(2.0, 0.001, 0.008, -0.07, 0.08),
                  StudentT(3.6, 0.017, 0.01, -0.03, 0.09), StudentT(3.4, -0.93, 0.29, -2.9, 0.03)), 1000)
    path = tmp_path_factory.mktemp("motion") / "motion.json"
    MotionModel(1, six, sources=("hand-made",)).save(path)
    return path


@pytest.fixture(scope="session")
def rendered_sequence(tmp_path_factory) -> Path:
    """4 frames of the street scene at 640x192 with stereo, moving cars and waving flags, in our format."""
    pytest.importorskip("mujoco")
    try:
        from deepslam.scenes import SceneConfig
        from deepslam.sim.config import RenderConfig, SimConfig, TrajectoryConfig
        from deepslam.sim.simulator import Simulator
    except ImportError as e:  # the simulator is another package of this project
        pytest.skip(f"simulator not importable: {e}")
    root = tmp_path_factory.mktemp("rendered") / "street"
    n = 4
    cfg = SimConfig(SceneConfig(name="street", seed=0, moving_objects=4, deform_amplitude_m=0.2),
                    TrajectoryConfig(frames=n), RenderConfig(width=640, height=192))
    with Simulator(cfg) as sim:
        header = {"num_frames": n, "rate_hz": sim.rate_hz, "camera": sim.camera.to_dict(),
                  "stereo_baseline_m": sim.baseline_m,
                  "has": {"rgb_right": True, "depth": True, "flow": True, "mask": True}}
        w = OursWriter(root, header)
        for i in range(n):
            f = sim.frame(i)
            w.write_frame(i, f.timestamp_s, f.world_from_cam, f.rgb, f.depth_z, f.flow if i < n - 1 else None,
                          f.mask, f.rgb_right)
        w.finish()
    return root
