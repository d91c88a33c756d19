"""A compact learned optical-flow estimator, trained only on the simulator's renders (training: :mod:`deepslam.flow.train`).

Architecture (PWC-Net's coarse-to-fine scheme, Sun et al. 2018, made small for 2 CPU cores): a shared
feature pyramid of grey images at 1/2 ... 1/32 of the input; at the coarsest level a cost volume
(correlation of the two images' features over +-``search_px`` feature pixels) and a small conv stack
give a flow; at each finer level the second image's features are warped by the upsampled flow, a new
cost volume is built, and the stack predicts a residual. The finest estimate (1/4 of the input) is
upsampled bilinearly. Input: grey images, resized so their width is ``work_width`` (the height keeps
the aspect and is padded to a multiple of 32); output: flow (H, W, 2) float32 px at the images' own
resolution, the project's convention ``flow[v, u] = (du, dv)`` from the first image to the second.
"""
from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from deepslam.core.errors import InputError
from deepslam.flow.estimators import DISFlow, resize_flow
from deepslam.flow.images import GreyCache, to_grey
from deepslam.models import modelfile, models_dir

MODEL_FORMAT = "deepslam-flow-model"
CHECKPOINT_FORMAT = "deepslam-flow-checkpoint"


@dataclasses.dataclass(frozen=True)
class FlowNetConfig:
    """The flow network's shape."""

    channels: tuple[int, ...] = (16, 32, 48, 64, 96)
    """Feature channels at 1/2, 1/4, 1/8, 1/16, 1/32 of the input."""
    search_px: int = 3
    """Cost-volume search radius in feature pixels at every level ((2r+1)^2 correlation channels)."""
    estimator_channels: tuple[int, ...] = (64, 48, 32)
    """Hidden channels of each level's flow estimator."""
    finest_level: int = 2
    """Finest level with an estimate: 1 = 1/2, 2 = 1/4 of the input (then upsampled)."""
    work_width: int = 640
    """Images are resized to this width for the network (the height keeps the aspect)."""

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> "FlowNetConfig":
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1), nn.LeakyReLU(0.1, inplace=True))


def correlation(f1: torch.Tensor, f2: torch.Tensor, radius: int) -> torch.Tensor:
    """(B, (2r+1)^2, H, W): the cosine similarity of each pixel's feature vector in ``f1`` with those of
    ``f2`` shifted by (dx, dy) in [-r, r]^2 (0 outside). Features are normalised per pixel first, so the
    cost volume keeps its scale however deep the pyramid (an unnormalised dot product of deep features
    starts near 0, and the network then barely learns)."""
    b, c, h, w = f1.shape
    a = F.normalize(f1, dim=1, eps=1e-6)
    pad = F.pad(F.normalize(f2, dim=1, eps=1e-6), (radius, radius, radius, radius))
    out = []
    for dy in range(2 * radius + 1):
        for dx in range(2 * radius + 1):
            out.append((a * pad[:, :, dy:dy + h, dx:dx + w]).sum(1, keepdim=True))
    return torch.cat(out, 1)


def warp(x: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """``x`` (B, C, H, W) sampled at pixel + flow (B, 2, H, W) px, bilinear, zeros outside."""
    b, _, h, w = x.shape
    gy, gx = torch.meshgrid(torch.arange(h, dtype=x.dtype, device=x.device),
                            torch.arange(w, dtype=x.dtype, device=x.device), indexing="ij")
    u = (gx + flow[:, 0]) * (2.0 / max(w - 1, 1)) - 1.0
    v = (gy + flow[:, 1]) * (2.0 / max(h - 1, 1)) - 1.0
    return F.grid_sample(x, torch.stack([u, v], -1), mode="bilinear", padding_mode="zeros", align_corners=True)


class FlowNet(nn.Module):
    """See the module docstring. ``forward(img0, img1)`` with (B, 1, H, W) float images in [0, 1] (H, W
    multiples of 32) returns the flow estimates (B, 2, H / 2^l, W / 2^l) in pixels of that level, finest
    last."""

    def __init__(self, cfg: FlowNetConfig = FlowNetConfig()):
        super().__init__()
        self.cfg = cfg
        ch = (1,) + tuple(cfg.channels)
        self.pyramid = nn.ModuleList([nn.Sequential(_conv(ch[i], ch[i + 1], 2), _conv(ch[i + 1], ch[i + 1]))
                                      for i in range(len(cfg.channels))])
        n_corr = (2 * cfg.search_px + 1) ** 2
        self.estimators = nn.ModuleList()
        for lvl in range(len(cfg.channels), cfg.finest_level - 1, -1):
            cin = n_corr + cfg.channels[lvl - 1] + (0 if lvl == len(cfg.channels) else 2)
            layers, c = [], cin
            for e in cfg.estimator_channels:
                layers.append(_conv(c, e))
                c = e
            layers.append(nn.Conv2d(c, 2, 3, 1, 1))
            self.estimators.append(nn.Sequential(*layers))

    def features(self, img: torch.Tensor) -> list[torch.Tensor]:
        out, x = [], img
        for stage in self.pyramid:
            x = stage(x)
            out.append(x)
        return out  # level 1 (1/2) first

    def forward(self, img0: torch.Tensor, img1: torch.Tensor) -> list[torch.Tensor]:
        f0, f1 = self.features(img0), self.features(img1)
        n = len(self.cfg.channels)
        flow, outs = None, []
        for k, lvl in enumerate(range(n, self.cfg.finest_level - 1, -1)):
            a, b = f0[lvl - 1], f1[lvl - 1]
            if flow is None:
                x = torch.cat([correlation(a, b, self.cfg.search_px), a], 1)
                flow = self.estimators[k](x)
            else:
                flow = 2.0 * F.interpolate(flow, size=a.shape[-2:], mode="bilinear", align_corners=False)
                x = torch.cat([correlation(a, warp(b, flow), self.cfg.search_px), a, flow], 1)
                flow = flow + self.estimators[k](x)
            outs.append(flow)
        return outs


def resize_to_width(grey: np.ndarray, width: int) -> np.ndarray:
    """A grey uint8 image (H, W) resized to ``width`` px, its height keeping the aspect (at least 32 px):
    what the network is given (area averaging when shrinking, bilinear when enlarging)."""
    h0, w0 = grey.shape
    h = max(32, int(round(h0 * width / w0)))
    return cv2.resize(grey, (width, h), interpolation=cv2.INTER_AREA if width < w0 else cv2.INTER_LINEAR)


def upsample_flow(flow: torch.Tensor, factor: int) -> torch.Tensor:
    """A flow estimate (B, 2, h, w) in px of its level, bilinearly upsampled by ``factor`` and scaled to
    px of the finer grid: (B, 2, h * factor, w * factor)."""
    return factor * F.interpolate(flow, scale_factor=factor, mode="bilinear", align_corners=False)


def _prepare(grey: np.ndarray, width: int) -> tuple[torch.Tensor, int, int]:
    """A grey uint8 image (H, W) resized to ``width`` and zero-padded to multiples of 32: (1, 1, Hp, Wp)
    float32 in [0, 1], and the resized (h, w) before padding."""
    img = resize_to_width(grey, width)
    h = img.shape[0]
    hp, wp = -(-h // 32) * 32, -(-width // 32) * 32
    t = torch.zeros(1, 1, hp, wp)
    t[0, 0, :h, :width] = torch.from_numpy(img.astype(np.float32) / 255.0)
    return t, h, width


class LearnedFlow:
    """A trained :class:`FlowNet` behind the :mod:`flow.estimators` interface (``name``,
    ``estimate``, ``pair_flow``).

    Args:
        path: a ``flow.safetensors`` model file (default: the shipped ``models/flow_learned.safetensors``).
        threads: torch CPU threads (0: torch's default).
    """

    def __init__(self, path: str | Path | None = None, threads: int = 0):
        if path is None:
            path = models_dir() / "flow_learned.safetensors"
        self.model, self.meta = load_flow_model(path)
        self.threads = int(threads)
        self.name = "learned"

        self._grey = GreyCache()

    @torch.inference_mode()
    def estimate(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        """Flow (H, W, 2) float32 px from ``img0`` to ``img1`` (uint8 (H, W) grey or (H, W, 3) RGB), at the
        images' own resolution: estimated at ``work_width``, upsampled from the finest level and resized
        back (:func:`flow.estimators.resize_flow`)."""
        g0, g1 = to_grey(img0), to_grey(img1)
        if g0.shape != g1.shape:
            raise ValueError(f"images differ in size: {g0.shape} vs {g1.shape}")
        before = torch.get_num_threads() if self.threads > 0 else None  # 0: torch's setting left alone
        if before is not None:
            torch.set_num_threads(self.threads)
        try:
            t0, h, w = _prepare(g0, self.model.cfg.work_width)
            t1 = _prepare(g1, self.model.cfg.work_width)[0]
            up = upsample_flow(self.model(t0, t1)[-1], 2 ** self.model.cfg.finest_level)
        finally:
            if before is not None:
                torch.set_num_threads(before)
        work = up[0, :, :h, :w].permute(1, 2, 0).numpy()
        return resize_flow(work, g0.shape[1], g0.shape[0])

    def pair_flow(self, seq, i: int, j: int) -> np.ndarray:
        return self.estimate(self._grey(seq, i), self._grey(seq, j))

    def replica(self) -> "LearnedFlow":
        """An estimator on the same network (shared, not copied: its forward pass keeps no state) for
        another thread, sharing the decoded images. It leaves torch's thread count as it is (``threads``
        0: that setting is process-wide, and replicas setting and restoring it in turn would race). On 2 cores two of them do 1.4x the pairs a second of one
        (KITTI 07: 33 against 46 ms a pair)."""
        twin = copy.copy(self)  # a shallow copy: the same model object and image cache; a subclass stays its class
        twin.threads = 0
        return twin


class LearnedDISFlow:
    """The learned flow as the starting point of OpenCV's DIS (``--flow learned-dis``).

    DIS (coarse-to-fine patch search, then variational refinement) loses large displacements on real
    roads, where the network trained on renders with exact flow holds them but is not sub-pixel on real
    texture. Here the network's flow (:class:`LearnedFlow`, at the images' resolution) is the flow DIS
    starts from at its coarsest level (a flow passed to ``cv2.DISOpticalFlow.calc``), and DIS medium
    refines it at every finer level. Measured (``bench.results_flow``, README: Learned flow): on held-out
    renders and on real KITTI consistency at least as good as DIS, at about 2.5x DIS's time.

    Args:
        path: the learned flow model file (default: the shipped ``models/flow_learned.safetensors``).
        threads: torch CPU threads for the network (0: torch's default).
    """

    def __init__(self, path: str | Path | None = None, threads: int = 0):
        self.learned = LearnedFlow(path, threads=threads)
        self.dis = DISFlow("medium")
        self.name = "learned-dis"
        self._grey = GreyCache()

    def estimate(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        """Flow (H, W, 2) float32 px from ``img0`` to ``img1`` (uint8 (H, W) grey or (H, W, 3) RGB)."""
        g0, g1 = to_grey(img0), to_grey(img1)
        start = np.ascontiguousarray(self.learned.estimate(g0, g1), dtype=np.float32)
        return self.dis.estimate(g0, g1, start=start)

    def pair_flow(self, seq, i: int, j: int) -> np.ndarray:
        return self.estimate(self._grey(seq, i), self._grey(seq, j))

    def replica(self) -> "LearnedDISFlow":
        """An estimator for another thread: the same network (:meth:`LearnedFlow.replica`), a DIS of its own,
        the decoded images shared; the same flows."""
        twin = copy.copy(self)
        twin.learned, twin.dis = self.learned.replica(), self.dis.replica()
        return twin


def load_flow_model(path: str | Path) -> tuple[FlowNet, dict]:
    """(FlowNet in eval mode, meta) from a flow model or training checkpoint file; InputError otherwise."""
    path = Path(path)
    kind, d = modelfile.load(path, (MODEL_FORMAT, CHECKPOINT_FORMAT))
    try:
        cfg = FlowNetConfig.from_dict(d["net"])
        sd = d["state_dict"]
        model = FlowNet(cfg)
        model.load_state_dict({k: v.float() for k, v in sd.items()})
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        raise InputError(path, f"malformed flow model ({type(e).__name__}: {e})") from None
    return model.eval(), d.get("meta", {})
