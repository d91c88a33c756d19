"""``SequencePairs``: a torch Dataset of frame pairs over any sequence folder deepslam reads.

Our format, KITTI odometry, EuRoC ASL and TUM RGB-D folders (real or rendered) are opened with
:func:`deepslam.core.readers.open_sequence`; each item is the pair (k, k + step) as tensors in the
shapes a flow or odometry network takes::

    from torch.utils.data import DataLoader
    from deepslam.data import SequencePairs

    loader = DataLoader(SequencePairs("out/quick"), batch_size=8, shuffle=True, num_workers=2)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.core.sequence import Sequence


def _image_tensor(img: np.ndarray) -> torch.Tensor:
    """(3, H, W) float32 in [0, 1] of a uint8/uint16 (H, W) grey or (H, W, 3) RGB image (grey repeated)."""
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    chw = np.ascontiguousarray(img.transpose(2, 0, 1))
    return torch.from_numpy(chw.astype(np.float32) / np.float32(scale))


def _flow_tensor(flow: np.ndarray) -> torch.Tensor:
    """(2, H, W) float32 of an (H, W, 2) flow."""
    return torch.from_numpy(np.ascontiguousarray(flow.transpose(2, 0, 1), dtype=np.float32))


class SequencePairs(Dataset):
    """Item k is the pair of frames (k, k + step) of a sequence folder; ``len`` = frames - step.

    Args:
        path: a sequence folder :func:`deepslam.core.readers.open_sequence` opens (ours, KITTI
            ``sequences/NN``, EuRoC holding ``mav0/``, TUM RGB-D); InputError when it cannot.
        step: frames between the two of a pair (an integer >= 1).

    Each item is a dict of tensors (a key is absent in every item when the sequence lacks the data):

    - ``image0``, ``image1``: float32 (3, H, W) in [0, 1], RGB, frames k and k + step as
      :meth:`Sequence.image` serves them (rectified; a grey image repeated in the three channels).
    - ``depth0``: float32 (1, H, W) depth_z of frame k in metres, 0 = no depth; absent when the sequence
      has no depth.
    - ``flow``: float32 (2, H, W) (du, dv) pixels from frame k to frame k + 1 as stored (NaN where the
      render had none: the point behind the next camera); only with ``step == 1`` and stored flow.
    - ``flow_backward``: float32 (2, H, W) (du, dv) pixels from frame k + 1 back to frame k; only with
      ``step == 1`` and stored backward flow.
    - ``occlusion``: bool (1, H, W), True where the surface seen in frame k is not visible in frame k + 1;
      only with ``step == 1`` and stored occlusion masks.
    - ``mask0``: int64 (1, H, W) instance ids of frame k, 0 = static scene; where stored.
    - ``cam1_from_cam0``: float64 (4, 4) = inverse(world_from_cam[k + step]) @ world_from_cam[k], the
      motion of frame k's camera into frame k + step's, OpenCV camera axes, metres; present when the
      sequence has ground truth, all NaN for a pair with a frame it does not cover (TUM's motion
      capture can start late).
    - ``intrinsics``: float32 (4,) = fx, fy, cx, cy in pixels of the images served.

    Works with ``DataLoader(num_workers=N)`` under fork or spawn: the sequence is opened again in a
    worker that received the dataset pickled (readers hold functions that do not pickle).
    """

    def __init__(self, path: str | Path, step: int = 1):
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < 1:
            raise InputError(None, f"step must be an integer >= 1, got {step!r}")
        self.path = Path(path)
        self.step = int(step)
        seq = open_sequence(self.path)
        self._seq: Sequence | None = seq
        self._len = max(0, len(seq) - self.step)
        one = self.step == 1
        self.keys: tuple[str, ...] = tuple(
            k for k, present in (("image0", True), ("image1", True), ("depth0", seq.depth_paths is not None),
                                 ("flow", one and seq.flow_paths is not None),
                                 ("flow_backward", one and seq.flow_backward_paths is not None),
                                 ("occlusion", one and seq.occlusion_paths is not None),
                                 ("mask0", seq.mask_paths is not None), ("cam1_from_cam0", seq.gt is not None),
                                 ("intrinsics", True)) if present)
        """The keys of every item, in order."""
        cam = seq.camera
        self._intrinsics = cam.intrinsics(np.float32)

    @property
    def sequence(self) -> Sequence:
        """The opened sequence (opened again after unpickling, e.g. in a DataLoader worker)."""
        if self._seq is None:
            self._seq = open_sequence(self.path)
        return self._seq

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_seq"] = None
        return state

    def __len__(self) -> int:
        return self._len

    def __getitem__(self, k: int) -> dict[str, torch.Tensor]:
        if isinstance(k, torch.Tensor):
            k = int(k)
        if not isinstance(k, (int, np.integer)) or isinstance(k, bool):
            raise TypeError(f"index must be an integer, got {type(k).__name__}")
        k = int(k)
        if k < 0:
            k += self._len
        if not 0 <= k < self._len:
            raise IndexError(f"pair {k} out of range (0..{self._len - 1})")
        s, j = self.sequence, k + self.step
        out: dict[str, torch.Tensor] = {"image0": _image_tensor(s.image(k)), "image1": _image_tensor(s.image(j))}
        if "depth0" in self.keys:
            out["depth0"] = torch.from_numpy(np.ascontiguousarray(s.depth(k), dtype=np.float32))[None]
        if "flow" in self.keys:
            out["flow"] = _flow_tensor(s.flow(k))
        if "flow_backward" in self.keys:
            out["flow_backward"] = _flow_tensor(s.flow_backward(j))
        if "occlusion" in self.keys:
            out["occlusion"] = torch.from_numpy(np.ascontiguousarray(s.occlusion(k), dtype=bool))[None]
        if "mask0" in self.keys:
            out["mask0"] = torch.from_numpy(s.mask(k).astype(np.int64))[None]
        if "cam1_from_cam0" in self.keys:
            w0, w1 = s.gt_pose(k), s.gt_pose(j)
            rel = np.full((4, 4), np.nan) if w0 is None or w1 is None else se3.relative(w1, w0)
            out["cam1_from_cam0"] = torch.from_numpy(np.asarray(rel, np.float64))
        out["intrinsics"] = torch.from_numpy(self._intrinsics.copy())
        return out
