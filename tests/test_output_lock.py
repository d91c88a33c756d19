"""One writer per output folder: a second run into a folder another run holds exits 2 naming it.

Parametrized over the commands that write a folder (render, gen, train, stress); a real race of two
render processes checks that the one that runs is byte-identical to a lone run.
"""
from __future__ import annotations

import hashlib
import shutil
import os
import subprocess
import sys
from pathlib import Path

import pytest

from deepslam.core.lock import lock_holder, output_lock

REPO = Path(__file__).resolve().parents[1]


def _render_argv(out: Path, seed: int = 1) -> list[str]:
    return ["render", "--scene", "street", "--frames", "3", "--width", "160", "--seed", str(seed), "--out", str(out),
            "--quiet"]


def _tree_digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def small_sequence(tmp_path_factory) -> Path:
    from deepslam.cli import main

    out = tmp_path_factory.mktemp("seq") / "street"
    assert main(_render_argv(out)) == 0
    return out


@pytest.mark.parametrize("command", ["render", "gen", "train", "stress"])
def test_second_writer_is_refused_naming_the_first(command, small_sequence, tmp_path, capsys):
    from deepslam.cli import main

    out = tmp_path / "out"
    argv = {
        "render": _render_argv(out),
        "gen": ["gen", "--source", str(small_sequence), "--motion", str(REPO / "models" / "motion" / "kitti_s1.json"),
                "--samples", "8", "--resolution", "24x80", "--out", str(out)],
        "train": ["train", "--mode", "synthetic", "--toy", "64", "--net", "tiny", "--quiet", "--out", str(out)],
        "stress": ["stress", "--quick", "--out", str(out)],
    }[command]
    with output_lock(out):  # another run holds the folder (a separate open file: flock conflicts in-process too)
        assert lock_holder(out) == os.getpid()
        rc = main(argv)
        err = capsys.readouterr().err
        assert rc == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
        assert f"process {os.getpid()}" in err and str(out) in err
        assert list(out.iterdir()) == []  # the refused run wrote nothing


def test_lock_is_released_when_the_holder_dies_and_a_failed_run_leaves_no_folder(tmp_path):
    out = tmp_path / "out"
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from deepslam.core.lock import output_lock\n"
                               f"with output_lock({str(out)!r}):\n    print('held', flush=True); time.sleep(60)"],
                              stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    assert lock_holder(out) == holder.pid
    holder.kill()
    holder.wait()
    with output_lock(out):  # a killed run's lock is gone: nothing stale to clean up
        pass
    fresh = tmp_path / "fresh"
    with pytest.raises(RuntimeError):
        with output_lock(fresh):
            raise RuntimeError("failed before writing")
    assert not fresh.exists()


def test_two_renders_racing_into_one_folder(tmp_path):
    """Started together with different seeds: exactly one renders, and its output equals a lone run's."""
    env = {**os.environ, "DEEPSLAM_PROGRESS": "0"}
    out = tmp_path / "race"
    procs = [subprocess.Popen([sys.executable, "-m", "deepslam", *_render_argv(out, seed)], env=env, cwd=tmp_path,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for seed in (1, 2)]
    results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]
    codes = sorted(rc for rc, _ in results)
    if codes == [0, 0]:
        pytest.skip("the two renders did not overlap on this machine (the first finished before the second started)")
    assert codes == [0, 2], results
    winner = 1 if results[0][0] == 0 else 2
    refused = [err for rc, err in results if rc == 2][0]
    # overlapping: the lock refuses it; if the winner had already finished, the non-empty folder does
    assert len(refused.strip().splitlines()) == 1 and ("is writing this folder" in refused or "not empty" in refused)
    from deepslam.cli import main

    assert main(_render_argv(tmp_path / "lone", winner)) == 0
    assert _tree_digest(out) == _tree_digest(tmp_path / "lone")


@pytest.mark.parametrize("command", ["train", "stress"])
def test_an_unrelated_non_empty_out_is_refused(command, tmp_path, capsys):
    from deepslam.cli import main

    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    argv = {"train": ["train", "--mode", "synthetic", "--toy", "64", "--net", "tiny", "--quiet", "--out", str(out)],
            "stress": ["stress", "--quick", "--out", str(out)]}[command]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not empty" in err[0], err
    assert sorted(p.name for p in out.iterdir()) == ["thesis.tex"]


def test_gen_on_a_source_without_valid_depth_fails_and_leaves_nothing(small_sequence, tmp_path, capsys):
    """All-NaN depth used to give shards with no valid pixel and exit 0; now: exit 2 naming the file,
    and a plain rerun is not refused as "not empty" (nothing was left behind)."""
    import numpy as np

    from deepslam.cli import main

    src = tmp_path / "src"
    shutil.copytree(small_sequence, src)
    for f in (src / "depth").glob("*.npy"):
        np.save(f, np.full_like(np.load(f), np.nan))
    out = tmp_path / "shards"
    argv = ["gen", "--source", str(src), "--motion", str(REPO / "models" / "motion" / "kitti_s1.json"), "--samples", "8",
            "--resolution", "24x80", "--out", str(out)]
    for _ in range(2):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "no valid pixel" in err[0] and "depth" in err[0], err
        assert not out.exists()


@pytest.mark.parametrize("argv,what", [
    (["train", "--mode", "synthetic", "--toy", "64", "--batch", "-4"], "--batch must be > 0"),
    (["train", "--mode", "synthetic", "--toy", "64", "--batch", "100000000"], "at most 65536"),
    (["train", "--mode", "synthetic", "--toy", "64", "--width", "100000"], "input_width must be in 1..2048"),
    (["train", "--mode", "synthetic", "--toy", "64", "--max-minutes", "nan"], "--max-minutes must be >= 0"),
    (["train", "--mode", "synthetic", "--toy", "64", "--lr-max", "inf"], "--lr-max must be a positive number"),
    (["gen", "--source", "x", "--motion", "y", "--samples", "0"], "--samples must be in 1.."),
    (["gen", "--source", "x", "--motion", "y", "--samples", "8", "--resolution", "96x99999"], "--resolution must be"),
    (["render", "--width", "100000"], "width must be an integer in 1..4096"),
    (["vo", "--sequence", ".", "--batch", "0"], "--batch must be in 1..4096"),
])
def test_numeric_flags_out_of_range_are_one_line_exit_2(argv, what, tmp_path, capsys):
    from deepslam.cli import main

    out = tmp_path / "out"
    full = argv + (["--out", str(out)] if argv[0] != "vo" else ["--out", str(tmp_path / "t.txt")])
    if argv[0] == "vo":
        full[2] = str(REPO / ".." / "shared" / "data" / "kitti" / "sequences" / "06")
    assert main(full) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and what in err[0], err
    assert not out.exists()


def test_render_resume_redoes_a_damaged_frame(small_sequence, tmp_path):
    """An interrupted render whose finished frame was damaged afterwards: --resume checks each kept
    frame's files against the sha256 in its record and renders that frame again."""
    import json

    from deepslam.cli import main

    seq = tmp_path / "seq"
    shutil.copytree(small_sequence, seq)
    header = json.loads((seq / "sequence.json").read_text())
    header["complete"] = False  # as if killed before the end
    (seq / "sequence.json").write_text(json.dumps(header))
    depth = seq / "depth" / "000001.npy"
    data = bytearray(depth.read_bytes())
    data[-3] ^= 0xFF
    depth.write_bytes(bytes(data))
    rec = json.loads((seq / "frames" / "000001.json").read_text())
    assert "depth/000001.npy" in rec["files"]
    assert main(_render_argv(seq) + ["--resume"]) == 0
    assert _tree_digest(seq) == _tree_digest(small_sequence)
