"""The flags of ``deepslam train`` and their reading into the library's typed settings: the network
(:func:`net_config`), the training run (:func:`train_config`) and its data (:func:`data_sources`). Not a
subcommand (no ``NAME``): the CLI's discovery skips it.
"""
from __future__ import annotations

import argparse
import math

from deepslam.commands import _dis_flags, _odometry_flags
from deepslam.core.errors import InputError

# Library imports sit in the functions: building the parser of every command (deepslam --help) must
# not import numpy, torch or the simulator.


def _ints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def _window(size: tuple[int, ...] | None) -> tuple[int, int] | None:
    """``--crop-window W,H``: (width, height), or None when not given."""
    if size is None:
        return None
    if len(size) != 2:
        raise InputError(None, f"--crop-window must be two integers W,H, got {','.join(map(str, size))}")
    return size[0], size[1]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mode", choices=("synthetic", "supervised"), required=True)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.safetensors")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help="no progress; print one JSON object at the end: model, "
                   "stop_reason, epochs, best_val_loss, holdout_nll, out, last (history.json's last row), minutes "
                   "(of the whole command, data preparation included)")
    p.add_argument("--tensorboard", default=None, metavar="DIR",
                   help="also write TensorBoard scalars into DIR: per step the batch loss and learning rate, per epoch "
                        "the history row (losses, held-out loss and RMSE, learning-rate bounds); needs the tensorboard "
                        "package; the trained bytes are the same with or without it")
    g = p.add_argument_group("data (synthetic)")
    # one list, a later --source replacing an earlier one: scripts put a default list in a shared prefix
    g.add_argument("--source", nargs="+", default=[], metavar="DIR",
                   help="sequences whose single frames (with depth) are the training images")
    # the older spelling, hidden: --frames is a count in every other command; bench and the demo study pass it
    g.add_argument("--frames", nargs="+", dest="source", help=argparse.SUPPRESS)
    g.add_argument("--depth", choices=("auto", "rendered", "stereo"), default="auto",
                   help="depth of the frames: rendered maps, from stereo (gen.stereo), or auto")
    g.add_argument("--frame-step", type=int, default=1, help="use every N-th frame")
    g.add_argument("--max-frames", type=int, default=0, help="at most this many frames per sequence (0 = all)")
    g.add_argument("--motion", action="append", default=[], metavar="FILE[:loops][@WEIGHT]",
                   help="gen.motion JSON (deepslam fit-motion); ':loops' samples its loop distribution (NN_loops); "
                        "repeat for a mixture (strides 1, 2, 3...), optional @weight")
    g.add_argument("--speed-range", default=None, metavar="MIN:MAX[@FRACTION]",
                   help="draw the forward speed uniformly in MIN:MAX m/s (at --rate-hz) instead of from the motion "
                        "model, keeping its other DoFs: the network must read speed from the flow, not a prior. "
                        "@FRACTION: only that share of the motions (e.g. 0:30@0.2: a flat tail to 30 m/s beside "
                        "the fitted prior)")
    g.add_argument("--rate-hz", type=float, default=10.0, help="frame rate of the motion model, for --speed-range")
    g.add_argument("--camera-tilt-deg", default=None, metavar="PMIN:PMAX[:ROLL]",
                   help="rotate each sample's camera by a pitch drawn uniformly in [PMIN, PMAX] degrees (positive: "
                        "looking down) and a roll in [-ROLL, ROLL], exactly from the single frame (vo.data.motion.CameraTilt); "
                        "the road then sits at other rows, as under another camera mounting (KITTI's looks ~1 deg down)")
    g.add_argument("--scene-scale", default=None, metavar="MIN:MAX",
                   help="scale each sample's depth (the whole scene) by a factor drawn log-uniformly in [MIN, MAX] "
                        "(vo.data.motion.SceneScale): the same frames then stand for nearer or farther worlds, so the "
                        "same motion makes more or less parallax")
    g.add_argument("--missing-depth", choices=("infinity", "invalid"), default=None,
                   help="pixels without depth: points at infinity (rotation-only flow; a render's sky) or left out "
                        "(flow 0, never made-up geometry). Default: invalid when a sequence has sensor depth "
                        "(TUM RGB-D: a hole is a missing reading, not the sky), else infinity")
    g.add_argument("--samples-per-epoch", type=int, default=20000)
    g.add_argument("--holdout-samples", type=int, default=0,
                   help="fixed held-out samples from the held-out frames (0 = holdout fraction x samples per epoch)")
    g.add_argument("--synth-factor", type=int, default=2, help="synthesize flow at this multiple of the network "
                   "resolution and average it down")
    g.add_argument("--synthetic-flow", default="exact", metavar="NAME",
                   help="flow of the synthetic samples: 'exact' (synthesized from depth + motion, the paper) or a flow "
                        "estimator's name (e.g. dis: the second view is rendered from the single frame and the "
                        "estimator runs on the pair, so the network learns the flow it will be given; --dis-preset)")
    g.add_argument("--frame-scales", type=_floats, default=(1.0,), metavar="S,S...",
                   help="with --synthetic-flow NAME: use each frame scaled by these factors (e.g. 1,0.65; above 1 "
                        "upsampled as `vo --read-width` reads a narrow frame: 1.546 = 414 -> 640 px), as the "
                        "estimator's errors depend on the resolution")
    g.add_argument("--crop-window", type=_ints, default=None, metavar="W,H",
                   help="with --synthetic-flow NAME: cut each sample's frame and second view to a W x H window (pixels "
                        "of the frame as the estimator reads it, after --frame-scales) at a random place, its principal "
                        "point moved with it: frames rendered wider than the test image spread the principal point as "
                        "real cameras place it (with --coord-channels the network is told where)")
    g.add_argument("--mirror-frames", action="store_true",
                   help="synthetic mode: also train on every single frame flipped left-right (its camera mirrored): "
                        "the near side of the street on the other hand, so the network does not take a scene's "
                        "left-right asymmetry for a turn (held-out frames are mirrored on their own side)")
    g.add_argument("--appearance-noise", type=float, default=0.0, metavar="SIGMA",
                   help="with --synthetic-flow NAME: Gaussian noise (grey levels) on the rendered second view, for "
                        "the appearance changes a real next frame has and a resampled one lacks (0 = none)")
    g.add_argument("--synth-device", choices=("auto", "cpu"), default="auto",
                   help="where exact synthetic flow is made: auto = the training device (on a GPU, where a CPU core's "
                        "~1,600 samples/s would limit the training) or cpu")
    g.add_argument("--data-threads", type=int, default=2, help="threads that render and estimate (--synthetic-flow NAME)")
    g.add_argument("--sample-pool", type=int, default=0, metavar="N",
                   help="make N synthetic samples once and train on passes over them (an epoch is one pass) "
                        "instead of fresh samples every epoch: for an expensive --synthetic-flow (0 = fresh)")
    g.add_argument("--shards", default=None, metavar="DIR",
                   help="train on the samples of a finished `deepslam gen` folder (verified against its manifest; "
                        "flow at the network's input size) instead of synthesizing on the fly")
    g.add_argument("--toy", type=int, default=0, metavar="N",
                   help="instead of frames: N toy samples (flow of random motions over a ground plane)")
    g = p.add_argument_group("data (supervised)")
    g.add_argument("--sequence", nargs="+", default=[], metavar="DIR", help="sequences with ground-truth poses")
    g.add_argument("--strides", type=_ints, default=(1,), help="frame gaps of the pairs, e.g. 1,2,3 (a mixture)")
    g.add_argument("--pairs", choices=("consecutive", "loops"), default="consecutive",
                   help="consecutive pairs (NN_cons) or loop pairs far apart in time (NN_loops)")
    g.add_argument("--max-pairs", type=int, default=0, help="at most this many pairs per sequence (0 = all)")
    g.add_argument("--flow", default="dis", help="flow estimator: dis or gt")
    g.add_argument("--read-width", type=int, default=_odometry_flags.READ_WIDTH_PX, metavar="PX",
                   help="estimated flow is made between frames narrower than PX upsampled to PX wide, as `deepslam vo "
                        "--read-width` reads them (default %(default)s; 0: as recorded; exact flow and depth-reading "
                        "networks: always as recorded)")
    _dis_flags.add_arguments(g, training=True)
    g = p.add_argument_group("network")
    g.add_argument("--net", choices=("cpu", "paper", "tiny"), default="paper", help="preset, refined by the options below")
    g.add_argument("--height", type=int, help="input rows")
    g.add_argument("--width", type=int, help="input columns")
    g.add_argument("--filters", type=int)
    g.add_argument("--kernels", type=_ints)
    g.add_argument("--conv-strides", type=_ints)
    g.add_argument("--hidden", type=int, help="units per fully connected layer")
    g.add_argument("--hidden-layers", type=int)
    g.add_argument("--coord-channels", action="store_true", help="add (u-cx)/fx, (v-cy)/fy input channels")
    g.add_argument("--depth-channel", action="store_true",
                   help="add the first frame's inverse depth as an input channel (RGB-D cameras, renders, stereo: "
                        "vo/slam then read each frame's depth too); needs frames with depth: --source, or supervised --sequence")
    g.add_argument("--valid-channel", action="store_true",
                   help="add a channel marking where the flow is known (DIS's textureless pixels left out with "
                        "--dis-min-texture, depth holes): unknown flow is then left out when it is resized, instead "
                        "of read as 0 and averaged in")
    g.add_argument("--flow-scale", type=float, help="multiplier after flow / (W, H) (1 = the paper)")
    g.add_argument("--pose-head", choices=("regress", "solve"), default="regress",
                   help="regress: the paper's fully connected output; solve: the network weighs each pixel and the "
                        "pose is the weighted Gauss-Newton fit of the flow with the frame's depth (RGB-D, renders; "
                        "needs --depth-channel --valid-channel)")
    g.add_argument("--solve-iterations", type=int, help="Gauss-Newton steps of the solve head (default 3)")
    g.add_argument("--solve-robust", choices=("none", "cauchy"), default="none",
                   help="the solve head's kernel: none (weighted least squares) or cauchy (iteratively reweighted "
                        "from the second step on, scale from the residuals' median: pixels the flow gets wrong "
                        "stop pulling the pose)")
    g = p.add_argument_group("recipe")
    g.add_argument("--batch", type=int, default=128)
    g.add_argument("--lr-min", type=float, default=1e-4)
    g.add_argument("--lr-max", type=float, default=1e-3)
    g.add_argument("--half-cycle-steps", type=int, default=0, help="CyclicLR step_size_up (0 = one epoch)")
    g.add_argument("--patience", type=int, default=10, help="epochs without improvement before halving the LR bounds")
    g.add_argument("--lr-stop", type=float, default=1e-5)
    g.add_argument("--max-epochs", type=int, default=1000)
    g.add_argument("--max-minutes", type=float, default=0.0,
                   help="stop training after about this many minutes, both stages, checked every batch (0 = no cap)")
    g.add_argument("--max-samples", type=int, default=0,
                   help="stop stage 1 after this many training samples, checked every batch: a bounded run that is "
                        "bit-reproducible, unlike --max-minutes (0 = no cap)")
    g.add_argument("--rot-weight", type=float, default=50.0)
    g.add_argument("--loss", choices=("l1", "mse"), default="l1",
                   help="stage-1 loss per DoF: l1 (the paper's published code) or mse (the shipped models' recipe)")
    g.add_argument("--holdout", type=float, default=0.1, help="held-out fraction (validation + NLL stage)")
    g.add_argument("--nll-epochs", type=int, default=20)
    g.add_argument("--nll-lr", type=float, default=1e-3)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--bf16", choices=("auto", "on", "off"), default="auto", help="bf16 autocast (auto: native bf16 CPUs)")
    g.add_argument("--channels-last", choices=("on", "off"), default="on")
    g.add_argument("--threads", type=int, default=0, help="torch threads (0 = default)")
    g.add_argument("--device", default="auto", help="auto (CUDA when torch sees one, else the CPU), cpu, cuda or "
                   "cuda:N; bf16 autocast by default on CUDA")
    g.add_argument("--half-weights", action="store_true", help="store model.safetensors's weights as float16")


def net_config(args):
    """The network the flags ask for: the ``--net`` preset (:data:`vo.net.NET_PRESETS`) with each architecture
    flag given taking precedence."""
    from deepslam.vo.net import preset_config

    overrides = {field: getattr(args, arg, None) for arg, field in (
        ("height", "input_height"), ("width", "input_width"), ("filters", "filters"), ("kernels", "kernels"),
        ("conv_strides", "strides"), ("hidden", "hidden_units"), ("hidden_layers", "hidden_layers"),
        ("flow_scale", "flow_scale"), ("solve_iterations", "solve_iterations"))}
    overrides.update(coord_channels=args.coord_channels or None, depth_channel=args.depth_channel or None,
                     valid_channel=args.valid_channel or None,
                     pose_head=None if args.pose_head == "regress" else args.pose_head,
                     solve_robust=None if args.solve_robust == "none" else args.solve_robust)
    return preset_config(args.net, **overrides)


def check_ranges(args) -> None:
    """Numeric flags that cannot be: one line naming the flag (exit 2)."""
    from deepslam.vo.pipeline import check_read_width

    positive = {"--batch": args.batch, "--samples-per-epoch": args.samples_per_epoch, "--frame-step": args.frame_step,
                "--max-epochs": args.max_epochs, "--synth-factor": args.synth_factor, "--data-threads": args.data_threads}
    non_negative = {"--max-minutes": args.max_minutes, "--max-samples": args.max_samples, "--nll-epochs": args.nll_epochs,
                    "--max-frames": args.max_frames, "--holdout-samples": args.holdout_samples, "--toy": args.toy,
                    "--sample-pool": args.sample_pool, "--threads": args.threads, "--patience": args.patience,
                    "--appearance-noise": args.appearance_noise, "--half-cycle-steps": args.half_cycle_steps}
    for flag, v in positive.items():
        if not (math.isfinite(v) and v > 0):
            raise InputError(None, f"{flag} must be > 0, got {v}")
    if args.batch > 65536:
        raise InputError(None, f"--batch must be at most 65536, got {args.batch}")
    for flag, v in non_negative.items():
        if not (math.isfinite(v) and v >= 0):
            raise InputError(None, f"{flag} must be >= 0, got {v}")
    for flag, v in {"--lr-min": args.lr_min, "--lr-max": args.lr_max, "--nll-lr": args.nll_lr,
                    "--rot-weight": args.rot_weight, "--lr-stop": args.lr_stop}.items():
        if not (math.isfinite(v) and v > 0):
            raise InputError(None, f"{flag} must be a positive number, got {v}")
    if args.lr_min > args.lr_max:
        raise InputError(None, f"--lr-min {args.lr_min} is above --lr-max {args.lr_max}")
    check_read_width(args.read_width)


def train_config(args: argparse.Namespace, net, device):
    """The :class:`vo.trainconfig.TrainConfig` of the flags, for network ``net`` on torch ``device`` (bf16 ``auto``:
    on CUDA, and on CPUs that compute bf16 natively). InputError for a hold-out fraction outside (0, 1)."""
    from deepslam.runtime.device import resolve_bf16
    from deepslam.vo.trainconfig import TrainConfig

    bf16 = resolve_bf16(args.bf16, device)
    cfg = TrainConfig(net=net, batch_size=args.batch, lr_min=args.lr_min, lr_max=args.lr_max,
                      lr_half_cycle_steps=args.half_cycle_steps, patience_epochs=args.patience, lr_stop=args.lr_stop,
                      max_epochs=args.max_epochs, max_minutes=args.max_minutes, max_samples=args.max_samples,
                      rot_weight=args.rot_weight, loss=args.loss,
                      holdout_fraction=args.holdout, nll_epochs=args.nll_epochs, nll_lr=args.nll_lr, seed=args.seed,
                      bf16=bf16, channels_last=args.channels_last == "on", threads=args.threads, device=str(device))
    if not 0 < args.holdout < 1:
        raise InputError(None, f"--holdout must be in (0, 1), got {args.holdout}")
    return cfg


def data_sources(args: argparse.Namespace, net, progress: bool, device) -> tuple:
    """The training data the flags name, as the library builds it (:mod:`vo.data.sources`,
    :func:`vo.data.recipe.synthetic_sources`): (training source, held-out source, meta), the meta what config.json
    and the model file record of the data; exact synthetic flow is made on torch ``device`` (the training
    device) unless ``--synth-device cpu``."""
    from deepslam.vo.data import motion, sources
    from deepslam.vo.data.recipe import SyntheticData, synthetic_sources
    from deepslam.vo.data.supervised import PairSpec

    tilt = motion.CameraTilt.parse(args.camera_tilt_deg) if args.camera_tilt_deg else None
    scene_scale = motion.SceneScale.parse(args.scene_scale) if args.scene_scale else None
    if args.mode != "synthetic" or args.shards or args.toy:  # no single frames to act on
        for flag, what, given in (("--scene-scale", "scales single frames", scene_scale is not None),
                                  ("--camera-tilt-deg", "rotates single frames", tilt is not None),
                                  ("--mirror-frames", "mirrors single frames", args.mirror_frames),
                                  ("--crop-window", "cuts single frames", args.crop_window is not None)):
            if given:
                raise InputError(None, f"{flag} {what}: it needs --mode synthetic with --source "
                                       "(not --toy, --shards or supervised pairs)")
    if net.depth_channel and (args.shards or args.toy):  # supervised pairs read their first frame's depth
        raise InputError(None, "--depth-channel reads each pair's first-frame depth: it needs frames with depth "
                               "(--source, or supervised --sequence), not --toy or --shards")
    if args.mode == "synthetic" and args.shards:
        train_src, hold_src, data_meta = sources.shard_sources(args.shards, net, args.holdout, args.seed)
    elif args.mode == "synthetic" and args.toy:
        train_src, hold_src, data_meta = sources.toy_sources(args.toy, net, args.holdout, args.seed)
    elif args.mode == "synthetic":
        if not args.source:
            raise InputError(None, "synthetic mode needs --source DIR... (or --toy N, or --shards DIR)")
        spec = SyntheticData(
            frames=tuple(args.source), motion=tuple(args.motion or ()), depth=args.depth,
            frame_step=args.frame_step, max_frames=args.max_frames, samples_per_epoch=args.samples_per_epoch,
            holdout=args.holdout, holdout_samples=args.holdout_samples, batch_size=args.batch,
            synth_factor=args.synth_factor, synthetic_flow=args.synthetic_flow,
            flow_options=_dis_flags.given_options(args.synthetic_flow, args), frame_scales=tuple(args.frame_scales),
            crop_window=_window(args.crop_window), appearance_noise=args.appearance_noise,
            data_threads=args.data_threads, sample_pool=args.sample_pool,
            missing_depth=args.missing_depth, speed_range=args.speed_range, rate_hz=args.rate_hz,
            camera_tilt_deg=args.camera_tilt_deg, scene_scale=args.scene_scale, mirror_frames=args.mirror_frames,
            device="cpu" if args.synth_device == "cpu" else str(device))
        train_src, hold_src, data_meta = synthetic_sources(spec, net, args.seed, progress)
    else:
        spec = sources.SupervisedData(
            sequences=tuple(args.sequence), flow=args.flow, flow_options=_dis_flags.given_options(args.flow, args),
            pairs=PairSpec(strides=tuple(args.strides), kind=args.pairs, max_pairs=args.max_pairs),
            holdout=args.holdout, read_width_px=args.read_width)
        train_src, hold_src, data_meta = sources.supervised_sources(spec, net, args.seed, progress)
    return train_src, hold_src, data_meta
