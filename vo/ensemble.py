"""Seed ensembles of flow -> 6DoF networks (a deep ensemble: Lakshminarayanan et al., 2017).

Networks trained by the same recipe with different seeds agree on what the data pins down and
disagree where it does not; their average is steadier than any one of them (two seeds of
one recipe read KITTI 07's heading differently enough to double the end-point drift). The ensemble
predicts the moments of the members' equal mixture, each member being Gaussian ``N(mean_i, std_i^2)``
per DoF:

    mean = 1/N sum_i mean_i
    std^2 = 1/N sum_i (std_i^2 + mean_i^2) - mean^2   (the members' own variance plus their spread)

An ensemble file is an ordinary VO model file (kind ``deepslam-vo-model``, :mod:`models.modelfile`)
whose tree holds ``ensemble``: a list of member trees (``net``, ``state_dict``, ``meta``) with one
network shape, so every command that takes ``--model`` takes it, and the pose graph gets the larger
uncertainty where the members disagree.
"""
from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from deepslam.vo.net import LOG_STD_MAX, LOG_STD_MIN, PoseNet



def mixture_moments(means: torch.Tensor, log_stds: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and log-std of an equal mixture of Gaussians, per DoF.

    Args:
        means: (N, B, 6) member means (any float dtype; radians and metres).
        log_stds: (N, B, 6) member log-stds (natural log of the std, same units as the means).

    Returns:
        (mean (B, 6), log_std (B, 6)), float32; log_std clamped to [LOG_STD_MIN, LOG_STD_MAX] like a
        single network's.
    """
    m = means.double()
    var_i = torch.exp(2.0 * log_stds.double())
    mean = m.mean(0)
    # E[x^2] - E[x]^2, written as the members' variance plus the spread of their means (no cancellation)
    var = var_i.mean(0) + ((m - mean) ** 2).mean(0)
    log_std = 0.5 * torch.log(var)
    return mean.float(), log_std.clamp(LOG_STD_MIN, LOG_STD_MAX).float()


class EnsemblePoseNet(nn.Module):
    """Several :class:`vo.net.PoseNet` (either pose head) of one input shape, answering as one (see the module doc).

    ``forward(flow, intrinsics, inv_depth)`` takes what a member takes and returns ``(mean6, log_std6)``,
    float32 (B, 6), the mixture's moments. ``cfg`` is the first member's (input size, channels).
    """

    def __init__(self, members: Sequence[PoseNet]):
        super().__init__()
        members = list(members)
        if len(members) < 2:
            raise ValueError("an ensemble needs at least two members")
        first = members[0].cfg
        for k, m in enumerate(members[1:], start=1):
            if not same_input(first, m.cfg):
                raise ValueError(f"ensemble member {k} reads another input than member 0 ({input_key(m.cfg)} "
                                 f"against {input_key(first)})")
        self.members = nn.ModuleList(members)
        self.cfg = first
        self.channels_last = False

    def set_channels_last(self, on: bool = True) -> "EnsemblePoseNet":
        """Channels-last convolutions in every member (see :meth:`vo.net.PoseNet.set_channels_last`)."""
        for m in self.members:
            m.set_channels_last(on)
        self.channels_last = bool(on)
        return self

    def forward(self, flow_px: torch.Tensor, intrinsics: torch.Tensor | None = None,
                inv_depth: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        outs = [m(flow_px, intrinsics, inv_depth) for m in self.members]
        return mixture_moments(torch.stack([o[0].float() for o in outs]), torch.stack([o[1].float() for o in outs]))


def input_key(cfg) -> dict:
    """What decides whether two networks can read the same prepared input (size, scale, extra channels)."""
    d = cfg.to_dict()
    return {k: d[k] for k in ("input_height", "input_width", "flow_scale", "coord_channels", "depth_channel",
                                 "valid_channel")
            if k in d}


def same_input(a, b) -> bool:
    """True when networks with configs ``a`` and ``b`` take the same prepared input."""
    return input_key(a) == input_key(b)
