"""Sequence readers on the real KITTI and EuRoC slices, on our own format, and on bad input."""
from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.core.euroc import read_euroc, read_sensor_yaml
from deepslam.core.kitti import read_kitti
from deepslam.core.ours import OursWriter, read_ours
from deepslam.core.readers import open_sequence
from deepslam.cli import main


# ---------------------------------------------------------------- KITTI
def test_kitti06_slice(shared_data):
    seq = open_sequence(shared_data / "kitti" / "sequences" / "06")
    assert seq.kind == "kitti" and len(seq) == 51
    assert seq.baseline_m == pytest.approx(0.537, abs=5e-4)
    assert seq.camera.fx == pytest.approx(707.0912) and seq.camera.cy == pytest.approx(183.1104)
    img = seq.image(0)
    assert img.dtype == np.uint8 and img.shape == (370, 1226)
    assert (seq.camera.width, seq.camera.height) == (1226, 370)
    assert seq.image_right(50).shape == img.shape
    # Ground truth: rows 0..50 of poses/06.txt, starting at the identity.
    rows = np.loadtxt(shared_data / "kitti" / "poses" / "06.txt")[:51]
    np.testing.assert_allclose(seq.gt.world_from_cam[:, :3, :].reshape(51, 12), rows)
    np.testing.assert_allclose(seq.gt.world_from_cam[0], np.eye(4), atol=1e-6)
    assert seq.timestamps_s[1] == pytest.approx(0.1044989)


def _stereo_offsets(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(du, dv) = left - right pixel positions of SIFT matches passing a 0.6 ratio test."""
    sift = cv2.SIFT_create(1000)
    k0, d0 = sift.detectAndCompute(left, None)
    k1, d1 = sift.detectAndCompute(right, None)
    matches = [m for m, n in cv2.BFMatcher().knnMatch(d0, d1, k=2) if m.distance < 0.6 * n.distance]
    d = np.array([np.subtract(k0[m.queryIdx].pt, k1[m.trainIdx].pt) for m in matches]).reshape(-1, 2)
    return d[:, 0], d[:, 1]


def test_kitti_stereo_rows_are_aligned(shared_data):
    """Rectified KITTI: SIFT matches between left and right lie on the same row, disparity >= 0."""
    seq = open_sequence(shared_data / "kitti" / "sequences" / "06")
    du, dv = _stereo_offsets(seq.image(10), seq.image_right(10))
    assert len(du) > 100
    assert np.median(np.abs(dv)) < 0.5
    assert np.mean(du > -1) > 0.95


def _copy_kitti(shared_data: Path, tmp_path: Path, frames: int = 3) -> Path:
    src = shared_data / "kitti" / "sequences" / "06"
    dst = tmp_path / "sequences" / "06"
    for cam in ("image_0", "image_1"):
        (dst / cam).mkdir(parents=True)
        for i in range(frames):
            shutil.copy(src / cam / f"{i:06d}.png", dst / cam / f"{i:06d}.png")
    shutil.copy(src / "calib.txt", dst / "calib.txt")
    shutil.copy(src / "times.txt", dst / "times.txt")
    return dst


def test_kitti_calib_without_p0(shared_data, tmp_path, capsys):
    seq_dir = _copy_kitti(shared_data, tmp_path)
    lines = (seq_dir / "calib.txt").read_text().splitlines()
    (seq_dir / "calib.txt").write_text("\n".join(l for l in lines if not l.startswith("P0")) + "\n")
    with pytest.raises(InputError, match="P0 is missing"):
        read_kitti(seq_dir)
    assert main(["info", str(seq_dir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "calib.txt" in err[0] and "P0" in err[0]


def test_kitti_calib_non_number_names_line(shared_data, tmp_path):
    seq_dir = _copy_kitti(shared_data, tmp_path)
    text = (seq_dir / "calib.txt").read_text().replace("3.798145000000e+02", "abc")
    (seq_dir / "calib.txt").write_text(text)
    with pytest.raises(InputError) as e:
        read_kitti(seq_dir)
    assert e.value.line == 2 and e.value.path.endswith("calib.txt")


def test_kitti_missing_image(shared_data, tmp_path, capsys):
    seq_dir = _copy_kitti(shared_data, tmp_path)
    (seq_dir / "image_1" / "000001.png").unlink()
    assert main(["info", str(seq_dir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "image_1/000001.png" in err[0] and "missing" in err[0]


def test_kitti_truncated_image(shared_data, tmp_path, capsys):
    seq_dir = _copy_kitti(shared_data, tmp_path)
    p = seq_dir / "image_0" / "000002.png"
    p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2])
    seq = read_kitti(seq_dir)  # lazily: opening works
    with pytest.raises(InputError, match="truncated"):
        seq.image(2)
    assert main(["info", "--check", str(seq_dir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "000002.png" in err[-1]


def test_kitti_colour_pair_pose_offset(tmp_path):
    """With only image_2/3, ground truth is cam2's: cam0's pose shifted by P2's offset."""
    seq_dir = tmp_path / "sequences" / "00"
    k = np.array([[700.0, 0, 50], [0, 700.0, 40], [0, 0, 1]])
    p2 = k @ np.hstack([np.eye(3), [[0.06], [0], [0]]])
    p3 = k @ np.hstack([np.eye(3), [[-0.47], [0], [0]]])
    seq_dir.mkdir(parents=True)
    (seq_dir / "calib.txt").write_text("".join(f"{n}: " + " ".join(map(str, p.ravel())) + "\n"
                                               for n, p in [("P2", p2), ("P3", p3)]))
    (seq_dir / "times.txt").write_text("0.0\n0.1\n")
    for cam in ("image_2", "image_3"):
        (seq_dir / cam).mkdir()
        for i in range(2):
            cv2.imwrite(str(seq_dir / cam / f"{i:06d}.png"), np.full((80, 100, 3), 7, np.uint8))
    poses = tmp_path / "poses"
    poses.mkdir()
    world_from_cam0 = np.stack([np.eye(4), se3.from_euler6([0, 0.3, 0, 1, 0, 2])])
    (poses / "00.txt").write_text("".join(" ".join(map(str, p[:3].ravel())) + "\n" for p in world_from_cam0))
    seq = read_kitti(seq_dir)
    assert seq.baseline_m == pytest.approx(0.53)
    assert seq.image(0).shape == (80, 100, 3)
    # cam2's centre is 0.06 m to the LEFT of cam0's (p_cam2 = p_cam0 + t2 with t2 = +0.06 x).
    centre_cam0 = world_from_cam0[1][:3, 3]
    expected = centre_cam0 + world_from_cam0[1][:3, :3] @ np.array([-0.06, 0, 0])
    np.testing.assert_allclose(seq.gt.world_from_cam[1][:3, 3], expected, atol=1e-12)


# ---------------------------------------------------------------- EuRoC
def test_euroc_slice(shared_data):
    seq = open_sequence(shared_data / "euroc" / "V1_01_easy")
    assert seq.kind == "euroc" and len(seq) == 20
    assert seq.baseline_m == pytest.approx(0.110, abs=2e-3)
    assert seq.image(0).shape == (480, 752) and seq.image(0).dtype == np.uint8
    assert seq.gt is not None and seq.gt.world_from_cam.shape == (20, 4, 4)
    # The MAV stands still in this slice: under 2 mm of motion.
    assert np.linalg.norm(seq.gt.positions - seq.gt.positions[0], axis=1).max() < 0.005
    assert seq.timestamps_s[0] == pytest.approx(1403715274.312143104)


def test_euroc_gt_is_camera_pose_via_t_bs(shared_data):
    """world_from_rect = world_from_body @ T_BS(cam0) @ inv(rect_from_cam0), body positions from the csv."""
    seq = read_euroc(shared_data / "euroc" / "V1_01_easy")
    body_from_cam0 = np.array(seq.meta["body_from_cam0"])
    rect_from_cam0 = np.array(seq.meta["rect_from_cam0"])
    world_from_body = seq.gt.world_from_cam[0] @ rect_from_cam0 @ se3.inverse(body_from_cam0)
    # The camera-rate re-estimated ground truth disagrees with the original by a few cm (see data README).
    first = np.loadtxt(shared_data / "euroc" / "V1_01_easy" / "groundtruth_window" /
                       "V1_01_easy_openvins_camrate_groundtruth_window.csv", delimiter=",", skiprows=1, max_rows=1)
    assert np.linalg.norm(world_from_body[:3, 3] - first[1:4]) < 0.06
    world_from_body_ref = se3.from_quat_wxyz(first[4:8], first[1:4])
    assert np.rad2deg(se3.rotation_angle(se3.inverse(world_from_body_ref) @ world_from_body)) < 3.0


def test_euroc_stereo_rectified_rows(shared_data):
    seq = open_sequence(shared_data / "euroc" / "V1_01_easy")
    du, dv = _stereo_offsets(seq.image(5), seq.image_right(5))
    assert len(du) > 50
    assert np.median(np.abs(dv)) < 0.7  # raw images are off by several pixels


def test_euroc_undistortion_keeps_straight_lines_straight(shared_data):
    """Draw a straight 3D line through cam0's real distortion, undistort it with the reader, fit a line."""
    mav = shared_data / "euroc" / "V1_01_easy" / "mav0"
    cam0 = read_sensor_yaml(mav / "cam0" / "sensor.yaml")
    seq = read_euroc(shared_data / "euroc" / "V1_01_easy")
    rect_from_cam0 = np.array(seq.meta["rect_from_cam0"])
    # A line in cam0 coordinates crossing most of the image near its border (strong distortion).
    s = np.linspace(-1.0, 1.0, 4000)
    p_cam0 = np.stack([s * 1.2, 0.55 + 0.2 * s, np.full_like(s, 1.5)], axis=-1)
    uv_dist, _ = cv2.projectPoints(p_cam0, np.zeros(3), np.zeros(3), cam0["k"], cam0["dist"])
    uv_dist = uv_dist.reshape(-1, 2)
    raw = np.zeros((cam0["height"], cam0["width"]), np.uint8)
    inside = (uv_dist[:, 0] >= 0) & (uv_dist[:, 0] < 751) & (uv_dist[:, 1] >= 0) & (uv_dist[:, 1] < 479)
    for u, v in uv_dist[inside]:
        raw[int(round(v)), int(round(u))] = 255
    raw = cv2.GaussianBlur(raw, (5, 5), 1.0)
    rectified = seq.postprocess(raw, "left")
    # The curve bends visibly before undistortion...
    def line_residual(img: np.ndarray) -> float:
        vs, us = np.nonzero(img > 0.5 * img.max())
        w = img[vs, us].astype(np.float64)
        a = np.polyfit(us, vs, 1, w=w)
        return float(np.sqrt(np.average((vs - np.polyval(a, us)) ** 2, weights=w)))
    assert line_residual(raw) > 3.0
    # ...and is straight after it, and lies where the rectified camera projects the 3D line.
    assert line_residual(rectified) < 1.0
    uv, _ = seq.camera.project(se3.transform_points(rect_from_cam0, p_cam0))
    vs, us = np.nonzero(rectified > 0.5 * rectified.max())
    pred_v = np.interp(us, uv[:, 0], uv[:, 1])
    assert np.median(np.abs(vs - pred_v)) < 1.0


def test_euroc_yaml_without_intrinsics(shared_data, tmp_path, capsys):
    dst = tmp_path / "V1"
    shutil.copytree(shared_data / "euroc" / "V1_01_easy" / "mav0", dst / "mav0")
    y = dst / "mav0" / "cam0" / "sensor.yaml"
    y.write_text("\n".join(l for l in y.read_text().splitlines() if not l.startswith("intrinsics")))
    assert main(["info", str(dst)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cam0/sensor.yaml" in err[0] and "intrinsics" in err[0]


# ---------------------------------------------------------------- ours
def _write_tiny(root: Path, n: int = 3, complete: bool = True) -> tuple[PinholeCamera, np.ndarray]:
    cam = PinholeCamera(8, 6, 10.0, 10.0, 3.5, 2.5)
    rng = np.random.default_rng(0)
    poses = np.stack([se3.from_euler6([0, 0.01 * i, 0, 0.1 * i, 0, 0]) for i in range(n)])
    w = OursWriter(root, {"num_frames": n, "rate_hz": 10.0, "camera": cam.to_dict(), "scene": "test",
                          "has": {"rgb_right": False, "depth": True, "flow": True, "mask": True}})
    for i in range(n):
        w.write_frame(i, i / 10.0, poses[i], rng.integers(0, 255, (6, 8, 3), dtype=np.uint8),
                      depth=np.full((6, 8), 2.0 + i, np.float32),
                      flow=np.full((6, 8, 2), i, np.float32) if i < n - 1 else None,
                      mask=np.full((6, 8), 300 * i, np.uint16))
    if complete:
        w.finish()
    return cam, poses


def test_ours_round_trip(tmp_path):
    cam, poses = _write_tiny(tmp_path / "s")
    seq = open_sequence(tmp_path / "s")
    assert seq.kind == "ours" and len(seq) == 3 and seq.camera == cam
    np.testing.assert_allclose(seq.gt.world_from_cam, poses, atol=1e-11)
    np.testing.assert_allclose(seq.timestamps_s, [0.0, 0.1, 0.2])
    assert seq.depth(2)[0, 0] == 4.0 and seq.depth(2).dtype == np.float32
    assert seq.flow(1)[0, 0, 1] == 1.0 and seq.flow(2) is None
    assert seq.mask(2).dtype == np.uint16 and seq.mask(2)[0, 0] == 600
    assert seq.image(0).shape == (6, 8, 3)


def test_ours_incomplete_is_refused(tmp_path, capsys):
    _write_tiny(tmp_path / "s", complete=False)
    with pytest.raises(InputError, match="incomplete"):
        read_ours(tmp_path / "s")
    assert main(["info", str(tmp_path / "s")]) == 2
    assert "incomplete" in capsys.readouterr().err


def test_ours_resume_refuses_other_settings(tmp_path):
    _write_tiny(tmp_path / "s", complete=False)
    with pytest.raises(InputError, match="num_frames"):
        OursWriter(tmp_path / "s", {"num_frames": 4, "rate_hz": 10.0,
                                    "camera": PinholeCamera(8, 6, 10.0, 10.0, 3.5, 2.5).to_dict(), "scene": "test",
                                    "has": {"rgb_right": False, "depth": True, "flow": True, "mask": True}}, resume=True)


def test_ours_bad_depth_file(tmp_path):
    _write_tiny(tmp_path / "s")
    (tmp_path / "s" / "depth" / "000001.npy").write_bytes(b"\x93NUMPY garbage")
    seq = open_sequence(tmp_path / "s")
    with pytest.raises(InputError, match="000001.npy"):
        seq.depth(1)


def test_unknown_folder(tmp_path, capsys):
    assert main(["info", str(tmp_path)]) == 2
    assert "not a KITTI sequence" in capsys.readouterr().err
    assert main(["info", str(tmp_path / "nope")]) == 2


def test_input_error_survives_pickling():
    import pickle

    e = pickle.loads(pickle.dumps(InputError("a/b.txt", "bad row", 3)))
    assert isinstance(e, InputError) and e.message() == "a/b.txt:3: bad row"


def test_atomic_files_get_normal_permissions(tmp_path):
    import os

    from deepslam.core import atomic

    atomic.write_text(tmp_path / "x.txt", "hi")
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "x.txt").stat().st_mode & 0o777 == 0o666 & ~umask
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_read_for_estimated_flow_upsamples_only_narrow_frames_of_estimated_flow_without_depth(plane_sequence):
    from deepslam.core.sequence import UpsampledView, read_for_estimated_flow

    seq = open_sequence(plane_sequence)
    wide = 2 * seq.camera.width
    asked = []

    def reads_depth(answer):
        return lambda: asked.append(answer) or answer

    view = read_for_estimated_flow(seq, wide, "dis", reads_depth(False))
    assert isinstance(view, UpsampledView) and view.camera.width == wide and len(view) == len(seq)
    assert read_for_estimated_flow(seq, wide, "dis", reads_depth(True)) is seq           # the network reads depth
    assert asked == [False, True]
    assert read_for_estimated_flow(seq, wide, "gt", reads_depth(False)) is seq           # stored flow: its own size
    assert read_for_estimated_flow(seq, seq.camera.width, "dis", reads_depth(False)) is seq  # wide enough already
    assert read_for_estimated_flow(seq, 0, "dis", reads_depth(False)) is seq
    assert asked == [False, True]  # the model's header is asked only where the first two conditions hold
