"""``deepslam vo``: learned visual odometry on a sequence (KITTI, EuRoC or ours) -> trajectory file.

Writes, beside ``--out``: ``<stem>.motions.csv`` (the relative motions with their predicted std),
``<stem>.config.json`` (the resolved settings) and, when the sequence has ground truth,
``<stem>.metrics.json`` and ``<stem>.png`` (top-down plot against the ground truth).

Outputs never clobber anything (:mod:`core.outputs`), checked before any work: ``--out`` and its side
files must not be an input (the sequence folder or a file inside it, the model file) nor each other
(``--out traj.png`` is its own plot); an existing side file is overwritten only when ``<stem>.config.json``
records it as written by an earlier ``deepslam vo`` with the same bytes (the config is the ownership
record: ``written_by`` and ``files`` with each side file's sha256); anything else there is refused,
named. One run writes a folder at a time: ``--out``'s folder is locked (:func:`core.lock.output_lock`)
for the run, and a second ``vo`` or ``slam`` into it exits 2 naming the first.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from deepslam.commands import _dis_flags, _odometry_flags
from deepslam.core.errors import InputError
from deepslam.core.lock import output_lock

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "vo"
HELP = "learned visual odometry: flow between frames -> network -> chained trajectory (+ CSV of motions with std)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sequence", required=True, help="sequence folder: KITTI sequences/NN, EuRoC (holding mav0/), or ours")
    p.add_argument("--model", default=None,
                   help="model file (model.safetensors / checkpoint.safetensors), or a shipped one: kitti, euroc, kitti:loops, "
                        "euroc:loops (default: the shipped NN_cons for the sequence's camera kind, trained on --flow's flow "
                        "where such a model is shipped)")
    p.add_argument("--out", required=True, help="trajectory file to write")
    p.add_argument("--format", choices=("kitti", "tum"), default=None,
                   help="trajectory format of --out (default: the sequence's own: kitti for KITTI sequences, tum "
                        "(timestamped) otherwise)")
    p.add_argument("--flow", default="dis", help="flow estimator: dis (OpenCV DIS, default), learned (the network "
                   "`deepslam train-flow` trains on renders), learned-dis (that network's flow refined by DIS: the most "
                   "consistent on real KITTI, 2.5x DIS's time), gt (the sequence's ground-truth flow, our format), or a "
                   "plug-in MODULE:FACTORY")
    _dis_flags.add_arguments(p)
    p.add_argument("--pose", choices=("net", "epipolar"), default=None,
                   help="net: the network's 6DoF (the paper); epipolar: the rotation and the direction of travel from "
                        "the essential matrix of the full-resolution flow (OpenCV USAC), the distance from the network "
                        "(pairs without parallax keep the network's motion; see vo/geometry/epipolar.py). Default: the mode the "
                        "model file records (deepslam set-pose), net where it records none")
    p.add_argument("--scale", choices=("network", "road", "road-flow"), default=None,
                   help="with --pose epipolar, where the distance travelled comes from: network (the network's "
                        "translation), road (the road's motion in the flow and the camera's height above it, "
                        "--camera-height; where the flow loses the road, the road bands of the two images aligned "
                        "directly; short gaps between read pairs interpolated; other pairs keep the network's "
                        "distance) or road-flow (the road's motion in the flow only). "
                        "Default: the source the model file records (deepslam set-pose --scale), network where none")
    p.add_argument("--camera-height", type=float, default=1.65, metavar="M",
                   help="camera height above the road for --scale road, metres (default 1.65: KITTI and the "
                        "simulated street)")
    p.add_argument("--read-width", type=int, default=_odometry_flags.READ_WIDTH_PX, metavar="PX",
                   help=_odometry_flags.READ_WIDTH_HELP)
    p.add_argument("--centre-principal-point", action="store_true", help=_odometry_flags.CENTRE_HELP)
    _odometry_flags.add_mirror_average(p)
    p.add_argument("--std-from-geometry", action="store_true", help=_odometry_flags.GEOMETRY_STD_HELP)
    p.add_argument("--stride", type=int, default=1, help="frame gap k: predict cam_{t+k}_from_cam_t for t = 0, k, 2k, ...")
    p.add_argument("--start", type=int, default=0, help="first frame")
    p.add_argument("--end", type=int, default=None, help="one past the last frame (default: all)")
    p.add_argument("--batch", type=int, default=64, help="flows per forward pass")
    p.add_argument("--device", default="auto", help="auto (CUDA when torch sees one, else the CPU), cpu, cuda or cuda:N")
    p.add_argument("--bf16", choices=("auto", "on", "off"), default="auto",
                   help="bfloat16 inference (auto: when the CPU computes bf16 natively)")
    p.add_argument("--odometry", default=None, metavar="MODULE:FACTORY|NAME",
                   help="a plug-in odometry instead of the network: a factory returning an object with name and "
                        "predict(seq, pairs) -> (mean6, std6), or a name registered under the entry-point group "
                        "deepslam.odometry (see the README)")
    p.add_argument("--odometry-command", default=None, metavar="'CMD {sequence} {out}'",
                   help="an external program that reads the sequence folder and writes a KITTI or TUM trajectory "
                        "to {out}; its poses become the relative motions")
    p.add_argument("--command-timeout", type=float, default=3600.0, metavar="S",
                   help="seconds the --odometry-command may run on the sequence (3600); it runs without a shell: "
                        "the template is split into arguments once and {sequence}/{out} replaced inside them "
                        "({{ and }} for literal braces)")
    p.add_argument("--json", action="store_true", help="print one JSON object: out, poses, format, model_name, and "
                   "metrics (ATE, RPE, drift: see deepslam eval --json) when the sequence has ground truth")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


COMMAND = "deepslam vo"
"""The ``written_by`` of the ownership record (``<stem>.config.json``)."""


def side_files(out) -> dict:
    """The files ``vo`` writes beside ``out``: {"motions", "config", "metrics", "plot"} -> path."""
    stem = Path(out).with_suffix("")
    return {"motions": Path(f"{stem}.motions.csv"), "config": Path(f"{stem}.config.json"),
            "metrics": Path(f"{stem}.metrics.json"), "plot": Path(f"{stem}.png")}


def check_outputs(args: argparse.Namespace) -> None:
    """InputError before any work when ``--out`` or a side file would clobber an input, another output
    or a file an earlier ``vo`` did not write (module docstring)."""
    from deepslam.core.outputs import check_run_outputs, same_path

    out = Path(args.out)
    if out.is_dir():
        raise InputError(out, "--out is a folder, expected a trajectory file name")
    side = side_files(out)
    inputs = [("--sequence", args.sequence)]
    if args.model is not None and Path(args.model).exists():
        inputs.append(("--model", args.model))
    check_run_outputs([("--out", out)] + [(f"--out's {k} file {p.name}", p) for k, p in side.items()], inputs,
                      side["config"], [side["motions"], side["metrics"], side["plot"]], COMMAND,
                      legacy_owner=lambda rec: "sequence_kind" in rec and same_path(rec.get("out"), out))


def run(args: argparse.Namespace) -> int:
    check_outputs(args)
    # one writer per output folder: a second vo/slam into it is refused, naming this one
    with output_lock(Path(args.out).parent, "--out"):
        check_outputs(args)  # again under the lock: another run may have written meanwhile
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from deepslam.core import atomic, trajio
    from deepslam.core.outputs import write_side_files
    from deepslam.core.readers import open_sequence_for_flow
    from deepslam.core.trajectory import Trajectory
    from deepslam.slam import plugins
    from deepslam.vo import report as report_io
    from deepslam.vo.pipeline import VOConfig, run_vo

    seq = open_sequence_for_flow(args.sequence)
    cfg = VOConfig(model=args.model, flow=args.flow, flow_options=_dis_flags.given_options(args.flow, args),
                   pose=args.pose, scale=args.scale, camera_height_m=args.camera_height, stride=args.stride,
                   start=args.start, end=args.end, batch=args.batch, device=args.device,
                   bf16=None if args.bf16 == "auto" else args.bf16 == "on", progress=not (args.quiet or args.json),
                   read_width_px=args.read_width, centre_principal_point=args.centre_principal_point,
                   mirror_average=args.mirror_average,
                   std_from_geometry=args.std_from_geometry)
    cfg.frames(len(seq))  # the range checked before a plug-in loads
    fmt = args.format or trajio.default_format(seq.kind, seq.timestamps_s is not None)
    plugin = plugins.from_options(args.odometry, args.odometry_command, args.command_timeout)
    res = run_vo(seq, cfg, plugin)
    frames, name = res.frames, res.name
    est = Trajectory(res.world_from_cam, seq.timestamps_s[frames])
    out = Path(args.out)
    side = side_files(out)
    stem = out.with_suffix("")
    motions_text = report_io.motions_csv(seq, res)
    writers = [(side["motions"], lambda p: atomic.write_text(p, motions_text))]
    config = {"sequence": str(Path(seq.root).resolve()), "sequence_kind": seq.kind,
              "frames": [int(frames[0]), int(frames[-1])], "stride": args.stride, "format": fmt, "out": str(out)}
    if plugin is not None:
        config.update(odometry=args.odometry, odometry_command=args.odometry_command)
    config.update(res.record)
    say = (lambda *a, **k: None) if args.json else print
    report = None
    if seq.gt is not None and len(frames) >= 3:
        from deepslam.core import plots

        report, gt, est_scored = report_io.score(seq, res)
        writers += [(side["metrics"], lambda p: atomic.write_json(p, report)),
                    (side["plot"], lambda p: plots.plot_trajectories_topdown(
                        p, {"ground truth": gt.positions, name: est_scored.positions},
                        title=report_io.plot_title(seq, name, config)))]
    trajio.write_trajectory(out, est, fmt)  # after the metrics, which can refuse: nothing half-written
    write_side_files(side["config"], config, COMMAND, writers)
    say(f"wrote {out} ({len(frames)} poses, {fmt}) and {stem}.motions.csv")
    if report is not None:
        say(report_io.summary_line(report, args.stride))
        say(f"wrote {stem}.metrics.json and {stem}.png")
    elif seq.gt is not None:
        say("not scored: the metrics align the trajectory to the ground truth, which needs at least 3 poses")
    if args.json:
        print(json.dumps({"out": str(out), "poses": int(len(frames)), "format": fmt, "model_name": name,
                          "metrics": report}))
    return 0
