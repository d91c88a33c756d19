"""``deepslam set-solve MODEL --robust cauchy --iterations 6 --out OUT``: change a solve-head model's solve."""
from __future__ import annotations

import argparse

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "set-solve"
HELP = ("write a solve-head VO model (train --pose-head solve) with another kernel or number of Gauss-Newton "
        "steps: same learned weights, a test-time change of the solve, recorded in the file's meta")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="model.safetensors with the solve pose head")
    p.add_argument("--robust", required=True, choices=("none", "cauchy"),
                   help="none: weighted least squares; cauchy: reweighted from the second step on")
    p.add_argument("--iterations", type=int, help="Gauss-Newton steps (default: the file's)")
    p.add_argument("--out", required=True, help="model file to write (may be MODEL itself)")


def run(args: argparse.Namespace) -> int:
    from deepslam.vo.modelfiles.modelio import write_with_solve_kernel

    now = write_with_solve_kernel(args.model, args.out, args.robust, args.iterations)["solve_changed"]
    print(f"wrote {args.out}: solve {now['now']['robust']}, {now['now']['iterations']} steps "
          f"(trained with {now['trained_with']['robust']}, {now['trained_with']['iterations']} steps)")
    return 0
