"""``deepslam info DIR``: what a sequence folder holds (KITTI, EuRoC or ours), checked frame by frame."""
from __future__ import annotations

import argparse
import json

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "info"
HELP = "describe a sequence folder (KITTI, EuRoC or deepslam format) and check that its files read"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("sequence", help="sequence folder: KITTI sequences/NN, EuRoC (holding mav0/), or ours")
    p.add_argument("--check", action="store_true", help="decode every file of every frame and check it: image sizes against the camera, "
                   "depth/flow shapes and finite values, mask sizes, increasing timestamps")
    p.add_argument("--json", action="store_true", help="print one JSON object (no progress bar)")
    p.add_argument("--quiet", action="store_true", help="no progress bar (--check)")


def run(args: argparse.Namespace) -> int:
    from deepslam.core.progress import progress
    from deepslam.core.readers import open_sequence

    seq = open_sequence(args.sequence)
    if args.check:
        seq.check_timestamps()
        for i in progress(range(len(seq)), desc="checking", unit="frame", disable=True if (args.json or args.quiet) else None):
            seq.check(i)
    info = {
        "name": seq.name, "kind": seq.kind, "frames": len(seq), "camera": seq.camera.to_dict(),
        "baseline_m": seq.baseline_m, "has_ground_truth": seq.gt is not None,
        "ground_truth_frames": 0 if seq.gt is None else (len(seq) if seq.gt_frames is None else int(len(seq.gt_frames))),
        "duration_s": float(seq.timestamps_s[-1] - seq.timestamps_s[0]),
        "path_length_m": None if seq.gt is None else seq.gt.path_length_m(),
        "has_depth": seq.has_depth, "has_flow": seq.flow_paths is not None, "has_mask": seq.mask_paths is not None,
    }
    if args.json:
        print(json.dumps(info))
    else:
        for k, v in info.items():
            print(f"{k:>17}: {v}")
    return 0
