"""``deepslam ensemble-model A B [C ...] --out E``: join seeds of one recipe into one model file."""
from __future__ import annotations

import argparse

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "ensemble-model"
HELP = ("join two or more VO model files of one input shape (seeds of one recipe) into one ensemble file: "
        "it predicts the members' mean and, as uncertainty, their own spread plus their disagreement "
        "(vo.ensemble); every --model option takes it")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("models", nargs="+", help="model.safetensors files (single networks, same input size)")
    p.add_argument("--out", required=True, help="ensemble model file to write")


def run(args: argparse.Namespace) -> int:
    from deepslam.core.outputs import check_output_not_input
    from deepslam.vo.modelfiles.modelio import write_ensemble

    check_output_not_input(args.out, [("model", m) for m in args.models])
    meta = write_ensemble(args.models, args.out)
    seeds = ", ".join(str(m["seed"]) for m in meta["ensemble_of"])
    print(f"wrote {args.out} ({len(meta['ensemble_of'])} members, seeds {seeds})")
    return 0
