"""``deepslam train``: train the flow -> 6DoF network (synthetic from single frames, or supervised).

Synthetic (the paper's method, no ground-truth poses of the training sequences): single frames with
depth (rendered, or from stereo) + a motion model (gen.motion JSON; several = a mixture, e.g. strides
1, 2, 3, or NN_loops' loop distribution) -> flow synthesized on the fly. Supervised: flow between real
frame pairs (DIS or ground-truth flow) + ground-truth relative poses.

Writes into ``--out``: config.json (resolved settings and data), checkpoint.safetensors (every epoch,
atomically), history.json, model.safetensors (the result), summary.json, loss.png. ``--resume`` continues an
interrupted run from checkpoint.safetensors; ``--tensorboard DIR`` adds TensorBoard scalars.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

from deepslam.commands import _train_flags

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "train"
HELP = "train the flow->6DoF network: --mode synthetic (single frames + depth + motion model) or supervised"


def add_arguments(p: argparse.ArgumentParser) -> None:
    _train_flags.add_arguments(p)


def run(args: argparse.Namespace) -> int:
    from deepslam.vo.train import TrainingDiverged, speed_summary, train

    t0 = time.perf_counter()
    _train_flags.check_ranges(args)
    from deepslam.core.outputs import check_output_not_input
    from deepslam.runtime.device import resolve_device
    from deepslam.vo.distributed import finish, init_from_env, world

    check_output_not_input(args.out, [("--source", d) for d in args.source] + [("--sequence", d) for d in args.sequence]
                           + [("--shards", args.shards)])  # never write into the training data
    device = init_from_env(resolve_device(args.device))  # torchrun: one rank per process, one device each
    rank, n_ranks = world()
    net = _train_flags.net_config(args)
    cfg = _train_flags.train_config(args, net, device)
    progress = not (args.quiet or args.json) and rank == 0
    train_src, hold_src, data_meta = _train_flags.data_sources(args, net, progress, device)
    meta: dict = {"mode": args.mode, **data_meta}
    meta["argv"] = sys.argv[1:]
    if progress:
        print(speed_summary(cfg, args.net, meta["data"], len(train_src), len(hold_src)), flush=True)
    try:
        res = train(cfg, train_src, hold_src, args.out, resume=args.resume, progress=progress, meta=meta,
                    half_weights=args.half_weights, tensorboard=args.tensorboard)
    except TrainingDiverged as e:
        print(f"deepslam train: error: {e}", file=sys.stderr)
        return 2
    finish()
    if rank != 0:
        return 0
    if args.json:
        print(json.dumps({"model": str(res.model_path), "stop_reason": res.stop_reason,
                          "epochs": sum(1 for h in res.history if h["stage"] == 1), "best_val_loss": res.best_val_loss,
                          "holdout_nll": res.holdout_nll, "out": str(args.out),
                          "last": res.history[-1] if res.history else None,
                          "minutes": round((time.perf_counter() - t0) / 60, 3)}))
        return 0
    print(f"model: {res.model_path}")
    return 0
