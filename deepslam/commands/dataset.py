"""``deepslam dataset``: render many sequences from a config and a seed into one folder with a manifest."""
from __future__ import annotations

import argparse
import dataclasses
import json

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "dataset"
HELP = "render many sequences (scenes, seeds, movers from a config and a seed) with a manifest; local or Ray"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default=None, metavar="FILE",
                   help="JSON object with any field of sim.dataset.DatasetConfig (README: deepslam dataset); "
                        "the flags below override it")
    p.add_argument("--scenes", default=None, help="comma-separated scenes dealt round-robin: street,room (default both)")
    p.add_argument("--sequences", type=int, default=None, help="number of sequences (default 4)")
    p.add_argument("--frames", type=int, default=None, help="frames per sequence (default 100)")
    p.add_argument("--width", type=int, default=None, help="image width in pixels (default: the scene camera's)")
    p.add_argument("--height", type=int, default=None, help="image height in pixels (default: from the width)")
    p.add_argument("--seed", type=int, default=None, help="seed of the whole dataset (default 0)")
    p.add_argument("--format", default=None, help="layout of each sequence: ours, kitti, euroc or tum (default ours)")
    p.add_argument("--out", required=True, help="output folder (new or empty, or an interrupted run with --resume)")
    p.add_argument("--executor", "--backend", dest="backend", default="ray", choices=("local", "ray"),
                   help="where the sequences render: ray (default: a local Ray instance with --workers CPUs, or "
                        "--address) or local (this process). --backend is the older name")
    p.add_argument("--workers", type=int, default=2, help="Ray workers (default 2)")
    p.add_argument("--address", default=None, help="address of an existing Ray cluster (default: start one here)")
    p.add_argument("--resume", action="store_true", help="finish an interrupted run in --out (same config)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (out, sequences, frames, sha256) instead of a line")



def NEEDS(args: argparse.Namespace) -> tuple[str, ...]:
    """Optional modules this run needs (checked before any work by the command line): [sim], and [ray] for
    the ray executor."""
    return ("mujoco",) + (("ray",) if args.backend == "ray" else ())

def run(args: argparse.Namespace) -> int:
    from deepslam.core.textio import read_json_object
    from deepslam.sim.dataset import DatasetConfig, build

    from deepslam.core.outputs import check_output_not_input

    check_output_not_input(args.out, [("--config", args.config)])
    fields = read_json_object(args.config) if args.config else {}
    cfg = DatasetConfig.from_dict(fields, source=args.config)
    overrides = {k: getattr(args, k) for k in ("sequences", "frames", "width", "height", "seed", "format")
                 if getattr(args, k) is not None}
    if args.scenes is not None:
        overrides["scenes"] = tuple(s.strip() for s in args.scenes.split(",") if s.strip())
    cfg = dataclasses.replace(cfg, **overrides).validate()
    manifest = build(cfg, args.out, backend=args.backend, workers=args.workers, address=args.address,
                     resume=args.resume, progress=not (args.quiet or args.json))
    summary = {"out": str(args.out), "sequences": len(manifest["sequences"]), "frames": manifest["frames"],
               "sha256": manifest["sha256"]}
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"wrote {summary['sequences']} sequences ({summary['frames']} frames) to {summary['out']}; "
              f"sha256 {summary['sha256']}")
    return 0
