"""A compact learned optical-flow estimator, trained only on the simulator's renders (issue 12, item 1).

Architecture (PWC-Net's coarse-to-fine scheme, Sun et al. 2018, made small for 2 CPU cores): a shared
feature pyramid of grey images at 1/2 ... 1/32 of the input; at the coarsest level a cost volume
(correlation of the two images' features over +-``search_px`` feature pixels) and a small conv stack
give a flow; at each finer level the second image's features are warped by the upsampled flow, a new
cost volume is built, and the stack predicts a residual. The finest estimate (1/4 of the input) is
upsampled bilinearly. Input: grey images, resized so their width is ``work_width`` (the height keeps
the aspect and is padded to a multiple of 32); output: flow (H, W, 2) float32 px at the images' own
resolution, the project's convention ``flow[v, u] = (du, dv)`` from the first image to the second.

Training (:func:`train_flow`): pairs of rendered frames (i -> i+1 with the stored forward flow, and
i+1 -> i with the stored backward flow, so both directions are seen), random crops, horizontal flips,
and photometric augmentation (brightness, contrast, gamma shared by the pair, sometimes an exposure
change between the two, Gaussian noise per image), a
multi-scale end-point-error loss against the exact flow (robust: Charbonnier). Checkpoints every
``checkpoint_steps`` (safetensors, :mod:`vo.modelfile`), ``--resume``, step and time caps.
"""
from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
import torch.utils.data

from deepslam.core.errors import InputError

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
    import cv2

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
    """A trained :class:`FlowNet` behind the :mod:`vo.flow_estimators` interface (``name``,
    ``estimate``, ``pair_flow``).

    Args:
        path: a ``flow.safetensors`` model file (default: the shipped ``models/flow_learned.safetensors``).
        threads: torch CPU threads (0: torch's default).
    """

    def __init__(self, path: str | Path | None = None, threads: int = 0):
        if path is None:
            from deepslam.vo.models import models_dir

            path = models_dir() / "flow_learned.safetensors"
        self.model, self.meta = load_flow_model(path)
        self.threads = int(threads)
        self.name = "learned"
        from deepslam.vo.flow_estimators import GreyCache

        self._grey = GreyCache()

    @torch.inference_mode()
    def estimate(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        """Flow (H, W, 2) float32 px from ``img0`` to ``img1`` (uint8 (H, W) grey or (H, W, 3) RGB), at the
        images' own resolution: estimated at ``work_width``, upsampled from the finest level and resized
        back (:func:`vo.flow_estimators.resize_flow`)."""
        from deepslam.vo.flow_estimators import resize_flow, to_grey

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
        import copy

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
        from deepslam.vo.flow_estimators import DISFlow, GreyCache

        self.learned = LearnedFlow(path, threads=threads)
        self.dis = DISFlow("medium")
        self.name = "learned-dis"
        self._grey = GreyCache()

    def estimate(self, img0: np.ndarray, img1: np.ndarray) -> np.ndarray:
        """Flow (H, W, 2) float32 px from ``img0`` to ``img1`` (uint8 (H, W) grey or (H, W, 3) RGB)."""
        from deepslam.vo.flow_estimators import to_grey

        g0, g1 = to_grey(img0), to_grey(img1)
        start = np.ascontiguousarray(self.learned.estimate(g0, g1), dtype=np.float32)
        return self.dis.estimate(g0, g1, start=start)

    def pair_flow(self, seq, i: int, j: int) -> np.ndarray:
        return self.estimate(self._grey(seq, i), self._grey(seq, j))

    def replica(self) -> "LearnedDISFlow":
        """An estimator for another thread: the same network (:meth:`LearnedFlow.replica`), a DIS of its own,
        the decoded images shared; the same flows."""
        import copy

        twin = copy.copy(self)
        twin.learned, twin.dis = self.learned.replica(), self.dis.replica()
        return twin


def load_flow_model(path: str | Path) -> tuple[FlowNet, dict]:
    """(FlowNet in eval mode, meta) from a flow model or training checkpoint file; InputError otherwise."""
    from deepslam.vo import modelfile

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


# ---------------------------------------------------------------------------------------------------
# training


@dataclasses.dataclass(frozen=True)
class FlowTrainConfig:
    """How the flow network is trained."""

    net: FlowNetConfig = FlowNetConfig()
    """The network."""
    crop: tuple[int, int] = (128, 320)
    """Training crop (height, width) in pixels of the renders, multiples of 32."""
    batch_size: int = 8
    """Pairs per step."""
    lr: float = 1e-3
    """Adam learning rate (cosine decay to 1/20 of it over ``max_steps``)."""
    max_steps: int = 20000
    """Steps to train (the schedule's length)."""
    max_minutes: float = 0.0
    """Stop after this much training time (0: no cap); the schedule still spans ``max_steps``."""
    stop_after_steps: int = 0
    """Stop after this many steps (0: at ``max_steps``); the schedule still spans ``max_steps``. A step
    count, unlike minutes, gives the same model on every machine."""
    level_weights: tuple[float, ...] = (0.32, 0.08, 0.02, 0.01)
    """Loss weight of each estimate, finest first (PWC-Net's, per pixel of that level)."""
    seed: int = 0
    """Seed of the crops, flips and photometric draws."""
    checkpoint_steps: int = 250
    """Write a checkpoint every this many steps."""
    threads: int = 2
    """torch CPU threads."""
    device: str = "cpu"
    """Torch device to train on (``cpu``, ``cuda``, ``cuda:N``); bf16 autocast on either."""
    loader_workers: int = 0
    """Processes that build the batches ahead of the training step (0: built in the training process).
    Each step's batch is drawn from its own seed stream, so the batches (and the model) are the same
    for any count; on a GPU machine the crops and photometric draws, not the network, bound the speed."""
    init: str = ""
    """A flow model file (or training checkpoint) whose weights start the training: fine-tuning a trained
    estimator on new data (its network must be ``net``). Empty: random initialisation from ``seed``."""
    real_batch_size: int = 0
    """Real (unlabelled) pairs per step for the unsupervised loss (:mod:`vo.flow_unsup`); 0: none."""
    real_weight: float = 1.0
    """Weight of the unsupervised loss on the real pairs against the supervised one on the renders."""
    smooth_weight: float = 4.0
    """Weight of the edge-aware smoothness term inside the unsupervised loss."""
    smooth_order: int = 1
    """Order of that smoothness term: 1 (first differences) or 2 (second differences: a linearly varying
    flow, as a plane's, is free)."""

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["net"] = self.net.to_dict()
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def initial_weights(cfg: FlowTrainConfig) -> FlowNet:
    """The network ``cfg.init`` names (fine-tuning's start); InputError when the file is missing, not a
    flow model, or holds another network than ``cfg.net``."""
    start, _ = load_flow_model(cfg.init)
    if start.cfg.to_dict() != cfg.net.to_dict():
        raise InputError(cfg.init, "its network differs from the one to train; cannot start from it")
    return start


class FlowPairs:
    """Rendered frame pairs with exact flow, in memory: (grey0, grey1, flow) uint8, uint8, float16.

    Every consecutive pair (i, i+1) of each sequence gives two samples: forward with ``flow/``, and
    backward (i+1 -> i) with ``flow_backward/`` where the sequence has it. Non-finite flow (a point
    behind the next camera) is stored as NaN and left out of the loss.
    """

    def __init__(self, sequences, progress: bool = True):
        from tqdm import tqdm

        from deepslam.vo.flow_estimators import to_grey

        self.grey0, self.grey1, self.flow, self.names = [], [], [], []
        for seq in sequences:
            if seq.flow_paths is None:
                raise InputError(seq.root, "sequence has no ground-truth flow (render it with flow)")
            greys = [to_grey(seq.image(i)) for i in tqdm(range(len(seq)), desc=f"images {seq.name}", leave=False,
                                                          disable=not progress)]
            for i in range(len(seq) - 1):
                f = seq.flow(i)
                if f is not None:
                    self._add(greys[i], greys[i + 1], f, f"{seq.name}:{i}>{i + 1}")
                b = seq.flow_backward(i + 1) if seq.flow_backward_paths is not None else None
                if b is not None:
                    self._add(greys[i + 1], greys[i], b, f"{seq.name}:{i + 1}>{i}")
        if not self.flow:
            raise InputError(None, "no frame pairs with flow to train on")

    def _add(self, g0, g1, flow, name):
        self.grey0.append(g0)
        self.grey1.append(g1)
        flow = np.asarray(flow, np.float32)
        # float16 holds |x| < 65504: a larger (non-physical) flow is stored as NaN, left out of the loss
        self.flow.append(np.where(np.abs(flow) < np.finfo(np.float16).max, flow, np.nan).astype(np.float16))
        self.names.append(name)

    def __len__(self) -> int:
        return len(self.flow)

    def min_size(self) -> tuple[int, int]:
        """(height, width) of the smallest frame, pixels."""
        return min(g.shape[0] for g in self.grey0), min(g.shape[1] for g in self.grey0)

    def batch(self, rng: np.random.Generator, n: int, crop: tuple[int, int]) -> dict[str, torch.Tensor]:
        """``n`` augmented crops: img0, img1 (n, 1, h, w) float in [0, 1], flow (n, 2, h, w) px (NaN: no label)."""
        ch, cw = crop
        i0, i1, fl = [], [], []
        for k in rng.integers(0, len(self), n):
            a, b, (y, x) = crop_pair(rng, self.grey0[k], self.grey1[k], crop, "frames")
            ff = self.flow[k][y:y + ch, x:x + cw].astype(np.float32).transpose(2, 0, 1).copy()
            if rng.random() < 0.5:  # mirror: u flips sign
                a, b, ff = a[:, ::-1], b[:, ::-1], ff[:, :, ::-1]
                ff[0] = -ff[0]
            a, b = _photometric_pair(a, b, rng)
            i0.append(a)
            i1.append(b)
            fl.append(np.ascontiguousarray(ff))
        return {"img0": torch.from_numpy(np.stack(i0)[:, None]), "img1": torch.from_numpy(np.stack(i1)[:, None]),
                "flow": torch.from_numpy(np.stack(fl))}


class _StepBatch(torch.utils.data.Dataset):
    """Item ``i``: the batch of training step ``first + i``, drawn from the step's own seed stream."""

    def __init__(self, pairs, cfg: "FlowTrainConfig", first: int, last: int):
        self.pairs, self.cfg, self.first, self.last = pairs, cfg, first, last

    def __len__(self) -> int:
        return max(0, self.last - self.first)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        rng = np.random.default_rng([self.cfg.seed, self.first + i])
        return self.pairs.batch(rng, self.cfg.batch_size, self.cfg.crop)


def step_batches(pairs, cfg: "FlowTrainConfig", first: int, last: int, pin: bool = False):
    """Generator of the training batches of steps ``first`` .. ``last - 1`` in order, each from
    ``np.random.default_rng([cfg.seed, step])``: the same tensors whether ``cfg.loader_workers`` processes
    build them ahead (torch DataLoader, ``pin``: page-locked for a fast copy to the GPU) or this one does."""
    steps = _StepBatch(pairs, cfg, first, last)
    if cfg.loader_workers <= 0:
        for i in range(len(steps)):
            yield steps[i]
        return
    loader = torch.utils.data.DataLoader(steps, batch_size=None, shuffle=False, num_workers=cfg.loader_workers,
                                         pin_memory=pin, prefetch_factor=4, persistent_workers=False)
    it = iter(loader)
    try:
        yield from it
    finally:
        del it  # stops the workers when training ends before the last step (a time cap)


def crop_pair(rng: np.random.Generator, g0: np.ndarray, g1: np.ndarray, crop: tuple[int, int],
              what: str) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """The same random ``crop`` (height, width) of two grey uint8 images (H, W), as float32 in [0, 1],
    and its top-left (y, x); InputError naming ``what`` when the images are smaller than the crop."""
    ch, cw = crop
    h, w = g0.shape
    if h < ch or w < cw:
        raise InputError(None, f"{what} {h}x{w} are smaller than the crop {ch}x{cw}")
    y, x = int(rng.integers(0, h - ch + 1)), int(rng.integers(0, w - cw + 1))
    return (g0[y:y + ch, x:x + cw].astype(np.float32) / 255.0, g1[y:y + ch, x:x + cw].astype(np.float32) / 255.0,
            (y, x))


def _photometric_pair(a: np.ndarray, b: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The same brightness x[0.7, 1.3], contrast x[0.7, 1.3] and gamma [0.7, 1.5] for both images; in one
    pair of five, an extra gain x[0.9, 1.1] per image (exposure changing between frames); Gaussian
    noise std [0, 0.02] per image. (Drawing everything per image stopped the network from learning to
    match at all in its first thousands of steps.)"""
    gain, contrast, gamma = rng.uniform(0.7, 1.3), rng.uniform(0.7, 1.3), rng.uniform(0.7, 1.5)
    extra = rng.uniform(0.9, 1.1, 2) if rng.random() < 0.2 else np.ones(2)
    out = []
    for img, e in zip((a, b), extra):
        x = img * gain * e
        m = x.mean()
        x = np.clip((x - m) * contrast + m, 0.0, 1.0) ** gamma
        x = x + rng.normal(0.0, rng.uniform(0.0, 0.02), x.shape)
        out.append(np.ascontiguousarray(np.clip(x, 0.0, 1.0), dtype=np.float32))
    return out[0], out[1]


def multiscale_loss(outs: list[torch.Tensor], flow_gt: torch.Tensor, weights) -> torch.Tensor:
    """Sum over levels of weight * mean Charbonnier end-point error against the label averaged down
    to that level (its values scaled to that level's pixels); NaN labels are left out."""
    valid = torch.isfinite(flow_gt).all(1, keepdim=True).float()
    gt = torch.nan_to_num(flow_gt, nan=0.0)
    total = flow_gt.new_zeros(())
    for out, wgt in zip(reversed(outs), weights):  # finest first
        h, w = out.shape[-2:]
        s = flow_gt.shape[-1] / w
        v = F.adaptive_avg_pool2d(valid, (h, w))
        g = F.adaptive_avg_pool2d(gt * valid, (h, w)) / v.clamp_min(1e-6) / s
        epe = torch.sqrt(((out - g) ** 2).sum(1, keepdim=True) + 1e-6)
        m = (v > 0.5).float()
        total = total + wgt * (epe * m).sum() / m.sum().clamp_min(1.0) * (h * w) ** 0.5 / 16.0
    return total


def endpoint_error(pred: np.ndarray, gt: np.ndarray) -> dict:
    """EPE (mean, px) and Fl-all (KITTI 2015: share of pixels with EPE > 3 px and > 5 % of |gt|) over
    pixels with a finite label; ``pred``, ``gt`` (H, W, 2) float px."""
    ok = np.isfinite(gt).all(-1)
    e = np.linalg.norm(pred[ok] - gt[ok], axis=-1)
    mag = np.linalg.norm(gt[ok], axis=-1)
    return {"epe": float(e.mean()), "fl_all": float(np.mean((e > 3.0) & (e > 0.05 * mag))), "pixels": int(ok.sum())}


def train_flow(cfg: FlowTrainConfig, pairs: FlowPairs, out_dir: str | Path, resume: bool = False,
               progress: bool = True, meta: dict | None = None, real_pairs=None) -> Path:
    """Train, checkpointing to ``out_dir/checkpoint.safetensors``; writes ``flow.safetensors`` at the end
    (or when a cap stops it) and ``history.json``. Returns the model file's path.

    With ``real_pairs`` (a :class:`vo.flow_unsup.RealPairs`) and ``cfg.real_batch_size`` > 0, each step
    adds ``cfg.real_weight`` times the unsupervised census + smoothness loss of that many real pairs
    (drawn from their own random stream, so the supervised batches are those of a run without them)."""
    from tqdm import tqdm

    from deepslam.core import atomic
    from deepslam.core.lock import output_lock
    from deepslam.vo import modelfile

    out = Path(out_dir)
    use_real = real_pairs is not None and cfg.real_batch_size > 0
    for what, src in (("frame", pairs), ("real frame at the network's width", real_pairs if use_real else None)):
        min_size = getattr(src, "min_size", None)
        if min_size is not None and (min_size()[0] < cfg.crop[0] or min_size()[1] < cfg.crop[1]):
            raise InputError(None, f"the training crop {cfg.crop[0]}x{cfg.crop[1]} is larger than the smallest {what} "
                                   f"({min_size()[0]}x{min_size()[1]}); choose a smaller --crop")
    before = torch.get_num_threads()
    torch.set_num_threads(max(1, cfg.threads))
    with output_lock(out):
        ck = out / "checkpoint.safetensors"
        if ck.exists() and not resume:
            raise InputError(ck, "a flow training run is already here; pass --resume or choose another --out")
        if not resume and any(out.iterdir()):
            raise InputError(out, "output folder is not empty; choose another --out")
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(cfg.seed)
            model = FlowNet(cfg.net)
        if cfg.init and not (resume and ck.is_file()):
            model.load_state_dict(initial_weights(cfg).state_dict())
        dev = torch.device(cfg.device)
        model = model.to(dev)
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.max_steps, eta_min=cfg.lr / 20)
        state = {"step": 0, "seconds": 0.0, "history": []}
        if resume and ck.is_file():
            _, d = modelfile.load(ck, (CHECKPOINT_FORMAT,))
            if d["config"] != json.loads(json.dumps(cfg.to_dict())):
                diff = sorted(k for k in d["config"] if d["config"][k] != cfg.to_dict().get(k))
                if any(k not in ("max_minutes", "threads", "stop_after_steps", "device", "loader_workers") for k in diff):
                    raise InputError(ck, f"cannot resume: settings differ ({', '.join(diff)})")
            started = (d.get("meta") or {}).get("init_sha256")
            if cfg.init and started and started != (meta or {}).get("init_sha256", started):
                raise InputError(cfg.init, "differs from the flow model this run started from (sha256); cannot resume")
            model.load_state_dict({k: v.to(dev) for k, v in d["state_dict"].items()})
            opt.load_state_dict(d["optimizer"])
            sched.load_state_dict(d["scheduler"])
            state = d["state"]
        atomic.write_json(out / "config.json", {"train": cfg.to_dict(), "meta": meta or {}, "pairs": len(pairs)})

        def save(kind: str, path: Path) -> None:
            tree = {"net": cfg.net.to_dict(), "state_dict": model.state_dict(), "meta": {**(meta or {}), "train": cfg.to_dict(),
                    "steps": state["step"], "train_seconds": state["seconds"]}}
            if kind == CHECKPOINT_FORMAT:
                tree.update(config=cfg.to_dict(), optimizer=opt.state_dict(), scheduler=sched.state_dict(), state=state)
            modelfile.save(path, kind, tree)
            atomic.write_json(out / "history.json", state["history"])

        limit = cfg.max_minutes * 60 if cfg.max_minutes > 0 else math.inf
        bar = tqdm(total=cfg.max_steps, initial=state["step"], desc="flow training", unit="step", disable=not progress,
                   dynamic_ncols=True)
        t_start = time.perf_counter() - state["seconds"]
        run_loss, run_n, run_census = 0.0, 0, 0.0
        if use_real:
            from deepslam.vo.flow_unsup import unsupervised_loss
        model.train()
        last = cfg.stop_after_steps if 0 < cfg.stop_after_steps < cfg.max_steps else cfg.max_steps
        batches = step_batches(pairs, cfg, state["step"], last, pin=dev.type == "cuda")
        while state["step"] < last and time.perf_counter() - t_start < limit:
            b = next(batches)
            if dev.type != "cpu":
                b = {k: v.pin_memory().to(dev, non_blocking=True) for k, v in b.items()}
            with torch.autocast(dev.type, dtype=torch.bfloat16):
                outs = model(b["img0"], b["img1"])
            loss = multiscale_loss([o.float() for o in outs], b["flow"], cfg.level_weights)
            if use_real:
                rb = real_pairs.batch(np.random.default_rng([cfg.seed, state["step"], 1]), cfg.real_batch_size, cfg.crop)
                if dev.type != "cpu":
                    rb = {k: v.to(dev) for k, v in rb.items()}
                uloss, parts = unsupervised_loss(model, rb["img0"], rb["img1"], rb["aug0"], rb["aug1"],
                                                 cfg.smooth_weight, dev.type, cfg.smooth_order)
                run_census += parts["census"]
                loss = loss + cfg.real_weight * uloss
            if not torch.isfinite(loss):
                raise RuntimeError(f"non-finite flow loss at step {state['step']}")
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
            opt.step()
            sched.step()
            state["step"] += 1
            state["seconds"] = time.perf_counter() - t_start
            run_loss += float(loss.detach())
            run_n += 1
            bar.update(1)
            if state["step"] % 50 == 0:
                bar.set_postfix(loss=f"{run_loss / run_n:.3g}")
            if state["step"] % cfg.checkpoint_steps == 0:
                entry = {"step": state["step"], "loss": run_loss / max(run_n, 1), "seconds": state["seconds"]}
                if use_real:
                    entry["real_census"] = run_census / max(run_n, 1)
                state["history"].append(entry)
                run_loss, run_n, run_census = 0.0, 0, 0.0
                save(CHECKPOINT_FORMAT, ck)
        bar.close()
        batches.close()
        save(CHECKPOINT_FORMAT, ck)
        model_path = out / "flow.safetensors"
        model.eval()
        save(MODEL_FORMAT, model_path)
    torch.set_num_threads(before)
    return model_path
