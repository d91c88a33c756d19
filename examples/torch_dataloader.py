"""Read a rendered sequence into a torch DataLoader: consecutive pairs with images, depth, exact flow and the
relative motion, in the shapes a flow or odometry network takes.

    python examples/torch_dataloader.py out/quick          # prints one batch's shapes
"""
from __future__ import annotations

import sys

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from deepslam.core import se3
from deepslam.core.readers import open_sequence


class Pairs(Dataset):
    """Item k: the pair (k, k + 1) of a sequence folder deepslam reads (ours, KITTI, EuRoC or TUM layout).

    ``image0``, ``image1``: float32 (3, H, W) in [0, 1]; ``depth0``: float32 (1, H, W) depth_z in m (0 = none);
    ``flow``: float32 (2, H, W) px from frame k to k + 1 (channel 0 = du); ``cam1_from_cam0``: float64 (4, 4),
    OpenCV camera axes; ``intrinsics``: float32 (4,) = fx, fy, cx, cy in px.
    """

    def __init__(self, path: str):
        self.path = path
        self.seq = open_sequence(path)

    def __len__(self) -> int:
        return len(self.seq) - 1

    def __getitem__(self, k: int) -> dict[str, torch.Tensor]:
        s, cam = self.seq, self.seq.camera
        image = lambda i: torch.from_numpy(np.ascontiguousarray(s.image(i).transpose(2, 0, 1))).float() / 255.0
        world_from_cam = s.gt.world_from_cam
        return {"image0": image(k), "image1": image(k + 1),
                "depth0": torch.from_numpy(s.depth(k))[None],
                "flow": torch.from_numpy(np.ascontiguousarray(s.flow(k).transpose(2, 0, 1))),
                "cam1_from_cam0": torch.from_numpy(se3.relative(world_from_cam[k + 1], world_from_cam[k])),
                "intrinsics": torch.tensor([cam.fx, cam.fy, cam.cx, cam.cy], dtype=torch.float32)}


def main(path: str) -> dict[str, tuple]:
    loader = DataLoader(Pairs(path), batch_size=4, shuffle=True, num_workers=2,
                        generator=torch.Generator().manual_seed(0))
    batch = next(iter(loader))
    shapes = {k: tuple(v.shape) for k, v in batch.items()}
    for k, v in batch.items():
        print(f"{k:15s} {tuple(v.shape)} {v.dtype}")
    return shapes


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "out/quick")
