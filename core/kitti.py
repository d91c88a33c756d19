"""KITTI odometry reader: ``<root>/sequences/NN/{image_0..3, calib.txt, times.txt}`` + ``<root>/poses/NN.txt``.

calib.txt holds any subset of P0..P3 (3x4 rectified projection matrices, ``Pk = K [I | t_k]`` with
``t_k`` in cam0 coordinates) and optionally Tr (velodyne to cam0). Ground truth poses are cam0
world_from_cam, one 3x4 row-major matrix per line. When image_0 is present the grey pair
(image_0, image_1; P0, P1) is used, otherwise the colour pair (image_2, image_3; P2, P3), whose
poses are shifted from cam0's by the offset in P2.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.core.textio import read_text
from deepslam.core.sequence import Sequence, ground_truth_files, read_image
from deepslam.core.trajectory import Trajectory
from deepslam.core.trajio import read_trajectory


def read_calib(path: Path) -> dict[str, np.ndarray]:
    """Parse calib.txt into {"P0": (3,4), ..., "Tr": (3,4)}; InputError names the bad line."""
    if not path.exists():
        raise InputError(path, "calib.txt is missing")
    out: dict[str, np.ndarray] = {}
    seen: dict[str, int] = {}
    for lineno, line in enumerate(read_text(path, path.name).splitlines(), start=1):
        if not line.strip():
            continue
        key, sep, rest = line.partition(":")
        if not sep:
            raise InputError(path, "expected 'KEY: 12 numbers'", line=lineno)
        if key.strip() in seen:  # which one would be meant? refuse rather than silently keep the last
            raise InputError(path, f"{key.strip()[:20]} is given twice (first on line {seen[key.strip()]})", line=lineno)
        seen[key.strip()] = lineno
        try:
            vals = np.array([float(x) for x in rest.split()])
        except ValueError:
            raise InputError(path, f"non-number in {key.strip()}", line=lineno) from None
        if key.strip() in {"P0", "P1", "P2", "P3", "Tr"}:
            if vals.size != 12 or not np.isfinite(vals).all():
                raise InputError(path, f"{key.strip()} needs 12 finite numbers, got {vals.size}", line=lineno)
            out[key.strip()] = vals.reshape(3, 4)
    return out


def _read_times(path: Path) -> np.ndarray:
    if not path.exists():
        raise InputError(path, "times.txt is missing")
    times = []
    for lineno, line in enumerate(read_text(path, path.name).splitlines(), start=1):
        if not line.strip():
            continue
        try:
            t = float(line.split()[0])
        except ValueError:
            raise InputError(path, f"not a number: {line.strip()[:40]!r}", line=lineno) from None
        if not np.isfinite(t):
            raise InputError(path, "timestamp is not finite", line=lineno)
        times.append(t)
    return np.array(times, dtype=np.float64)


_FRAME_NAME = re.compile(r"^([0-9]+)\.(?:png|jpe?g)$", re.IGNORECASE)


def _frame_files(folder: Path) -> dict[int, Path]:
    """{frame number: image} of a KITTI image folder (``NNNNNN.png``; any zero padding, png or jpg).
    Exactly one file per frame: two files of one number (``3.png`` beside ``000003.png``, or
    ``000003.jpg`` beside it) are an InputError naming both."""
    files: dict[int, Path] = {}
    for p in sorted(folder.iterdir()):
        m = _FRAME_NAME.match(p.name)
        if m is None:
            continue
        i = int(m.group(1))
        if i in files:
            raise InputError(p, f"a second image of frame {i} (beside {files[i].name}); keep exactly one file per frame")
        files[i] = p
    return files


def _offset(p: np.ndarray) -> np.ndarray:
    """t_k (metres, cam0 axes) of ``P_k = K [I | t_k]``: p_camk = p_cam0 + t_k."""
    return np.linalg.solve(p[:, :3], p[:, 3])


def read_kitti(seq_dir: str | Path, poses_path: str | Path | None = None) -> Sequence:
    """Open a KITTI odometry sequence folder ``.../sequences/NN``.

    Args:
        seq_dir: the sequence folder.
        poses_path: ground-truth file; by default ``<seq_dir>/../../poses/NN.txt`` when it exists.
    """
    seq_dir = Path(seq_dir)
    calib_path = seq_dir / "calib.txt"
    calib = read_calib(calib_path)
    if (seq_dir / "image_0").is_dir():
        left, right, pl, pr = "image_0", "image_1", "P0", "P1"
    elif (seq_dir / "image_2").is_dir():
        left, right, pl, pr = "image_2", "image_3", "P2", "P3"
    else:
        raise InputError(seq_dir, "no image_0/ or image_2/ folder")
    if pl not in calib:
        raise InputError(calib_path, f"{pl} is missing (needed for {left}/)")
    p_left = calib[pl]
    k = p_left[:, :3]
    if abs(k[1, 0]) > 1e-9 or abs(k[0, 1]) > 1e-6 or abs(k[2, 2] - 1) > 1e-9:
        raise InputError(calib_path, f"{pl} is not a rectified pinhole projection K [I | t]")
    fx = k[0, 0]
    left_files = _frame_files(seq_dir / left)
    if not left_files:
        raise InputError(seq_dir / left, "no images")
    indices = sorted(left_files)
    if indices != list(range(indices[0], indices[0] + len(indices))):
        gap = next(i for i in range(indices[0], indices[-1]) if i not in left_files)
        raise InputError(seq_dir / left / f"{gap:06d}.png", "image is missing (numbering has a gap)")
    first = read_image(left_files[indices[0]])
    height, width = first.shape[:2]
    try:
        camera = PinholeCamera(width, height, float(fx), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]))
    except ValueError as e:
        raise InputError(calib_path, f"{pl} is not a usable camera ({e})") from None

    right_paths = None
    baseline = None
    if (seq_dir / right).is_dir() and pr in calib:
        right_files = _frame_files(seq_dir / right)
        for i in indices:
            if i not in right_files:
                raise InputError(seq_dir / right / left_files[i].name, "right image is missing")
        right_paths = [right_files[i] for i in indices]
        # P_k = K [I | t_k] with p_camk = p_cam0 + t_k; the right camera sits at x = +B in the left frame.
        baseline = float(_offset(p_left)[0] - _offset(calib[pr])[0])

    times_path = seq_dir / "times.txt"
    times_all = _read_times(times_path)
    if indices[-1] >= len(times_all):
        raise InputError(times_path, f"has {len(times_all)} timestamps but images go up to {indices[-1]:06d}")
    times = times_all[indices]

    gt = None
    if poses_path is None:
        candidate = seq_dir.parent.parent / "poses" / f"{seq_dir.name}.txt"
        poses_path = candidate if candidate.is_file() else None
    if poses_path is not None:
        traj = read_trajectory(Path(poses_path), fmt="kitti")
        if indices[-1] >= len(traj):
            raise InputError(poses_path, f"has {len(traj)} poses but images go up to {indices[-1]:06d}")
        world_from_cam0 = traj.world_from_cam[indices]
        # Pose of the left camera actually used: cam_l = cam0 shifted by t_l (P_l = K [I | t_l]).
        cam_l_from_cam0 = se3.from_rt(np.eye(3), _offset(p_left))
        gt = Trajectory(world_from_cam0 @ se3.inverse(cam_l_from_cam0), times)

    def beside(folder: str, suffix: str) -> list[Path] | None:
        return [seq_dir / folder / f"{i:06d}{suffix}" for i in indices] if (seq_dir / folder).is_dir() else None

    return Sequence(
        name=f"kitti/{seq_dir.name}", kind="kitti", root=seq_dir, camera=camera, timestamps_s=times,
        image_paths=[left_files[i] for i in indices], right_paths=right_paths, baseline_m=baseline, gt=gt,
        **ground_truth_files(beside),
        meta={"calib": {k2: v.tolist() for k2, v in calib.items()}, "first_index": indices[0]},
    )
