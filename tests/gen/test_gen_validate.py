"""validate-flow: synthesized vs true flow on an analytic sequence with occlusion and a mover, and on a render."""
from __future__ import annotations

import json

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.ours import OursWriter
from deepslam.core.readers import open_sequence
from deepslam.cli import main
from deepslam.gen.flow_reference import synthesize_reference
from deepslam.gen.validate import validate_sequence

CAM = PinholeCamera(64, 48, 50.0, 50.0, 31.5, 23.5)
BOX_X = (-0.6, 0.4)    # world x extent of a board 3 m in front of a wall at 10 m, metres
BOX_Y = (-0.5, 0.5)


def _depth_at(cam_x: float) -> np.ndarray:
    """Depth seen by a camera at (cam_x, 0, 0) looking along +z: wall at 10 m, board at 3 m."""
    u = np.arange(CAM.width)[None, :]
    v = np.arange(CAM.height)[:, None]
    x3 = cam_x + (u - CAM.cx) / CAM.fx * 3.0
    y3 = (v - CAM.cy) / CAM.fy * 3.0
    board = (x3 >= BOX_X[0]) & (x3 <= BOX_X[1]) & (y3 >= BOX_Y[0]) & (y3 <= BOX_Y[1])
    return np.where(board, 3.0, 10.0).astype(np.float32)


def write_analytic_sequence(root, cam_xs=(0.0, 0.12, 0.25, 0.33), mover_shift_px=0.5, flow_error_px=0.0):
    """Camera sliding sideways; true flow from the float64 reference, except on a 'moving' patch
    (mask id 7) whose flow is shifted by ``mover_shift_px``; ``flow_error_px`` adds a wrong offset
    everywhere (for a sequence that must fail)."""
    n = len(cam_xs)
    header = {"num_frames": n, "rate_hz": 10.0, "camera": CAM.to_dict(), "stereo_baseline_m": None,
              "has": {"rgb_right": False, "depth": True, "flow": True, "mask": True}}
    w = OursWriter(root, header)
    poses = [se3.from_rt(np.eye(3), [x, 0.0, 0.0]) for x in cam_xs]
    for t in range(n):
        depth = _depth_at(cam_xs[t])
        mask = np.zeros(depth.shape, np.uint16)
        mask[30:40, 4:14] = 7
        flow = None
        if t < n - 1:
            f, _, _ = synthesize_reference(depth, CAM, se3.relative(poses[t + 1], poses[t]))
            f = f.astype(np.float32)
            f[mask == 7, 0] += mover_shift_px
            f += flow_error_px
            flow = f
        w.write_frame(t, t / 10.0, poses[t], np.zeros((CAM.height, CAM.width, 3), np.uint8), depth=depth,
                      flow=flow, mask=mask)
    w.finish()
    return root


def test_static_visible_matches_and_occlusion_and_movers_are_separated(tmp_path):
    seq = open_sequence(write_analytic_sequence(tmp_path / "seq"))
    r = validate_sequence(seq, progress=False)
    assert r["frames_compared"] == 3 and r["met"]
    assert r["static_visible"]["epe_mean_px"] < 1e-4 and r["static_visible"]["pixels"] > 3 * 1500
    # Wall points that slide behind the board at t+1 are occluded (compared apart, still geometric).
    occl = r["static_occluded"]
    assert occl["pixels"] > 0 and occl["epe_max_px"] < 1e-3
    # Exactly the wall points whose landing spot in frame t+1 has board pixels all around it (the
    # 2x2 pixels of the next depth map), and about the board's slide over the wall:
    # (fx dx / 3 - fx dx / 10) px in each of its rows per step.
    cam_xs = [0.0, 0.12, 0.25, 0.33]
    expected = 0
    for t in range(3):
        d0, d1 = _depth_at(cam_xs[t]), _depth_at(cam_xs[t + 1])
        x1 = np.arange(CAM.width)[None, :] - CAM.fx * (cam_xs[t + 1] - cam_xs[t]) / d0
        y1 = np.broadcast_to(np.arange(CAM.height)[:, None], d0.shape).astype(float)
        x0, y0 = np.floor(x1).astype(int), np.floor(y1).astype(int)
        inside = (x0 >= 0) & (x0 + 1 < CAM.width)
        x0, x1c = np.clip(x0, 0, CAM.width - 1), np.clip(x0 + 1, 0, CAM.width - 1)
        y1c = np.clip(y0 + 1, 0, CAM.height - 1)
        all_board = (d1[y0, x0] == 3) & (d1[y0, x1c] == 3) & (d1[y1c, x0] == 3) & (d1[y1c, x1c] == 3)
        static = np.ones(d0.shape, bool)
        static[30:40, 4:14] = False  # the mover's patch
        expected += int(((d0 == 10) & inside & all_board & static).sum())
    assert occl["pixels"] == expected
    rows = int(np.sum(np.abs((np.arange(CAM.height) - CAM.cy) / CAM.fy * 3.0) <= 0.5))
    slide = sum(rows * CAM.fx * dx * (1 / 3 - 1 / 10) for dx in np.diff(cam_xs))
    assert 0.5 * slide < occl["pixels"] < 1.2 * slide
    # The mover's error is its own motion: 0.5 px.
    assert r["moving"]["pixels"] == 3 * 100 and r["moving"]["epe_mean_px"] == pytest.approx(0.5, abs=1e-4)
    assert set(r["per_instance"]) == {"7"}
    assert r["zbuffer_vs_next_depth"]["agreement"] > 0.99


def test_a_wrong_flow_fails_and_the_cli_reports_it(tmp_path, capsys):
    good = write_analytic_sequence(tmp_path / "good")
    bad = write_analytic_sequence(tmp_path / "bad", flow_error_px=0.05)
    assert main(["validate-flow", "--sequence", str(good), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["met"] and report["static_visible"]["epe_mean_px"] < 1e-4
    assert main(["validate-flow", "--sequence", str(bad)]) == 1
    out = capsys.readouterr().out
    assert "NOT met" in out
    assert main(["validate-flow", "--sequence", str(good), "--frames", "1:3", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames_compared"] == 2


def test_sequences_without_flow_are_bad_input(shared_data, tmp_path, capsys):
    assert main(["validate-flow", "--sequence", str(shared_data / "kitti" / "sequences" / "06")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no depth" in err[0]
    assert main(["validate-flow", "--sequence", str(tmp_path / "absent")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_rendered_sequence(rendered_sequence):
    """The simulator's true flow on static surfaces is what depth + ground-truth pose predict."""
    seq = open_sequence(rendered_sequence)
    r = validate_sequence(seq, progress=False)
    sv = r["static_visible"]
    assert r["met"] and sv["epe_mean_px"] < 0.01 and sv["pixels"] > 0.5 * 3 * 640 * 192
    assert sv["epe_p95_px"] < 0.01
    if r["moving"]["pixels"] > 100:  # cars and flags in view: the rigid-scene assumption breaks there
        assert r["moving"]["epe_mean_px"] > 0.05
