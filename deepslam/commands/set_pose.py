"""``deepslam set-pose MODEL --pose epipolar --out OUT``: record how a VO model's motions are used."""
from __future__ import annotations

import argparse

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "set-pose"
HELP = ("write a VO model file with its pose mode recorded in its meta: net (the network's 6DoF) or epipolar "
        "(rotation and direction from the essential matrix of the flow, distance from the network); vo and slam "
        "use the recorded mode when --pose is not given")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="VO model file (model.safetensors or an ensemble file)")
    p.add_argument("--pose", required=True, choices=("net", "epipolar"), help="the pose mode to record")
    p.add_argument("--scale", choices=("network", "road", "road-flow"), default=None,
                   help="with --pose epipolar, the distance source to record: network (its translation), road "
                        "(the road's motion and the camera's height, the images where the flow loses it; vo --scale "
                        "road) or road-flow (the flow's road only); default: keep the file's")
    p.add_argument("--out", required=True, help="model file to write (may be MODEL itself)")


def run(args: argparse.Namespace) -> int:
    from deepslam.vo.modelfiles.models import write_with_pose

    write_with_pose(args.model, args.out, args.pose, args.scale)
    print(f"wrote {args.out}: pose {args.pose}" + (f", scale {args.scale}" if args.scale else ""))
    return 0
