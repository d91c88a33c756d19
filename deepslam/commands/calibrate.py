"""``deepslam calibrate MODEL --sequence VAL --out OUT``: fit a VO model's predicted std to a validation sequence.

Runs ``deepslam vo``'s pipeline with MODEL on VAL (a sequence with ground truth, of the data the model is to
run on: KITTI 06 for KITTI, a rendered street for the simulated ones), fits one factor per DoF so that 68 % of
VAL's errors fall within the scaled 1-sigma (:mod:`vo.calibration`), and writes MODEL's copy OUT with the factor
recorded (meta ``std_scale``): ``vo`` and ``slam`` then predict the scaled std, and the pose graph weighs the
motions by it. Score it on another sequence of the same data; VAL's own share is 0.68 by construction.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from deepslam.commands import _dis_flags, _odometry_flags
from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "calibrate"
HELP = ("fit a VO model's predicted std to a validation sequence with ground truth (one factor per DoF) and write "
        "the model with it recorded")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="VO model file, or a shipped name (kitti, euroc, ...)")
    p.add_argument("--sequence", required=True, metavar="DIR", help="validation sequence with ground truth")
    p.add_argument("--out", required=True, help="model file to write (never MODEL itself)")
    p.add_argument("--flow", default="dis", help="flow estimator (as deepslam vo; default dis)")
    _dis_flags.add_arguments(p)
    p.add_argument("--pose", choices=("net", "epipolar"), default=None,
                   help="pose mode (default: the file's): the std is calibrated for the motions of that mode")
    p.add_argument("--read-width", type=int, default=_odometry_flags.READ_WIDTH_PX, metavar="PX",
                   help=_odometry_flags.READ_WIDTH_HELP)
    p.add_argument("--centre-principal-point", action="store_true", help=_odometry_flags.CENTRE_HELP)
    _odometry_flags.add_mirror_average(p)
    p.add_argument("--json", action="store_true",
                   help="print one JSON object: std_scale, within_1_sigma before (no progress bar)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from deepslam.core.outputs import check_output_not_input
    from deepslam.core.readers import open_sequence_for_flow
    from deepslam.vo import calibration
    from deepslam.vo.modelfiles import models, modeltree
    from deepslam.vo.pipeline import VOConfig, run_vo

    seq = open_sequence_for_flow(args.sequence)
    if seq.gt is None or getattr(seq, "gt_frames", None) is not None:
        raise InputError(args.sequence, "calibration needs a ground-truth pose for every frame")
    model_path, _ = models.locate(args.model, seq, "cons", args.flow)
    check_output_not_input(args.out, [("MODEL", model_path), ("--sequence", args.sequence)])
    res = run_vo(seq, VOConfig(model=args.model, flow=args.flow, flow_options=_dis_flags.given_options(args.flow, args),
                               pose=args.pose, read_width_px=args.read_width,
                               centre_principal_point=args.centre_principal_point, mirror_average=args.mirror_average,
                               progress=not (args.json or args.quiet)))
    err6 = calibration.pair_errors(seq.gt.world_from_cam, res.pairs, res.mean6)
    try:
        scale = calibration.std_scale(err6, res.std6)
    except ValueError as e:
        raise InputError(args.sequence, str(e)) from None
    before = calibration.within_one_sigma(err6, res.std6)
    recorded = models.recorded_std_scale(modeltree.meta(modeltree.read_header_tree(model_path)))
    total = scale * recorded  # the std it predicted already carried the file's own factor
    models.write_with_meta(model_path, args.out, {"std_scale": [float(x) for x in total],
                                                  "std_calibrated_on": str(Path(args.sequence).resolve())})
    if args.json:
        print(json.dumps({"out": str(args.out), "std_scale": total.tolist(), "within_1_sigma_before": before.tolist()}))
        return 0
    print(f"within 1-sigma on {seq.name} before: {', '.join(f'{x:.2f}' for x in before)} (euler x, y, z, t x, y, z)")
    print(f"std scaled by {', '.join(f'{x:.3g}' for x in total)}: 0.68 on {seq.name} by construction; score it on "
          "another sequence")
    print(f"wrote {args.out}")
    return 0
