"""Reliability, by class: checks that run before any work, bounded readers, plug-in faults, nothing
half-written, units and calibration, and the extras.

Each class is closed where it starts (deepslam/cli.py ``check_before_work``, core.trajio's bounded
decompression, core.ours' frame count, core.camera's size, distortion and depth-unit checks,
slam.plugins' isolated calls, core.trajectory.check_finite_poses), and each test here is parametrized
over the commands the class touches.
"""
from __future__ import annotations

import gzip
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from deepslam.testing import assert_trajectory_close
from tests.test_reliability import _bounded_cli, _cli, _one_line_exit_2, write_kitti, write_tum

REPO = Path(__file__).resolve().parents[1]
PLUGIN = '''
import os, sys, time
import numpy as np

class O:
    name = "faulty"
    def __init__(self, kind):
        self.kind = kind
    def predict(self, seq, pairs):
        p = len(pairs)
        mean = np.zeros((p, 6)); mean[:, 5] = 0.5
        if self.kind == "overflow": mean[:, 5] = 1e308
        if self.kind == "huge": mean[:, 5] = 1e200
        if self.kind == "exit0": sys.exit(0)
        if self.kind == "osexit": os._exit(0)
        if self.kind == "sleep": time.sleep(600)
        if self.kind == "prints": print("a plug-in talking on stdout")
        return mean, np.full((p, 6), 0.1)

def make(kind):
    return lambda: O(kind)

overflow, huge, exit0, osexit, sleep, prints = (make(k) for k in ("overflow", "huge", "exit0", "osexit", "sleep", "prints"))
'''


@pytest.fixture()
def seq(plane_sequence, tmp_path) -> Path:
    return Path(shutil.copytree(plane_sequence, tmp_path / "seq"))


@pytest.fixture()
def faulty_plugin(tmp_path, monkeypatch) -> str:
    (tmp_path / "plug").mkdir()
    (tmp_path / "plug" / "faulty_odometry.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path / "plug"))
    return "faulty_odometry"


def _child(code: str, timeout_s: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout_s, cwd=REPO,
                          env={**os.environ, "DEEPSLAM_PROGRESS": "0"})


# ---------------------------------------------------------------- missing extras

EXTRA_CASES = [
    (["render", "--scene", "street", "--frames", "2", "--out", "{tmp}/r"], ("mujoco", "pyrender"), "sim"),
    (["stress", "--quick", "--out", "{tmp}/s"], ("mujoco", "pyrender"), "sim"),
    (["dataset", "--out", "{tmp}/d", "--sequences", "1", "--frames", "2"], ("ray",), "ray"),
    (["view", "{seq}", "--save", "{tmp}/v.rrd"], ("rerun",), "viz"),
    (["train", "--mode", "synthetic", "--toy", "100", "--net", "tiny", "--out", "{tmp}/t", "--tensorboard", "{tmp}/tb"],
     ("tensorboard",), "train"),
]


@pytest.mark.parametrize("argv, hidden, extra", EXTRA_CASES, ids=[c[0][0] for c in EXTRA_CASES])
def test_missing_extra_is_one_line_naming_the_extra(argv, hidden, extra, seq, tmp_path):
    argv = [a.format(tmp=tmp_path, seq=seq) for a in argv]
    hide = "; ".join(f"sys.modules[{m!r}] = None" for m in hidden)
    p = _child(f"import sys; {hide}\nfrom deepslam.cli import main; sys.exit(main({argv!r}))")
    err = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2 and len(err) == 1 and "Traceback" not in p.stderr, p.stderr[-2000:]
    assert "pip install" in err[0] and (f"[{extra}]" in err[0] or hidden[0] in err[0]), err
    assert not (tmp_path / argv[argv.index("--out") + 1].split("/")[-1]).exists() if "--out" in argv else True


# ---------------------------------------------------------------- outputs checked before any work

INSIDE_CASES = [
    ("train", ["train", "--mode", "synthetic", "--source", "{seq}", "--motion", "{motion}", "--net", "tiny",
               "--out", "{tmp}/t", "--tensorboard", "{seq}/rgb/tb"], "--tensorboard"),
    ("adapt", ["adapt", "--sequence", "{seq}", "--out", "{tmp}/a", "--tensorboard", "{seq}/tb"], "--tensorboard"),
    ("train-flow", ["train-flow", "--sequence", "{seq}", "--out", "{tmp}/f", "--tensorboard", "{seq}/tb"], "--tensorboard"),
    ("slam-plot", ["slam", "--sequence", "{seq}", "--out", "{tmp}/s.txt", "--plot", "{seq}/p.png"], "--plot"),
    ("slam-vocabulary", ["slam", "--sequence", "{seq}", "--out", "{tmp}/s.txt", "--save-vocabulary", "{seq}/v.npz"],
     "--save-vocabulary"),
    ("view", ["view", "{seq}", "--save", "{seq}/v.rrd"], "--save"),
    ("vo", ["vo", "--sequence", "{seq}", "--out", "{seq}/depth/t.txt"], "--out"),
]


@pytest.mark.parametrize("argv, flag", [c[1:] for c in INSIDE_CASES], ids=[c[0] for c in INSIDE_CASES])
def test_no_output_option_writes_into_an_input(argv, flag, seq, motion_json, tmp_path, capsys):
    before = {p: p.stat().st_mtime_ns for p in seq.rglob("*")}
    rc, err = _cli([a.format(seq=seq, tmp=tmp_path, motion=motion_json) for a in argv], capsys)
    _one_line_exit_2(rc, err, flag, "inside the input")
    assert {p: p.stat().st_mtime_ns for p in seq.rglob("*")} == before  # nothing written into it
    assert not any(tmp_path.glob("[tasf]*")) or not any(p.is_file() for p in tmp_path.rglob("*") if "seq" not in p.parts)


LONG = "n" * 240
LONG_CASES = [
    ("vo", ["vo", "--sequence", "{seq}", "--out", "{tmp}/" + LONG + ".txt"]),
    ("slam", ["slam", "--sequence", "{seq}", "--out", "{tmp}/" + LONG + ".txt"]),
    ("render", ["render", "--scene", "street", "--frames", "2", "--out", "{tmp}/" + LONG]),
    ("eval-plot", ["eval", "--gt", "{seq}/poses.txt", "--est", "{seq}/poses.txt", "--plot", "{tmp}/" + LONG + ".png"]),
]


@pytest.mark.parametrize("argv", [c[1] for c in LONG_CASES], ids=[c[0] for c in LONG_CASES])
def test_output_names_too_long_for_their_side_files_are_refused_first(argv, seq, tmp_path, capsys):
    rc, err = _cli([a.format(seq=seq, tmp=tmp_path) for a in argv], capsys)
    _one_line_exit_2(rc, err, "bytes long")
    assert not any(tmp_path.glob("n*"))


@pytest.mark.parametrize("argv", [
    ["render", "--scene", "street", "--frames", "2", "--out", "{tmp}/r", "--seed", "-1"],
    ["train", "--mode", "synthetic", "--toy", "100", "--net", "tiny", "--out", "{tmp}/t", "--seed", "-1"],
    ["slam", "--sequence", "{seq}", "--out", "{tmp}/s.txt", "--seed", "4294967296"],
    ["adapt", "--sequence", "{seq}", "--out", "{tmp}/a", "--seed", "-3"],
    ["gen", "--source", "{seq}", "--motion", "{motion}", "--samples", "8", "--out", "{tmp}/g", "--seed", "-1"],
], ids=["render", "train", "slam", "adapt", "gen"])
def test_seeds_out_of_range_are_refused_before_work(argv, seq, motion_json, tmp_path, capsys):
    rc, err = _cli([a.format(seq=seq, tmp=tmp_path, motion=motion_json) for a in argv], capsys)
    _one_line_exit_2(rc, err, "--seed must be in 0..4294967295")
    assert not any(tmp_path.iterdir()) or [p.name for p in tmp_path.iterdir()] == ["seq"]


# ---------------------------------------------------------------- bounded readers

def test_trajectory_decompression_bomb_is_refused_in_bounded_memory(seq, tmp_path):
    bomb = tmp_path / "bomb.txt.gz"
    bomb.write_bytes(gzip.compress(b"0 0 0 0 0 0 0 1\n" * (2**20 * 8), 9))  # 0.3 MB -> 128 MiB of text
    rc, err, seconds = _bounded_cli(["eval", "--gt", seq / "poses.txt", "--est", bomb], memory_gib=2.0)
    assert rc == 2 and len(err) == 1 and "decompresses to more than" in err[0], err
    ok = tmp_path / "ok.txt.gz"
    ok.write_bytes(gzip.compress((seq / "poses.txt").read_bytes()))
    rc, err, _ = _bounded_cli(["eval", "--gt", seq / "poses.txt", "--est", ok])
    assert rc == 0, err


@pytest.mark.parametrize("command", ["info", "vo", "slam"])
def test_header_claiming_a_billion_frames_is_refused_against_the_files(command, seq, tmp_path):
    header = json.loads((seq / "sequence.json").read_text())
    header["num_frames"] = 10**9
    (seq / "sequence.json").write_text(json.dumps(header))
    argv = [command, seq] if command == "info" else [command, "--sequence", seq, "--out", tmp_path / "t.txt"]
    rc, err, _ = _bounded_cli(argv, timeout_s=60, memory_gib=3.0)
    assert rc == 2 and len(err) == 1 and "num_frames 1000000000" in err[0] and "000012.png" in err[0], err


def test_render_too_small_for_flow_is_refused_and_writes_nothing(tmp_path, capsys):
    rc, err = _cli(["render", "--scene", "street", "--frames", "2", "--width", "8", "--out", tmp_path / "r"], capsys)
    _one_line_exit_2(rc, err, "too small for optical flow")
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("command", ["vo", "slam", "adapt", "validate-flow"])
def test_sequences_too_small_for_flow_are_refused_before_work(command, tmp_path, capsys):
    small = write_kitti(tmp_path / "k", n=4, w=24, h=8)
    out = ["--out", tmp_path / ("o" if command == "adapt" else "o.txt")] if command != "validate-flow" else []
    rc, err = _cli([command, "--sequence", small, *out], capsys)
    _one_line_exit_2(rc, err, "too small for optical flow")
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.txt").exists()


# ---------------------------------------------------------------- model files, settings, resume

def test_adapt_checks_its_model_file_kind_before_work(seq, tmp_path, capsys):
    import pickle

    pick = tmp_path / "old.pt"
    pick.write_bytes(pickle.dumps({"state_dict": {}}))
    flow_model = REPO / "models" / "flow_learned.safetensors"
    for model, needle in ((pick, "pickle-based"), (flow_model, "deepslam-flow-model")):
        rc, err = _cli(["adapt", "--sequence", seq, "--out", tmp_path / "a", "--model", model], capsys)
        _one_line_exit_2(rc, err, needle)
        assert not (tmp_path / "a").exists()


def test_adapt_resume_with_a_truncated_settings_file_is_one_line(seq, tmp_path, capsys):
    out = tmp_path / "a"
    out.mkdir()
    (out / "settings.json").write_text('{"sequence": "')
    rc, err = _cli(["adapt", "--sequence", seq, "--out", out, "--resume", "--samples", "128", "--epochs", "1",
                    "--no-loops", "--quiet"], capsys)
    _one_line_exit_2(rc, err, "settings.json")


def test_train_model_file_is_the_same_bytes_header_included(tmp_path):
    argv = ["train", "--mode", "synthetic", "--toy", "200", "--net", "tiny", "--max-epochs", "2", "--nll-epochs", "1",
            "--threads", "1", "--out", tmp_path / "run", "--quiet"]
    assert _bounded_cli(argv)[0] == 0  # two processes, as a user runs them
    first = (tmp_path / "run" / "model.safetensors").read_bytes()
    shutil.rmtree(tmp_path / "run")
    assert _bounded_cli(argv)[0] == 0
    assert (tmp_path / "run" / "model.safetensors").read_bytes() == first


# ---------------------------------------------------------------- plug-in faults, nothing half-written

PLUGIN_FAULTS = [("overflow", "at most 1e+06 m"), ("huge", "at most 1e+06 m"), ("exit0", "sys.exit(0)"),
                 ("osexit", "ended without an answer"), ("sleep", "no answer within 2 s")]


@pytest.mark.parametrize("command", ["vo", "slam"])
@pytest.mark.parametrize("kind, needle", PLUGIN_FAULTS, ids=[k for k, _ in PLUGIN_FAULTS])
def test_plugin_faults_are_one_line_naming_it_and_write_nothing(command, kind, needle, faulty_plugin, seq, tmp_path,
                                                                capsys):
    rc, err = _cli([command, "--sequence", seq, "--odometry", f"{faulty_plugin}:{kind}", "--command-timeout", "2",
                    "--out", tmp_path / "out" / "t.txt", "--quiet"] + (["--no-loops"] if command == "slam" else []),
                   capsys)
    _one_line_exit_2(rc, err, f"{faulty_plugin}:{kind}", needle)
    assert not any((tmp_path / "out").glob("*")) if (tmp_path / "out").exists() else True


@pytest.mark.parametrize("command", ["vo", "slam"])
def test_plugin_prints_never_reach_json_output(command, faulty_plugin, seq, tmp_path, capfd):
    from deepslam.cli import main

    rc = main([command, "--sequence", str(seq), "--odometry", f"{faulty_plugin}:prints", "--out",
               str(tmp_path / "t.txt"), "--json"] + (["--no-loops"] if command == "slam" else []))
    out = capfd.readouterr().out
    assert rc == 0
    json.loads(out)  # stdout is the one JSON object


def test_an_isolated_plugin_may_use_torch_after_the_parent_did():
    """A forked child that uses the thread pool its parent started hangs; the plug-in's child runs torch on one
    thread (the stress study runs the network, then the plug-ins)."""
    import torch

    from deepslam.slam.plugins import call_isolated

    torch.randn(256, 256) @ torch.randn(256, 256)  # the parent's pool is started
    conv = torch.nn.Conv2d(3, 8, 3)
    conv(torch.randn(4, 3, 32, 32))
    out = call_isolated(lambda: float(conv(torch.randn(4, 3, 32, 32)).sum()) * 0 + 1.0, "torch-plug-in", 60)
    assert out == 1.0


def test_chained_trajectory_must_be_finite():
    from deepslam.core.errors import InputError
    from deepslam.core.trajectory import check_finite_poses

    poses = np.tile(np.eye(4), (5, 1, 1))
    check_finite_poses(poses, "x")
    poses[3, 0, 3] = np.inf
    with pytest.raises(InputError, match="not finite from pose 3"):
        check_finite_poses(poses, "the odometry x")


def test_vo_on_two_frames_writes_an_unscored_run_and_slam_refuses_before_work(seq, tmp_path, capsys):
    rc, _ = _cli(["vo", "--sequence", seq, "--end", "2", "--out", tmp_path / "v" / "t.txt", "--quiet"], capsys)
    assert rc == 0 and (tmp_path / "v" / "t.txt").is_file() and not (tmp_path / "v" / "t.metrics.json").exists()
    two = write_kitti(tmp_path / "k2", n=2, w=64, h=32)
    rc, err = _cli(["slam", "--sequence", two, "--out", tmp_path / "s" / "t.txt", "--quiet"], capsys)
    _one_line_exit_2(rc, err, "at least 3")
    assert not (tmp_path / "s").exists() or not any((tmp_path / "s").iterdir())


# ---------------------------------------------------------------- units and calibration

@pytest.mark.parametrize("command", ["info", "vo", "adapt"])
def test_tum_depth_in_other_units_is_refused(command, tmp_path, capsys):
    tum = write_tum(tmp_path, n=4, w=64, h=32)
    (tum / "depth_scale.txt").write_text("5000000\n")  # the depth's 1 m read as 0.2 mm
    argv = {"info": ["info", tum], "vo": ["vo", "--sequence", tum, "--out", tmp_path / "t.txt"],
            "adapt": ["adapt", "--sequence", tum, "--out", tmp_path / "a"]}[command]
    rc, err = _cli(argv, capsys)
    _one_line_exit_2(rc, err, "median depth", "other units")


@pytest.mark.parametrize("kind", ["tum", "euroc"])
def test_distortion_that_blacks_out_the_image_is_refused(kind, tmp_path, capsys):
    from tests.test_reliability import write_euroc

    if kind == "tum":
        root = write_tum(tmp_path, n=4, w=64, h=32)
        (root / "intrinsics.txt").write_text("30 30 32 16 1e30 0 0 0\n")
    else:
        root = write_euroc(tmp_path / "e", w=64, h=32)
        y = root / "mav0" / "cam0" / "sensor.yaml"
        y.write_text(y.read_text().replace("distortion_coefficients: [0.0, 0.0, 0.0, 0.0]",
                                           "distortion_coefficients: [1.0e+30, 0.0, 0.0, 0.0]"))
    rc, err = _cli(["info", root], capsys)
    _one_line_exit_2(rc, err, "distortion coefficients", "outside the recorded frame")


# ---------------------------------------------------------------- info --check reads what readers read

@pytest.mark.parametrize("folder", ["occlusion", "flow_backward", "flow_flo"])
def test_info_check_reads_every_file_a_reader_reads(folder, tmp_path, capsys):
    from deepslam.core import flowio

    from deepslam.cli import main

    assert main(["render", "--scene", "street", "--frames", "4", "--width", "64", "--out", str(tmp_path / "r"),
                 "--quiet"]) == 0
    r = tmp_path / "r"
    if folder == "flow_flo":
        flowio.write_flo(r / "flow" / "000001.flo", np.zeros((5, 7, 2), np.float32))  # a copy of another size
        target = r / "flow" / "000001.flo"
    else:
        target = sorted((r / folder).iterdir())[1]
        target.write_bytes(target.read_bytes()[:60])  # truncated
    capsys.readouterr()
    rc, err = _cli(["info", r, "--check", "--quiet"], capsys)
    _one_line_exit_2(rc, err, target.name)


# ---------------------------------------------------------------- deepslam.testing, records

def test_testing_refuses_degenerate_alignments():
    still = np.tile(np.eye(4), (20, 1, 1))
    wander = still.copy()
    wander[:, 0, 3] = np.linspace(0, 9, 20)
    with pytest.raises(AssertionError, match="stands still"):
        assert_trajectory_close(still, wander, 0.1, align="sim3")
    with pytest.raises(AssertionError, match="at least 3"):
        assert_trajectory_close(wander[:2], wander[:2], 0.1, align="sim3")
    assert assert_trajectory_close(wander, wander * 1.0, 1e-9, align="sim3")["rmse_m"] < 1e-9


def test_vo_record_names_its_sequence_absolutely(seq, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(seq.parent)
    rc, _ = _cli(["vo", "--sequence", "seq", "--out", tmp_path / "v" / "t.txt", "--quiet"], capsys)
    assert rc == 0
    assert json.loads((tmp_path / "v" / "t.config.json").read_text())["sequence"] == str(seq.resolve())


def test_view_save_on_a_full_disk_is_one_line_and_leaves_nothing(seq, tmp_path, capsys):
    small = tmp_path / "small"
    small.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(small)], capture_output=True).returncode:
        pytest.skip("needs root to mount a 64 kB tmpfs")
    try:
        rc, err = _cli(["view", seq, "--save", small / "v.rrd"], capsys)
        _one_line_exit_2(rc, err, "no space left")
        assert list(small.iterdir()) == []
    finally:
        subprocess.run(["umount", str(small)], capture_output=True)


def test_only_motion_specs_are_cut_to_their_file():
    from deepslam.cli import _paths

    assert _paths("motion", ["m.json:loops@2", "n.json@0.5", "o.json"]) == ["m.json", "n.json", "o.json"]
    assert _paths("out", "runs@2/t:loops.txt") == ["runs@2/t:loops.txt"]  # a path with @ or : is a path
    assert _paths("source", ["a", Path("b"), None, ""]) == ["a", "b"]
