"""Read a rendered sequence into a torch DataLoader: consecutive pairs with images, depth, exact flow and the
relative motion, in the shapes a flow or odometry network takes (``deepslam.data.SequencePairs``; its
docstring lists every key with its shape, dtype and unit).

    python examples/torch_dataloader.py out/quick          # prints one batch's shapes
"""
from __future__ import annotations

import sys

import torch
from torch.utils.data import DataLoader

from deepslam.data import SequencePairs


def main(path: str) -> dict[str, tuple]:
    loader = DataLoader(SequencePairs(path), batch_size=4, shuffle=True, num_workers=2,
                        generator=torch.Generator().manual_seed(0))
    batch = next(iter(loader))
    for k, v in batch.items():
        print(f"{k:15s} {tuple(v.shape)} {v.dtype}")
    return {k: tuple(v.shape) for k, v in batch.items()}


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "out/quick")
