"""The command-line flags that override, at inference, how DIS is set up for a model (``deepslam vo`` and
``deepslam slam``). Not a subcommand (no ``NAME``): the CLI's discovery skips it.

A model file records the DIS options it was trained on (``vo.models.recorded_flow_options``); each flag
not given (None) keeps the model's.
"""
from __future__ import annotations

import argparse

FLAGS = ("dis_preset", "dis_min_texture", "dis_fb_check", "dis_max_width", "dis_patch_stride")
"""The attributes :func:`add_arguments` sets on the namespace, in :func:`vo.flow_estimators.estimator_options`'
order."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add ``--dis-preset``, ``--dis-min-texture``, ``--dis-fb-check``, ``--dis-max-width`` and
    ``--dis-patch-stride`` to ``p``, each None when not given."""
    p.add_argument("--dis-preset", default=None, choices=("ultrafast", "fast", "medium"),
                   help="DIS preset (default: the one the model was trained on, medium where it does not say)")
    p.add_argument("--dis-min-texture", type=float, default=None, metavar="T",
                   help="DIS flow is unknown where the first image's texture is below T ((grey levels/px)^2: the "
                        "structure tensor's smaller eigenvalue over 7x7 px; 0 = keep all). Default: the model's, "
                        "as it was trained (0 where it does not say)")
    p.add_argument("--dis-fb-check", type=float, default=None, metavar="PX",
                   help="DIS flow is unknown where the backward flow does not bring a pixel back to within PX "
                        "pixels (occlusions, wrong matches; twice DIS's time; 0 = no check). Default: the model's, "
                        "as it was trained (0 where it does not say)")
    p.add_argument("--dis-max-width", type=int, default=None, metavar="PX",
                   help="DIS runs on frames wider than PX downscaled to PX wide, and its flow is resized back to the "
                        "frame's size (about (PX/width)^2 of DIS's time; 0 = full size). Default: the model's, as it "
                        "was trained (0 where it does not say)")
    p.add_argument("--dis-patch-stride", type=int, default=None, metavar="PX",
                   help="pixels between the patches DIS matches (0 = the preset's: medium 3; 4: about three quarters "
                        "of medium's time, the speed option for a slow CPU). Default: the model's, as it was trained "
                        "(the preset's where it does not say)")
