"""``deepslam slam``: flow -> odometry -> relocalization -> pose graph on a KITTI, EuRoC or our sequence.

Writes the SLAM trajectory (``--out``), the odometry-only trajectory beside it (``<stem>_vo<suffix>``)
and a JSON record (``<stem>.json``: parameters, configuration, loops, timings and, with ground truth,
the metrics of both). Models: ``--model-cons`` / ``--model-loops`` take a model file or a shipped name
(``kitti``, ``euroc``, ``kitti:loops``); without them the shipped models for the sequence's camera
kind are used.

Outputs never clobber anything (:mod:`core.outputs`), checked before any work: ``--out``, ``--plot``,
``--save-vocabulary`` and the side files (``<stem>_vo<suffix>``, ``<stem>.json``) must not be an input
(the sequence folder or a file in it, a model file, ``--params``, ``--vocabulary``) nor each other
(``--out run.json`` would be its own record); the side files are overwritten only when ``<stem>.json``,
the ownership record, lists them as written by an earlier ``deepslam slam`` with the same bytes
(``written_by`` and ``files`` with each one's sha256); anything else there is refused, named. The output
folder is locked for the run (:func:`core.lock.output_lock`): a second ``slam`` or ``vo`` into it exits
2 naming the first.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from deepslam.commands import _dis_flags, _odometry_flags
from deepslam.core.errors import InputError
from deepslam.core.lock import output_lock

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "slam"
HELP = "run SLAM (learned odometry + BoVW loop closure + gtsam pose graph) on a sequence"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sequence", required=True, metavar="DIR", help="KITTI sequences/NN, EuRoC folder or ours")
    p.add_argument("--model-cons", default=None, metavar="M",
                   help="NN_cons model file or shipped name (default: the shipped model for the camera kind and, where one is shipped, trained on --flow's flow)")
    p.add_argument("--model-loops", default=None, metavar="M",
                   help="NN_loops model file or shipped name (default: the shipped loops model)")
    p.add_argument("--params", default=None, metavar="JSON", help="C_s, C_r, T_loop from `deepslam tune-slam`")
    p.add_argument("--out", required=True, metavar="FILE", help="trajectory to write")
    p.add_argument("--format", choices=("kitti", "tum", "euroc"), default=None,
                   help="trajectory format of --out and <stem>_vo (default: the sequence's own: kitti for KITTI "
                        "sequences, tum (timestamped) otherwise, as deepslam vo)")
    p.add_argument("--plot", default=None, metavar="PNG", help="top-down plot of VO, SLAM and ground truth")
    p.add_argument("--flow", default="dis", help="optical flow estimator for the models: dis (default), learned, learned-dis, gt or a "
                   "plug-in MODULE:FACTORY (as deepslam vo)")
    _dis_flags.add_arguments(p)  # NN_cons' and NN_loops' DIS, each flag given overriding both models' records
    p.add_argument("--pose", choices=("net", "epipolar"), default=None,
                   help="consecutive-frame motions: net (the network's 6DoF) or epipolar (rotation and direction of "
                        "travel from the essential matrix of the flow, distance from the network; as deepslam vo "
                        "--pose). Default: the mode the NN_cons file records, net where it records none. Loop pairs "
                        "always take the rotation and direction of their flow's fit where it serves, and NN_loops' "
                        "distance")
    p.add_argument("--vocabulary", default=None, metavar="NPZ",
                   help="BoW vocabulary (default: train one on the sequence's keyframes)")
    p.add_argument("--save-vocabulary", default=None, metavar="NPZ", help="write the vocabulary used")
    p.add_argument("--keyframe-stride", type=int, default=3, metavar="K", help=_odometry_flags.KEYFRAME_STRIDE_HELP)
    p.add_argument("--no-loops", action="store_true", help="odometry only (no loop closure)")
    p.add_argument("--no-loop-check", action="store_true",
                   help="keep loop pairs whose flow fits no rigid motion (by default they are left out)")
    p.add_argument("--robust", choices=("none", "huber", "cauchy"), default="cauchy",
                   help="robust kernel on loop edges (default: cauchy)")
    p.add_argument("--align", choices=("none", "se3", "sim3"), default="se3",
                   help="alignment before ATE/RPE (default: se3)")
    p.add_argument("--json", action="store_true", help="print the record as one JSON object (no progress bar)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _odometry_flags.add_arguments(p)


COMMAND = "deepslam slam"
"""The ``written_by`` of the ownership record (``<stem>.json``)."""


def side_files(out) -> dict:
    """The files ``slam`` writes beside ``out``: {"vo": the odometry-only trajectory, "record": the JSON record}."""
    out = Path(out)
    stem = out.with_suffix("")
    return {"vo": out.with_name(f"{stem.name}_vo{out.suffix}"), "record": out.with_name(f"{stem.name}.json")}


def check_outputs(args: argparse.Namespace) -> None:
    """InputError before any work when an output would clobber an input, another output or a file an
    earlier ``slam`` did not write (module docstring)."""
    from deepslam.core.outputs import check_run_outputs, same_path

    out = Path(args.out)
    if out.is_dir():
        raise InputError(out, "--out is a folder, expected a file name")
    side = side_files(out)
    inputs = [("--sequence", args.sequence), ("--params", args.params), ("--vocabulary", args.vocabulary)]
    inputs += [(flag, m) for flag, m in (("--model-cons", args.model_cons), ("--model-loops", args.model_loops))
               if m is not None and Path(m).exists()]
    outputs = [("--out", out), (f"--out's odometry trajectory {side['vo'].name}", side["vo"]),
               (f"--out's record {side['record'].name}", side["record"]), ("--plot", args.plot),
               ("--save-vocabulary", args.save_vocabulary)]
    check_run_outputs(outputs, inputs, side["record"], [side["vo"]], COMMAND,
                      legacy_owner=lambda rec: "trajectory_vo" in rec and same_path(rec.get("trajectory"), out))


def run(args: argparse.Namespace) -> int:
    check_outputs(args)
    with output_lock(Path(args.out).parent, "--out"):  # one writer per output folder
        check_outputs(args)
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    from deepslam.core import plots
    from deepslam.core.outputs import write_side_files
    from deepslam.core.readers import open_sequence_for_flow
    from deepslam.core.trajectory import check_finite_poses
    from deepslam.core.trajio import default_format, write_trajectory
    from deepslam.slam import plugins
    from deepslam.slam.pipeline import PipelineConfig, SlamParams, run_slam
    from deepslam.slam.posegraph import PoseGraphConfig
    from deepslam.slam.reloc import Vocabulary
    from deepslam.slam.report import format_report, plot_series, slam_record

    if args.keyframe_stride < 1:
        raise InputError(None, f"--keyframe-stride must be at least 1, got {args.keyframe_stride}")
    out = Path(args.out)
    if out.is_dir():
        raise InputError(out, "--out is a folder, expected a file name")
    seq = open_sequence_for_flow(args.sequence)
    if len(seq) < 3:
        raise InputError(args.sequence, f"holds {len(seq)} frames; SLAM needs at least 3 (and its metrics align 3 poses)")
    fmt = args.format or default_format(seq.kind, seq.timestamps_s is not None)
    if fmt != "kitti" and seq.timestamps_s is None:
        raise InputError(args.sequence, f"the {fmt} format needs timestamps and the sequence has none")
    params = SlamParams.load(args.params) if args.params else SlamParams()
    vocab = Vocabulary.load(args.vocabulary) if args.vocabulary else None
    opts = _odometry_flags.options(args)
    recorded = seq
    seq = plugins.network_view(opts, seq)  # frames narrower than --read-width read upsampled
    odo_cons, odo_loops = plugins.odometries(opts, seq)
    if args.no_loops:
        odo_loops = None
    config = PipelineConfig(graph=PoseGraphConfig(robust=args.robust), keyframe_stride=args.keyframe_stride,
                            loops=not args.no_loops, loop_check=not args.no_loop_check, seed=args.seed)
    res = run_slam(seq, odo_cons, odo_loops, params, config, vocabulary=vocab, show_progress=not (args.json or args.quiet))

    check_finite_poses(res.vo.world_from_cam, f"the odometry {odo_cons.name}")
    check_finite_poses(res.slam.world_from_cam, "the pose graph")
    side = side_files(out)
    vo_path, record_path = side["vo"], side["record"]
    record, aligned = slam_record(seq, args.sequence, res, config, odo_cons, odo_loops, out, vo_path, fmt, args.align)
    if seq is not recorded:
        record["read_at_px"] = [seq.camera.width, seq.camera.height]
    write_trajectory(out, res.slam, fmt)  # after the metrics, which can refuse: nothing half-written
    if args.plot:
        series, title = plot_series(seq, record, aligned, res, args.align)
        try:
            plots.plot_trajectories_topdown(args.plot, series, title=title)
        except OSError as e:
            raise InputError(args.plot, f"cannot write the plot ({e.strerror or e})") from None
        record["plot"] = str(args.plot)
    if args.save_vocabulary:
        _save_vocab(args, res, seq, vocab)
        record["vocabulary"] = str(args.save_vocabulary)
    write_side_files(record_path, _clean(record), COMMAND, [(vo_path, lambda p: write_trajectory(p, res.vo, fmt))])
    if args.json:
        sys.stdout.write(json.dumps(_clean(record), sort_keys=True) + "\n")
    else:
        sys.stdout.write(format_report(record))
    return 0


def _save_vocab(args, res, seq, vocab) -> None:
    v = vocab if vocab is not None else res.vocabulary
    if v is None:
        raise InputError(None, "--save-vocabulary: no vocabulary was used (loop closure is off)")
    v.save(args.save_vocabulary, meta={"trained_on": str(args.sequence)})


def _clean(v):
    """JSON-safe copy (see core.atomic.json_safe)."""
    from deepslam.core.atomic import json_safe

    return json_safe(v)
