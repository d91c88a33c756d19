"""``deepslam tune-slam``: search C_s, C_r and T_loop on validation sequences, ranked by ATE.

The odometry, features and loop verifications of each sequence are computed once; every parameter
set then costs one pose-graph solve per sequence (plus one loop search per distinct T_loop). The best
parameters go to ``--out`` as JSON (with the whole search table), which ``deepslam slam --params``
reads.
"""
from __future__ import annotations

import argparse
import json
import sys

from deepslam.commands import _odometry_flags
from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "tune-slam"
HELP = "search the SLAM hyperparameters C_s, C_r, T_loop on validation sequences (ranked by ATE)"
# slam.tune.SearchSpace's defaults (kept literal so that building the parser imports nothing heavy;
# tests/slam/test_cli_slam.py checks they agree)
DEFAULT_C_S = "0.1,0.3,1,3,10,30"
DEFAULT_C_R = "0.1,1,10,100"
DEFAULT_T_LOOP = "20,50,100,200"


def _floats(text: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not vals or min(vals) <= 0:
        raise argparse.ArgumentTypeError(f"expected positive numbers, got {text!r}")
    return vals


def _ints(text: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not vals or min(vals) < 1:
        raise argparse.ArgumentTypeError(f"expected integers >= 1, got {text!r}")
    return vals


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sequence", required=True, nargs="+", metavar="DIR", help="validation sequences with ground truth")
    p.add_argument("--model-cons", default=None, metavar="M", help="NN_cons model (default: shipped)")
    p.add_argument("--model-loops", default=None, metavar="M", help="NN_loops model (default: shipped)")
    p.add_argument("--out", required=True, metavar="JSON", help="parameter file to write")
    p.add_argument("--method", choices=("grid", "coordinate"), default="grid", help="search method (default: grid)")
    p.add_argument("--score", choices=("ate", "ate_ratio"), default="ate",
                   help="mean ATE over sequences, or mean ATE / VO ATE (default: ate)")
    p.add_argument("--c-s", type=_floats, default=None, metavar="LIST",
                   help=f"C_s values (default: {DEFAULT_C_S})")
    p.add_argument("--c-r", type=_floats, default=None, metavar="LIST",
                   help=f"C_r values (default: {DEFAULT_C_R})")
    p.add_argument("--t-loop", type=_ints, default=None, metavar="LIST",
                   help=f"T_loop values, frames (default: {DEFAULT_T_LOOP})")
    p.add_argument("--flow", default="dis", help="optical flow estimator for the models (default: dis; as deepslam slam)")
    p.add_argument("--pose", choices=("net", "epipolar"), default=None,
                   help="consecutive-frame motions as deepslam slam --pose (tune with the mode slam will run): net or "
                        "epipolar; default: the mode the NN_cons file records")
    p.add_argument("--keyframe-stride", type=int, default=3, metavar="K", help=_odometry_flags.KEYFRAME_STRIDE_HELP)
    p.add_argument("--robust", choices=("none", "huber", "cauchy"), default="cauchy", help="robust kernel on loops")
    p.add_argument("--no-loop-check", action="store_true",
                   help="keep loop pairs whose flow fits no rigid motion (as deepslam slam --no-loop-check)")
    p.add_argument("--vocabulary", default=None, metavar="NPZ", help="BoW vocabulary (default: train per sequence)")
    p.add_argument("--json", action="store_true", help="print one JSON object: c_s, c_r, t_loop, score, best_score, "
                   "evaluations, method, vo_ate_m (per sequence), out (no progress bar)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _odometry_flags.add_arguments(p)


def run(args: argparse.Namespace) -> int:
    from deepslam.core.readers import open_sequence_for_flow
    from deepslam.slam.plugins import network_view, odometries
    from deepslam.slam.pipeline import PipelineConfig, prepare
    from deepslam.slam.posegraph import PoseGraphConfig
    from deepslam.slam.reloc import Vocabulary
    from deepslam.slam.tune import SearchSpace, problem_from_prepared, tune

    if args.keyframe_stride < 1:
        raise InputError(None, f"--keyframe-stride must be at least 1, got {args.keyframe_stride}")
    from deepslam.core.outputs import check_output_not_input

    check_output_not_input(args.out, [("--sequence", s) for s in args.sequence] + [
        ("--model-cons", args.model_cons), ("--model-loops", args.model_loops), ("--vocabulary", args.vocabulary)])
    args.no_loops = False
    space = SearchSpace(c_s=args.c_s or _floats(DEFAULT_C_S), c_r=args.c_r or _floats(DEFAULT_C_R),
                        t_loop=args.t_loop or _ints(DEFAULT_T_LOOP))
    vocab = Vocabulary.load(args.vocabulary) if args.vocabulary else None
    graph = PoseGraphConfig(robust=args.robust)
    config = PipelineConfig(graph=graph, keyframe_stride=args.keyframe_stride, loop_check=not args.no_loop_check,
                            seed=args.seed)
    problems = []
    for path in args.sequence:
        seq = open_sequence_for_flow(path)
        if seq.gt is None:
            raise InputError(path, "a validation sequence needs ground truth")
        opts = _odometry_flags.options(args)
        seq = network_view(opts, seq)  # frames narrower than --read-width read upsampled
        odo_cons, odo_loops = odometries(opts, seq)
        prep = prepare(seq, odo_cons, odo_loops, config, vocab)
        problems.append(problem_from_prepared(prep, graph, name=str(path)))
    res = tune(problems, space, args.method, args.score, show_progress=not (args.json or args.quiet))
    extra = {"tuned_on": [str(s) for s in args.sequence], "vo_ate_m": {p.name: p.vo_ate_m for p in problems},
             "robust": args.robust, "keyframe_stride": args.keyframe_stride, **res.to_dict()}
    res.best.save(args.out, extra)
    if getattr(args, "json", False):
        print(json.dumps({"c_s": res.best.c_s, "c_r": res.best.c_r, "t_loop": res.best.t_loop, "score": res.score,
                          "best_score": res.best_score, "evaluations": res.evaluations, "method": res.method,
                          "vo_ate_m": extra["vo_ate_m"], "out": str(args.out)}))
        return 0
    rows = sorted(res.rows, key=lambda r: r["score"])
    out = [f"{'C_s':>8}{'C_r':>8}{'T_loop':>8}{'score':>12}"]
    for r in rows[:10]:
        out.append(f"{r['c_s']:>8g}{r['c_r']:>8g}{r['t_loop']:>8d}{r['score']:>12.4f}")
    out.append(f"best: C_s {res.best.c_s:g}, C_r {res.best.c_r:g}, T_loop {res.best.t_loop} "
               f"({res.score} {res.best_score:.4f}; VO ATE "
               + ", ".join(f"{p.vo_ate_m:.4f}" for p in problems)
               + f" m) after {res.evaluations} solves by {res.method} search; wrote {args.out}")
    sys.stdout.write("\n".join(out) + "\n")
    return 0
