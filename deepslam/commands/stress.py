"""``deepslam stress``: where the rigid-scene assumption breaks (moving objects, their size, deformation).

Sweeps the number and size of moving objects and the flags' deformation amplitude in simulation; for
every setting renders a short sequence and measures the synthesized-vs-true flow error on dynamic and
static pixels, the VO error (learned odometry on ground-truth and on DIS flow) and the SLAM error, and
those of any plug-in odometry (``--odometry``) or external program (``--odometry-command``) beside them.
Writes ``stress.md`` (table + conclusion), ``report.html`` (the same page with the plots), ``stress.json``,
``config.json`` and four PNG plots of the errors against the fraction of dynamic pixels into ``--out``.
See :mod:`deepslam.studies.stress`.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from deepslam.commands import _odometry_flags
from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "stress"
HELP = ("stress study: sweep moving objects (count, size) and deformation in simulation; flow, VO and SLAM "
        "errors against the fraction of dynamic pixels")

QUICK = {"frames": 100, "objects": (0, 8), "object_sizes": (2.0,), "deform_amplitudes_m": (0.3,), "combined": False}
"""What ``--quick`` changes (only where the option is not given)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="out/stress", metavar="DIR", help="output folder (default: out/stress)")
    p.add_argument("--scene", default="street", help="street (car, KITTI-like camera; default) or room (drone, EuRoC-like)")
    p.add_argument("--frames", type=int, default=None, metavar="N", help="frames per setting (default 300; --quick 100)")
    p.add_argument("--width", type=int, default=320, metavar="W", help="image width in pixels (default 320)")
    p.add_argument("--objects", default=None, metavar="LIST",
                   help="numbers of moving objects, comma-separated (default 0,2,8,32; --quick 0,8)")
    p.add_argument("--object-size", default=None, metavar="LIST",
                   help="scale factors of the moving objects, comma-separated (default 0.5,1,2; --quick 2)")
    p.add_argument("--size-objects", type=int, default=8, metavar="K",
                   help="number of moving objects in the size sweep (default 8)")
    p.add_argument("--deform", default=None, metavar="LIST",
                   help="flag deformation amplitudes in metres, comma-separated (default 0,0.15,0.3; --quick 0.3)")
    p.add_argument("--no-combined", dest="combined", action="store_false",
                   help="leave out the setting with the most of everything (largest count, size and amplitude)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="scene and trajectory seed (default 0)")
    p.add_argument("--backend", default="mujoco", help="renderer: mujoco (default) or pyrender")
    p.add_argument("--odometry", action="append", default=None, metavar="ODOMETRY",
                   help="model (learned NN_cons/NN_loops; falls back to rigid-fit, noted, when none is available) "
                        "or rigid-fit (least-squares rigid motion from flow + depth over all pixels); repeat to add "
                        "plug-ins measured side by side (MODULE:FACTORY or an entry-point name, e.g. pnp: SIFT + "
                        "PnP with depth), in one table and one plot")
    p.add_argument("--odometry-command", action="append", default=None, metavar="'CMD {sequence} {out}'",
                   help="an external program measured side by side like a plug-in (repeat for several): it reads "
                        "each rendered sequence folder and writes a KITTI or TUM trajectory to {out}; it runs without "
                        "a shell (the template is split into arguments once, {sequence}/{out} replaced inside them, "
                        "{{ and }} for literal braces)")
    p.add_argument("--command-timeout", type=float, default=3600.0, metavar="S",
                   help="seconds an --odometry-command may run on one rendered sequence (3600)")
    p.add_argument("--json", action="store_true", help="no progress; print one JSON object: {\"settings\": [one "
                   "entry per setting and odometry], \"conclusion\", \"odometry\", \"out\"}")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--model-cons", default=None, metavar="M", help="NN_cons model file or shipped name (default: shipped)")
    p.add_argument("--model-loops", default=None, metavar="M", help="NN_loops model file or shipped name (default: shipped)")
    p.add_argument("--dis-preset", default="medium", help="DIS optical flow preset: ultrafast, fast, medium (default)")
    p.add_argument("--read-width", type=int, default=_odometry_flags.READ_WIDTH_PX, metavar="PX",
                   help=_odometry_flags.READ_WIDTH_HELP)
    p.add_argument("--params", default=None, metavar="JSON", help="SLAM C_s, C_r, T_loop from `deepslam tune-slam`")
    p.add_argument("--no-loops", action="store_true", help="SLAM without loop closure")
    p.add_argument("--quick", action="store_true", help="a small sweep (about a minute): 100 frames, 4 settings")
    p.add_argument("--resume", action="store_true", help="reuse the per-setting results already in --out")
    p.add_argument("--device", default="auto", help="torch device of the learned odometry: auto (CUDA when torch "
                                                    "sees one, else the CPU), cpu, cuda or cuda:N")
    p.add_argument("--threads", type=int, default=1, metavar="N",
                   help="CPU threads for torch, OpenCV and OpenBLAS (default 1: fastest on a busy 2-core machine)")
    p.add_argument("--keep-sequences", action="store_true", help="keep the rendered sequences under DIR/sequences")



def NEEDS(args: argparse.Namespace) -> tuple[str, ...]:
    """Optional modules this run needs (checked before any work by the command line): the [sim] extra."""
    return ("mujoco",) + (("pyrender",) if args.backend == "pyrender" else ())

def parse_list(text: str, kind, what: str) -> tuple:
    """Comma-separated numbers -> tuple; InputError on an empty list or a bad number."""
    items = [t.strip() for t in str(text).split(",")]
    if not any(items):
        raise InputError(None, f"--{what}: the list is empty")
    out = []
    for t in items:
        if not t:
            raise InputError(None, f"--{what}: empty item in {text!r}")
        try:
            out.append(kind(t))
        except ValueError:
            raise InputError(None, f"--{what}: {t!r} is not {'an integer' if kind is int else 'a number'}") from None
    return tuple(out)


def config_from_args(args: argparse.Namespace):
    """The :class:`deepslam.studies.stress.StressConfig` of the command line (validated)."""
    from deepslam.studies.stress import StressConfig

    base = StressConfig()
    quick = QUICK if args.quick else {}
    given = list(args.odometry or [])
    main_odometry = given.pop(0) if given and given[0] in ("model", "rigid-fit") else "model"
    plugins = tuple(given)
    kw = {
        "scene": args.scene, "width": args.width, "seed": args.seed, "backend": args.backend,
        "odometry": main_odometry, "plugins": plugins, "commands": tuple(args.odometry_command or ()),
        "command_timeout_s": args.command_timeout, "model_cons": args.model_cons, "model_loops": args.model_loops,
        "dis_preset": args.dis_preset, "read_width_px": args.read_width, "slam_params": args.params,
        "loops": not args.no_loops,
        "keep_sequences": args.keep_sequences, "combined": args.combined and quick.get("combined", True), "threads": args.threads, "device": args.device,
        "size_objects": args.size_objects,
        "frames": args.frames if args.frames is not None else quick.get("frames", base.frames),
        "objects": (parse_list(args.objects, int, "objects") if args.objects is not None
                    else quick.get("objects", base.objects)),
        "object_sizes": (parse_list(args.object_size, float, "object-size") if args.object_size is not None
                         else quick.get("object_sizes", base.object_sizes)),
        "deform_amplitudes_m": (parse_list(args.deform, float, "deform") if args.deform is not None
                                else quick.get("deform_amplitudes_m", base.deform_amplitudes_m)),
    }
    return StressConfig(**kw).validate()


def run(args: argparse.Namespace) -> int:
    if "numpy" not in sys.modules and args.threads >= 1:
        # OpenBLAS reads its thread count once, when numpy loads: BoVW matching (float32 matrix products
        # of 400 x 400 descriptors) ran 6x faster with one thread than with two on a busy 2-core machine
        os.environ.setdefault("OPENBLAS_NUM_THREADS", str(args.threads))

    from deepslam.studies.stress import run_stress

    from deepslam.core.outputs import check_output_not_input

    check_output_not_input(args.out, [("--params", args.params), ("--model-cons", args.model_cons),
                                      ("--model-loops", args.model_loops)])
    config = config_from_args(args)
    t0 = time.perf_counter()
    report = run_stress(config, args.out, resume=args.resume, progress=False if args.json or args.quiet else None)
    out = Path(args.out)
    rows = report["rows"]
    if args.json:
        print(json.dumps({"settings": report["side_by_side"], "conclusion": report["conclusion"]["text"],
                          "odometry": report["odometry_description"], "out": str(out)}))
        return 0
    print(f"{len(rows)} settings in {time.perf_counter() - t0:.0f} s; odometry: {report['odometry_description']}")
    if report.get("odometry_note"):
        print(f"note: {report['odometry_note']}")
    print(f"{'setting':<16}{'dyn %':>7}{'EPE dyn px':>12}{'VO ATE gt':>11}{'VO ATE dis':>11}{'SLAM ATE gt':>12}"
          f"{'SLAM ATE dis':>13}")

    def num(v, f=".3g"):
        return "n/a" if v is None else format(v, f)
    for r in rows:
        print(f"{r['setting']:<16}{r['dynamic_pct']:>7.2f}{num(r['epe_dynamic_px']):>12}{num(r.get('vo_ate_gt_m')):>11}"
              f"{num(r.get('vo_ate_dis_m')):>11}{num(r.get('slam_ate_gt_m')):>12}{num(r.get('slam_ate_dis_m')):>13}")
    print(report["conclusion"]["text"])
    print(f"wrote {out / 'stress.md'}, {out / 'report.html'}, {out / 'stress.json'}, {out / 'config.json'} and "
          f"the plots {out}/stress_*.png")
    return 0
