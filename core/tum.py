"""TUM RGB-D reader: the layout as published (Sturm et al., 2012), lazily.

Layout (``<root>`` = e.g. ``rgbd_dataset_freiburg3_teddy``)::

    rgb.txt          "timestamp filename" per line (seconds; ``#`` comments), colour images
    depth.txt        the same for the depth maps
    groundtruth.txt  TUM trajectory "t tx ty tz qx qy qz qw" of the colour camera's optical frame
                     (OpenCV axes: x right, y down, z forward), world_from_cam
    rgb/*.png        8-bit colour, 640x480
    depth/*.png      16-bit, ``depth_scale`` units per metre (5000 = 1 m), 0 = no reading
    intrinsics.txt   optional: "fx fy cx cy [k1 k2 p1 p2 k3]" (overrides the freiburg id's values)
    depth_scale.txt  optional: one number, units per metre (overrides 5000)

Colour and depth frames are associated as TUM's ``associate.py`` does: every pair closer than
``max_diff_s`` (0.02 s) is a candidate, taken greedily by increasing time difference, each frame at
most once; the frames of the sequence are the associated colour frames in time order, at the colour
image's time. Ground truth is interpolated at the frame times it covers (slerp + linear); frames
outside it have none (``Sequence.gt_frames`` lists the frames that do, and the metrics say how many
were scored). Intrinsics come from the freiburg id in the folder name (TUM's published calibration);
fr1 and fr2 images have radial-tangential distortion, undone here with OpenCV (colour bilinear,
depth nearest, so no depth is invented between surfaces).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from deepslam.core.camera import PinholeCamera, check_depth_units, check_distortion
from deepslam.core.errors import InputError
from deepslam.core.sequence import Sequence, dataset_file, ground_truth_files, read_image
from deepslam.core.textio import read_text
from deepslam.core.trajectory import Trajectory
from deepslam.core.trajio import read_trajectory

TUM_INTRINSICS = {
    "freiburg1": ((517.3, 516.5, 318.6, 255.3), (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "freiburg2": ((520.9, 521.0, 325.1, 249.7), (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "freiburg3": ((535.4, 539.2, 320.1, 247.6), (0.0, 0.0, 0.0, 0.0, 0.0)),
}
"""TUM's published calibration per sensor: (fx, fy, cx, cy), (k1, k2, p1, p2, k3) (OpenCV order)."""
DEPTH_SCALE = 5000.0
"""Depth PNG units per metre."""
MAX_DIFF_S = 0.02
"""Largest colour-depth time difference of an association, seconds (associate.py's default)."""


def is_tum(root: Path) -> bool:
    """True for a folder holding rgb.txt and depth.txt."""
    return (root / "rgb.txt").is_file() and (root / "depth.txt").is_file()


def read_file_list(path: Path) -> list[tuple[float, str, int]]:
    """(timestamp s, file name, line number) of each entry of an rgb.txt / depth.txt, in strictly
    increasing time (an entry out of order or at the time of the one before is an InputError naming the
    line; TUM's files are in time order)."""
    out = []
    for lineno, line in enumerate(read_text(path, path.name).splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) < 2:
            raise InputError(path, "expected 'timestamp filename'", line=lineno)
        try:
            t = float(parts[0])
        except ValueError:
            raise InputError(path, f"timestamp is not a number: {parts[0][:30]!r}", line=lineno) from None
        if not np.isfinite(t):
            raise InputError(path, "timestamp is not finite", line=lineno)
        if out and t <= out[-1][0]:  # the frames are the listing's order: it must be time order
            raise InputError(path, f"out of time order: {parts[0][:30]} s is not after {out[-1][0]!r} s on line "
                                   f"{out[-1][2]}", line=lineno)
        out.append((t, parts[1], lineno))
    if not out:
        raise InputError(path, "lists no frames")
    return out


def associate_times(ta: np.ndarray, tb: np.ndarray, max_diff_s: float = MAX_DIFF_S) -> list[tuple[int, int]]:
    """TUM's association: candidate pairs (i, j) with |ta[i] - tb[j]| < max_diff_s, taken greedily by
    increasing difference, each index at most once; returned sorted by i."""
    ta, tb = np.asarray(ta, np.float64), np.asarray(tb, np.float64)
    cand = []
    order = np.argsort(tb)
    tbs = tb[order]
    for i, t in enumerate(ta):
        lo, hi = np.searchsorted(tbs, t - max_diff_s), np.searchsorted(tbs, t + max_diff_s, side="right")
        for k in range(lo, hi):
            d = abs(tbs[k] - t)
            if d < max_diff_s:
                cand.append((d, i, int(order[k])))
    cand.sort()
    used_a, used_b, pairs = set(), set(), []
    for _, i, j in cand:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    return sorted(pairs)


def _intrinsics(root: Path) -> tuple[tuple[float, ...], tuple[float, ...]]:
    path = root / "intrinsics.txt"
    if path.exists():
        try:
            vals = [float(x) for x in read_text(path, "intrinsics.txt").split()]
        except ValueError:
            raise InputError(path, "expected 'fx fy cx cy [k1 k2 p1 p2 k3]' as numbers") from None
        if len(vals) not in (4, 8, 9) or not np.isfinite(vals).all():
            raise InputError(path, f"expected 4, 8 or 9 numbers (fx fy cx cy [k1 k2 p1 p2 [k3]]), got {len(vals)}")
        dist = tuple(vals[4:]) + (0.0,) * (9 - len(vals)) if len(vals) > 4 else (0.0,) * 5
        return tuple(vals[:4]), dist
    name = root.resolve().name.lower()
    for key, value in TUM_INTRINSICS.items():
        if key in name:
            return value
    raise InputError(root, "unknown TUM sensor: the folder name holds no freiburg1/2/3 id and there is no "
                           "intrinsics.txt ('fx fy cx cy [k1 k2 p1 p2 k3]')")


def _depth_scale(root: Path) -> float:
    path = root / "depth_scale.txt"
    if not path.exists():
        return DEPTH_SCALE
    try:
        v = float(read_text(path, "depth_scale.txt").split()[0])
    except (ValueError, IndexError):
        raise InputError(path, "expected one number (depth units per metre)") from None
    if not (np.isfinite(v) and v > 0):
        raise InputError(path, f"depth scale must be positive, got {v}")
    return v


def read_tum(root: str | Path, max_diff_s: float = MAX_DIFF_S) -> Sequence:
    """Open a TUM RGB-D sequence folder (see the module docstring)."""
    root = Path(root)
    rgb = read_file_list(root / "rgb.txt")
    depth = read_file_list(root / "depth.txt")
    for listing, entries in (("rgb.txt", rgb), ("depth.txt", depth)):
        for _, name, lineno in entries:
            if not dataset_file(root, name, root / listing, lineno).is_file():
                raise InputError(root / listing, f"lists {name[:80]}, which is missing", line=lineno)
    pairs = associate_times(np.array([e[0] for e in rgb]), np.array([e[0] for e in depth]), max_diff_s)
    if not pairs:
        raise InputError(root / "depth.txt", f"no depth map within {max_diff_s} s of any colour image (rgb.txt)")
    times = np.array([rgb[i][0] for i, _ in pairs])
    image_paths = [root / rgb[i][1] for i, _ in pairs]
    depth_paths = [root / depth[j][1] for _, j in pairs]
    first = read_image(image_paths[0])
    height, width = first.shape[:2]
    (fx, fy, cx, cy), dist = _intrinsics(root)
    try:
        camera = PinholeCamera(width, height, fx, fy, cx, cy)
    except ValueError as e:
        raise InputError(root / "intrinsics.txt", f"not a usable camera ({e})") from None
    scale = _depth_scale(root)
    maps = None
    if any(dist):
        k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], np.float64)
        check_distortion(k, dist, width, height, root / "intrinsics.txt")
        maps = cv2.initUndistortRectifyMap(k, np.array(dist, np.float64), None, k, (width, height), cv2.CV_32FC1)

    def postprocess(img: np.ndarray, side: str) -> np.ndarray:
        return img if maps is None else cv2.remap(img, maps[0], maps[1], cv2.INTER_LINEAR)

    def read_depth(path: Path) -> np.ndarray:
        raw = read_image(path)
        if raw.dtype != np.uint16 or raw.ndim != 2:
            raise InputError(path, f"depth PNG must be 16-bit single-channel, got {raw.dtype} with shape {raw.shape}")
        if raw.shape != (height, width):
            raise InputError(path, f"depth is {raw.shape[1]}x{raw.shape[0]}, the images are {width}x{height}")
        if maps is not None:
            raw = cv2.remap(raw, maps[0], maps[1], cv2.INTER_NEAREST)
        return raw.astype(np.float32) / np.float32(scale)

    if depth_paths:
        check_depth_units(read_depth(depth_paths[0]), depth_paths[0], f"depth_scale {scale:g} units per metre")

    gt, gt_frames = None, None
    gt_path = root / "groundtruth.txt"
    if gt_path.exists():
        full = read_trajectory(gt_path, "tum")
        t0, t1 = full.timestamps_s[0], full.timestamps_s[-1]
        inside = np.flatnonzero((times >= t0) & (times <= t1))
        if len(inside):
            gt = full.interpolate(times[inside])
            gt_frames = inside
    def beside(folder: str, suffix: str) -> list[Path] | None:
        # ground truth a deepslam render writes beside the TUM lists, one file per colour image, same stem
        return [root / folder / f"{p.stem}{suffix}" for p in image_paths] if (root / folder).is_dir() else None

    extra = {k: v for k, v in ground_truth_files(beside).items() if k != "depth_paths"}
    return Sequence(
        name=root.name, kind="tum", root=root, camera=camera, timestamps_s=times, image_paths=image_paths,
        gt=gt, gt_frames=gt_frames, depth_paths=depth_paths, depth_reader=read_depth, **extra,
        postprocess=postprocess if maps is not None else None,
        meta={"depth_scale": scale, "distortion": list(dist), "associated": len(pairs), "rgb_listed": len(rgb),
              "depth_listed": len(depth), "max_diff_s": max_diff_s},
    )
