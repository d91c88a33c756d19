"""The command-line flags that set DIS up: in ``deepslam train`` (what the model is trained on, and records) and,
overriding a model's record at inference, in ``deepslam vo`` and ``deepslam slam``. Not a subcommand (no
``NAME``): the CLI's discovery skips it. They set the attributes ``flow.registry.DIS_FLAGS`` names, which
:func:`given_options` reads into the typed options the library takes.
"""
from __future__ import annotations

import argparse

_HELP = {
    "dis_min_texture": "DIS flow is unknown (0 in the network's input) where the first image's texture is below T "
                       "((grey levels/px)^2: the structure tensor's smaller eigenvalue over 7x7 px; 0 = keep all)",
    "dis_fb_check": "DIS flow is unknown where the backward flow does not bring a pixel back to within PX pixels "
                    "(occlusions, wrong matches; twice DIS's time; 0 = no check)",
    "dis_max_width": "DIS runs on frames wider than PX downscaled to PX wide, and its flow is resized back to the "
                     "frame's size (about (PX/width)^2 of DIS's time; 0 = full size)",
    "dis_patch_stride": "pixels between the patches DIS matches (0 = the preset's: medium 3; 4: about three quarters "
                        "of medium's time, the speed option for a slow CPU)",
}


def add_arguments(p: argparse.ArgumentParser, training: bool = False) -> None:
    """Add ``--dis-preset``, ``--dis-min-texture``, ``--dis-fb-check``, ``--dis-max-width`` and
    ``--dis-patch-stride`` to ``p`` (a parser or one of its argument groups). ``training``: ``train``'s flags
    (preset medium and texture threshold 0 by default, the rest None: not recorded); else inference overrides,
    each None when not given (the model's own)."""
    if training:
        tail = "; recorded in the model, so vo and slam set DIS up the same way"
        p.add_argument("--dis-preset", default="medium", choices=("ultrafast", "fast", "medium"), help="DIS preset")
        p.add_argument("--dis-min-texture", type=float, default=0.0, metavar="T", help=_HELP["dis_min_texture"] + tail)
    else:
        tail = ". Default: the model's, as it was trained (where it does not say: {})"
        p.add_argument("--dis-preset", default=None, choices=("ultrafast", "fast", "medium"),
                       help="DIS preset (default: the one the model was trained on, medium where it does not say)")
        p.add_argument("--dis-min-texture", type=float, default=None, metavar="T",
                       help=_HELP["dis_min_texture"] + tail.format("0"))
    p.add_argument("--dis-fb-check", type=float, default=None, metavar="PX",
                   help=_HELP["dis_fb_check"] + tail.format("0"))
    p.add_argument("--dis-max-width", type=int, default=None, metavar="PX",
                   help=_HELP["dis_max_width"] + tail.format("0"))
    p.add_argument("--dis-patch-stride", type=int, default=None, metavar="PX",
                   help=_HELP["dis_patch_stride"] + tail.format("the preset's"))


def given_options(name: str, args: argparse.Namespace) -> tuple[tuple[str, object], ...]:
    """:func:`flow.registry.estimator_options` for estimator ``name`` from the DIS flags of a parsed command line
    (an attribute absent or None: not given), the options not given left out, as the sorted-by-flag pairs the
    library's configs take (``VOConfig.flow_options``, ``OdometryOptions.flow_options``,
    ``SyntheticData.flow_options``): what overrides a model file's record. InputError for a flag ``name`` does
    not read."""
    # deferred: the registry imports torch (the learned estimators); building a parser must not
    from deepslam.flow.registry import DIS_FLAGS, estimator_options

    options = estimator_options(name, *(getattr(args, flag, None) for flag in DIS_FLAGS))
    return tuple((k, v) for k, v in options.items() if v is not None)
