"""``deepslam adapt``: train the odometry on a sequence's own single frames (no poses), from the shipped models."""
from __future__ import annotations

import argparse
import json

from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "adapt"
HELP = "adapt NN_cons / NN_loops to a camera from a sequence's single frames with depth (no poses; the paper's method)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sequence", required=True, help="the sequence to adapt to: TUM RGB-D, KITTI or EuRoC (stereo), "
                                                     "or a deepslam render; its poses are never read")
    p.add_argument("--out", required=True, help="output folder: model.safetensors (NN_cons), loops.safetensors "
                                                "(NN_loops), adapt.json (the record), cons/ and loops/ (the runs)")
    p.add_argument("--model", default=None, help="start NN_cons from this model file (default: the shipped one "
                                                 "for the sequence's camera kind)")
    p.add_argument("--motion", default=None, metavar="FILE",
                   help="motion model (deepslam fit-motion JSON) instead of the camera kind's")
    p.add_argument("--max-minutes", type=float, default=20.0,
                   help="safety cap of the whole run (20); the sample budget ends it first on 2 cores")
    p.add_argument("--samples", type=int, default=6000, help="NN_cons training samples (6000; NN_loops: half)")
    p.add_argument("--epochs", type=int, default=5, help="NN_cons epochs over its samples (5; NN_loops: 3)")
    p.add_argument("--no-loops", action="store_true", help="adapt NN_cons only")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resume", action="store_true", help="continue a killed run in --out")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help="no progress bars; print the record (adapt.json) as one "
                                                        "JSON object")
    p.add_argument("--tensorboard", default=None, metavar="DIR",
                   help="also write TensorBoard scalars of the training runs into DIR/cons and DIR/loops (as "
                        "`deepslam train --tensorboard`); needs the tensorboard package; the adapted models are the "
                        "same bytes with or without it")


def run(args: argparse.Namespace) -> int:
    from deepslam.vo.adapt import AdaptConfig, adapt

    if not (0 < args.max_minutes <= 24 * 60) or not (128 <= args.samples <= 10_000_000) or not (1 <= args.epochs <= 1000):
        raise InputError(None, "--max-minutes must be in (0, 1440], --samples in [128, 1e7], --epochs in [1, 1000]")
    cfg = AdaptConfig(seed=args.seed, cons_samples=args.samples, cons_epochs=args.epochs,
                      loops_samples=max(128, args.samples // 2), loops_epochs=max(1, (args.epochs * 3) // 5),
                      max_minutes=args.max_minutes, loops=not args.no_loops, model=args.model, motion=args.motion)
    record = adapt(args.sequence, args.out, cfg, resume=args.resume, progress=not (args.quiet or args.json),
                   tensorboard=args.tensorboard)
    if args.json:
        print(json.dumps(record))
    else:
        print(f"adapted {record['kind']} models in {record['seconds']:.0f} s: "
              + ", ".join(f"{args.out}/{s['file']}" for s in record["stages"].values()))
    return 0
