"""``deepslam eval`` and ``python -m deepslam.studies.demo_reference``: output, JSON, plots, and bad input (exit 2, one line)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepslam.core import se3
from deepslam.core.trajectory import Trajectory
from deepslam.core.trajio import write_trajectory
from deepslam.cli import main

REPO = Path(__file__).resolve().parents[1]


def _car(n: int = 300, step_m: float = 0.5, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    yaw = np.cumsum(rng.normal(0, 0.02, size=n))
    rot = Rotation.from_euler("y", yaw[:, None]).as_matrix()
    pos = np.concatenate([[np.zeros(3)], np.cumsum(rot[:-1, :, 2] * step_m, axis=0)])
    return se3.from_rt(rot, pos)


@pytest.fixture
def pair(tmp_path):
    """A 150 m KITTI ground truth and an estimate with 2 % too long steps."""
    gt = _car()
    est = gt.copy()
    est[:, :3, 3] *= 1.02
    write_trajectory(tmp_path / "gt.txt", Trajectory(gt), "kitti")
    write_trajectory(tmp_path / "est.txt", Trajectory(est), "kitti")
    return tmp_path / "gt.txt", tmp_path / "est.txt"


def test_eval_table(pair, capsys):
    gt, est = pair
    assert main(["eval", "--gt", str(gt), "--est", str(est)]) == 0
    out = capsys.readouterr().out
    assert "ATE rmse" in out and "KITTI t_err" in out
    rows = out.split("length [m]")[1].strip().splitlines()[1:]
    assert [r.split()[0] for r in rows] == ["100"]  # 150 m of ground truth: only 100 m segments
    assert float(rows[0].split()[2]) == pytest.approx(2.0, abs=0.1)  # t_err of 2 % longer steps


def test_eval_json_one_object_with_required_keys(pair, capsys):
    gt, est = pair
    assert main(["eval", "--gt", str(gt), "--est", str(est), "--json", "--align", "none"]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    r = json.loads(out)
    for key in ("ate_m", "rpe_t_m", "rpe_r_deg", "kitti_t_err_pct", "kitti_r_err_deg_per_100m", "n_matched"):
        assert isinstance(r[key], (int, float)), key
    assert r["kitti_t_err_pct"] == pytest.approx(2.0, abs=0.1)  # steps 2 % too long
    assert r["kitti_r_err_deg_per_100m"] == pytest.approx(0.0, abs=1e-6)
    assert r["gt_format"] == r["est_format"] == "kitti" and r["n_matched"] == 300


def test_eval_mixed_formats_and_plot(tmp_path, capsys):
    """ASL csv ground truth (ns) against a TUM estimate (s) at a different rate: associated by time."""
    gt = _car(n=400, step_m=0.05, seed=1)
    t = 1403715524.9 + np.arange(400) * 0.05
    write_trajectory(tmp_path / "gt.csv", Trajectory(gt, t), "euroc")
    moved = se3.from_rt(Rotation.from_euler("z", [[0.7]]).as_matrix()[0], [3.0, -2.0, 1.0]) @ gt[::3]
    write_trajectory(tmp_path / "est.tum", Trajectory(moved, t[::3] + 0.002), "tum")
    png = tmp_path / "plot.png"
    assert main(["eval", "--gt", str(tmp_path / "gt.csv"), "--est", str(tmp_path / "est.tum"), "--json",
                 "--plot", str(png)]) == 0
    r = json.loads(capsys.readouterr().out)
    assert (r["gt_format"], r["est_format"], r["matched_by"]) == ("euroc", "tum", "timestamps")
    assert r["n_matched"] == 134
    assert r["ate_m"] == pytest.approx(0.0, abs=1e-6)
    assert "kitti_t_err_pct" not in r  # 20 m of ground truth
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000


K = "1 0 0 0 0 1 0 0 0 0 1 {z}"

BAD = {
    "columns": ("\n".join([K.format(z=0), K.format(z=1), "1 0 0 0 0 1 0 0 0 0 1"]), ":3:"),
    "non_number": ("\n".join([K.format(z=0), K.format(z="1.0x")]), ":2:"),
    "nan": ("\n".join([K.format(z=0), K.format(z=1), K.format(z="nan")]), ":3:"),
    "rotation": ("\n".join([K.format(z=0), "1 0.1 0 0 0 1 0 0 0 0 1 1"]), ":2:"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_estimate_exits_2_with_one_line(tmp_path, pair, capsys, case):
    gt, _ = pair
    text, where = BAD[case]
    bad = tmp_path / f"bad_{case}.txt"
    bad.write_text(text + "\n")
    png = tmp_path / "never.png"
    assert main(["eval", "--gt", str(gt), "--est", str(bad), "--plot", str(png)]) == 2
    cap = capsys.readouterr()
    assert cap.out == ""
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1, cap.err
    assert str(bad) + where in lines[0] and "Traceback" not in cap.err
    assert not png.exists() and not list(tmp_path.glob(".never*"))


def test_no_association_exits_2_naming_both_files(tmp_path, capsys):
    write_trajectory(tmp_path / "gt.txt", Trajectory(_car(50), np.arange(50.0)), "tum")
    write_trajectory(tmp_path / "est.txt", Trajectory(_car(50), np.arange(50.0) + 500.0), "tum")
    png = tmp_path / "p.png"
    assert main(["eval", "--gt", str(tmp_path / "gt.txt"), "--est", str(tmp_path / "est.txt"),
                 "--plot", str(png)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert str(tmp_path / "gt.txt") in err and str(tmp_path / "est.txt") in err
    assert not png.exists()


def test_missing_file_and_length_mismatch_exit_2(tmp_path, pair, capsys):
    gt, est = pair
    assert main(["eval", "--gt", str(tmp_path / "missing.txt"), "--est", str(est)]) == 2
    err = capsys.readouterr().err
    assert "missing.txt: no such file" in err and len(err.strip().splitlines()) == 1
    write_trajectory(tmp_path / "short.txt", Trajectory(_car(100)), "kitti")
    assert main(["eval", "--gt", str(gt), "--est", str(tmp_path / "short.txt")]) == 2
    assert "counts must be equal" in capsys.readouterr().err
    assert main(["eval", "--gt", str(gt), "--est", str(est), "--format", "tum"]) == 2
    assert ":1: expected 8 columns" in capsys.readouterr().err


def test_python_m_deepslam_eval_end_to_end(pair):
    gt, est = pair
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.run([sys.executable, "-m", "deepslam", "eval", "--gt", str(gt), "--est", str(est), "--json"],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["kitti_t_err_pct"] == pytest.approx(2.0, abs=0.1)
    bad = gt.parent / "bad.txt"
    bad.write_text("1 2 3\n")
    proc = subprocess.run([sys.executable, "-m", "deepslam", "eval", "--gt", str(gt), "--est", str(bad)],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and f"{bad}:1:" in proc.stderr


def test_eval_on_kitti_00_orb(shared_data, capsys):
    assert main(["eval", "--gt", str(shared_data / "kitti/poses/00.txt"),
                 "--est", str(shared_data / "reference/KITTI_00_ORB.txt"), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["kitti_t_err_pct"] == pytest.approx(0.70, abs=0.05)
    assert r["kitti_r_err_deg_per_100m"] == pytest.approx(0.25, abs=0.03)
    assert [row["length_m"] for row in r["kitti_per_length"]] == [100.0 * k for k in range(1, 9)]


def test_reference_report(shared_data, tmp_path, capsys):
    from deepslam.studies import demo_reference as demo

    assert demo.main(["--data", str(shared_data), "--out", str(tmp_path / "demo")]) == 0
    out = capsys.readouterr().out
    assert "KITTI 00 ORB-SLAM2" in out and "0.700" in out
    assert out.strip().splitlines()[-1] == f"report: {tmp_path / 'demo' / 'reference.md'}"
    report = (tmp_path / "demo" / "reference.md").read_text()
    assert "| KITTI 00 ORB-SLAM2 | se3 | 4541 |" in report
    for png in ("kitti00_topdown.png", "kitti00_per_length.png", "euroc_v102_topdown.png"):
        assert (tmp_path / "demo" / png).read_bytes()[:4] == b"\x89PNG"


def test_eval_several_estimates_one_row_each_and_a_json_list(pair, tmp_path, capsys):
    gt, est = pair
    assert main(["eval", "--gt", str(gt), "--est", str(est), "--json"]) == 0
    single = json.loads(capsys.readouterr().out)
    exact = tmp_path / "exact.txt"
    exact.write_bytes(gt.read_bytes())
    png = tmp_path / "both.png"
    assert main(["eval", "--gt", str(gt), "--est", str(est), "--est", str(exact), "--json", "--plot", str(png)]) == 0
    both = json.loads(capsys.readouterr().out)
    assert isinstance(both, list) and [r["est"] for r in both] == [str(est), str(exact)]
    assert both[0]["kitti_t_err_pct"] == pytest.approx(single["kitti_t_err_pct"], rel=1e-12)
    assert both[1]["ate_m"] == pytest.approx(0.0, abs=1e-9)
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert main(["eval", "--gt", str(gt), "--est", str(est), "--est", str(exact)]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.startswith(("est.txt", "exact.txt"))}
    assert set(rows) == {"est.txt", "exact.txt"}
    assert float(rows["est.txt"][-2]) == pytest.approx(single["kitti_t_err_pct"], abs=1e-4)
    assert float(rows["exact.txt"][4]) == pytest.approx(0.0, abs=1e-4)  # ATE column


def test_eval_several_estimates_one_bad_exits_2(pair, tmp_path, capsys):
    gt, est = pair
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2 3\n")
    assert main(["eval", "--gt", str(gt), "--est", str(est), "--est", str(bad)]) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and f"{bad}:1:" in cap.err and len(cap.err.strip().splitlines()) == 1
