"""TUM RGB-D reader: association as associate.py does it, 16-bit depth at 5000/m, intrinsics by
freiburg id or intrinsics.txt, ground truth where it covers the frames, and one-line refusals."""
from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.core.tum import associate_times

TEDDY = "tum/rgbd_dataset_freiburg3_teddy"


def test_association_is_greedy_one_to_one_within_the_window():
    ta = np.array([0.000, 0.033, 0.066, 0.100])
    tb = np.array([0.001, 0.030, 0.031, 0.200])
    # 0.033 is nearest to both 0.030 and 0.031: greedy by difference takes (1, 2) [0.002] then (0, 0);
    # 0.030 is left for no one within 0.02 s of 0.066 (0.036 away); 0.100 has nothing
    assert associate_times(ta, tb, 0.02) == [(0, 0), (1, 2)]
    assert associate_times(ta, tb + 1.0, 0.02) == []


def test_teddy_reads_as_published(shared_data):
    seq = open_sequence(shared_data / TEDDY)
    assert seq.kind == "tum" and len(seq) == seq.meta["associated"] and 150 < len(seq) <= 200
    cam = seq.camera
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (640, 480, 535.4, 539.2, 320.1, 247.6)
    img, d = seq.image(10), seq.depth(10)
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    assert d.shape == (480, 640) and d.dtype == np.float32
    raw = cv2.imread(str(seq.depth_paths[10]), cv2.IMREAD_ANYDEPTH)
    np.testing.assert_array_equal(d, raw.astype(np.float32) / 5000.0)
    assert 0.3 < np.median(d[d > 0]) < 4.0  # a hand-held Kinect a metre or two from the teddy
    # the motion capture starts about 0.14 s after the first frame: those frames have no ground truth
    assert seq.gt_frames is not None and seq.gt_frames[0] > 0 and len(seq.gt) == len(seq.gt_frames)
    assert seq.gt_pose(0) is None and seq.gt_pose(int(seq.gt_frames[0])) is not None
    assert np.all(np.diff(seq.timestamps_s) > 0)
    for i in (0, len(seq) // 2, len(seq) - 1):
        seq.check(i)


def _copy(shared_data: Path, tmp_path: Path, name: str = "rgbd_dataset_freiburg3_teddy") -> Path:
    root = tmp_path / name
    src = shared_data / TEDDY
    root.mkdir()
    for f in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        shutil.copy(src / f, root / f)
    (root / "rgb").symlink_to(src / "rgb")
    (root / "depth").symlink_to(src / "depth")
    return root


def test_intrinsics_file_and_depth_scale_override(shared_data, tmp_path):
    root = _copy(shared_data, tmp_path, "my_kinect")
    with pytest.raises(InputError, match="freiburg"):
        open_sequence(root)
    (root / "intrinsics.txt").write_text("500 501 320 240\n")
    (root / "depth_scale.txt").write_text("1000\n")
    seq = open_sequence(root)
    assert (seq.camera.fx, seq.camera.fy, seq.camera.cx, seq.camera.cy) == (500, 501, 320, 240)
    raw = cv2.imread(str(seq.depth_paths[3]), cv2.IMREAD_ANYDEPTH)
    np.testing.assert_array_equal(seq.depth(3), raw.astype(np.float32) / 1000.0)


def test_freiburg1_distortion_is_undone_for_images_and_depth(shared_data, tmp_path):
    root = _copy(shared_data, tmp_path, "rgbd_dataset_freiburg1_fake")
    seq = open_sequence(root)
    assert seq.camera.fx == 517.3 and seq.postprocess is not None
    raw = cv2.imread(str(seq.depth_paths[0]), cv2.IMREAD_ANYDEPTH).astype(np.float32) / 5000.0
    d = seq.depth(0)
    assert not np.array_equal(d, raw)  # remapped
    assert set(np.unique(d)) <= set(np.unique(raw)) | {0.0}  # nearest: no invented depth values


@pytest.mark.parametrize("fault,what", [
    ("missing-listed-file", "which is missing"),
    ("bad-line", "timestamp is not a number"),
    ("no-association", "no depth map within 0.02 s"),
    ("depth-8-bit", "16-bit"),
    ("not-utf8", "not UTF-8"),
])
def test_bad_tum_input_is_one_line_exit_2(shared_data, tmp_path, capsys, fault, what):
    from deepslam.cli import main

    root = _copy(shared_data, tmp_path)
    rgb = (root / "rgb.txt").read_text().splitlines()
    if fault == "missing-listed-file":
        rgb.insert(5, "1341841873.320000 rgb/nope.png")  # in time order: only the file is missing
        (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    elif fault == "bad-line":
        rgb.insert(4, "soon rgb/x.png")
        (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    elif fault == "no-association":
        depth = [ln if ln.startswith("#") else f"{float(ln.split()[0]) + 100:.6f} {ln.split()[1]}"
                 for ln in (root / "depth.txt").read_text().splitlines()]
        (root / "depth.txt").write_text("\n".join(depth) + "\n")
    elif fault == "depth-8-bit":
        (root / "depth").unlink()
        shutil.copytree(shared_data / TEDDY / "depth", root / "depth")
        first = sorted((root / "depth").glob("*.png"))[0]
        cv2.imwrite(str(first), np.zeros((480, 640), np.uint8))
    else:
        (root / "depth.txt").write_bytes(b"# depth\n\xff\xfe\n")
    argv = ["info", str(root)] + (["--check"] if fault == "depth-8-bit" else [])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and what in err[0] and "Traceback" not in err[0], err
