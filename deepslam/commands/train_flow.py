"""``deepslam train-flow``: train the compact learned flow estimator on rendered pairs with exact flow, and
optionally fine-tune it on real unlabelled pairs beside them (``--real``, :mod:`flow.unsup`)."""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.

NAME = "train-flow"
HELP = "train the learned optical-flow estimator (--flow learned) on rendered sequences with exact flow"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sequence", nargs="+", action="extend", required=True, metavar="DIR",
                   help="rendered sequences with flow/ (and flow_backward/): ours, KITTI or EuRoC layout, or a "
                        "`deepslam dataset` folder (all its sequences); list several, or repeat the flag")
    p.add_argument("--out", required=True, help="output folder (checkpoint.safetensors, flow.safetensors, history.json)")
    p.add_argument("--max-steps", type=int, default=20000, help="training steps, the learning-rate schedule's length (20000)")
    p.add_argument("--max-minutes", type=float, default=0.0, help="stop after this much training time (0: no cap)")
    p.add_argument("--stop-after", type=int, default=0, metavar="STEPS",
                   help="stop after this many steps, the schedule still spanning --max-steps (0: at --max-steps)")
    p.add_argument("--batch", type=int, default=8, help="pairs per step (8)")
    p.add_argument("--crop", default="128x320", metavar="HxW", help="training crop, multiples of 32 (128x320)")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (1e-3, cosine decay)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads (2)")
    p.add_argument("--loader-workers", type=int, default=0, metavar="K",
                   help="processes that build the batches ahead of each step (0: none); the same batches for any K. "
                        "On a GPU machine the batches, not the network, bound the speed: use most of its cores")
    p.add_argument("--bf16", choices=("auto", "on", "off"), default="auto",
                   help="bf16 autocast (auto: with CUDA and on CPUs that compute bf16 natively)")
    p.add_argument("--device", default="auto", help="auto (CUDA when torch sees one, else the CPU), cpu, cuda or cuda:N")
    p.add_argument("--init", default="", metavar="FLOW_MODEL",
                   help="start from this flow model's weights (fine-tuning, e.g. models/flow_learned.safetensors "
                        "on new renders); default: random initialisation")
    p.add_argument("--real", nargs="+", default=[], metavar="DIR",
                   help="real sequences without flow (e.g. ../shared/data/kitti/sequences/06; stereo: both cameras) "
                        "for unsupervised fine-tuning beside the rendered pairs: census photometric loss with "
                        "forward-backward occlusion masks and edge-aware smoothness (flow/unsup.py)")
    p.add_argument("--real-batch", type=int, default=4, help="real pairs per step with --real (4)")
    p.add_argument("--real-weight", type=float, default=1.0, help="weight of the unsupervised loss (1.0)")
    p.add_argument("--smooth-weight", type=float, default=4.0, help="weight of its smoothness term (4.0)")
    p.add_argument("--smooth-order", type=int, choices=(1, 2), default=1,
                   help="order of the smoothness term: 1 (first differences) or 2 (second: a plane's flow is free)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true",
                   help="no progress bar; print one JSON object at the end: model, out, steps, last (history.json's "
                        "last row), minutes (of the whole command, loading the pairs included)")
    p.add_argument("--tensorboard", default=None, metavar="DIR",
                   help="also write TensorBoard scalars into DIR: per step the loss and learning rate, every "
                        "checkpoint the history row; needs the tensorboard package; the trained bytes are the same "
                        "with or without it")


def _sequence_dirs(paths: list[str]) -> list[str]:
    out = []
    for p in paths:
        root = Path(p)
        if (root / "manifest.json").is_file() and (root / "dataset.json").is_file():
            out.extend(str(d) for d in sorted(root.glob("seq_*")) if d.is_dir())
        else:
            out.append(str(root))
    return out


def run(args: argparse.Namespace) -> int:
    from deepslam.core.readers import open_sequence
    from deepslam.runtime.device import resolve_bf16, resolve_device
    from deepslam.flow.train import FlowPairs, FlowTrainConfig, train_flow
    from deepslam.runtime.training import TrainingDiverged

    t0 = time.perf_counter()
    try:
        ch, cw = (int(x) for x in args.crop.lower().split("x"))
    except ValueError:
        raise InputError(None, f"--crop must be HxW, got {args.crop!r}") from None
    if ch % 32 or cw % 32 or not (32 <= ch <= 1024 and 32 <= cw <= 2048):
        raise InputError(None, f"--crop must be multiples of 32 within 1024x2048, got {args.crop}")
    for name, v, lo, hi in (("--max-steps", args.max_steps, 1, 10_000_000), ("--batch", args.batch, 1, 1024),
                            ("--threads", args.threads, 1, 256), ("--loader-workers", args.loader_workers, 0, 256)):
        if not lo <= v <= hi:
            raise InputError(None, f"{name} must be in [{lo}, {hi}], got {v}")
    if not (args.lr > 0 and args.lr < 1) or not (args.max_minutes >= 0):
        raise InputError(None, "--lr must be in (0, 1) and --max-minutes >= 0")
    if args.real and not (1 <= args.real_batch <= 1024 and 0 < args.real_weight < 1e3 and 0 <= args.smooth_weight < 1e3):
        raise InputError(None, "--real-batch must be in [1, 1024], --real-weight in (0, 1000), --smooth-weight in [0, 1000)")
    from deepslam.core.outputs import check_output_not_input

    check_output_not_input(args.out, [("--sequence", s) for s in args.sequence] + [("--real", s) for s in args.real]
                           + [("--init", args.init or None)])
    device = resolve_device(args.device)
    cfg = FlowTrainConfig(crop=(ch, cw), batch_size=args.batch, lr=args.lr, max_steps=args.max_steps,
                          max_minutes=args.max_minutes, stop_after_steps=args.stop_after, seed=args.seed,
                          threads=args.threads, device=str(device), bf16=resolve_bf16(args.bf16, device), loader_workers=args.loader_workers,
                          init=args.init,
                          real_batch_size=args.real_batch if args.real else 0, real_weight=args.real_weight,
                          smooth_weight=args.smooth_weight, smooth_order=args.smooth_order)
    init_meta = {}
    if args.init:  # checked before minutes of loading frames
        from deepslam.flow.train import initial_weights

        initial_weights(cfg)
        init_meta["init_sha256"] = hashlib.sha256(Path(args.init).read_bytes()).hexdigest()
    seqs = [open_sequence(d) for d in _sequence_dirs(args.sequence)]
    real = [open_sequence(d) for d in args.real]
    progress = not (args.quiet or args.json)
    pairs = FlowPairs(seqs, progress=progress)
    meta = {"sequences": [str(s.root) for s in seqs], "pairs": len(pairs), **init_meta}
    real_pairs = None
    if real:
        from deepslam.flow.unsup import RealPairs

        real_pairs = RealPairs(real, cfg.net.work_width, progress=progress)
        meta.update(real_sequences=[str(s.root) for s in real], real_pairs=len(real_pairs))
    try:
        path = train_flow(cfg, pairs, args.out, resume=args.resume, progress=progress, meta=meta,
                          real_pairs=real_pairs, tensorboard=args.tensorboard)
    except TrainingDiverged as e:
        print(f"deepslam train-flow: error: {e}", file=sys.stderr)
        return 2
    if args.json:
        from deepslam.flow.net import load_flow_model

        # history.json holds a row every checkpoint interval; the model file records the steps actually run
        history = json.loads((Path(args.out) / "history.json").read_text())
        print(json.dumps({"model": str(path), "out": str(args.out), "steps": load_flow_model(path)[1]["steps"],
                          "last": history[-1] if history else None,
                          "minutes": round((time.perf_counter() - t0) / 60, 3)}))
        return 0
    print(f"model: {path}")
    return 0
