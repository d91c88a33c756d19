"""Speed of trajectory reading and the KITTI metrics, each against a baseline measured in the same run.

- reading KITTI 00 (4541 poses) with core.trajio (validating every line) vs numpy.loadtxt (no checks);
- KITTI t_err/r_err on KITTI 00 ORB-SLAM2, vectorised (core.metrics) vs a loop-by-loop port of the
  devkit's evaluate_odometry.cpp (the reference it must equal); quick mode uses the first 1500 frames.
"""
from __future__ import annotations

import math
import time

import numpy as np

from deepslam.core import metrics
from deepslam.core.paths import shared_data_dir
from deepslam.core.trajio import read_trajectory


def _best_of(fn, repeat: int) -> float:
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _devkit_loop(gt: np.ndarray, est: np.ndarray) -> tuple[float, float]:
    lengths = [100, 200, 300, 400, 500, 600, 700, 800]
    dist = [0.0]
    for i in range(1, len(gt)):
        dist.append(dist[-1] + math.sqrt(sum((gt[i - 1][k][3] - gt[i][k][3]) ** 2 for k in range(3))))
    t_sum = r_sum = 0.0
    num = 0
    for first in range(0, len(gt), 10):
        for length in lengths:
            last = next((i for i in range(first, len(dist)) if dist[i] > dist[first] + length), -1)
            if last == -1:
                continue
            err = np.linalg.inv(np.linalg.inv(est[first]) @ est[last]) @ (np.linalg.inv(gt[first]) @ gt[last])
            d = 0.5 * (err[0][0] + err[1][1] + err[2][2] - 1.0)
            r_sum += math.acos(max(min(d, 1.0), -1.0)) / length
            t_sum += math.sqrt(err[0][3] ** 2 + err[1][3] ** 2 + err[2][3] ** 2) / length
            num += 1
    return t_sum / num * 100.0, r_sum / num * 180.0 / math.pi * 100.0


def _row(name, value, unit, baseline, baseline_value, target=None, met=None) -> dict:
    ratio = value / baseline_value if value is not None and baseline_value else None
    return {"name": name, "value": value, "unit": unit, "baseline": baseline, "baseline_value": baseline_value,
            "ratio": ratio, "target": target, "met": met}


def run(quick: bool) -> list[dict]:
    data = shared_data_dir()
    gt_path, est_path = data / "kitti/poses/00.txt", data / "reference/KITTI_00_ORB.txt"
    if not gt_path.is_file():
        return [{"name": "metrics (skipped: ../shared/data absent)", "value": None, "unit": ""}]
    repeat = 2 if quick else 5
    t_read = _best_of(lambda: read_trajectory(gt_path), repeat)
    t_loadtxt = _best_of(lambda: np.loadtxt(gt_path), repeat)
    gt = read_trajectory(gt_path).world_from_cam
    est = read_trajectory(est_path).world_from_cam
    if quick:
        gt, est = gt[:1500], est[:1500]
    t_vec = _best_of(lambda: metrics.kitti_errors(gt, est), repeat)
    t0 = time.perf_counter()
    ref = _devkit_loop(gt, est)
    t_loop = time.perf_counter() - t0
    got = metrics.kitti_errors(gt, est)
    same = abs(got["t_err_pct"] - ref[0]) < 1e-9 and abs(got["r_err_deg_per_100m"] - ref[1]) < 1e-9
    return [
        # ratio = our time / baseline time (bench/run.py's convention): < 1 means faster than the baseline
        _row("read KITTI 00 poses with validation", t_read, "s",
             "numpy.loadtxt (no validation)", t_loadtxt, "<= 2x loadtxt's time", t_read <= 2 * t_loadtxt),
        _row(f"KITTI t_err/r_err, {len(gt)} frames (equal to the port: {same})", t_vec, "s",
             "loop port of evaluate_odometry.cpp", t_loop, "<= 0.1x the loop's time, equal",
             same and t_vec <= 0.1 * t_loop),
    ]
