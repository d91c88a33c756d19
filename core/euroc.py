"""EuRoC MAV (ASL layout) reader with OpenCV undistortion and stereo rectification.

Layout: ``<root>/mav0/cam0/{data.csv, data/<ns>.png, sensor.yaml}`` and the same for cam1.
``sensor.yaml`` gives ``T_BS`` (body_from_sensor), ``intrinsics [fu, fv, cu, cv]``,
``distortion_model: radial-tangential`` with ``[k1, k2, p1, p2]`` and ``resolution [W, H]``.

Images are served undistorted and, when cam1 exists, stereo-rectified (``cv2.stereoRectify`` with
alpha = 0, so every output pixel is valid). The rectified left camera is rotated from the physical
cam0 by ``rect_from_cam0`` (R1 of stereoRectify), which the ground truth follows:

    world_from_rect = world_from_body @ body_from_cam0 @ inverse(rect_from_cam0)

Ground truth (world_from_body, body = the IMU frame) is read from, in order: ``gt_path`` if given,
``mav0/state_groundtruth_estimate0/data.csv``, or ``<root>/../groundtruth/<root name>.{csv,txt}[.xz]``,
and interpolated (slerp + linear) at the frame times; frames outside the ground truth's time span
are an error.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera, check_distortion
from deepslam.core.errors import InputError
from deepslam.core.textio import loads_yaml, read_text, short
from deepslam.core.sequence import Sequence, dataset_file, ground_truth_files
from deepslam.core.trajectory import Trajectory
from deepslam.core.trajio import ns_to_s, read_trajectory


def read_sensor_yaml(path: Path) -> dict:
    """Parse a EuRoC camera sensor.yaml into {"body_from_cam", "k", "dist", "width", "height", "rate_hz"}."""
    text = read_text(path, "sensor.yaml")
    offset = 0
    if text.startswith("%YAML"):  # OpenCV's "%YAML:1.0" first line is not YAML 1.1
        text = text.split("\n", 1)[1] if "\n" in text else ""
        offset = 1
    # bounded: aliases limited, no duplicate keys, at most 1 MB (core.textio)
    y = loads_yaml(text, path, "sensor.yaml", line_offset=offset) or {}
    if not isinstance(y, dict):
        raise InputError(path, "not a YAML mapping")
    intr = y.get("intrinsics")
    if not isinstance(intr, list) or len(intr) != 4:
        raise InputError(path, "intrinsics [fu, fv, cu, cv] are missing")
    model = y.get("distortion_model", "radial-tangential")
    if model not in ("radial-tangential", "radtan", "none"):
        raise InputError(path, f"unsupported distortion_model {short(model)} (radial-tangential only)")
    dist = y.get("distortion_coefficients", [0, 0, 0, 0])
    res = y.get("resolution")
    if not isinstance(res, list) or len(res) != 2:
        raise InputError(path, "resolution [width, height] is missing")
    tbs = y.get("T_BS", {})
    data = tbs.get("data") if isinstance(tbs, dict) else None
    if not isinstance(data, list) or len(data) != 16:
        raise InputError(path, "T_BS with 16 numbers is missing")
    try:
        body_from_cam = np.array(data, dtype=np.float64).reshape(4, 4)
        k = np.array([[intr[0], 0, intr[2]], [0, intr[1], intr[3]], [0, 0, 1]], dtype=np.float64)
        dist = np.array(dist, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(path, "non-number in T_BS, intrinsics or distortion_coefficients") from None
    if not (np.isfinite(body_from_cam).all() and np.isfinite(k).all() and np.isfinite(dist).all()):
        raise InputError(path, "non-finite number in T_BS, intrinsics or distortion_coefficients")
    if se3.orthonormality_error(body_from_cam[:3, :3]) > 1e-4:
        raise InputError(path, "T_BS rotation is not orthonormal")
    k_und = None
    und = y.get("undistorted_intrinsics")  # deepslam's simulator: the pinhole camera its ground truth is in
    if und is not None:
        try:
            k_und = np.array([[und[0], 0, und[2]], [0, und[1], und[3]], [0, 0, 1]], dtype=np.float64)
        except (TypeError, ValueError, IndexError, KeyError):
            raise InputError(path, "undistorted_intrinsics must be [fu, fv, cu, cv]") from None
        if not np.isfinite(k_und).all():
            raise InputError(path, "non-finite number in undistorted_intrinsics")
    try:
        width, height, rate_hz = int(res[0]), int(res[1]), float(y.get("rate_hz", 20.0))
    except (TypeError, ValueError):
        raise InputError(path, f"resolution must be two integers and rate_hz a number, got {short(res)} and "
                               f"{short(y.get('rate_hz'))}") from None
    check_distortion(k, dist, width, height, path)
    return {"body_from_cam": body_from_cam, "k": k, "dist": dist, "width": width, "height": height,
            "rate_hz": rate_hz, "k_undistorted": k_und}


def _read_data_csv(path: Path, cam_dir: Path) -> tuple[np.ndarray, list[Path]]:
    if not path.exists():
        raise InputError(path, "data.csv is missing")
    stamps, files = [], []
    lines_of: dict[Path, int] = {}
    for lineno, line in enumerate(read_text(path, "data.csv").splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        parts = [p.strip() for p in line.split(",")]
        if len(parts) != 2:
            raise InputError(path, f"expected 2 columns (timestamp [ns], filename), got {len(parts)}", line=lineno)
        if not parts[0].isdigit():
            raise InputError(path, f"timestamp is not an integer number of ns: {parts[0][:30]!r}", line=lineno)
        f = dataset_file(cam_dir / "data", parts[1], path, lineno)
        if f in lines_of:
            raise InputError(path, f"{parts[1][:80]} is listed twice (first on line {lines_of[f]}); one file per frame",
                             line=lineno)
        lines_of[f] = lineno
        if stamps and int(parts[0]) <= stamps[-1]:
            raise InputError(path, f"timestamps are not strictly increasing ({parts[0]} ns after {stamps[-1]} ns)",
                             line=lineno)
        stamps.append(int(parts[0]))
        files.append(f)
    if not stamps:
        raise InputError(path, "no frames")
    ns = np.array(stamps, dtype=np.int64)
    return ns, files


def _find_gt(root: Path, gt_path: Path | None) -> Path | None:
    if gt_path is not None:
        return Path(gt_path)
    cand = root / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    if cand.is_file():
        return cand
    for ext in (".csv", ".csv.xz", ".txt", ".txt.xz"):
        cand = root.parent / "groundtruth" / f"{root.name}{ext}"
        if cand.is_file():
            return cand
    return None


def read_euroc(root: str | Path, gt_path: str | Path | None = None, rectify: bool = True) -> Sequence:
    """Open a EuRoC sequence folder (the one holding ``mav0``, or ``mav0`` itself).

    Args:
        root: sequence folder.
        gt_path: ground truth (ASL csv or TUM, world_from_body, optionally .xz); searched when None.
        rectify: undistort and stereo-rectify (True) or serve raw images with cam0's K (False).
    """
    root = Path(root)
    if root.name == "mav0":
        root = root.parent
    mav = root / "mav0"
    cam0 = read_sensor_yaml(mav / "cam0" / "sensor.yaml")
    ns, files0 = _read_data_csv(mav / "cam0" / "data.csv", mav / "cam0")
    for f in files0:
        if not f.is_file():
            raise InputError(f, "image file is missing")
    times = ns_to_s(ns)
    size = (cam0["width"], cam0["height"])

    right_paths = None
    baseline = None
    rect_from_cam0 = np.eye(4)
    maps = {}
    try:
        camera = PinholeCamera.from_k(cam0["k"], *size)
    except ValueError as e:
        raise InputError(mav / "cam0" / "sensor.yaml", f"not a usable camera ({e})") from None
    if (mav / "cam1" / "sensor.yaml").is_file():
        cam1 = read_sensor_yaml(mav / "cam1" / "sensor.yaml")
        ns1, files1 = _read_data_csv(mav / "cam1" / "data.csv", mav / "cam1")
        by_ns = dict(zip(ns1.tolist(), files1))
        right_paths = []
        for t, f0 in zip(ns.tolist(), files0):
            f1 = by_ns.get(t)
            if f1 is None or not f1.is_file():
                raise InputError(f1 or (mav / "cam1" / "data" / f0.name), "right image is missing")
            right_paths.append(f1)
        cam1_from_cam0 = se3.inverse(cam1["body_from_cam"]) @ cam0["body_from_cam"]
        # Already a rectified, undistorted pair (as the simulator exports): serve it as it is, so
        # that depth/, flow/ and mask/ beside the images stay aligned with them.
        rectified = (np.allclose(cam0["k"], cam1["k"]) and np.allclose(cam1_from_cam0[:3, :3], np.eye(3), atol=1e-9)
                     and np.allclose(cam1_from_cam0[1:3, 3], 0.0, atol=1e-9))
        already = rectified and not cam0["dist"].any() and not cam1["dist"].any()
        if already:
            baseline = float(-cam1_from_cam0[0, 3])
        elif rectify and rectified and cam0["k_undistorted"] is not None and cam1["k_undistorted"] is not None:
            # a rectified pair behind distorting lenses (the simulator's): undistort each to the pinhole
            # camera its ground truth is in
            for side, cam in (("left", cam0), ("right", cam1)):
                maps[side] = cv2.initUndistortRectifyMap(cam["k"], cam["dist"], None, cam["k_undistorted"], size,
                                                         cv2.CV_32FC1)
            camera = PinholeCamera.from_k(cam0["k_undistorted"], *size)
            baseline = float(-cam1_from_cam0[0, 3])
        elif rectify:
            r1, r2, p1, p2, _, _, _ = cv2.stereoRectify(
                cam0["k"], cam0["dist"], cam1["k"], cam1["dist"], size,
                cam1_from_cam0[:3, :3], cam1_from_cam0[:3, 3], flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
            maps["left"] = cv2.initUndistortRectifyMap(cam0["k"], cam0["dist"], r1, p1, size, cv2.CV_32FC1)
            maps["right"] = cv2.initUndistortRectifyMap(cam1["k"], cam1["dist"], r2, p2, size, cv2.CV_32FC1)
            rect_from_cam0 = se3.from_rt(r1, np.zeros(3))
            camera = PinholeCamera.from_k(p1[:, :3], *size)
            baseline = float(-p2[0, 3] / p2[0, 0])
        else:
            baseline = float(np.linalg.norm(cam1_from_cam0[:3, 3]))
    elif rectify and cam0["dist"].any():
        new_k = cam0["k_undistorted"]
        if new_k is None:
            new_k, _ = cv2.getOptimalNewCameraMatrix(cam0["k"], cam0["dist"], size, 0, size)
        maps["left"] = cv2.initUndistortRectifyMap(cam0["k"], cam0["dist"], None, new_k, size, cv2.CV_32FC1)
        camera = PinholeCamera.from_k(new_k, *size)

    def postprocess(img: np.ndarray, side: str) -> np.ndarray:
        m = maps.get(side)
        return img if m is None else cv2.remap(img, m[0], m[1], cv2.INTER_LINEAR)

    gt = None
    gt_file = _find_gt(root, gt_path)
    if gt_file is not None:
        world_from_body = read_trajectory(gt_file)
        try:
            at_frames = world_from_body.interpolate(times)
        except ValueError as e:
            raise InputError(gt_file, f"ground truth does not cover the frames: {e}") from None
        world_from_rect = at_frames.world_from_cam @ cam0["body_from_cam"] @ se3.inverse(rect_from_cam0)
        gt = Trajectory(world_from_rect, times)

    cam_dir = mav / "cam0"

    def beside(folder: str, suffix: str) -> list[Path] | None:
        return [cam_dir / folder / f"{i:06d}{suffix}" for i in range(len(files0))] if (cam_dir / folder).is_dir() else None

    return Sequence(
        name=f"euroc/{root.name}", kind="euroc", root=root, camera=camera, timestamps_s=times,
        image_paths=files0, right_paths=right_paths, baseline_m=baseline, gt=gt,
        **ground_truth_files(beside),
        postprocess=postprocess if maps else None,
        meta={"timestamps_ns": ns.tolist(), "rect_from_cam0": rect_from_cam0.tolist(),
              "body_from_cam0": cam0["body_from_cam"].tolist(), "gt_path": None if gt_file is None else str(gt_file)},
    )
