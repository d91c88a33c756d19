"""``deepslam adapt``: the paper's method on a sequence's own single frames; it never reads poses."""
from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import pytest
from safetensors import safe_open

from deepslam.cli import main
from deepslam.vo.adapt import frames_view

TEDDY = "tum/rgbd_dataset_freiburg3_teddy"


def _teddy_slice(shared_data: Path, dest: Path, n: int = 24, groundtruth: str | None = "copy") -> Path:
    """The first ``n`` RGB-D frames of teddy in a folder of the same name; ``groundtruth`` = copy, junk or None."""
    src = shared_data / TEDDY
    out = dest / src.name
    (out / "rgb").mkdir(parents=True)
    (out / "depth").mkdir()
    for lst in ("rgb.txt", "depth.txt"):
        lines = src.joinpath(lst).read_text().splitlines()
        head = [ln for ln in lines if ln.startswith("#")]
        body = [ln for ln in lines if ln.strip() and not ln.startswith("#")][:n]
        for ln in body:
            shutil.copy2(src / ln.split()[1], out / ln.split()[1])
        (out / lst).write_text("\n".join(head + body) + "\n")
    if groundtruth == "copy":
        shutil.copy2(src / "groundtruth.txt", out / "groundtruth.txt")
    elif groundtruth == "junk":
        (out / "groundtruth.txt").write_text("this is not a trajectory\n")
    return out


def _tensors(path: Path) -> dict:
    with safe_open(path, "pt") as f:
        return {k: f.get_tensor(k) for k in f.keys()}


def _adapt(seq: Path, out: Path, capsys, *extra) -> dict:
    rc = main(["adapt", "--sequence", str(seq), "--out", str(out), "--samples", "128", "--epochs", "1", "--no-loops",
               "--json", *extra])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    return json.loads(cap.out.strip().splitlines()[-1])


@pytest.mark.slow
def test_adapt_reads_no_poses_and_is_deterministic(shared_data, tmp_path, capsys):
    """With teddy's ground truth, without it, or with a junk file in its place: the same weights, bit for bit;
    also with --tensorboard, whose scalars land per network and leave the bytes alone."""
    tensorboard = importlib.util.find_spec("tensorboard") is not None
    runs = {}
    for gt in ("copy", None, "junk"):
        seq = _teddy_slice(shared_data, tmp_path / f"seq_{gt}", groundtruth=gt)
        extra = ["--tensorboard", str(tmp_path / "tb")] if gt == "junk" and tensorboard else []
        record = _adapt(seq, tmp_path / f"out_{gt}", capsys, *extra)
        assert record["kind"] == "tum" and record["poses_opened"] is False
        runs[gt] = _tensors(tmp_path / f"out_{gt}" / "model.safetensors")
    if tensorboard:
        assert list((tmp_path / "tb" / "cons").glob("events.out.tfevents.*"))
        assert not (tmp_path / "tb" / "loops").exists()  # --no-loops
    for gt in (None, "junk"):
        assert runs[gt].keys() == runs["copy"].keys()
        assert all((runs[gt][k] == runs["copy"][k]).all() for k in runs["copy"])
    # the adapted model is what vo reads with --model; a finished run resumes as done, other settings are refused
    seq = tmp_path / "seq_copy" / Path(TEDDY).name
    rc = main(["vo", "--sequence", str(seq), "--model", str(tmp_path / "out_copy" / "model.safetensors"),
               "--out", str(tmp_path / "vo.txt")])
    assert rc == 0, capsys.readouterr().err
    again = _adapt(seq, tmp_path / "out_copy", capsys, "--resume")
    assert again["stages"]["cons"]["stop_reason"] == "finished earlier"
    rc = main(["adapt", "--sequence", str(seq), "--out", str(tmp_path / "out_copy"), "--samples", "256", "--resume"])
    assert rc == 2 and "cannot resume" in capsys.readouterr().err


def test_frames_view_leaves_the_pose_files_out(tmp_path):
    seq = tmp_path / "rgbd_dataset_freiburg1_xyz"
    (seq / "rgb").mkdir(parents=True)
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "intrinsics.txt"):
        (seq / name).write_text("#\n")
    view = frames_view(seq, tmp_path / "view")
    assert view.name == seq.name  # readers read the camera off TUM's folder name
    assert sorted(p.name for p in view.iterdir()) == ["depth.txt", "intrinsics.txt", "rgb", "rgb.txt"]


def test_adapt_refuses_a_folder_holding_something_else_or_inside_the_sequence(tmp_path, capsys):
    seq = tmp_path / "seq"
    seq.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("keep")
    rc = main(["adapt", "--sequence", str(seq), "--out", str(out)])
    assert rc == 2 and "not empty" in capsys.readouterr().err
    assert (out / "mine.txt").read_text() == "keep"
    rc = main(["adapt", "--sequence", str(seq), "--out", str(seq / "models")])
    assert rc == 2 and "lies inside the input --sequence" in capsys.readouterr().err
    assert not (seq / "models").exists()


def test_a_sequence_without_depth_is_one_line_and_leaves_nothing(shared_data, tmp_path, capsys):
    """KITTI 07's slice is monocular (no depth, no stereo pair): one line, exit 2, no output folder."""
    out = tmp_path / "out"
    rc = main(["adapt", "--sequence", str(shared_data / "kitti" / "sequences" / "07"), "--out", str(out),
               "--samples", "128", "--epochs", "1", "--no-loops", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "neither depth maps nor a rectified stereo pair" in err[0]
    assert not out.exists()
