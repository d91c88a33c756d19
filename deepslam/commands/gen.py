"""``deepslam gen``: synthetic (flow, 6DoF) training samples from single frames with depth, as tar shards."""
from __future__ import annotations

import argparse
import json
import re

from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "gen"
HELP = "write synthetic flow + 6DoF training samples (deterministic tar shards + manifest) from frames with depth"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source", required=True, metavar="DIR",
                   help="sequence folder with depth (ours, KITTI/EuRoC export with depth/), or a KITTI stereo "
                        "sequence with --depth-from-stereo")
    p.add_argument("--motion", required=True, metavar="JSON", help="motion model from `deepslam fit-motion`")
    p.add_argument("--samples", type=int, required=True, help="number of samples")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (shards, manifest.json)")
    p.add_argument("--resolution", default=None, metavar="HxW", help="output size, e.g. 96x320 (default: the source's)")
    p.add_argument("--seed", type=int, default=0, help="base seed: sample i depends on (seed, i) only (0)")
    p.add_argument("--workers", type=int, default=1, help="parallel shard builders (1)")
    p.add_argument("--executor", "--backend", dest="backend", choices=("local", "ray"), default="local",
                   help="where the shards are built: local (a process pool, default) or ray (Ray tasks; joins "
                        "RAY_ADDRESS, else a local instance). --backend is the older name")
    p.add_argument("--resume", action="store_true", help="finish an interrupted run in --out")
    p.add_argument("--shard-size", type=int, default=256, help="samples per shard (256)")
    p.add_argument("--depth-from-stereo", choices=("sgbm", "dis"), default=None,
                   help="compute depth from the stereo pair when the source has no depth files")
    p.add_argument("--loop-fraction", type=float, default=0.0,
                   help="share of motions drawn from the loop distribution (needs fit-motion --loops)")
    p.add_argument("--zbuffer", action="store_true", help="mark flow hidden by nearer points as invalid")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (out, samples, shards, bytes, resolution_hw) instead of a line")


MAX_SIDE = 4096
"""Largest output side, pixels (the simulator's too)."""
MAX_SAMPLES = 100_000_000
"""Most samples one run writes."""


def parse_resolution(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or not (2 <= int(m.group(1)) <= MAX_SIDE) or not (2 <= int(m.group(2)) <= MAX_SIDE):
        raise InputError(None, f"--resolution must be HxW with 2 <= H, W <= {MAX_SIDE} (e.g. 96x320), got {text!r}")
    return int(m.group(1)), int(m.group(2))


def run(args: argparse.Namespace) -> int:
    from deepslam.gen.motion import MotionModel
    from deepslam.gen.shards import GenConfig, generate

    if not 1 <= args.samples <= MAX_SAMPLES:
        raise InputError(None, f"--samples must be in 1..{MAX_SAMPLES}, got {args.samples}")
    if not 1 <= args.shard_size <= 1_000_000:
        raise InputError(None, f"--shard-size must be in 1..1000000, got {args.shard_size}")
    if not 1 <= args.workers <= 1024:
        raise InputError(None, f"--workers must be in 1..1024, got {args.workers}")
    if not 0.0 <= args.loop_fraction <= 1.0:
        raise InputError(None, f"--loop-fraction must be in [0, 1], got {args.loop_fraction}")
    resolution_hw = parse_resolution(args.resolution)
    from deepslam.core.outputs import check_output_not_input

    check_output_not_input(args.out, [("--source", args.source), ("--motion", args.motion)])
    motion = MotionModel.load(args.motion)
    if args.loop_fraction > 0 and motion.loop is None:
        raise InputError(args.motion, "--loop-fraction > 0 but the motion model has no loop distribution (fit-motion --loops)")
    config = GenConfig(source=str(args.source), motion=motion.to_dict(), num_samples=args.samples, seed=args.seed,
                       resolution_hw=resolution_hw, samples_per_shard=args.shard_size,
                       depth_from_stereo=args.depth_from_stereo, loop_fraction=args.loop_fraction,
                       zbuffer=args.zbuffer)
    manifest = generate(config, args.out, workers=args.workers, backend=args.backend, resume=args.resume,
                        progress=False if (args.quiet or args.json) else None)
    summary = {"out": args.out, "samples": manifest["num_samples"], "shards": manifest["num_shards"],
               "bytes": sum(s["bytes"] for s in manifest["shards"]),
               "resolution_hw": [manifest["camera"]["height"], manifest["camera"]["width"]]}
    if args.json:
        print(json.dumps(summary))
    else:
        h, w = summary["resolution_hw"]
        print(f"wrote {summary['samples']} samples at {h}x{w} in {summary['shards']} shards "
              f"({summary['bytes'] / 1e6:.1f} MB) to {summary['out']}")
    return 0
