"""`deepslam view` (deepslam/view.py): sequences and vo/slam runs as rerun recordings, read back from the .rrd;
`deepslam render --preview`; bad input exits 2 with one line and writes nothing."""
from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest

from deepslam.cli import main
from deepslam.core.readers import open_sequence
from deepslam.core.trajio import read_trajectory
from deepslam.slam.synthetic import write_loop_sequence
from deepslam.view import find_run, place_estimate

rerun_chunk = pytest.importorskip("rerun.chunk", reason="rerun-sdk is the optional `viz` extra")

SEQUENCE_ENTITIES = {"/world", "/world/camera", "/world/camera/image", "/world/camera/image/rgb",
                     "/world/camera/image/depth", "/world/camera/image/flow", "/world/camera/image/mask",
                     "/world/camera/image/occlusion", "/world/path"}


def _chunks(rrd):
    return list(rerun_chunk.RrdReader(rrd).stream())


def _rows(chunks, entity: str) -> int:
    return sum(c.num_rows for c in chunks if c.entity_path == entity and not c.is_static)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A 3-frame street with a moving car (rate 2 Hz: the camera moves between frames) and its contact sheet."""
    root = tmp_path_factory.mktemp("view")
    seq, sheet = root / "seq", root / "sheet.png"
    assert main(["render", "--scene", "street", "--frames", "3", "--width", "160", "--rate", "2",
                 "--moving-objects", "1", "--out", str(seq), "--preview", str(sheet), "--quiet"]) == 0
    return seq, sheet


def test_render_preview_writes_a_contact_sheet(rendered):
    seq_dir, sheet = rendered
    img = cv2.imread(str(sheet))[..., ::-1]
    seq = open_sequence(seq_dir)
    h = round(seq.camera.height * 160 / seq.camera.width)
    assert img.shape == (18 + 2 * h, 4 * 160, 3)  # frames 0 and 1 (the last has no flow); RGB | depth | flow | mask
    flow = img[18 + h:, 320:480].astype(int)
    assert flow.std() > 5, "the camera moves between frames: the flow panel is not constant"
    assert not any(p.name.endswith(".png") for p in seq_dir.iterdir())


def test_view_saves_a_sequence_with_every_layer(rendered, tmp_path, capsys):
    seq_dir, _ = rendered
    rrd = tmp_path / "seq.rrd"
    assert main(["view", str(seq_dir), "--save", str(rrd)]) == 0
    assert "wrote" in capsys.readouterr().out
    chunks = _chunks(rrd)
    assert SEQUENCE_ENTITIES <= {c.entity_path for c in chunks}
    assert _rows(chunks, "/world/camera/image/rgb") == 3
    assert _rows(chunks, "/world/camera") == 3
    assert {"frame", "time"} <= {t for c in chunks if not c.is_static for t in c.timeline_names}
    assert [p.name for p in tmp_path.iterdir()] == ["seq.rrd"]  # no temporary left behind


def test_view_frame_selection(rendered, tmp_path):
    seq_dir, _ = rendered
    rrd = tmp_path / "every.rrd"
    assert main(["view", str(seq_dir), "--save", str(rrd), "--every", "2"]) == 0
    assert _rows(_chunks(rrd), "/world/camera/image/rgb") == 2  # frames 0 and 2
    assert main(["view", str(seq_dir), "--save", str(rrd), "--start", "1", "--end", "2"]) == 0
    assert _rows(_chunks(rrd), "/world/camera/image/rgb") == 1


def test_view_a_vo_run_aligned_as_vo_scores_it(rendered, tmp_path, capsys):
    seq_dir, _ = rendered
    out = tmp_path / "run" / "vo.txt"
    assert main(["vo", "--sequence", str(seq_dir), "--odometry", "pnp", "--out", str(out), "--quiet"]) == 0
    rrd = tmp_path / "vo.rrd"
    assert main(["view", str(out), "--save", str(rrd)]) == 0
    chunks = _chunks(rrd)
    assert {"/world/ground_truth", "/world/estimate", "/metrics", "/world/camera", "/world/camera/image/rgb"} <= \
        {c.entity_path for c in chunks}
    assert _rows(chunks, "/world/camera/image/rgb") == 3
    run = find_run(out)
    assert run.command == "vo" and run.record_path.name == "vo.config.json"
    placed, scores = place_estimate(open_sequence(run.sequence), read_trajectory(out), np.arange(3), "se3")
    assert placed.shape == (3, 4, 4)
    assert scores["ate_m"] == pytest.approx(json.loads((out.parent / "vo.metrics.json").read_text())["ate_m"])

    # the run moved elsewhere and its sequence gone: the estimate alone, and a note saying why
    moved = tmp_path / "moved"
    moved.mkdir()
    record = json.loads((out.parent / "vo.config.json").read_text())
    (moved / "vo.config.json").write_text(json.dumps({**record, "sequence": str(tmp_path / "gone")}))
    (moved / "vo.txt").write_text(out.read_text())
    assert main(["view", str(moved / "vo.txt"), "--save", str(rrd)]) == 0
    assert "note: the run's sequence" in capsys.readouterr().out
    assert {"/world/estimate"} <= {c.entity_path for c in _chunks(rrd)}
    assert "/world/ground_truth" not in {c.entity_path for c in _chunks(rrd)}


@pytest.fixture(scope="module")
def slam_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("view_slam")
    write_loop_sequence(root / "seq", n_frames=60, laps=2.0, lap_offset_m=0.2, seed=2)
    params = root / "p20.json"  # revisits are 30 frames apart: T_loop 20 admits them
    params.write_text(json.dumps({"format": "deepslam-slam-params-v1", "c_s": 1.0, "c_r": 1.0, "t_loop": 20}))
    out = root / "run" / "slam.txt"
    assert main(["slam", "--sequence", str(root / "seq"), "--odometry", "gt-noisy", "--out", str(out),
                 "--params", str(params), "--json"]) == 0
    return out


def test_view_a_slam_run_draws_its_loop_edges(slam_run, tmp_path):
    rrd = tmp_path / "slam.rrd"
    assert main(["view", str(slam_run.parent), "--save", str(rrd)]) == 0  # the folder holding one run
    chunks = _chunks(rrd)
    entities = {c.entity_path for c in chunks}
    assert {"/world/ground_truth", "/world/estimate", "/world/odometry", "/world/loops/kept", "/metrics"} <= entities
    record = json.loads(slam_run.with_suffix(".json").read_text())
    kept = sum(record["loops_kept_by_pose_graph"])
    assert kept > 0
    loops = next(c for c in chunks if c.entity_path == "/world/loops/kept")
    strips = loops.to_record_batch().column("LineStrips3D:strips")
    assert len(strips[0]) == kept
    # the slam estimate is placed with the same ATE the run recorded (se3)
    run = find_run(slam_run)
    _, scores = place_estimate(open_sequence(run.sequence), read_trajectory(slam_run), np.arange(60), "se3")
    assert scores["ate_m"] == pytest.approx(record["metrics_slam"]["ate_m"])


def test_view_draws_the_loop_pairs_slam_left_out(slam_run, tmp_path, capsys):
    """loops_not_rigid (pairs whose flow fits no rigid motion) drawn apart from the graph's edges; a pair naming
    no frame is one line naming the field, exit 2."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(slam_run.parent, run)
    record = json.loads((run / "slam.json").read_text())
    (run / "slam.json").write_text(json.dumps({**record, "loops_not_rigid": [[0, 35], [3, 40]]}))
    rrd = tmp_path / "slam.rrd"
    assert main(["view", str(run / "slam.txt"), "--save", str(rrd)]) == 0
    chunks = _chunks(rrd)
    left_out = next(c for c in chunks if c.entity_path == "/world/loops/not_rigid")
    assert len(left_out.to_record_batch().column("LineStrips3D:strips")[0]) == 2
    kept = next(c for c in chunks if c.entity_path == "/world/loops/kept")
    assert len(kept.to_record_batch().column("LineStrips3D:strips")[0]) == sum(record["loops_kept_by_pose_graph"])
    (run / "slam.json").write_text(json.dumps({**record, "loops_not_rigid": [[0, 999]]}))
    capsys.readouterr()
    err = _bad(["view", str(run / "slam.txt"), "--save", str(tmp_path / "bad.rrd")], capsys)
    assert "slam.json" in err and "loops_not_rigid[0]" in err
    assert not (tmp_path / "bad.rrd").exists()


def _bad(argv, capsys):
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert err.startswith("deepslam view: error:") and "\n" not in err and "Traceback" not in err
    return err


def test_bad_input_is_one_line_and_exit_2(rendered, tmp_path, capsys, monkeypatch):
    seq_dir, _ = rendered
    rrd = tmp_path / "x.rrd"
    assert "does not exist" in _bad(["view", str(tmp_path / "nope"), "--save", str(rrd)], capsys)
    (tmp_path / "empty").mkdir()
    assert "neither a sequence" in _bad(["view", str(tmp_path / "empty"), "--save", str(rrd)], capsys)
    bare = tmp_path / "bare.txt"
    bare.write_text((seq_dir / "poses.txt").read_text())
    assert "record" in _bad(["view", str(bare), "--save", str(rrd)], capsys)
    (tmp_path / "other.json").write_text('{"written_by": "someone"}')
    assert "not the record" in _bad(["view", str(tmp_path / "other.json"), "--save", str(rrd)], capsys)
    assert ".rrd" in _bad(["view", str(seq_dir), "--save", str(tmp_path / "x.txt")], capsys)
    assert "inside the input" in _bad(["view", str(seq_dir), "--save", str(seq_dir / "x.rrd")], capsys)
    assert "--every" in _bad(["view", str(seq_dir), "--save", str(rrd), "--every", "0"], capsys)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert "--save" in _bad(["view", str(seq_dir)], capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bare.txt", "empty", "other.json"]


def test_a_damaged_frame_leaves_no_recording(rendered, tmp_path, capsys):
    seq_dir, _ = rendered
    broken = tmp_path / "seq"
    broken.mkdir()
    for p in seq_dir.rglob("*"):
        if p.is_file():
            (broken / p.relative_to(seq_dir)).parent.mkdir(parents=True, exist_ok=True)
            (broken / p.relative_to(seq_dir)).write_bytes(p.read_bytes())
    last = sorted((broken / "rgb").iterdir())[-1]
    last.write_bytes(last.read_bytes()[:100])  # truncated PNG: read only when the frame is logged
    out = tmp_path / "out"
    out.mkdir()
    assert "truncated" in _bad(["view", str(broken), "--save", str(out / "x.rrd")], capsys)
    assert os.listdir(out) == []
