"""Reliability: bounded parsers, outputs that never clobber inputs, strict readers.

Bounded parsing: a "billion laughs" YAML (scene file, EuRoC sensor.yaml), 50,000-deep JSON (a sequence
header, a model file's tree) and a model file of 100,000 tensors are each one line and exit 2, quickly
and in bounded memory. Outputs: no command writes onto or into one of its inputs, vo/slam side files
are overwritten only when an earlier run of the same command wrote them, and a second vo into a
folder another run holds is refused naming it. Readers: one file per frame, TUM listings in time
order, frames at the camera's size wherever they are read, no calibration key twice, and dataset
listings that stay inside the dataset.
"""
from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from deepslam.core.errors import InputError

REPO = Path(__file__).resolve().parents[1]


def _cli(argv: list[str], capsys) -> tuple[int, list[str]]:
    from deepslam.cli import main

    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    return rc, [ln for ln in err.splitlines() if ln.strip()]


def _one_line_exit_2(rc: int, err: list[str], *needles: str) -> None:
    assert rc == 2 and len(err) == 1 and "Traceback" not in err[0], err
    for n in needles:
        assert n in err[0], (n, err)


def _bounded_cli(argv: list[str], timeout_s: float = 120, memory_gib: float = 6.0) -> tuple[int, list[str], float]:
    """Run ``deepslam`` in a child process with a wall-clock limit and an address-space cap, so that a
    parser that blows up fails this test instead of taking the machine."""
    def limit():
        cap = int(memory_gib * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

    env = {**os.environ, "DEEPSLAM_PROGRESS": "0"}
    t0 = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, "-m", "deepslam", *map(str, argv)], capture_output=True, text=True,
                           timeout=timeout_s, env=env, preexec_fn=limit, cwd=REPO)
    except subprocess.TimeoutExpired:
        pytest.fail(f"deepslam {argv[0]} ran past {timeout_s} s")
    return p.returncode, [ln for ln in p.stderr.splitlines() if ln.strip()], time.perf_counter() - t0


def _laughs(indent: str = "  ") -> str:
    """A flow sequence of nine anchors, each nine aliases of the one before: 9^9 (~4e8) strings."""
    rows = [f'{indent}- &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    prev = "a"
    for name in "bcdefghi":
        rows.append(f"{indent}- &{name} [" + ",".join([f"*{prev}"] * 9) + "]")
        prev = name
    return "\n".join(rows) + "\n"


# ---------------------------------------------------------------- tiny datasets, written here

def _png(path: Path, img: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), img)
    return path


def _grey(h: int, w: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, (h, w), dtype=np.uint8)


def write_kitti(root: Path, n: int = 5, w: int = 40, h: int = 24) -> Path:
    seq = root / "sequences" / "00"
    for i in range(n):
        _png(seq / "image_0" / f"{i:06d}.png", _grey(h, w, i))
    (seq / "calib.txt").write_text(f"P0: 30 0 {w / 2} 0 0 30 {h / 2} 0 0 0 1 0\n")
    (seq / "times.txt").write_text("".join(f"{0.1 * i:e}\n" for i in range(n)))
    return seq


SENSOR_YAML = """sensor_type: camera
rate_hz: 20
resolution: [{w}, {h}]
camera_model: pinhole
intrinsics: [30.0, 30.0, {cx}, {cy}]
distortion_model: {model}
distortion_coefficients: [0.0, 0.0, 0.0, 0.0]
T_BS:
  cols: 4
  rows: 4
  data: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
"""


def write_euroc(root: Path, n: int = 4, w: int = 48, h: int = 32, model: str = "radial-tangential",
                extra: str = "") -> Path:
    cam = root / "mav0" / "cam0"
    lines = ["#timestamp [ns],filename"]
    for i in range(n):
        ns = 1_000_000_000 + 50_000_000 * i
        _png(cam / "data" / f"{ns}.png", _grey(h, w, i))
        lines.append(f"{ns},{ns}.png")
    (cam / "data.csv").write_text("\n".join(lines) + "\n")
    (cam / "sensor.yaml").write_text(SENSOR_YAML.format(w=w, h=h, cx=w / 2, cy=h / 2, model=model) + extra)
    return root


def write_tum(root: Path, n: int = 4, w: int = 40, h: int = 24) -> Path:
    root = root / "rgbd_dataset_freiburg3_tiny"
    rgb, depth = ["# colour"], ["# depth"]
    for i in range(n):
        t = 100.0 + i / 30
        _png(root / "rgb" / f"{t:.6f}.png", np.dstack([_grey(h, w, i)] * 3))
        _png(root / "depth" / f"{t:.6f}.png", np.full((h, w), 5000, np.uint16))
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth.append(f"{t + 0.001:.6f} depth/{t:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (root / "depth.txt").write_text("\n".join(depth) + "\n")
    return root


@pytest.fixture()
def plane_copy(plane_sequence, tmp_path) -> Path:
    """A private copy of the shared 12-frame plane sequence (ours format), safe to damage."""
    return Path(shutil.copytree(plane_sequence, tmp_path / "seq"))


def _digest(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# ---------------------------------------------------------------- item 2: bounded parsing

def test_billion_laughs_scene_file_is_one_line_exit_2_quickly(tmp_path):
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("scene:\n" + _laughs())
    assert len(bomb.read_bytes()) < 400
    rc, err, took = _bounded_cli(["render", "--scene", bomb, "--frames", "2", "--width", "32", "--out",
                                  tmp_path / "out", "--quiet"])
    _one_line_exit_2(rc, err, "bomb.yaml", "alias")
    assert took < 60 and not (tmp_path / "out").exists()


def test_billion_laughs_euroc_sensor_yaml_is_one_line_exit_2_quickly(tmp_path):
    root = write_euroc(tmp_path / "euroc", model="\n" + _laughs())
    rc, err, took = _bounded_cli(["info", root])
    _one_line_exit_2(rc, err, "sensor.yaml", "alias")
    assert took < 60


def test_yaml_limits_in_process():
    from deepslam.core.textio import YAML_MAX_BYTES, loads_yaml

    t0 = time.perf_counter()
    with pytest.raises(InputError, match="alias"):
        loads_yaml("x:\n" + _laughs(), "f.yaml")
    with pytest.raises(InputError, match="more than 100 aliases"):
        loads_yaml("a: &a 1\nb: [" + ", ".join(["*a"] * 101) + "]\n", "f.yaml")
    with pytest.raises(InputError, match="recursive"):
        loads_yaml("a: &a [1, *a]\n", "f.yaml")
    with pytest.raises(InputError, match="too large"):
        loads_yaml("#" * (YAML_MAX_BYTES + 1), "f.yaml")
    assert time.perf_counter() - t0 < 5
    assert loads_yaml("a: &x [1, 2]\nb: *x\n", "f.yaml") == {"a": [1, 2], "b": [1, 2]}  # a few aliases are fine


def test_yaml_duplicate_key_is_refused_naming_the_line(tmp_path, capsys):
    root = write_euroc(tmp_path / "euroc", extra="intrinsics: [31.0, 31.0, 24.0, 16.0]\n")
    rc, err = _cli(["info", root], capsys)
    _one_line_exit_2(rc, err, "sensor.yaml:12", "intrinsics", "twice")


def test_error_messages_quote_values_short(tmp_path, capsys):
    scene = tmp_path / "long.yaml"
    scene.write_text("scene: " + "x" * 5000 + "\n")
    rc, err = _cli(["render", "--scene", scene, "--frames", "2", "--out", tmp_path / "out"], capsys)
    _one_line_exit_2(rc, err, "long.yaml")
    assert len(err[0]) < 400


def test_deep_json_sequence_header_is_one_line_exit_2(tmp_path, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    (seq / "sequence.json").write_text('{"format": ' + "[" * 50_000 + "]" * 50_000 + "}")
    rc, err = _cli(["info", seq], capsys)
    _one_line_exit_2(rc, err, "sequence.json", "nested too deeply")


def test_deep_json_motion_model_and_slam_params_are_refused(tmp_path):
    from deepslam.gen.motion import MotionModel
    from deepslam.slam.pipeline import SlamParams

    deep = tmp_path / "deep.json"
    deep.write_text("[" * 50_000 + "]" * 50_000)
    for load in (MotionModel.load, SlamParams.load):
        with pytest.raises(InputError, match="nested"):
            load(deep)


def test_shard_manifest_is_bounded_and_confined(tmp_path):
    from deepslam.gen.shards import verify

    (tmp_path / "manifest.json").write_text('{"shards": ' + "[" * 50_000 + "]" * 50_000 + "}")
    with pytest.raises(InputError, match="nested"):
        verify(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"shards": [{"name": "../x.tar", "sha256": "0"}]}))
    with pytest.raises(InputError, match="leaves the dataset folder"):
        verify(tmp_path)


def _safetensors_bytes(entries: dict, metadata: dict, data: bytes) -> bytes:
    header = json.dumps({"__metadata__": metadata, **entries}, separators=(",", ":")).encode()
    header += b" " * (-len(header) % 8)
    return len(header).to_bytes(8, "little") + header + data


def test_deep_model_tree_is_one_line_exit_2(tmp_path, capsys):
    from deepslam.models import modelfile

    path = tmp_path / "deep.safetensors"
    tree = '{"net": ' + "[" * 50_000 + "]" * 50_000 + "}"
    path.write_bytes(_safetensors_bytes({"w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}},
                                        {"deepslam": "deepslam-vo-model", "tree": tree}, b"\0" * 4))
    with pytest.raises(InputError, match="nested too deeply"):
        modelfile.load(path, ("deepslam-vo-model",))
    rc, err = _cli(["set-pose", path, "--pose", "net", "--out", tmp_path / "o.safetensors"], capsys)
    _one_line_exit_2(rc, err, "deep.safetensors")
    assert not (tmp_path / "o.safetensors").exists()


def test_model_file_with_100000_tensors_is_refused_quickly(tmp_path):
    n = 100_000
    entries = {f"{i:x}": {"dtype": "U8", "shape": [], "data_offsets": [i, i + 1]} for i in range(n)}
    tree = json.dumps({"format": "deepslam-vo-model", "state_dict": {}})
    path = tmp_path / "many.safetensors"
    path.write_bytes(_safetensors_bytes(entries, {"deepslam": "deepslam-vo-model", "tree": tree}, b"\1" * n))
    assert path.stat().st_size < 8_000_000
    code = ("import resource, sys, time\n"
            "from deepslam.core.errors import InputError\n"
            "from deepslam.models import modelfile\n"
            "base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
            "t0 = time.perf_counter()\n"
            "try:\n"
            f"    modelfile.load({str(path)!r}, ('deepslam-vo-model',))\n"
            "    print('loaded')\n"
            "except InputError as e:\n"
            "    print(e.message())\n"
            "print(time.perf_counter() - t0)\n"
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    message, took, grew_kib = p.stdout.strip().splitlines()[-3:]
    assert "100000 tensors" in message and "many.safetensors" in message, p.stdout + p.stderr
    assert float(took) < 3.0 and int(grew_kib) < 512 * 1024, (took, grew_kib)


def test_model_file_shapes_are_checked_before_reading(tmp_path):
    from deepslam.models import modelfile

    path = tmp_path / "lie.safetensors"
    tree = json.dumps({"w": {"$t": "w"}})
    path.write_bytes(_safetensors_bytes({"w": {"dtype": "F32", "shape": [1, 1, 1, 1, 1, 1, 1, 1, 1], "data_offsets": [0, 4]}},
                                        {"deepslam": "k", "tree": tree}, b"\0" * 4))
    with pytest.raises(InputError, match="at most 8"):
        modelfile.load(path, ("k",))
    path.write_bytes(_safetensors_bytes({"w": {"dtype": "F32", "shape": [2], "data_offsets": [0, 4]}},
                                        {"deepslam": "k", "tree": json.dumps({"a": {"$t": "w"}, "b": {"$t": "w"}})},
                                        b"\0" * 4))
    with pytest.raises(InputError, match="declares shape"):
        modelfile.load(path, ("k",))
    path.write_bytes(_safetensors_bytes({"w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}},
                                        {"deepslam": "k", "tree": json.dumps({"a": {"$t": "w"}, "b": {"$t": "w"}})},
                                        b"\0" * 4))
    with pytest.raises(InputError, match="twice"):
        modelfile.load(path, ("k",))
    shipped = modelfile.load(REPO / "models" / "kitti_cons.safetensors", ("deepslam-vo-model",))
    assert shipped[0] == "deepslam-vo-model"


# ---------------------------------------------------------------- item 3: outputs never clobber inputs

def _kitti_poses(path: Path, n: int = 150) -> Path:
    from deepslam.core import se3

    rng = np.random.default_rng(0)
    poses = [np.eye(4)]
    for _ in range(n - 1):
        step = np.array([*rng.normal(0, 0.01, 3), rng.normal(0, 0.02), rng.normal(0, 0.01), rng.uniform(0.5, 1.2)])
        poses.append(poses[-1] @ se3.from_euler6(step))
    path.write_text("".join(" ".join(f"{x:.9e}" for x in p[:3].ravel()) + "\n" for p in poses))
    return path


def test_fit_motion_out_onto_its_poses_is_refused(tmp_path, capsys):
    poses = _kitti_poses(tmp_path / "00.txt")
    before = poses.read_bytes()
    rc, err = _cli(["fit-motion", "--poses", poses, "--out", poses], capsys)
    _one_line_exit_2(rc, err, "00.txt", "--out is the input --poses")
    rc, err = _cli(["fit-motion", "--poses", poses, "--out", tmp_path / "m.json", "--plot", poses], capsys)
    _one_line_exit_2(rc, err, "--plot is the input --poses")
    link = tmp_path / "link.txt"
    link.symlink_to(poses)
    rc, err = _cli(["fit-motion", "--poses", poses, "--out", link], capsys)  # resolved: a link to the input
    _one_line_exit_2(rc, err, "--out is the input --poses")
    assert poses.read_bytes() == before and not (tmp_path / "m.json").exists()


@pytest.mark.parametrize("onto", ["--gt", "--est"])
def test_eval_plot_onto_an_input_is_refused(tmp_path, capsys, onto):
    gt = _kitti_poses(tmp_path / "gt.txt", 40)
    est = _kitti_poses(tmp_path / "est.txt", 40)
    before = {gt: gt.read_bytes(), est: est.read_bytes()}
    target = gt if onto == "--gt" else est
    rc, err = _cli(["eval", "--gt", gt, "--est", est, "--plot", target], capsys)
    _one_line_exit_2(rc, err, f"--plot is the input {onto}")
    assert all(p.read_bytes() == b for p, b in before.items())


def test_vo_out_onto_a_file_of_the_sequence_is_refused(plane_copy, tmp_path, capsys):
    before = _digest(plane_copy)
    rc, err = _cli(["vo", "--sequence", plane_copy, "--out", plane_copy / "times.txt", "--quiet"], capsys)
    _one_line_exit_2(rc, err, "times.txt", "inside the input --sequence")
    rc, err = _cli(["vo", "--sequence", plane_copy, "--out", plane_copy / "rgb" / "traj.txt", "--quiet"], capsys)
    _one_line_exit_2(rc, err, "inside the input --sequence")
    assert _digest(plane_copy) == before


def test_vo_out_that_is_its_own_plot_is_refused(plane_copy, tmp_path, capsys):
    rc, err = _cli(["vo", "--sequence", plane_copy, "--out", tmp_path / "traj.png", "--quiet"], capsys)
    _one_line_exit_2(rc, err, "traj.png", "same file")
    assert list(tmp_path.glob("traj*")) == []


def test_vo_side_files_are_overwritten_only_when_vo_wrote_them(plane_copy, tmp_path, capsys):
    out = tmp_path / "run" / "traj.txt"
    out.parent.mkdir()
    mine = out.parent / "traj.motions.csv"
    mine.write_text("my own notes\n")
    rc, err = _cli(["vo", "--sequence", plane_copy, "--out", out, "--quiet"], capsys)
    _one_line_exit_2(rc, err, "traj.motions.csv", "refusing to overwrite")
    assert mine.read_text() == "my own notes\n" and not out.exists()
    mine.unlink()
    rc, _ = _cli(["vo", "--sequence", plane_copy, "--out", out, "--quiet"], capsys)
    assert rc == 0
    record = json.loads((out.parent / "traj.config.json").read_text())
    assert record["written_by"] == "deepslam vo"
    assert set(record["files"]) == {"traj.motions.csv", "traj.metrics.json", "traj.png"}
    rc, _ = _cli(["vo", "--sequence", plane_copy, "--out", out, "--quiet"], capsys)
    assert rc == 0  # its own files from the earlier run: overwritten
    (out.parent / "traj.metrics.json").write_text("{}\n")  # the user changed it since
    rc, err = _cli(["vo", "--sequence", plane_copy, "--out", out, "--quiet"], capsys)
    _one_line_exit_2(rc, err, "traj.metrics.json", "changed")
    assert (out.parent / "traj.metrics.json").read_text() == "{}\n"


def test_vo_refuses_a_foreign_config_json(plane_copy, tmp_path, capsys):
    (tmp_path / "traj.config.json").write_text('{"my": "settings"}\n')
    rc, err = _cli(["vo", "--sequence", plane_copy, "--out", tmp_path / "traj.txt", "--quiet"], capsys)
    _one_line_exit_2(rc, err, "traj.config.json", "not a record")
    assert (tmp_path / "traj.config.json").read_text() == '{"my": "settings"}\n'


def test_second_vo_into_a_held_folder_is_refused_naming_the_first(plane_copy, tmp_path, capsys):
    from deepslam.core.lock import output_lock

    out = tmp_path / "runs" / "traj.txt"
    with output_lock(out.parent):  # the first run holds the folder
        rc, err = _cli(["vo", "--sequence", plane_copy, "--out", out, "--quiet"], capsys)
    _one_line_exit_2(rc, err, f"process {os.getpid()}", "runs")
    assert not out.exists()


def test_slam_outputs_never_clobber_inputs_or_each_other(plane_copy, tmp_path, capsys):
    before = _digest(plane_copy)
    rc, err = _cli(["slam", "--sequence", plane_copy, "--out", plane_copy / "poses.txt", "--no-loops"], capsys)
    _one_line_exit_2(rc, err, "inside the input --sequence")
    rc, err = _cli(["slam", "--sequence", plane_copy, "--out", tmp_path / "run.json", "--no-loops"], capsys)
    _one_line_exit_2(rc, err, "same file")
    rc, err = _cli(["slam", "--sequence", plane_copy, "--out", tmp_path / "t.txt", "--plot", tmp_path / "t.txt",
                    "--no-loops"], capsys)
    _one_line_exit_2(rc, err, "same file")
    (tmp_path / "t_vo.txt").write_text("someone else's trajectory\n")
    rc, err = _cli(["slam", "--sequence", plane_copy, "--out", tmp_path / "t.txt", "--no-loops"], capsys)
    _one_line_exit_2(rc, err, "t_vo.txt", "refusing to overwrite")
    assert _digest(plane_copy) == before and not (tmp_path / "t.txt").exists()


def test_gen_out_inside_its_source_is_refused(plane_copy, motion_json, capsys):
    before = _digest(plane_copy)
    rc, err = _cli(["gen", "--source", plane_copy, "--motion", motion_json, "--samples", "2", "--resolution", "24x80",
                    "--out", plane_copy / "shards"], capsys)
    _one_line_exit_2(rc, err, "inside the input --source")
    assert _digest(plane_copy) == before


def test_check_output_not_input_follows_links(tmp_path):
    from deepslam.core.outputs import check_distinct_outputs, check_output_not_input

    data = tmp_path / "data"
    data.mkdir()
    (data / "a.txt").write_text("a")
    os.link(data / "a.txt", tmp_path / "hard.txt")
    (tmp_path / "soft").symlink_to(data)
    for out in (tmp_path / "hard.txt", tmp_path / "soft" / "new.txt", data, tmp_path / "soft" / "a.txt"):
        with pytest.raises(InputError):
            check_output_not_input(out, [("--in", data / "a.txt"), ("--dir", data)])
    check_output_not_input(tmp_path / "other.txt", [("--in", data / "a.txt"), ("--dir", data), ("--gone", None)])
    with pytest.raises(InputError, match="same file"):
        check_distinct_outputs([("--out", tmp_path / "x"), ("--plot", tmp_path / "soft" / ".." / "x")])


def test_render_resume_into_a_folder_that_never_was_a_render_is_refused(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    (out / ".draft.abc123.tmp.tex").write_text("unsaved work")  # looks like one of our temporary files
    before = _digest(out)
    rc, err = _cli(["render", "--scene", "street", "--frames", "2", "--width", "32", "--out", out, "--resume",
                    "--quiet"], capsys)
    _one_line_exit_2(rc, err, "mine")
    assert _digest(out) == before


# ---------------------------------------------------------------- item 4: strict readers

@pytest.mark.parametrize("stray", ["3.png", "000003.jpg"])
def test_kitti_two_files_for_one_frame_name_both(tmp_path, capsys, stray):
    seq = write_kitti(tmp_path / "kitti")
    _png(seq / "image_0" / stray, _grey(24, 40, 9))
    for argv in (["info", seq], ["info", seq, "--check"]):
        rc, err = _cli(argv, capsys)
        _one_line_exit_2(rc, err, stray, "000003.png", "one file per frame")


def test_kitti_duplicate_calibration_key_is_refused(tmp_path, capsys):
    seq = write_kitti(tmp_path / "kitti")
    calib = seq / "calib.txt"
    calib.write_text(calib.read_text() + "P0: 31 0 20 0 0 31 12 0 0 0 1 0\n")
    rc, err = _cli(["info", seq], capsys)
    _one_line_exit_2(rc, err, "calib.txt:2", "P0", "twice")


@pytest.mark.parametrize("listing", ["rgb.txt", "depth.txt"])
def test_tum_listing_out_of_time_order_is_refused(tmp_path, capsys, listing):
    root = write_tum(tmp_path)
    rc, _ = _cli(["info", root], capsys)
    assert rc == 0
    lines = (root / listing).read_text().splitlines()
    lines[2], lines[3] = lines[3], lines[2]
    (root / listing).write_text("\n".join(lines) + "\n")
    rc, err = _cli(["info", root], capsys)
    _one_line_exit_2(rc, err, f"{listing}:4", "out of time order")


def test_tum_groundtruth_out_of_time_order_is_refused(tmp_path, capsys):
    root = write_tum(tmp_path)
    rows = [f"{100.0 + i / 30:.6f} {i * 0.1} 0 0 0 0 0 1" for i in range(5)]
    rows[1], rows[2] = rows[2], rows[1]
    (root / "groundtruth.txt").write_text("\n".join(rows) + "\n")
    rc, err = _cli(["info", root], capsys)
    _one_line_exit_2(rc, err, "groundtruth.txt:3")


@pytest.mark.parametrize("name", ["../../outside.png", "/etc/hostname", "data/../../cam1/x.png"])
def test_euroc_listing_outside_the_dataset_is_refused(tmp_path, capsys, name):
    root = write_euroc(tmp_path / "euroc")
    _png(tmp_path / "euroc" / "mav0" / "outside.png", _grey(32, 48))
    csv = root / "mav0" / "cam0" / "data.csv"
    lines = csv.read_text().splitlines()
    lines[2] = lines[2].split(",")[0] + "," + name
    csv.write_text("\n".join(lines) + "\n")
    rc, err = _cli(["info", root], capsys)
    _one_line_exit_2(rc, err, "data.csv:3", "leaves the dataset folder")


def test_euroc_file_listed_twice_is_refused(tmp_path, capsys):
    root = write_euroc(tmp_path / "euroc")
    csv = root / "mav0" / "cam0" / "data.csv"
    lines = csv.read_text().splitlines()
    lines[3] = lines[3].split(",")[0] + "," + lines[2].split(",")[1]
    csv.write_text("\n".join(lines) + "\n")
    rc, err = _cli(["info", root], capsys)
    _one_line_exit_2(rc, err, "data.csv:4", "listed twice")


def test_tum_listing_outside_the_dataset_is_refused(tmp_path, capsys):
    root = write_tum(tmp_path)
    _png(tmp_path / "elsewhere.png", np.dstack([_grey(24, 40)] * 3))
    lines = (root / "rgb.txt").read_text().splitlines()
    lines[1] = lines[1].split()[0] + " ../elsewhere.png"
    (root / "rgb.txt").write_text("\n".join(lines) + "\n")
    rc, err = _cli(["info", root], capsys)
    _one_line_exit_2(rc, err, "rgb.txt:2", "leaves the dataset folder")


def test_wrong_size_frame_is_refused_wherever_frames_are_read(tmp_path):
    from deepslam.core.readers import open_sequence

    root = write_euroc(tmp_path / "euroc", w=752 // 8, h=480 // 8)
    bad = sorted((root / "mav0" / "cam0" / "data").iterdir())[2]
    _png(bad, _grey(200 // 8, 320 // 8))
    seq = open_sequence(root)
    seq.image(1)
    with pytest.raises(InputError, match=r"40x25, expected 94x60") as e:
        seq.image(2)
    assert e.value.path == str(bad)


def test_wrong_size_frame_stops_vo_with_one_line(plane_copy, tmp_path, capsys):
    rgb = plane_copy / "rgb" / "000005.png"
    _png(rgb, cv2.resize(cv2.imread(str(rgb)), (200, 64)))
    rc, err = _cli(["vo", "--sequence", plane_copy, "--out", tmp_path / "t.txt", "--quiet"], capsys)
    _one_line_exit_2(rc, err, "000005.png", "200x64")
