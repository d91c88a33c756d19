"""The command-line flags that choose the odometry of ``slam`` and ``tune-slam`` (the network, a plug-in, an
external program, or noisy ground truth for tests), defined once, and their reading into the library's typed
:class:`slam.plugins.OdometryOptions`. Not a subcommand (no ``NAME``): the CLI's discovery skips it.
"""
from __future__ import annotations

import argparse

from deepslam.commands import _dis_flags

READ_WIDTH_PX = 640
"""The default of ``--read-width`` (``vo``, ``slam``, ``tune-slam``, ``stress``): frames narrower than 640 px are
read upsampled to 640 (decided by rule v2 of docs/experiments/2026-12-06_read_width.md)."""
READ_WIDTH_HELP = ("the network reads frames narrower than PX upsampled to PX wide (bicubic, the camera scaled "
                   "alike; a network on estimated flow that does not read depth; relocalization sees the same frames): "
                   "at 320 px DIS and the road scale over-read the distance. 0: as recorded (default %(default)s; wider frames, "
                   "KITTI's, EuRoC's and TUM's, are read as recorded)")
CENTRE_HELP = ("move each flow so that the camera's principal point lies at the image's centre before the network "
               "reads it (the simulator renders every camera centred; KITTI 04-10's principal point lies 10.6 px left "
               "of the centre; off by default: docs/experiments/2026-12-07_principal_point.md)")
"""Help of ``--centre-principal-point`` (``vo``, ``slam``, ``tune-slam``, ``calibrate``)."""
MIRROR_AVERAGE_CHOICES = ("auto", "on", "off")
"""``--mirror-average``'s choices (:data:`vo.modelfiles.models.MIRROR_AVERAGE`; not imported: the parsers build
without numpy)."""
MIRROR_AVERAGE_DEFAULT = "off"
"""``--mirror-average``'s default (:data:`vo.modelfiles.models.MIRROR_AVERAGE_DEFAULT`, a test keeps the two equal)."""
MIRROR_AVERAGE_HELP = ("read each flow also mirrored left-right and average the two motions (the mirrored one mirrored "
                       "back): what a network trained on mirrored frames still reads differently in a scene and its "
                       "mirror image cancels; auto: for a model trained with --mirror-frames, with its own pose "
                       "(default %(default)s; docs/experiments/2026-12-07_mirror_average.md)")
"""Help of ``--mirror-average`` (``vo``, ``slam``, ``tune-slam``, ``calibrate``)."""
GEOMETRY_STD_HELP = ("widen each consecutive pair's predicted std per DoF by the network's disagreement with the geometry "
                     "that reads the same flow (the epipolar fit's rotation and direction, the road's distance): "
                     "sqrt(std^2 + d^2); the motions stay the pose mode's (with --pose epipolar, --scale road)")
"""Help of ``--std-from-geometry`` (``vo``, ``slam``, ``tune-slam``)."""
KEYFRAME_STRIDE_HELP = ("relocalize every K-th frame (default %(default)s: the same revisits found as on every frame, at a "
                        "third of the cost; docs/experiments/2026-12-06_keyframe_stride.md)")
"""Help of ``--keyframe-stride`` (``slam``, ``tune-slam``; its default is :attr:`slam.pipeline.PipelineConfig.keyframe_stride`'s)."""
COMMAND_TIMEOUT_HELP = ("seconds the --odometry-command (or a Python plug-in's predict) may run on the sequence "
                        "(3600); a command runs without a shell: the template is split into arguments once and "
                        "{sequence}/{out} replaced inside them ({{ and }} for literal braces)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """``--odometry``, ``--device``, ``--odometry-loops``, ``--odometry-command``, ``--command-timeout`` and the
    hidden ``--gt-noise``, ``--gt-drift``, ``--seed`` (ground-truth odometry with noise, for tests and benches)."""
    p.add_argument("--odometry", default="model", metavar="MODULE:FACTORY|NAME",
                   help="consecutive-frame odometry: model (the network, default) or a plug-in: a factory returning "
                        "an object with name and predict(seq, pairs) -> (mean6, std6), or an entry-point name of group "
                        "deepslam.odometry")
    p.add_argument("--device", default="auto", help="where the network runs: auto (CUDA when torch sees one, else "
                   "the CPU), cpu, cuda or cuda:N")
    p.add_argument("--odometry-loops", default=None, metavar="MODULE:FACTORY|NAME",
                   help="loop-pair odometry plug-in (default: the --odometry plug-in, or NN_loops with the network)")
    p.add_argument("--odometry-command", default=None, metavar="'CMD {sequence} {out}'",
                   help="an external program that reads the sequence folder and writes a KITTI or TUM trajectory to "
                        "{out}; used for consecutive and loop pairs")
    p.add_argument("--command-timeout", type=float, default=3600.0, metavar="S", help=COMMAND_TIMEOUT_HELP)
    p.add_argument("--read-width", type=int, default=READ_WIDTH_PX, metavar="PX", help=READ_WIDTH_HELP)
    p.add_argument("--centre-principal-point", action="store_true", help=CENTRE_HELP)
    add_mirror_average(p)
    p.add_argument("--std-from-geometry", action="store_true", help=GEOMETRY_STD_HELP)
    p.add_argument("--gt-noise", default="0.002,0.02", help=argparse.SUPPRESS)
    p.add_argument("--gt-drift", type=float, default=0.002, help=argparse.SUPPRESS)
    p.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)


def add_mirror_average(p: argparse.ArgumentParser) -> None:
    """``--mirror-average {auto,on,off}``."""
    p.add_argument("--mirror-average", choices=MIRROR_AVERAGE_CHOICES, default=MIRROR_AVERAGE_DEFAULT,
                   help=MIRROR_AVERAGE_HELP)


def options(args: argparse.Namespace):
    """The :class:`slam.plugins.OdometryOptions` of parsed ``slam`` / ``tune-slam`` arguments."""
    # deferred: building the parser of every command (deepslam --help) must not import numpy
    from deepslam.slam.plugins import OdometryOptions

    return OdometryOptions(
        odometry=args.odometry, odometry_loops=args.odometry_loops, odometry_command=args.odometry_command,
        command_timeout_s=args.command_timeout, model_cons=args.model_cons, model_loops=args.model_loops,
        flow=args.flow, flow_options=_dis_flags.given_options(args.flow, args),
        no_loops=bool(getattr(args, "no_loops", False)), pose=args.pose, device=args.device, gt_noise=args.gt_noise,
        gt_drift=args.gt_drift, seed=args.seed, progress=not (args.quiet or args.json), read_width_px=args.read_width,
        centre_principal_point=args.centre_principal_point, mirror_average=args.mirror_average,
        std_from_geometry=args.std_from_geometry)
