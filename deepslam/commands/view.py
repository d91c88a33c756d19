"""``deepslam view``: a sequence (RGB, depth, flow, masks, camera and path) or a vo/slam run (estimate vs ground
truth, loop edges) in the rerun 3-D viewer, or written to a .rrd recording (:mod:`deepslam.view`)."""
from __future__ import annotations

import argparse

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "view"
HELP = "look at a sequence or a vo/slam run in the rerun 3-D viewer, or save a .rrd recording (--save)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("path", metavar="PATH",
                   help="a sequence folder (ours, KITTI sequences/NN, EuRoC, TUM RGB-D), or a vo/slam run: its "
                        "trajectory file (with the record the run wrote beside it), its record, or a folder holding "
                        "one run")
    p.add_argument("--save", default=None, metavar="FILE.rrd",
                   help="write a rerun recording instead of opening the viewer (for machines without a display; "
                        "open it later with `rerun FILE.rrd`)")
    p.add_argument("--start", type=int, default=0, help="first frame logged (default 0)")
    p.add_argument("--end", type=int, default=None, help="one past the last frame logged (default: all)")
    p.add_argument("--every", type=int, default=1, metavar="K", help="log every K-th frame (default 1)")
    p.add_argument("--align", choices=("none", "se3", "sim3"), default="se3",
                   help="a run's estimate aligned onto the ground truth as deepslam eval --align (default se3)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from deepslam.view import ViewConfig, view

    res = view(args.path, save=args.save,
               config=ViewConfig(start=args.start, end=args.end, every=args.every, align=args.align),
               show_progress=not args.quiet)
    for note in res.notes:
        print(f"note: {note}")
    what = "sequence" if res.kind == "sequence" else f"{res.kind} run"
    if res.saved is not None:
        print(f"wrote {res.saved} ({what} {res.name}, {res.frames_logged} frames); open it with: rerun {res.saved}")
    else:
        print(f"sent {what} {res.name} ({res.frames_logged} frames) to the rerun viewer")
    return 0
