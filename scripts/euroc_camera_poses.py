"""Turn EuRoC ground truth (world_from_body, IMU frame, ~200 Hz) into camera trajectories at the camera
rate (world_from_cam0 = world_from_body @ body_from_cam0, resampled at 20 Hz), written as TUM files,
so that ``deepslam fit-motion`` fits the motion of the camera (what the network predicts) rather
than of the IMU.

    .venv/bin/python scripts/euroc_camera_poses.py --out out/vo_data/euroc_cam_poses
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from deepslam.core import trajio  # noqa: E402
from deepslam.core.euroc import read_sensor_yaml  # noqa: E402
from deepslam.core.paths import shared_data_dir  # noqa: E402
from deepslam.core.trajectory import Trajectory  # noqa: E402


def main() -> int:
    data = shared_data_dir() / "euroc"
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--rate", type=float, default=20.0, help="camera rate, Hz")
    ap.add_argument("--exclude", nargs="*", default=["V1_01_easy"], help="sequences left out (test data)")
    args = ap.parse_args()
    body_from_cam = read_sensor_yaml(data / "V1_01_easy" / "mav0" / "cam0" / "sensor.yaml")["body_from_cam"]
    out = Path(args.out)
    for f in sorted((data / "groundtruth").glob("*.xz")):
        name = f.name.split(".")[0]
        if any(name.startswith(e) for e in args.exclude):
            continue
        body = trajio.read_trajectory(f)
        t = np.arange(body.timestamps_s[0], body.timestamps_s[-1], 1.0 / args.rate)
        cam = Trajectory(body.interpolate(t).world_from_cam @ body_from_cam, t)
        trajio.write_trajectory(out / f"{name}.txt", cam, "tum")
        print(out / f"{name}.txt", len(cam))
    return 0


if __name__ == "__main__":
    sys.exit(main())
