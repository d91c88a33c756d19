"""The paper's flow -> 6DoF network with per-DoF uncertainty (Slinko et al., 2019, Sec. 3.2).

Architecture (defaults = the paper): six convolutions of 64 filters, kernels 7, 5, 3, 3, 3, 3,
strides 2, 1, 4, 1, 2, 1, each followed by ReLU ("same" padding k // 2); flatten; two branches,
rotation and translation, each two fully connected layers of 500 units with ReLU and a linear output
of 3: euler x, y, z (radians) and t x, y, z (metres) of ``cam_{t+k}_from_cam_t``. At 96 x 320 the
convolutions give 64 x 6 x 20 features. Each branch also has a linear log-std head (3 outputs) on its
last hidden layer, trained in a second stage with the Gaussian negative log-likelihood while
everything else is frozen (:mod:`vo.train`).

Input normalisation (the paper's): the flow in pixels at the network's resolution is divided by the
image size, ``du / W`` and ``dv / H``, so a flow field means the same thing at any resolution; it is
then multiplied by ``NetConfig.flow_scale`` (1.0 = exactly the paper). With
``NetConfig.coord_channels`` two more channels hold each pixel's normalised image coordinates
``(u - cx) / fx`` and ``(v - cy) / fy`` (intrinsics at network resolution), which tell the network
the camera's field of view so that one model can serve several cameras. With
``NetConfig.depth_channel`` one more channel holds the first frame's inverse depth ``1 / depth_z``
(1/m, 0 where unknown; area-averaged to the network resolution, :func:`inverse_depth_input`): for
RGB-D cameras, renders and stereo, where the depth of the frame is known at test time. Flow alone
fixes a translation only up to the scene's scale; with the inverse depth the translation's flow
``f t / depth_z`` is read in metres. With ``NetConfig.valid_channel`` a last channel is 1 where the
flow is known and 0 where it is not (the input holds NaN there: DIS's textureless pixels left out,
depth holes), and the flow is averaged over known pixels only when it is resized to the network's
resolution; without it unknown flow reads as 0, indistinguishable from no motion, and a network pixel
that covers both is their average.
"""
from __future__ import annotations

import dataclasses
import json
import math

import cv2
import numpy as np
import torch
from torch import nn

from deepslam.core.errors import InputError
from deepslam.flow.estimators import unknown_flow


LOG_STD_MIN = -12.0
"""Lower clamp of a predicted log-std (std >= 6e-6 in radians or metres)."""
LOG_STD_MAX = 6.0
"""Upper clamp of a predicted log-std."""


POSE_HEADS = ("regress", "solve")
"""The values of :attr:`NetConfig.pose_head`."""


@dataclasses.dataclass(frozen=True)
class NetConfig:
    """Shape of the network. The defaults are the paper's; shrink them to train on a CPU."""

    input_height: int = 96
    """Rows of the input flow (network resolution), pixels."""
    input_width: int = 320
    """Columns of the input flow, pixels."""
    filters: int = 64
    """Filters of every convolution."""
    kernels: tuple[int, ...] = (7, 5, 3, 3, 3, 3)
    """Kernel size of each convolution; its length is the number of conv layers (the depth)."""
    strides: tuple[int, ...] = (2, 1, 4, 1, 2, 1)
    """Stride of each convolution (same length as ``kernels``)."""
    hidden_units: int = 500
    """Units of each fully connected layer of the two branches."""
    hidden_layers: int = 2
    """Fully connected hidden layers per branch."""
    coord_channels: bool = False
    """Add the normalised pixel coordinates (u - cx)/fx, (v - cy)/fy as two input channels."""
    depth_channel: bool = False
    """Add the first frame's inverse depth (1/m, 0 = unknown) as an input channel (RGB-D, renders, stereo)."""
    flow_scale: float = 1.0
    """Multiplier applied after the paper's normalisation flow / (W, H) (1.0 = the paper)."""
    valid_channel: bool = False
    """Add a channel that is 1 where the flow is known and 0 where it is not (NaN in the input: DIS's
    textureless pixels, no depth); such a network's flow is resized over known pixels only
    (:func:`flow.estimators.resize_flow` with ``unknown="nan"``). False: unknown flow reads as 0."""
    pose_head: str = "regress"
    """How the pose is read: ``regress`` (the paper: convolutions, fully connected branches, a linear
    output) or ``solve`` (:mod:`vo.geometry.posesolve`: a convolutional network weighs each pixel and the pose is
    the weighted Gauss-Newton fit of the flow with the first frame's depth; needs ``depth_channel`` and
    ``valid_channel``; ``kernels``, ``strides`` and the hidden sizes are then unused)."""
    solve_iterations: int = 3
    """Gauss-Newton steps of the ``solve`` head (the first is the linear motion-field solve)."""
    solve_robust: str = "none"
    """Kernel of the ``solve`` head's residuals: ``none`` (weighted least squares) or ``cauchy``
    (iteratively reweighted from the second step on, scale from the residuals' median: see
    :func:`vo.geometry.posesolve.solve_pose`). A model file without this field reads as ``none``."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "kernels", tuple(int(k) for k in self.kernels))
        object.__setattr__(self, "strides", tuple(int(s) for s in self.strides))
        if len(self.kernels) != len(self.strides) or not self.kernels:
            raise ValueError(f"kernels {self.kernels} and strides {self.strides} must be equally long and not empty")
        for name, most in (("input_height", 2048), ("input_width", 2048), ("filters", 1024), ("hidden_units", 8192),
                           ("hidden_layers", 16)):
            if not 1 <= int(getattr(self, name)) <= most:
                raise ValueError(f"{name} must be in 1..{most}, got {getattr(self, name)}")
        if not (math.isfinite(self.flow_scale) and self.flow_scale > 0):
            raise ValueError(f"flow_scale must be a positive number, got {self.flow_scale}")
        if self.pose_head not in POSE_HEADS:
            raise ValueError(f"pose_head must be one of {', '.join(POSE_HEADS)}, got {self.pose_head!r}")
        if self.pose_head == "solve" and not (self.depth_channel and self.valid_channel):
            raise ValueError("the solve pose head needs the depth channel and the validity channel "
                             "(--depth-channel --valid-channel): it fits the flow with the frame's depth where both are known")
        if not 1 <= int(self.solve_iterations) <= 20:
            raise ValueError(f"solve_iterations must be in 1..20, got {self.solve_iterations}")
        if self.solve_robust not in ("none", "cauchy"):
            raise ValueError(f"solve_robust must be none or cauchy, got {self.solve_robust!r}")

    @property
    def in_channels(self) -> int:
        return 2 + 2 * bool(self.coord_channels) + bool(self.depth_channel) + bool(self.valid_channel)

    @property
    def unknown_flow(self) -> str:
        """How this network's input flow is resized where the flow is unknown
        (:data:`flow.estimators.UNKNOWN_FLOW`): ``nan`` with a validity channel, else ``zero``."""
        return unknown_flow(self.valid_channel)

    def feature_shape(self) -> tuple[int, int, int]:
        """(channels, rows, columns) after the convolutions."""
        h, w = self.input_height, self.input_width
        for k, s in zip(self.kernels, self.strides):
            p = k // 2
            h = (h + 2 * p - k) // s + 1
            w = (w + 2 * p - k) // s + 1
        return self.filters, h, w

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["kernels"], d["strides"] = list(self.kernels), list(self.strides)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "NetConfig":
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown NetConfig fields: {sorted(unknown)}")
        return cls(**d)

    def __str__(self) -> str:
        return json.dumps(self.to_dict())


PAPER = NetConfig()
"""The paper's configuration (96 x 320 input, 64 filters, 500 hidden units)."""


NET_PRESETS = {
    "paper": {},
    "cpu": {"input_height": 48, "input_width": 160, "filters": 32, "hidden_units": 256, "flow_scale": 10.0},
    "tiny": {"input_height": 24, "input_width": 80, "filters": 16, "hidden_units": 64, "flow_scale": 10.0},
}
"""Network presets (``deepslam train --net``): ``paper`` = the paper's (96 x 320, 64 filters, 500 units); ``cpu``
trains in minutes on two cores; ``tiny`` is for tests and smoke runs."""


def preset_config(preset: str, **overrides) -> NetConfig:
    """:class:`NetConfig` of preset ``preset`` (:data:`NET_PRESETS`) with each override that is not None
    (``NetConfig`` field names). InputError for settings the network cannot take."""
    d = {**NET_PRESETS[preset], **{k: v for k, v in overrides.items() if v is not None}}
    try:
        return NetConfig(**d)
    except ValueError as e:
        raise InputError(None, f"bad network settings: {e}") from None


def _branch(n_in: int, cfg: NetConfig) -> nn.Sequential:
    layers: list[nn.Module] = []
    for _ in range(cfg.hidden_layers):
        layers += [nn.Linear(n_in, cfg.hidden_units), nn.ReLU(inplace=True)]
        n_in = cfg.hidden_units
    return nn.Sequential(*layers)


class PoseNet(nn.Module):
    """What both pose heads share (:class:`FlowPoseNet`, :class:`vo.geometry.posesolve.FlowSolvePoseNet`): the
    input tensor (:func:`network_input`), the split of the parameters between the two training stages
    (the log-std heads ``rot_log_std`` and ``trans_log_std`` against the rest), the memory format, and
    ``forward = (mean_head, log_std_head) of trunk``."""

    cfg: NetConfig

    def uncertainty_parameters(self) -> list[nn.Parameter]:
        """The log-std heads' parameters (trained in the second stage)."""
        return [*self.rot_log_std.parameters(), *self.trans_log_std.parameters()]

    def motion_parameters(self) -> list[nn.Parameter]:
        """Everything but the log-std heads (trained in the first stage, frozen in the second)."""
        unc = {id(p) for p in self.uncertainty_parameters()}
        return [p for p in self.parameters() if id(p) not in unc]

    def prepare_input(self, flow_px: torch.Tensor, intrinsics: torch.Tensor | None = None,
                      inv_depth: torch.Tensor | None = None) -> torch.Tensor:
        """The tensor the convolutions see: :func:`network_input`."""
        return network_input(self, flow_px, intrinsics, inv_depth)

    def set_channels_last(self, on: bool = True) -> "PoseNet":
        """Store the convolution weights (and feed inputs) channels-last (NHWC); faster on some CPUs."""
        self.channels_last = bool(on)
        return self.to(memory_format=torch.channels_last if on else torch.contiguous_format)

    def forward(self, flow_px: torch.Tensor, intrinsics: torch.Tensor | None = None,
                inv_depth: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        hr, ht = self.trunk(flow_px, intrinsics, inv_depth)
        return self.mean_head(hr, ht), self.log_std_head(hr, ht)


class FlowPoseNet(PoseNet):
    """Flow (B, 2, h, w) px at network resolution + intrinsics (B, 4) -> 6DoF mean and log-std.

    ``forward`` returns ``(mean6, log_std6)``, both float32 (B, 6): the paper's vector
    (euler x, y, z in radians, t x, y, z in metres) of ``cam_{t+k}_from_cam_t`` and the natural log
    of its per-DoF standard deviation (clamped to [LOG_STD_MIN, LOG_STD_MAX]).
    """

    def __init__(self, cfg: NetConfig = PAPER):
        super().__init__()
        self.cfg = cfg
        convs: list[nn.Module] = []
        c = cfg.in_channels
        for k, s in zip(cfg.kernels, cfg.strides):
            convs += [nn.Conv2d(c, cfg.filters, k, stride=s, padding=k // 2), nn.ReLU(inplace=True)]
            c = cfg.filters
        self.conv = nn.Sequential(*convs)
        fc, fh, fw = cfg.feature_shape()
        n_feat = fc * fh * fw
        self.rot_fc = _branch(n_feat, cfg)
        self.trans_fc = _branch(n_feat, cfg)
        self.rot_mean = nn.Linear(cfg.hidden_units, 3)
        self.trans_mean = nn.Linear(cfg.hidden_units, 3)
        self.rot_log_std = nn.Linear(cfg.hidden_units, 3)
        self.trans_log_std = nn.Linear(cfg.hidden_units, 3)
        for head in (self.rot_log_std, self.trans_log_std):
            nn.init.zeros_(head.weight)
            nn.init.zeros_(head.bias)
        register_input_buffers(self, cfg)

    @torch.no_grad()
    def calibrate_log_std(self, ht: torch.Tensor, rmse: torch.Tensor) -> None:
        """Start stage 2 from a calibrated constant: log-std heads' weights 0, biases log(``rmse``) (6,)
        (the held-out RMSE per DoF; ``ht``, the trunk's translation features, is not needed here)."""
        for head, part in ((self.rot_log_std, rmse[:3]), (self.trans_log_std, rmse[3:])):
            head.weight.zero_()
            head.bias.copy_(part.log())

    def trunk(self, flow_px: torch.Tensor, intrinsics: torch.Tensor | None = None,
              inv_depth: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The hidden features the heads read: (rotation branch (B, hidden_units), translation branch
        (B, hidden_units)), float32. Everything but the four output layers."""
        x = self.conv(self.prepare_input(flow_px, intrinsics, inv_depth))
        x = torch.flatten(x, 1)
        return self.rot_fc(x).float(), self.trans_fc(x).float()

    def mean_head(self, hr: torch.Tensor, ht: torch.Tensor) -> torch.Tensor:
        """(B, 6) mean from the trunk's features (float32, outside any autocast)."""
        # the output layers always run in float32 (under bf16 autocast too): tiny, and a bf16 output
        # would round a 1 m translation to 4 mm steps
        with torch.autocast(hr.device.type, enabled=False):
            return torch.cat([self.rot_mean(hr), self.trans_mean(ht)], dim=1)

    def log_std_head(self, hr: torch.Tensor, ht: torch.Tensor) -> torch.Tensor:
        """(B, 6) log-std from the trunk's features, clamped to [LOG_STD_MIN, LOG_STD_MAX] (float32)."""
        with torch.autocast(hr.device.type, enabled=False):
            log_std = torch.cat([self.rot_log_std(hr), self.trans_log_std(ht)], dim=1)
        return log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)


def register_input_buffers(net: nn.Module, cfg: NetConfig) -> None:
    """What :func:`network_input` reads from a network: ``_inv_size`` (1, 2, 1, 1) float32
    ``flow_scale / (W, H)`` and ``_grid_uv`` (1, 2, h, w) float32 pixel coordinates at network
    resolution (buffers, not saved), and ``channels_last`` (False).

    The buffers are made on the CPU under any device context (``.to`` moves them with the network): under
    ``torch.device("meta")``, where :func:`vo.modelfiles.modelio.load_model` checks a file's shapes, these few ops would run
    through torch's Python meta kernels, whose first use imports ``torch._dynamo`` (seconds a process)."""
    cpu = torch.device("cpu")
    size = torch.tensor([cfg.input_width, cfg.input_height], dtype=torch.float32, device=cpu).view(1, 2, 1, 1)
    net.register_buffer("_inv_size", cfg.flow_scale / size, persistent=False)
    v, u = torch.meshgrid(torch.arange(cfg.input_height, dtype=torch.float32, device=cpu),
                          torch.arange(cfg.input_width, dtype=torch.float32, device=cpu), indexing="ij")
    net.register_buffer("_grid_uv", torch.stack([u, v])[None], persistent=False)
    net.channels_last = False


def network_input(net: nn.Module, flow_px: torch.Tensor, intrinsics: torch.Tensor | None = None,
                  inv_depth: torch.Tensor | None = None) -> torch.Tensor:
    """The tensor a network's convolutions see: (B, in_channels, h, w) float32 (see the module docstring).
    ``net``: a :class:`PoseNet` of either head (its ``cfg``, its
    ``_inv_size`` and ``_grid_uv`` buffers, ``channels_last``); ``flow_px``: (B, 2, h, w) px, NaN where
    unknown; ``intrinsics``: (B, 4) fx, fy, cx, cy px at network resolution (needed with
    ``coord_channels``); ``inv_depth``: (B, 1, h, w) float32 1/m of the first frame (needed with
    ``depth_channel``)."""
    cfg = net.cfg
    if flow_px.shape[1:] != (2, cfg.input_height, cfg.input_width):
        raise ValueError(f"flow must be (B, 2, {cfg.input_height}, {cfg.input_width}), got {tuple(flow_px.shape)}")
    flow_px = flow_px.float()
    known = torch.isfinite(flow_px).all(dim=1, keepdim=True)
    flow_px = torch.where(known, flow_px, 0.0)  # unknown flow reads as 0 (and, with valid_channel, is marked)
    x = flow_px * net._inv_size
    if cfg.coord_channels:
        if intrinsics is None:
            raise ValueError("this network needs the intrinsics (coord_channels=True)")
        k = intrinsics.to(x.dtype).view(-1, 4, 1, 1)
        cu = (net._grid_uv[:, 0:1] - k[:, 2:3]) / k[:, 0:1]
        cv = (net._grid_uv[:, 1:2] - k[:, 3:4]) / k[:, 1:2]
        x = torch.cat([x, cu, cv], dim=1)
    if cfg.depth_channel:
        if inv_depth is None:
            raise ValueError("this network needs the first frame's inverse depth (depth_channel=True)")
        if inv_depth.shape != (len(x), 1, cfg.input_height, cfg.input_width):
            raise ValueError(f"inverse depth must be (B, 1, {cfg.input_height}, {cfg.input_width}), "
                             f"got {tuple(inv_depth.shape)}")
        x = torch.cat([x, inv_depth.to(x.dtype)], dim=1)
    if cfg.valid_channel:
        x = torch.cat([x, known.to(x.dtype)], dim=1)
    return x.contiguous(memory_format=torch.channels_last) if net.channels_last else x


POSE_LOSSES = ("l1", "mse")
"""The first-stage losses :func:`pose_loss` knows."""


def pose_loss(mean: torch.Tensor, target: torch.Tensor, rot_weight: float = 50.0, kind: str = "l1") -> torch.Tensor:
    """The first-stage loss: ``rot_weight * E(euler) + E(translation)`` (scalar), E the mean over batch
    and the three DoF of the absolute error (``kind="l1"``, the paper's published code: each output's
    mean absolute error, rotations weighted 50) or of the squared error (``kind="mse"``).

    mean, target: (B, 6) float (euler x, y, z in radians; t x, y, z in metres).
    """
    err = mean.float() - target.float()
    if kind == "l1":
        err = err.abs()
    elif kind == "mse":
        err = err * err
    else:
        raise ValueError(f"loss must be one of {', '.join(POSE_LOSSES)}, got {kind!r}")
    return rot_weight * err[:, :3].mean() + err[:, 3:].mean()


def gaussian_nll(mean: torch.Tensor, log_std: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean over batch and DoF of ``0.5 ((y - mu) / sigma)^2 + log sigma`` (the constant dropped)."""
    z = (target.float() - mean.float()) * torch.exp(-log_std.float())
    return (0.5 * z * z + log_std.float()).mean()


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def inverse_depth_input(depth_z, width: int, height: int):
    """The network's depth channel for one frame: (1, height, width) float32 ``1 / depth_z`` in 1/m,
    0 where the depth is unknown (0, negative, NaN, inf), area-averaged from ``depth_z`` (H, W) float
    metres of any size (numpy) to the network resolution."""
    d = np.asarray(depth_z, dtype=np.float32)
    ok = np.isfinite(d) & (d > 0)
    inv = np.zeros(d.shape, np.float32)
    np.divide(1.0, d, out=inv, where=ok)
    if inv.shape != (height, width):
        inv = cv2.resize(inv, (width, height), interpolation=cv2.INTER_AREA)
    return inv[None]
