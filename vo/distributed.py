"""Data-parallel training over processes (torch DistributedDataParallel, started by ``torchrun``).

``torchrun --nproc_per_node K -m deepslam train ...`` starts K copies of the command; each reads
``RANK``, ``WORLD_SIZE`` and ``LOCAL_RANK`` from its environment. :func:`init_from_env` joins them
into one process group (NCCL on CUDA, gloo on the CPU) and gives each its device (``cuda:LOCAL_RANK``
on a GPU machine). Then, in :func:`vo.train.train`:

- every rank builds the same model (same seed) and DDP averages the gradients, so all ranks hold the
  same weights after every step;
- every batch of ``--batch`` samples is split across the ranks (:meth:`vo.data.samples.TensorSamples.batches`
  ``rank::world``; on-the-fly sources make only their rank's share, from the rank's own seed stream):
  no sample is drawn twice, and with K ranks one step sees the same samples as one process would;
- the sample and time caps are agreed on by all ranks every step (the counts are summed, a stop on
  any rank stops all), so no rank waits for a step the others skip;
- only rank 0 locks and writes the output folder (checkpoint, config, history, model); the held-out
  evaluation and the uncertainty stage run on every rank on the same data (identical results).

Without ``WORLD_SIZE`` > 1 nothing here does anything and training is the single-process loop.
"""
from __future__ import annotations

import os

import torch
import torch.distributed as dist


def world() -> tuple[int, int]:
    """(rank, world size) of this process: (0, 1) outside a process group."""
    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def init_from_env(device: torch.device) -> torch.device:
    """Join the process group ``torchrun`` describes in the environment (no-op without ``WORLD_SIZE`` > 1).

    Args:
        device: the device the command resolved (``--device``); on CUDA each rank takes
            ``cuda:LOCAL_RANK`` instead.

    Returns:
        The device this rank trains on.
    """
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1 or (dist.is_available() and dist.is_initialized()):
        return device
    if device.type == "cuda":
        local = int(os.environ.get("LOCAL_RANK", "0"))
        torch.cuda.set_device(local)
        device = torch.device("cuda", local)
        dist.init_process_group("nccl")
    else:
        dist.init_process_group("gloo")
    return device


def agree(count: int, stop: bool, device: torch.device) -> tuple[int, bool]:
    """(sum of ``count`` over the ranks, whether any rank wants to ``stop``); unchanged alone."""
    rank, size = world()
    if size <= 1:
        return count, stop
    t = torch.tensor([float(count), 1.0 if stop else 0.0], dtype=torch.float64, device=device)
    dist.all_reduce(t)
    return int(t[0].item()), bool(t[1].item() > 0)


def finish() -> None:
    """Leave the process group (end of a distributed command)."""
    if dist.is_available() and dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()
