"""Training samples of the flow -> 6DoF network as tensors, and the per-epoch seeds of every source.

A *source* yields batches ``{"flow": (B, 2, h, w) float32 px at network resolution,
"intrinsics": (B, 4) float32 fx, fy, cx, cy at network resolution, "target": (B, 6) float32 paper
vector of cam_{t+k}_from_cam_t}`` (and, for a network with a depth channel, ``"inv_depth": (B, 1, h, w)
float32`` 1/m of the first frame, :func:`vo.net.inverse_depth_input`) through ``batches(epoch, batch_size)``; the
same epoch gives the same batches (seeded from the source's seed and the epoch number by :func:`epoch_seed`,
never a global RNG), which is what makes ``--resume`` reproduce an uninterrupted run bit for bit.

Here: :class:`TensorSamples` (samples held in memory: supervised pairs, a fixed validation set, shards of
``deepslam gen`` via :func:`shard_samples`), shuffled per epoch. The other sources: :mod:`vo.data.synthetic`
(flow made on the fly from single frames, :mod:`vo.data.frames`, and motions, :mod:`vo.data.motion`),
:mod:`vo.data.supervised` (flow between real frames + ground-truth poses) and :mod:`vo.data.toy` (plane flows).
"""
from __future__ import annotations

from typing import Iterator, Sequence as Seq

import numpy as np
import torch

from deepslam.core.errors import InputError
from deepslam.gen.shards import load_samples

Batch = dict[str, torch.Tensor]


def epoch_seed(seed: int, epoch: int, *more: int) -> int:
    """A 63-bit seed derived from (seed, epoch, ...) with numpy's SeedSequence."""
    return int(np.random.SeedSequence([int(seed), int(epoch), *map(int, more)]).generate_state(1, np.uint64)[0] >> 1)


class TensorSamples:
    """In-memory samples, shuffled per epoch with a ``torch.Generator`` seeded from (seed, epoch).

    Args:
        flow: (N, 2, h, w) float32 px at network resolution.
        intrinsics: (N, 4) float32 (fx, fy, cx, cy) at network resolution.
        target: (N, 6) float32 paper vectors of cam_{t+k}_from_cam_t.
        seed: shuffling seed.
        shuffle: shuffle each epoch (False: in order, e.g. for validation).
        inv_depth: optional (N, 1, h, w) float32 inverse depth of the first frames, 1/m (0 = unknown).
    """

    def __init__(self, flow, intrinsics, target, seed: int = 0, shuffle: bool = True, inv_depth=None):
        self.flow = torch.as_tensor(np.asarray(flow, dtype=np.float32))
        self.inv_depth = None if inv_depth is None else torch.as_tensor(np.asarray(inv_depth, dtype=np.float32))
        self.intrinsics = torch.as_tensor(np.asarray(intrinsics, dtype=np.float32))
        self.target = torch.as_tensor(np.asarray(target, dtype=np.float32))
        n = len(self.flow)
        if self.flow.ndim != 4 or self.flow.shape[1] != 2:
            raise ValueError(f"flow must be (N, 2, h, w), got {tuple(self.flow.shape)}")
        if self.intrinsics.shape != (n, 4) or self.target.shape != (n, 6):
            raise ValueError(f"intrinsics {tuple(self.intrinsics.shape)} / target {tuple(self.target.shape)} "
                             f"do not match {n} flows")
        if self.inv_depth is not None and self.inv_depth.shape != (n, 1, *self.flow.shape[2:]):
            raise ValueError(f"inverse depth {tuple(self.inv_depth.shape)} does not match the flows {tuple(self.flow.shape)}")
        self.seed = int(seed)
        self.shuffle = shuffle

    def __len__(self) -> int:
        return len(self.flow)

    def subset(self, idx: np.ndarray, shuffle: bool | None = None) -> "TensorSamples":
        idx = torch.as_tensor(np.asarray(idx, dtype=np.int64))
        return TensorSamples(self.flow[idx].numpy(), self.intrinsics[idx].numpy(), self.target[idx].numpy(),
                             self.seed, self.shuffle if shuffle is None else shuffle,
                             None if self.inv_depth is None else self.inv_depth[idx].numpy())

    def batches(self, epoch: int, batch_size: int, rank: int = 0, world: int = 1) -> Iterator[Batch]:
        """The epoch's batches of ``batch_size`` in a seeded order; with ``world`` > 1 (data-parallel
        training) this rank's share ``rank::world`` of each batch, so the ranks together see every
        sample of the batch once (a last batch smaller than ``world`` is dropped on every rank)."""
        n = len(self)
        if self.shuffle:
            g = torch.Generator().manual_seed(epoch_seed(self.seed, epoch))
            order = torch.randperm(n, generator=g)
        else:
            order = torch.arange(n)
        for s in range(0, n, batch_size):
            idx = order[s:s + batch_size]
            if world > 1:
                if len(idx) < world:
                    break
                idx = idx[rank::world]
            batch = {"flow": self.flow[idx], "intrinsics": self.intrinsics[idx], "target": self.target[idx]}
            if self.inv_depth is not None:
                batch["inv_depth"] = self.inv_depth[idx]
            yield batch

    def split(self, holdout_fraction: float, seed: int) -> tuple["TensorSamples", "TensorSamples"]:
        """(train, holdout) by a seeded permutation; holdout gets round(fraction * N) >= 1 samples."""
        n = len(self)
        n_hold = max(1, int(round(holdout_fraction * n)))
        if n_hold >= n:
            raise InputError(None, f"{n} samples are too few to hold out {holdout_fraction:.0%} and train on the rest")
        perm = np.random.default_rng(epoch_seed(seed, 0, 0x5EED)).permutation(n)
        return self.subset(np.sort(perm[n_hold:])), self.subset(np.sort(perm[:n_hold]))


def holdout_mask(groups: list, holdout_fraction: float, seed: int) -> np.ndarray:
    """(N,) bool, true for the held-out entries: a seeded permutation of the distinct ``groups`` (in
    order of first appearance) holds out ``holdout_fraction`` of them, each with all its entries."""
    uniq = list(dict.fromkeys(groups))
    n = len(uniq)
    n_hold = max(1, int(round(holdout_fraction * n)))
    if n_hold >= n:
        raise InputError(None, f"{n} frames are too few to hold out {holdout_fraction:.0%} and train on the rest")
    perm = np.random.default_rng(epoch_seed(seed, 0, 0xF4A3)).permutation(n)
    held = {uniq[k] for k in perm[:n_hold]}
    return np.array([g in held for g in groups], dtype=bool)


def shard_samples(out_dir, holdout_fraction: float, seed: int, height: int, width: int) -> tuple[TensorSamples, TensorSamples]:
    """(train, holdout) from a ``deepslam gen`` folder (:func:`deepslam.gen.shards.load_samples`, verified
    against its manifest), split by source frame so that no frame is on both sides; the flow must be
    at the network's input size ``height`` x ``width``."""
    s = load_samples(out_dir)
    h, w = s["flow"].shape[2:]
    if (h, w) != (height, width):
        raise InputError(out_dir, f"shards hold {h}x{w} flow, the network takes {height}x{width} "
                                  f"(make them with deepslam gen --resolution {height}x{width})")
    held = holdout_mask(s["frame"].tolist(), holdout_fraction, seed)
    every = TensorSamples(s["flow"], s["intrinsics"], s["target"], seed=seed)
    return every.subset(np.flatnonzero(~held)), every.subset(np.flatnonzero(held))


def concat_samples(parts: Seq[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The samples of ``parts`` (dicts of ``flow``, ``intrinsics``, ``target`` and, where every part has it,
    ``inv_depth``) one after another; ValueError where only some parts have ``inv_depth``."""
    with_depth = ["inv_depth" in p for p in parts]
    if any(with_depth) and not all(with_depth):
        raise ValueError("some parts have an inverse depth and some have none")
    keys = ("flow", "intrinsics", "target") + (("inv_depth",) if any(with_depth) else ())
    return {k: np.concatenate([p[k] for p in parts], axis=0) for k in keys}
