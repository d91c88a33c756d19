"""``deepslam fit-motion``: fit the paper's Student-t motion model to ground-truth trajectories."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "fit-motion"
HELP = ("fit the motion model (a Student-t per DoF, or a joint KDE) to the relative motions of ground-truth "
        "camera trajectories (motion.json)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--poses", nargs="+", required=True, metavar="FILE",
                   help="camera trajectory files (KITTI poses, TUM; world_from_cam), e.g. kitti/poses/00.txt ...")
    p.add_argument("--stride", type=int, default=1, help="frame stride k of cam_{i+k}_from_cam_i (default 1)")
    p.add_argument("--out", required=True, help="motion model JSON to write")
    p.add_argument("--loops", action="store_true", help="also fit the loop distribution (far-apart frames close in space)")
    p.add_argument("--loop-gap", type=int, default=100, help="loop pairs are more than this many frames apart (100)")
    p.add_argument("--loop-radius", type=float, default=5.0, help="... with centres closer than this, metres (5)")
    p.add_argument("--loop-max-angle", type=float, default=30.0, help="... and rotated less than this, degrees (30)")
    p.add_argument("--loop-fit", choices=("truncated", "plain"), default="truncated",
                   help="loop distribution's Student-t: refined for the truncation to the data's range (default), "
                        "or scipy's plain fit (narrower samples; what models/motion/kitti_s1.json's loops used)")
    # the literal, not gen.motion.CONSECUTIVE_KINDS: importing gen.motion here costs every command 0.5 s of start-up
    p.add_argument("--consecutive", choices=("student-t", "kde"), default="student-t",
                   help="consecutive motions: an independent Student-t per DoF (the paper's; default) or a joint "
                        "kernel density estimate of the motions themselves (keeps a turning car's sideways slide "
                        "and the real speed distribution; the loop distribution stays Student-t)")
    p.add_argument("--speed-scale", default=None, metavar="LO,HI",
                   help="with --consecutive kde: multiply each drawn motion's translation by a factor drawn "
                        "log-uniform in [LO, HI], its rotation kept: the same turn at another radius and speed "
                        "(frees the turn radius from the one the routes were driven at), e.g. 0.4,1.5")
    p.add_argument("--speed-scale-lever", type=float, default=0.0, metavar="M",
                   help="with --speed-scale: the routes' camera sits M metres ahead of the rear axle (render "
                        "--camera-ahead; KITTI's 0.84): the factor scales the axle's motion and keeps the camera's "
                        "sideways slide into a turn, which does not grow with the speed (default 0: the whole "
                        "translation is scaled)")
    p.add_argument("--mirror", action="store_true",
                   help="fit the consecutive motions together with their left-right mirror images (yaw, roll and "
                        "sideways motion negated): turns both ways as often, for routes that turn one way")
    p.add_argument("--body-from", nargs="+", default=None, metavar="FILE",
                   help="with --consecutive kde: camera trajectory files (as --poses) whose frame-to-frame pitch and "
                        "roll at the same stride are added to each drawn motion, drawn independently: the car body's "
                        "pitch and roll on its suspension, which the simulator's car lacks (e.g. "
                        "kitti/poses/00.txt ... 05.txt 08.txt ... 10.txt)")
    p.add_argument("--plot", default=None, metavar="PNG", help="write the paper's Figure 3 (histograms + fitted densities)")
    p.add_argument("--json", action="store_true", help="print a JSON summary instead of a table")


def run(args: argparse.Namespace) -> int:
    from deepslam.core.trajio import read_trajectory
    from deepslam.gen import motion

    if args.stride < 1:
        raise InputError(None, f"--stride must be >= 1, got {args.stride}")
    speed_scale = None
    if args.speed_scale is not None:
        if args.consecutive != "kde":
            raise InputError(None, "--speed-scale needs --consecutive kde")
        try:
            values = [float(x) for x in args.speed_scale.split(",")]
        except ValueError:
            raise InputError(None, f"--speed-scale must be LO,HI (two numbers), got {args.speed_scale!r}") from None
        lo_lim, hi_lim = motion.SPEED_SCALE_LIMITS
        speed_scale = motion.check_speed_scale(values, lambda _: InputError(
            None, f"--speed-scale must be LO,HI with {lo_lim:g} <= LO <= HI <= {hi_lim:g}, got {args.speed_scale!r}"))
    lever_m = motion.check_lever(args.speed_scale_lever, speed_scale, lambda m: InputError(None, m),
                                 ("--speed-scale-lever", "--speed-scale"))
    from deepslam.core.outputs import check_distinct_outputs, check_output_not_input

    if args.body_from and args.consecutive != "kde":
        raise InputError(None, "--body-from needs --consecutive kde")
    inputs = [("--poses", p) for p in args.poses] + [("--body-from", p) for p in args.body_from or ()]
    check_output_not_input(args.out, inputs, "--out")  # outputs never overwrite an input (core.outputs)
    check_output_not_input(args.plot, inputs, "--plot")
    check_distinct_outputs([("--out", args.out), ("--plot", args.plot)])
    trajectories = [read_trajectory(p) for p in args.poses]
    body = [read_trajectory(p) for p in args.body_from or ()]
    loop_cfg = motion.LoopConfig(min_gap_frames=args.loop_gap, max_distance_m=args.loop_radius,
                                 max_angle_deg=args.loop_max_angle)
    try:
        model, vec, loop_vec = motion.fit_motion(trajectories, args.stride, args.loops, loop_cfg,
                                                 sources=[Path(p).name for p in args.poses], loop_fit=args.loop_fit,
                                                 consecutive_kind=args.consecutive, speed_scale=speed_scale,
                                                 lever_m=lever_m,
                                                 mirror=args.mirror, body=body,
                                                 body_sources=[Path(p).name for p in args.body_from or ()])
    except ValueError as e:
        raise InputError(None, str(e)) from None
    model.save(args.out)
    ks = motion.ks_statistics(model.consecutive, vec)
    summary = {"out": args.out, "stride": args.stride, "num_motions": len(vec), "consecutive_kind": args.consecutive,
               "consecutive": {n: {**_d(model.consecutive, i), "ks": float(k)}
                               for i, (n, k) in enumerate(zip(motion.DOF_NAMES, ks))}}
    if model.loop is not None:
        ks_loop = motion.ks_statistics(model.loop, loop_vec)
        summary["num_loop_motions"] = len(loop_vec)
        summary["loop"] = {n: {**_d(model.loop, i), "ks": float(k)} for i, (n, k) in enumerate(zip(motion.DOF_NAMES, ks_loop))}
    if args.plot:
        motion.plot_motion_fit(args.plot, vec, model.consecutive,
                               title=f"Relative motions at stride {args.stride} ({', '.join(model.sources)})",
                               loop_data=loop_vec, loop_model=model.loop)
        summary["plot"] = args.plot
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"fitted {len(vec)} motions at stride {args.stride} -> {args.out}")
        for part in ("consecutive", "loop"):
            if part not in summary:
                continue
            print(f"  {part}:")
            for name, d in summary[part].items():
                fit = (f"bandwidth={d['bandwidth']:.3g}" if "bandwidth" in d
                       else f"df={d['df']:.3g} loc={d['loc']:+.3g} scale={d['scale']:.3g}")
                print(f"    {name:>8}: {fit} KS={d['ks']:.3f}")
    return 0


def _d(six, k: int) -> dict:
    """Summary of DoF ``k`` of a Student-t (df, loc, scale) or KDE (bandwidth) distribution."""
    from deepslam.gen.motion import KdeSix

    if isinstance(six, KdeSix):
        return {"bandwidth": float(six.bandwidth[k])}
    d = six.dofs[k]
    return {"df": d.df, "loc": d.loc, "scale": d.scale}
