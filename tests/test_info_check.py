"""``deepslam info --check`` finds what a later command would trip on, one fault class at a time."""
from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    from deepslam.cli import main

    out = tmp_path_factory.mktemp("info") / "seq"
    assert main(["render", "--scene", "street", "--frames", "3", "--width", "96", "--moving-objects", "1",
                 "--out", str(out), "--quiet"]) == 0
    return out


def _damage(seq, what: str):
    if what == "image-size":
        img = cv2.imread(str(seq / "rgb" / "000001.png"))
        cv2.imwrite(str(seq / "rgb" / "000001.png"), cv2.resize(img, (64, 20)))
        return "rgb/000001.png", "64x20"
    if what == "depth-nan":
        d = np.load(seq / "depth" / "000002.npy")
        d[3, 4] = np.nan
        np.save(seq / "depth" / "000002.npy", d)
        return "depth/000002.npy", "NaN"
    if what == "depth-shape":
        np.save(seq / "depth" / "000000.npy", np.zeros((5, 5), np.float32))
        return "depth/000000.npy", "expected"
    if what == "flow-shape":
        np.save(seq / "flow" / "000000.npy", np.zeros((5, 5, 2), np.float32))
        return "flow/000000.npy", "expected"
    if what == "mask-size":
        cv2.imwrite(str(seq / "mask" / "000001.png"), np.zeros((7, 9), np.uint16))
        return "mask/000001.png", "expected"
    (seq / "times.txt").write_text("0.0\n0.2\n0.1\n")
    return "", "do not increase at frame 2"


@pytest.mark.parametrize("what", ["image-size", "depth-nan", "depth-shape", "flow-shape", "mask-size", "times"])
def test_info_check_refuses_each_fault(rendered, tmp_path, capsys, what):
    from deepslam.cli import main

    seq = tmp_path / "seq"
    shutil.copytree(rendered, seq)
    assert main(["info", str(seq), "--check"]) == 0
    capsys.readouterr()
    where, text = _damage(seq, what)
    assert main(["info", str(seq), "--check"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and where in err[0] and text in err[0], err


@pytest.mark.parametrize("unbuffered", ["1", ""])
def test_a_reader_that_goes_away_is_no_traceback(shared_data, unbuffered):
    """`deepslam ... | head -1`: the command stops quietly with 141 (as a shell tool), whether stdout is
    line-buffered or block-buffered."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONUNBUFFERED": unbuffered}
    r, w = os.pipe()
    os.close(r)  # the reader is gone before the first line
    p = subprocess.run([sys.executable, "-m", "deepslam", "eval", "--gt", str(shared_data / "kitti" / "poses" / "00.txt"),
                        "--est", str(shared_data / "reference" / "KITTI_00_ORB.txt")], cwd=repo, env=env, stdout=w,
                       stderr=subprocess.PIPE, text=True)
    os.close(w)
    assert p.returncode == 141 and p.stderr == "", p.stderr
