"""``deepslam convert-model OLD [--out NEW]``: turn an old pickle-based model file into the safe format."""
from __future__ import annotations

import argparse
from pathlib import Path

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "convert-model"
HELP = ("convert an old pickle-based VO model or checkpoint (.pt) into a safetensors file that cannot carry "
        "code; read with torch's restricted unpickler, so only do it for a file you trust")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="old model.pt / checkpoint.pt (torch.save)")
    p.add_argument("--out", help="new file (default: the same name with .safetensors)")


def run(args: argparse.Namespace) -> int:
    from deepslam.vo.modelfiles.convert import convert_legacy

    src = Path(args.model)
    dst = Path(args.out) if args.out else src.with_suffix(".safetensors")
    from deepslam.core.outputs import check_output_not_input

    check_output_not_input(dst, [("MODEL", src)], "--out" if args.out else "the default --out (MODEL.safetensors)")
    kind = convert_legacy(src, dst)
    print(f"wrote {dst} ({kind})")
    return 0
