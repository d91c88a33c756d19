"""``deepslam validate-flow``: synthesized flow (frame t depth + ground-truth pose) vs. the simulator's true flow."""
from __future__ import annotations

import argparse
import json

from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "validate-flow"
HELP = ("compare flow synthesized from depth + ground-truth motion with a rendered sequence's true flow "
        "(static visible EPE target < 0.01 px; moving/deforming pixels reported separately)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sequence", required=True, metavar="DIR", help="rendered sequence (ours format with depth/, flow/, mask/)")
    p.add_argument("--start", type=int, default=None, metavar="A",
                   help="first frame compared (flow t -> t+1; default 0)")
    p.add_argument("--end", type=int, default=None, metavar="B",
                   help="compare frames before B (default: all that have flow, i.e. up to the last frame)")
    # the older spelling of --start A --end B (a frame range; --frames is a count in render, dataset, stress)
    p.add_argument("--frames", default=None, metavar="A:B", help=argparse.SUPPRESS)
    p.add_argument("--json", action="store_true", help="print the full report as one JSON object (no progress bar)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _frames(args: argparse.Namespace, n: int) -> range | None:
    """The frames t compared (flow t -> t+1) of an n-frame sequence: [--start, --end), or the older --frames A:B;
    None for all."""
    if args.frames is not None:
        if args.start is not None or args.end is not None:
            raise InputError(None, "give --start/--end or --frames A:B (the older spelling), not both")
        try:
            a, _, b = args.frames.partition(":")
            start = int(a) if a else 0
            stop = int(b) if b else n - 1
        except ValueError:
            raise InputError(None, f"--frames must be A:B, got {args.frames!r}") from None
        what = f"--frames {args.frames}"
    elif args.start is None and args.end is None:
        return None
    else:
        start = 0 if args.start is None else args.start
        stop = n - 1 if args.end is None else args.end
        what = f"--start {start} --end {stop}"
    if not 0 <= start < stop <= n - 1:
        raise InputError(None, f"{what} outside 0..{n - 1} (the last frame has no flow)")
    return range(start, stop)


def run(args: argparse.Namespace) -> int:
    from deepslam.core.readers import open_sequence_for_flow
    from deepslam.gen.validate import validate_sequence

    seq = open_sequence_for_flow(args.sequence)
    report = validate_sequence(seq, _frames(args, len(seq)), progress=False if (args.quiet or args.json) else None)
    if args.json:
        print(json.dumps(report))
    else:
        def line(name, s):
            if not s["pixels"]:
                return f"  {name:>16}: no pixels"
            return (f"  {name:>16}: {s['pixels']:>9} px  EPE mean {s['epe_mean_px']:.3g}  median {s['epe_median_px']:.3g}"
                    f"  p95 {s['epe_p95_px']:.3g}  max {s['epe_max_px']:.3g} px")
        print(f"{report['sequence']}: {report['frames_compared']} frame pairs")
        print(line("static visible", report["static_visible"]))
        print(line("static occluded", report["static_occluded"]))
        print(line("moving/deforming", report["moving"]))
        for k, s in report["per_instance"].items():
            print(line(f"instance {k}", s))
        z = report["zbuffer_vs_next_depth"]
        if z["agreement"] is not None:
            print(f"  z-buffer vs next-frame depth visibility agreement on static pixels: {z['agreement']:.4f}")
        print(f"  target: static visible mean EPE < {report['target_epe_px']} px: {'met' if report['met'] else 'NOT met'}")
    return 0 if report["met"] else 1
