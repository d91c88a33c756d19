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
import dataclasses
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
    p.add_argument("--keyframe-stride", type=int, default=1, metavar="K", help="relocalize every K-th frame")
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
    from deepslam.core import metrics, plots
    from deepslam.core.outputs import write_side_files
    from deepslam.core.readers import open_sequence_for_flow
    from deepslam.core.trajectory import check_finite_poses
    from deepslam.core.trajio import default_format, write_trajectory
    from deepslam.slam import plugins
    from deepslam.slam.pipeline import PipelineConfig, SlamParams, run_slam
    from deepslam.slam.posegraph import PoseGraphConfig, loop_coverage
    from deepslam.slam.reference import perfect_loops_record
    from deepslam.slam.reloc import Vocabulary

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
    odo_cons, odo_loops = plugins.odometries(_odometry_flags.options(args), seq)
    if args.no_loops:
        odo_loops = None
    config = PipelineConfig(graph=PoseGraphConfig(robust=args.robust), keyframe_stride=args.keyframe_stride,
                            loops=not args.no_loops, loop_check=not args.no_loop_check, seed=args.seed)
    res = run_slam(seq, odo_cons, odo_loops, params, config, vocabulary=vocab, show_progress=not (args.json or args.quiet))

    check_finite_poses(res.vo.world_from_cam, f"the odometry {odo_cons.name}")
    check_finite_poses(res.slam.world_from_cam, "the pose graph")
    side = side_files(out)
    vo_path, record_path = side["vo"], side["record"]
    in_cycles = loop_coverage(len(seq), res.loops.pairs)    # the frames loop edges constrain
    record = {
        "sequence": str(Path(args.sequence).resolve()), "frames": len(seq), "trajectory": str(out), "trajectory_vo": str(vo_path),
        "format": fmt, "odometry_cons": odo_cons.name, "odometry_loops": getattr(odo_loops, "name", None),
        "params": res.params.to_dict(),
        "config": {**config.to_dict(), "reloc": dataclasses.asdict(res.reloc) if res.reloc else None},
        "loops": res.loops.pairs.tolist(), "n_loops": len(res.loops),
        "loops_not_rigid": res.loops_not_rigid.tolist(),
        "frames_in_closed_cycles": int(in_cycles.sum()),
        "loops_kept_by_pose_graph": None if res.loop_inliers is None else res.loop_inliers.tolist(),
        "flow_cons": getattr(getattr(odo_cons, "flow_estimator", None), "name", None),
        "flow_loops": getattr(getattr(odo_loops, "flow_estimator", None), "name", None),
        "n_candidates": len(res.candidates),
        "n_verified_ok": int(sum(c.verification.accepted for c in res.candidates)),
        "timings": res.timings, "graph_error": list(res.graph_error),
    }
    if seq.gt is not None:
        for name, traj in (("vo", res.vo), ("slam", res.slam)):
            ev = metrics.evaluate(seq.gt, traj, align=args.align)
            record[f"metrics_{name}"] = {k: v for k, v in ev.items() if not k.startswith("_")}
            # the same ATE over the frames inside a closed cycle (what loop edges constrain) and the others
            inside, elsewhere = metrics.ate_parts(ev["_gt_poses"], ev["_est_aligned_poses"], in_cycles[ev["_est_index"]])
            record[f"metrics_{name}"].update(ate_in_closed_cycles_m=inside, ate_elsewhere_m=elsewhere)
            if name == "slam":
                gt_aligned = ev["_gt_poses"]
                slam_aligned = ev["_est_aligned_poses"]
            else:
                vo_aligned = ev["_est_aligned_poses"]
        # the same graph with an exact loop edge on every revisit: what loop closure gives on this route
        graph = dataclasses.replace(config.graph, c_s=res.params.c_s, c_r=res.params.c_r)
        perfect = perfect_loops_record(seq, res.cons, res.params.t_loop, graph, args.align)
        if perfect is not None:
            record["metrics_perfect_loops"] = perfect
    write_trajectory(out, res.slam, fmt)  # after the metrics, which can refuse: nothing half-written
    if args.plot:
        series = {}
        if seq.gt is not None:
            series["ground truth"] = gt_aligned[:, :3, 3]
            series[f"VO ({args.align})"] = vo_aligned[:, :3, 3]
            series[f"SLAM ({args.align})"] = slam_aligned[:, :3, 3]
            title = (f"{seq.name}: ATE VO {record['metrics_vo']['ate_m']:.3f} m, "
                     f"SLAM {record['metrics_slam']['ate_m']:.3f} m, {len(res.loops)} loops")
        else:
            series["SLAM"] = res.slam.positions
            series["VO"] = res.vo.positions
            title = f"{seq.name}: {len(res.loops)} loops"
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


def format_report(r: dict) -> str:
    t = r["timings"]
    lines = [f"sequence      {r['sequence']} ({r['frames']} frames)",
             f"odometry      cons {r['odometry_cons']}, loops {r['odometry_loops']}",
             f"parameters    C_s {r['params']['c_s']:g}, C_r {r['params']['c_r']:g}, T_loop {r['params']['t_loop']}",
             f"loops         {r['n_loops']} edges, {sum(r['loops_kept_by_pose_graph'] or [])} kept by the pose graph "
             f"({r['n_verified_ok']} of {r['n_candidates']} candidates passed verification; "
             f"{len(r['loops_not_rigid'])} left out, their flow fitting no rigid motion)",
             f"closed cycles {r['frames_in_closed_cycles']} of {r['frames']} frames lie inside a cycle a loop edge closes "
             "(the rest only the odometry places)",
             f"speed         {t['fps']:.2f} frames/s ({t['total_s']:.2f} s; optimisation {t['optimize_s']:.3f} s)",
             f"wrote         {r['trajectory']}, {r['trajectory_vo']}"]
    if "metrics_slam" in r:
        mv, ms = r["metrics_vo"], r["metrics_slam"]

        def num(x, f=".4f"):
            return "n/a" if x is None else format(x, f)
        lines += ["", f"{'metric':<24}{'VO':>12}{'SLAM':>12}  unit",
                  f"{'ATE rmse':<24}{num(mv['ate_m']):>12}{num(ms['ate_m']):>12}  m",
                  f"{'  in closed cycles':<24}{num(mv.get('ate_in_closed_cycles_m')):>12}"
                  f"{num(ms.get('ate_in_closed_cycles_m')):>12}  m",
                  f"{'  elsewhere':<24}{num(mv.get('ate_elsewhere_m')):>12}{num(ms.get('ate_elsewhere_m')):>12}  m",
                  *([f"{'  with perfect loops':<24}{'':>12}{num(r['metrics_perfect_loops']['ate_m']):>12}  m "
                     f"(an exact loop edge on each of the route's {r['metrics_perfect_loops']['revisit_pairs']} "
                     "revisiting frames)"] if r.get("metrics_perfect_loops") else []),
                  f"{'RPE trans rmse (d=1)':<24}{num(mv['rpe_t_m']):>12}{num(ms['rpe_t_m']):>12}  m",
                  f"{'RPE rot rmse (d=1)':<24}{num(mv['rpe_r_deg']):>12}{num(ms['rpe_r_deg']):>12}  deg"]
        if "kitti_t_err_pct" in ms:
            lines += [f"{'KITTI t_err':<24}{num(mv.get('kitti_t_err_pct')):>12}{num(ms['kitti_t_err_pct']):>12}  %",
                      f"{'KITTI r_err':<24}{num(mv.get('kitti_r_err_deg_per_100m')):>12}"
                      f"{num(ms['kitti_r_err_deg_per_100m']):>12}  deg/100 m"]
    if r.get("plot"):
        lines.append(f"plot          {r['plot']}")
    return "\n".join(lines) + "\n"
