"""``deepslam eval``: score an estimated trajectory against ground truth (ATE, RPE, KITTI t_err/r_err).

Alignment (``--align``, default ``se3``, as evo's ``-a``): ATE is the RMSE of the position error after
a least-squares rigid (se3) or similarity (sim3, for monocular scale) alignment of the estimate onto
the ground truth, or none. The KITTI figures follow the devkit, which aligns nothing: they compare
relative motions over 100..800 m segments, which a rigid alignment does not change, so with ``none``
or ``se3`` they equal the official numbers; with ``sim3`` they are computed after the scale fix.

Several ``--est`` are scored against the same ground truth, each on its own (its own association and
alignment): one table row each, or with ``--json`` a list of the objects one ``--est`` prints.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from deepslam.core import metrics_report
from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "eval"
HELP = "score an estimated trajectory against ground truth: ATE, RPE, KITTI t_err/r_err"

_FORMATS = ("kitti", "tum", "euroc")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = (HELP + ". Formats are detected from the content (KITTI: 12 columns; TUM: t x y z qx qy qz "
                     "qw; EuRoC: ASL csv with ns timestamps); trajectories with timestamps on both sides are "
                     "associated by time, otherwise matched by index. Default alignment se3 (evo's -a); the KITTI "
                     "t_err/r_err (shown when the ground truth is longer than 100 m) use relative segments as "
                     "the devkit does, so se3 alignment leaves them equal to the official figures.")
    p.add_argument("--gt", required=True, metavar="FILE", help="ground-truth trajectory (.xz/.gz accepted)")
    p.add_argument("--est", required=True, action="append", metavar="FILE",
                   help="estimated trajectory; repeat it to score several (one table row each; --json: a list)")
    p.add_argument("--format", choices=_FORMATS, default=None, help="format of both files (default: detect)")
    p.add_argument("--gt-format", choices=_FORMATS, default=None, help="format of --gt (overrides --format)")
    p.add_argument("--est-format", choices=_FORMATS, default=None, help="format of --est (overrides --format)")
    p.add_argument("--align", choices=("none", "se3", "sim3"), default="se3",
                   help="alignment of the estimate before ATE/RPE (default: se3)")
    p.add_argument("--rpe-delta", type=int, default=1, metavar="N", help="RPE frame delta (default: 1)")
    p.add_argument("--max-diff", type=float, default=0.01, metavar="S",
                   help="largest timestamp difference for association, seconds (default: 0.01)")
    p.add_argument("--json", action="store_true",
                   help="print the figures as JSON instead of a table: one object, or a list of them for several --est")
    p.add_argument("--plot", default=None, metavar="PNG", help="write a top-down plot of the ground truth and the estimates")


def run(args: argparse.Namespace) -> int:
    from deepslam.core import metrics, plots
    from deepslam.core.outputs import check_output_not_input
    from deepslam.core.trajio import read_trajectory_and_format

    if not (args.max_diff > 0 and math.isfinite(args.max_diff)):
        raise InputError(None, f"--max-diff must be a positive number of seconds, got {args.max_diff}")
    if args.rpe_delta < 1:
        raise InputError(None, f"--rpe-delta must be at least 1 frame, got {args.rpe_delta}")
    gt_path = Path(args.gt)
    est_paths = [Path(e) for e in args.est]
    inputs = [("--gt", gt_path)] + [("--est", e) for e in est_paths]
    check_output_not_input(args.plot, inputs, "--plot")  # never onto an input
    gt, gt_fmt = read_trajectory_and_format(gt_path, args.gt_format or args.format)
    results = []
    for est_path in est_paths:
        est, est_fmt = read_trajectory_and_format(est_path, args.est_format or args.format)
        res = metrics.evaluate(gt, est, align=args.align, rpe_delta=args.rpe_delta, max_diff_s=args.max_diff,
                               gt_path=gt_path, est_path=est_path)
        res.update({"gt": str(gt_path), "est": str(est_path), "gt_format": gt_fmt, "est_format": est_fmt})
        results.append(res)

    if args.plot:
        curves, title = metrics_report.plot_curves(gt, gt_path, est_paths, results, args.align)
        try:
            plots.plot_trajectories_topdown(args.plot, curves, title=title)
        except OSError as err:
            raise InputError(args.plot, f"cannot write the plot ({err.strerror or err})") from None
        for res in results:
            res["plot"] = str(args.plot)

    public = [{k: _clean(v) for k, v in res.items() if not k.startswith("_")} for res in results]
    if args.json:
        sys.stdout.write(json.dumps(public[0] if len(public) == 1 else public, sort_keys=True) + "\n")
    elif len(public) == 1:
        sys.stdout.write(metrics_report.format_table(public[0]))
    else:
        sys.stdout.write(metrics_report.format_rows(public))
    return 0




def _clean(v):
    """JSON-safe: NaN/inf -> None, recursively."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_clean(x) for x in v]
    return v
