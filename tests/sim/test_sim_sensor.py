"""The structured-light depth model: range, noise growing with depth, quantisation, missing readings
at edges; deterministic; the render keeps the exact depth beside it."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core.camera import PinholeCamera
from deepslam.sim.sensor import KinectModel, depth_statistics, kinect_depth

CAM = PinholeCamera(640, 480, 537.0, 537.0, 319.5, 239.5)


def _wall(z: float) -> np.ndarray:
    return np.full((CAM.height, CAM.width), z, np.float32)


@pytest.mark.parametrize("z", [0.3, 1.0, 2.0, 3.5, 5.0])
def test_a_fronto_parallel_wall_at_each_depth(z):
    d = kinect_depth(_wall(z), CAM, np.random.default_rng(0))
    got = d[d > 0]
    m = KinectModel()
    if not m.min_range_m <= z <= m.max_range_m:
        assert got.size == 0  # out of range: no reading at all
        return
    assert 0.994 < got.size / d.size < 0.9995  # only the sparse speckle (0.3 %) is missing
    sigma = m.sigma_a_m + m.sigma_b_per_m * (z - m.sigma_z0_m) ** 2
    step = z * z * m.disparity_step_px / (m.focal_ir_px * m.baseline_m)
    assert abs(float(got.mean()) - z) < 0.2 * sigma + 0.5 * step
    assert 0.7 * np.hypot(sigma, step / np.sqrt(12)) < got.std() < 1.5 * np.hypot(sigma, step / np.sqrt(12))
    assert len(np.unique(got)) < 200  # quantised: a handful of levels, not a continuum


def test_no_reading_behind_an_edge_and_same_seed_same_bytes():
    d = _wall(3.0)
    d[:, 300:] = 1.0  # a near surface on the right: the far side next to it loses its readings
    a = kinect_depth(d, CAM, np.random.default_rng(5))
    b = kinect_depth(d, CAM, np.random.default_rng(5))
    assert np.array_equal(a, b)
    assert (a[:, 298:300] == 0).all()   # the far wall's band next to the jump
    assert (a[:, 301:303] > 0).mean() > 0.95  # the near surface keeps its readings


def test_depth_statistics_of_exact_and_noisy_planes():
    exact = depth_statistics(_wall(2.5))
    assert exact["hole_fraction"] == 0 and exact["plane_residual_std_m"]["2-3 m"] < 1e-9
    noisy = depth_statistics(kinect_depth(_wall(2.5), CAM, np.random.default_rng(1)))
    assert 0.004 < noisy["plane_residual_std_m"]["2-3 m"] < 0.015


def test_render_writes_sensor_depth_and_keeps_the_exact_one(tmp_path):
    from deepslam.cli import main
    from deepslam.core.readers import open_sequence

    out = tmp_path / "room"
    assert main(["render", "--scene", "room", "--frames", "3", "--width", "160", "--height", "120",
                 "--focal-px", "134", "--stereo-baseline", "0", "--depth-noise", "kinect", "--out", str(out),
                 "--quiet"]) == 0
    seq = open_sequence(out)
    sensor, exact = seq.depth(1), np.load(out / "depth_exact" / "000001.npy")
    assert (sensor == 0).mean() > (exact == 0).mean()  # missing readings added
    both = (sensor > 0) & (exact > 0)
    assert 0 < np.abs(sensor[both] - exact[both]).mean() < 0.05
    assert seq.camera.fx == 134.0
    assert np.array_equal(seq.depth_exact(1), exact) and seq.meta["has"]["depth_exact"]

    # training on an estimator's flow: the second view comes from the true surfaces, the network's depth
    # channel reads what the sensor reported (0 where it has no reading), as on a real RGB-D camera
    from deepslam.vo.data.frames import load_image_frames
    from deepslam.vo.data.synthetic import EstimatedFlowSource
    from deepslam.vo.net import inverse_depth_input

    frames = load_image_frames([seq], progress=False)
    assert np.array_equal(frames.depth_z[1], exact) and np.array_equal(frames.depth_sensor[1], sensor)
    assert np.array_equal(frames.subset([1]).network_depth(0), sensor)
    src = EstimatedFlowSource(frames.subset([1]), lambda n, rng: np.tile([0, 0.01, 0, 0.02, 0, 0.05], (n, 1)), "dis",
                              32, 24, 2, threads=1, inv_depth=True)
    inv = next(iter(src.batches(0, 2)))["inv_depth"].numpy()
    assert np.array_equal(inv[0], inverse_depth_input(sensor, 32, 24))
    assert not np.array_equal(inv[0], inverse_depth_input(exact, 32, 24))


def test_a_render_without_a_sensor_model_has_one_depth(tmp_path):
    from deepslam.cli import main
    from deepslam.core.readers import open_sequence
    from deepslam.vo.data.frames import load_image_frames

    out = tmp_path / "room"
    assert main(["render", "--scene", "room", "--frames", "2", "--width", "64", "--height", "48",
                 "--focal-px", "54", "--stereo-baseline", "0", "--out", str(out), "--quiet"]) == 0
    seq = open_sequence(out)
    assert seq.depth_exact_paths is None and not (out / "depth_exact").exists()
    assert np.array_equal(seq.depth_exact(1), seq.depth(1))
    assert load_image_frames([seq], progress=False).depth_sensor is None
