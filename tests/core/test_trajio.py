"""Trajectory files: KITTI / TUM / EuRoC round trips, format detection, every real file, bad input."""
from __future__ import annotations

import gzip
import lzma
from pathlib import Path

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.trajectory import Trajectory
from deepslam.core.trajio import detect_format, format_trajectory, read_trajectory, read_trajectory_and_format, write_trajectory


def _random_traj(rng: np.random.Generator, n: int = 25, times: bool = True) -> Trajectory:
    q = rng.normal(size=(n, 4))
    poses = se3.from_quat_xyzw(q / np.linalg.norm(q, axis=1, keepdims=True), rng.normal(scale=50.0, size=(n, 3)))
    t = 1403715524.907143168 + np.cumsum(rng.uniform(0.01, 0.2, size=n)) if times else None
    return Trajectory(poses, t)


@pytest.mark.parametrize("fmt", ["kitti", "tum", "euroc"])
def test_round_trip_is_exact(tmp_path, fmt):
    traj = _random_traj(np.random.default_rng(1), times=fmt != "kitti")
    path = tmp_path / f"traj.{fmt}"
    write_trajectory(path, traj, fmt)
    back, got_fmt = read_trajectory_and_format(path)
    assert got_fmt == fmt
    assert len(back) == len(traj)
    # quaternion storage renormalises: allow a few ulps on rotations, exact on translations
    np.testing.assert_allclose(back.world_from_cam, traj.world_from_cam, rtol=0, atol=1e-12)
    if fmt == "kitti":
        assert back.timestamps_s is None
        np.testing.assert_array_equal(back.world_from_cam[:, :3, 3], traj.world_from_cam[:, :3, 3])
    elif fmt == "tum":
        np.testing.assert_array_equal(back.timestamps_s, traj.timestamps_s)
    else:  # whole nanoseconds; float64 seconds near 1.4e9 resolve ~0.24 us
        np.testing.assert_allclose(back.timestamps_s, traj.timestamps_s, rtol=0, atol=5e-7)


def test_quaternion_orders_in_files(tmp_path):
    """TUM stores (qx qy qz qw), EuRoC (q_w q_x q_y q_z): a 90 deg yaw must read back the same from both."""
    yaw90_xyzw = np.array([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])
    (tmp_path / "a.txt").write_text("1.0 1 2 3 0 0 0.7071067811865476 0.7071067811865476\n"
                                    "2.0 1 2 3 0 0 0.7071067811865476 0.7071067811865476\n")
    (tmp_path / "b.csv").write_text("#timestamp [ns],x,y,z,qw,qx,qy,qz\n"
                                    "1000000000,1,2,3,0.7071067811865476,0,0,0.7071067811865476\n"
                                    "2000000000,1,2,3,0.7071067811865476,0,0,0.7071067811865476\n")
    expected = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    for name, fmt in (("a.txt", "tum"), ("b.csv", "euroc")):
        traj, got = read_trajectory_and_format(tmp_path / name)
        assert got == fmt
        np.testing.assert_allclose(traj.world_from_cam[0, :3, :3], expected, atol=1e-12)
        np.testing.assert_allclose(se3.to_quat_xyzw(traj.world_from_cam[0]), yaw90_xyzw, atol=1e-12)
        np.testing.assert_allclose(traj.timestamps_s, [1.0, 2.0])
        np.testing.assert_allclose(traj.positions[0], [1, 2, 3])


def test_xz_and_gz_are_read_transparently(tmp_path):
    traj = _random_traj(np.random.default_rng(2))
    text = format_trajectory(traj, "tum").encode()
    (tmp_path / "t.txt.xz").write_bytes(lzma.compress(text))
    (tmp_path / "t.txt.gz").write_bytes(gzip.compress(text))
    for name in ("t.txt.xz", "t.txt.gz"):
        back = read_trajectory(tmp_path / name)
        np.testing.assert_allclose(back.world_from_cam, traj.world_from_cam, atol=1e-12)


def test_kitti_row_major_layout(tmp_path):
    (tmp_path / "k.txt").write_text("1 0 0 10 0 1 0 20 0 0 1 30\n0 -1 0 1 1 0 0 2 0 0 1 3\n")
    traj = read_trajectory(tmp_path / "k.txt")
    np.testing.assert_array_equal(traj.positions, [[10, 20, 30], [1, 2, 3]])
    np.testing.assert_array_equal(traj.world_from_cam[1, :3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    np.testing.assert_array_equal(traj.world_from_cam[:, 3], [[0, 0, 0, 1]] * 2)


def test_small_quaternion_deviation_is_normalised(tmp_path):
    (tmp_path / "q.txt").write_text("0 0 0 0 0 0 0 1.0005\n1 0 0 0 0 0 0 0.9995\n")
    traj = read_trajectory(tmp_path / "q.txt")
    np.testing.assert_allclose(traj.world_from_cam[:, :3, :3], np.broadcast_to(np.eye(3), (2, 3, 3)), atol=1e-15)


def test_repeated_timestamp_keeps_first_pose(tmp_path):
    (tmp_path / "d.txt").write_text("1 0 0 0 0 0 0 1\n2 5 0 0 0 0 0 1\n2 6 0 0 0 0 0 1\n3 7 0 0 0 0 0 1\n")
    traj = read_trajectory(tmp_path / "d.txt")
    np.testing.assert_array_equal(traj.timestamps_s, [1, 2, 3])
    np.testing.assert_array_equal(traj.positions[:, 0], [0, 5, 7])


def test_csv_header_without_hash_and_extra_columns(tmp_path):
    (tmp_path / "h.csv").write_text("timestamp,px,py,pz,qw,qx,qy,qz,vx\n"
                                    "1403715524907143168,1,2,3,1,0,0,0,9\n1403715524912143104,1,2,3,1,0,0,0,9\n")
    traj, fmt = read_trajectory_and_format(tmp_path / "h.csv")
    assert fmt == "euroc"
    np.testing.assert_allclose(np.diff(traj.timestamps_s), 0.004999936, atol=1e-6)


def test_write_is_atomic_and_refuses_missing_timestamps(tmp_path):
    traj = _random_traj(np.random.default_rng(3), times=False)
    with pytest.raises(ValueError, match="timestamps"):
        write_trajectory(tmp_path / "x.txt", traj, "tum")
    assert list(tmp_path.iterdir()) == []
    write_trajectory(tmp_path / "sub" / "x.txt", traj, "kitti")
    assert [p.name for p in (tmp_path / "sub").iterdir()] == ["x.txt"]


# --- every real file reads -------------------------------------------------------------------------

REAL_FILES = {
    # path relative to ../shared/data: (format, number of poses)
    "kitti/poses/00.txt": ("kitti", 4541),
    "kitti/poses/04.txt": ("kitti", 271),
    "reference/KITTI_00_ORB.txt": ("kitti", 4541),
    "reference/KITTI_00_SPTAM.txt": ("kitti", 4541),
    "reference/V102.txt": ("tum", 803),  # 807 lines, 4 repeated timestamps
    "reference/V102_groundtruth.csv": ("euroc", 16702),
    "reference/V101_gt.txt": ("tum", 2895),
    "reference/V101_openvins.txt": ("tum", 2776),
    "euroc/V1_01_easy/groundtruth_window/V1_01_easy_openvins_camrate_groundtruth_window.csv": ("euroc", 20),
    "euroc/V1_01_easy/groundtruth_window/V1_01_easy_original_ASL_groundtruth_tum_window.txt": ("tum", 203),
    "euroc/groundtruth/V1_01_easy.csv.xz": ("euroc", 2895),
    "euroc/groundtruth/MH_04_difficult.csv.xz": ("euroc", 19753),
    "euroc/groundtruth/MH_01_easy.txt.xz": ("tum", 36382),
}


@pytest.mark.parametrize("rel", sorted(REAL_FILES))
def test_real_files_read(shared_data, rel):
    fmt, n = REAL_FILES[rel]
    traj, got = read_trajectory_and_format(shared_data / rel)
    assert got == fmt
    assert len(traj) == n
    r = traj.world_from_cam[:, :3, :3]
    assert np.abs(np.swapaxes(r, 1, 2) @ r - np.eye(3)).max() < 1e-5
    if fmt == "kitti":
        assert traj.timestamps_s is None
    else:
        assert np.all(np.diff(traj.timestamps_s) > 0)
        assert 1.4e9 < traj.timestamps_s[0] < 1.42e9


def test_all_shared_trajectory_files_read(shared_data):
    files = (sorted((shared_data / "kitti" / "poses").glob("*.txt")) + sorted((shared_data / "reference").iterdir())
             + sorted((shared_data / "euroc" / "V1_01_easy" / "groundtruth_window").iterdir())
             + sorted((shared_data / "euroc" / "groundtruth").glob("*.xz")))
    assert len(files) >= 30
    for f in files:
        assert len(read_trajectory(f)) > 0, f


def test_real_values_kitti_and_asl(shared_data):
    kitti = read_trajectory(shared_data / "kitti/poses/00.txt")
    np.testing.assert_allclose(kitti.world_from_cam[0], np.eye(4), atol=1e-9)
    # second line of poses/00.txt ends with tz = 8.586941e-01 (m, forward)
    assert kitti.world_from_cam[1, 2, 3] == pytest.approx(0.8586941, abs=1e-12)
    asl = read_trajectory(shared_data / "reference/V102_groundtruth.csv")
    assert asl.timestamps_s[0] == pytest.approx(1403715524.907143168, abs=1e-6)
    np.testing.assert_allclose(asl.positions[0], [0.515356, 1.996773, 0.971104])
    q = se3.to_quat_wxyz(asl.world_from_cam[0])
    q_file = np.array([0.161996, 0.789985, -0.205376, 0.554528])
    np.testing.assert_allclose(q * np.sign(q[0]), q_file / np.linalg.norm(q_file), atol=1e-9)


# --- bad input: InputError naming the file and the line -------------------------------------------

K_ROW = "1 0 0 0 0 1 0 0 0 0 1 0"
T_ROW = "{t} 0 0 0 0 0 0 1"

BAD = {
    # name: (file text, expected line, words in the message)
    "kitti_11_columns": (f"{K_ROW}\n{K_ROW}\n1 0 0 0 0 1 0 0 0 0 1\n", 3, "12 columns"),
    "kitti_non_number": (f"{K_ROW}\n1 0 0 0 0 1 0 abc 0 0 1 0\n", 2, "'abc' is not a number"),
    "kitti_nan": (f"{K_ROW}\n{K_ROW}\n1 0 0 nan 0 1 0 0 0 0 1 0\n", 3, "not a finite number"),
    "kitti_inf": (f"{K_ROW}\n1 0 0 0 0 1 0 0 0 0 1 inf\n", 2, "not a finite number"),
    "kitti_not_orthonormal": (f"{K_ROW}\n{K_ROW}\n{K_ROW}\n1.01 0 0 0 0 1 0 0 0 0 1 0\n", 4, "not orthonormal"),
    "kitti_reflection": (f"{K_ROW}\n-1 0 0 0 0 1 0 0 0 0 1 0\n", 2, "not orthonormal"),
    "tum_9_columns": ("# comment\n" + T_ROW.format(t=1) + "\n" + T_ROW.format(t=2) + " 5\n", 3, "8 columns"),
    "tum_quaternion_norm": (T_ROW.format(t=1) + "\n2 0 0 0 0 0 0 1.1\n", 2, "quaternion norm"),
    "tum_zero_quaternion": ("1 0 0 0 0 0 0 0\n", 1, "quaternion norm"),
    "tum_time_goes_back": (T_ROW.format(t=1) + "\n" + T_ROW.format(t=3) + "\n\n" + T_ROW.format(t=2) + "\n", 4,
                           "goes back in time"),
    "euroc_truncated_line": ("#timestamp [ns],x,y,z,qw,qx,qy,qz\n1000,0,0,0,1,0,0,0\n2000,0,0,0,1,0\n", 3,
                             "at least 8"),
    "euroc_non_number": ("#t\n1000,0,0,0,1,0,0,0\n2000,0,x1,0,1,0,0,0\n", 3, "'x1' is not a number"),
    "unknown_column_count": ("# header\n1 2 3 4 5\n", 2, "cannot tell the format"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_content_names_file_and_line(tmp_path, case):
    text, line, words = BAD[case]
    path = tmp_path / f"{case}.txt"
    path.write_text(text)
    with pytest.raises(InputError) as ei:
        read_trajectory(path)
    e = ei.value
    assert e.path == str(path)
    assert e.line == line, e.message()
    assert words in e.what
    assert e.message().startswith(f"{path}:{line}: ")


def test_explicit_format_mismatch_is_an_error(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text(T_ROW.format(t=1) + "\n")
    with pytest.raises(InputError, match="12 columns") as ei:
        read_trajectory(path, fmt="kitti")
    assert ei.value.line == 1


@pytest.mark.parametrize("content,words", [
    (b"", "no poses"),
    (b"# only a comment\n\n", "no poses"),
    (b"\x00\x01\x02binary", "binary"),
    (b"\xfd7zXZ\x00truncated-xz", "compressed"),
    (b"\xff\xfe\xfa bad utf8 1 2 3", "UTF-8"),
])
def test_unreadable_files(tmp_path, content, words):
    path = tmp_path / "bad.txt"
    path.write_bytes(content)
    with pytest.raises(InputError, match=words) as ei:
        read_trajectory(path)
    assert ei.value.path == str(path)


def test_missing_file_and_folder(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_trajectory(tmp_path / "nope.txt")
    with pytest.raises(InputError, match="folder"):
        read_trajectory(tmp_path)
    with pytest.raises(InputError, match="unknown trajectory format"):
        read_trajectory(tmp_path / "nope.txt", fmt="csv")


def test_detect_format_of_text(tmp_path):
    p = Path(tmp_path / "x")
    assert detect_format(p, K_ROW + "\n") == "kitti"
    assert detect_format(p, "# t x y z qx qy qz qw\n" + T_ROW.format(t=1.5)) == "tum"
    assert detect_format(p, "#timestamp,...\n1403715524907143168,1,2,3,1,0,0,0,0,0,0\n") == "euroc"
