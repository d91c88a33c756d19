"""The paper's training data on the fly: single frames + depth + a motion model -> flow and the 6DoF target.

Nothing is read from video and nothing is written to disk: every item takes one depth map from a
:class:`DepthFrames` source, draws a camera motion ``cam1_from_cam0`` from a
:class:`gen.motion.MotionModel`, and synthesizes the optical flow that motion would cause
(:func:`gen.flow.synthesize`). A network that maps flow to 6DoF trains on these pairs.

Use::

    from deepslam.gen.dataset import SyntheticFlowDataset, open_depth_frames
    from deepslam.gen.motion import MotionModel

    frames = open_depth_frames("path/to/sequence")              # ours / KITTI / EuRoC export with depth/
    # frames = open_depth_frames("kitti/sequences/06", depth_from_stereo="sgbm")   # stereo -> depth
    ds = SyntheticFlowDataset(frames, MotionModel.load("motion.json"), num_samples=100_000, seed=0,
                              config=DatasetConfig(resolution_hw=(96, 320)))
    item = ds[17]                                               # one sample, see below
    batch = ds.get_batch(range(0, 128))                         # 128 samples in one batched synthesis
    loader = torch.utils.data.DataLoader(ds, batch_size=64, num_workers=2)   # also works

An item is a dict of torch tensors (``get_batch`` stacks them with a leading batch axis B):

=============== ========================= =======================================================
key             shape / dtype             meaning
=============== ========================= =======================================================
``flow``        (2, h, w) float32         optical flow in PIXELS AT THE OUTPUT RESOLUTION h x w,
                                          channel 0 = du (along u / columns / image x), channel 1
                                          = dv (rows, image y), from the frame (t) to the moved
                                          camera (t+1); 0 where ``valid`` is false. The paper's
                                          normalised flow is ``flow / (w, h)``
                                          (:func:`gen.flow.normalize_flow`, ``channel_axis=0``).
``valid``       (h, w) bool               flow defined: depth known, point in front of the moved
                                          camera and inside its image (and not hidden by a nearer
                                          point when ``config.zbuffer``).
``target``      (6,) float32              the paper's vector of ``cam1_from_cam0`` (the motion
                                          mapping points of camera t into camera t+1):
                                          euler_x, euler_y, euler_z (rad, R = Rz Ry Rx), then
                                          t_x, t_y, t_z (m, in camera t+1's axes), OpenCV axes
                                          (x right, y down, z forward).
``intrinsics``  (4,) float32              fx, fy, cx, cy in pixels at the output resolution.
``frame``       () int64                  index of the source frame the depth came from.
``loop``        () bool                   the motion was drawn from the loop distribution.
``index``       () int64                  the item's index.
=============== ========================= =======================================================

Determinism: item ``i`` depends only on ``(seed, i)`` (a ``numpy.random.Generator`` seeded with
``SeedSequence([seed, i])`` picks the frame, then the motion), never on the order of access, the
batch it is fetched in, or the number of DataLoader workers; the same torch build and thread count
give the same bits (synthesis is element-wise only).

Resolution: the depth map is resampled to h x w by taking, for each output pixel centre, the source
pixel that contains it (nearest, no averaging across depth edges), and the flow is computed directly
with the camera scaled to h x w (:meth:`core.camera.PinholeCamera.scaled`), so it is exactly the flow
of the output pixel centres' rays up to the half-source-pixel shift of the nearest sample.
"""
from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Iterable, Sequence as Seq

import numpy as np
import torch

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.gen.flow import synthesize
from deepslam.gen.motion import MotionModel
from deepslam.gen.stereo import StereoConfig, opencv_threads, sequence_depth


# ---------------------------------------------------------------------------------------- depth frames

class DepthFrames:
    """Frames with depth: ``len(frames)``, ``frames.camera`` (PinholeCamera of the depth maps) and
    ``frames.depth(i)`` -> (H, W) float32 depth_z in metres, 0 = unknown."""

    camera: PinholeCamera
    name: str = "frames"

    def __len__(self) -> int:
        raise NotImplementedError

    def depth(self, i: int) -> np.ndarray:
        raise NotImplementedError

    def describe(self) -> dict:
        """JSON-able description (recorded in shard manifests)."""
        return {"name": self.name, "frames": len(self), "camera": self.camera.to_dict()}


class ArrayDepthFrames(DepthFrames):
    """Depth maps held in memory: (N, H, W) float32 metres, with their camera."""

    def __init__(self, depths: np.ndarray, camera: PinholeCamera, name: str = "arrays"):
        self.depths = np.asarray(depths, dtype=np.float32)
        if self.depths.ndim != 3 or self.depths.shape[1:] != (camera.height, camera.width):
            raise ValueError(f"depths must be (N, {camera.height}, {camera.width}), got {self.depths.shape}")
        self.camera = camera
        self.name = name

    def __len__(self) -> int:
        return len(self.depths)

    def depth(self, i: int) -> np.ndarray:
        return self.depths[i]


class SequenceDepthFrames(DepthFrames):
    """The depth maps of a :class:`core.sequence.Sequence` that has them (ours, or exports with depth/)."""

    def __init__(self, seq):
        if not seq.has_depth:
            raise InputError(seq.root, "sequence has no depth (no depth/ folder); for a stereo sequence "
                             "compute it with depth_from_stereo='sgbm' or 'dis'")
        self.seq = seq
        self.camera = seq.camera
        self.name = seq.name

    def __len__(self) -> int:
        return len(self.seq)

    def depth(self, i: int) -> np.ndarray:
        d = self.seq.depth(i)
        if d.shape != (self.camera.height, self.camera.width):
            raise InputError(self.seq.depth_paths[i], f"depth is {d.shape[1]}x{d.shape[0]}, camera is "
                             f"{self.camera.width}x{self.camera.height}")
        if not (np.isfinite(d) & (d > 0)).any():
            raise InputError(self.seq.depth_paths[i], "depth has no valid pixel (all zero, NaN or negative): "
                                                      "no flow can be made from this frame")
        return d

    def describe(self) -> dict:
        return {**super().describe(), "kind": self.seq.kind, "depth": "files"}


class StereoDepthFrames(DepthFrames):
    """Depth computed from a stereo sequence's rectified pairs (:mod:`gen.stereo`), cached per frame.

    OpenCV runs single-threaded here so that the depth (and everything made from it) is bit-identical
    whichever process computes it.
    """

    def __init__(self, seq, method: str = "sgbm", cache_frames: int = 64):
        if not seq.has_stereo:
            raise InputError(seq.root, "sequence has neither depth nor a stereo pair (right images + baseline)")
        self.seq = seq
        self.camera = seq.camera
        self.name = seq.name
        self.config = StereoConfig(method=method)
        self.cache_frames = int(cache_frames)
        self._cached = functools.lru_cache(maxsize=self.cache_frames)(self._compute)

    def __len__(self) -> int:
        return len(self.seq)

    def _compute(self, i: int) -> np.ndarray:
        with opencv_threads(1):
            return sequence_depth(self.seq, i, self.config)

    def depth(self, i: int) -> np.ndarray:
        return self._cached(int(i))

    def describe(self) -> dict:
        return {**super().describe(), "kind": self.seq.kind, "depth": f"stereo:{self.config.method}",
                "stereo": dataclasses.asdict(self.config)}

    def __getstate__(self):
        state = self.__dict__.copy()
        state.pop("_cached", None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._cached = functools.lru_cache(maxsize=self.cache_frames)(self._compute)


def open_depth_frames(path: str | Path, depth_from_stereo: str | None = None) -> DepthFrames:
    """Frames with depth from a sequence folder (any layout :func:`core.readers.open_sequence` reads).

    Args:
        path: the sequence folder.
        depth_from_stereo: ``sgbm`` or ``dis`` to compute depth from the stereo pair (used only when the
            sequence has no depth files); None: the sequence must have depth.

    Raises:
        InputError when the folder is not a sequence, or has no depth (and no stereo to compute it).
    """
    seq = open_sequence(path)
    if seq.has_depth:
        return SequenceDepthFrames(seq)
    if depth_from_stereo is None:
        raise InputError(path, "sequence has no depth (no depth/ folder); pass --depth-from-stereo sgbm|dis "
                         "to compute it from a stereo pair")
    return StereoDepthFrames(seq, depth_from_stereo)


def resample_nearest(depth: np.ndarray, height: int, width: int) -> np.ndarray:
    """(height, width) depth whose pixel centres take the source pixel containing them (no averaging).

    Output centre (u', v') sits at source coordinate ((u' + 0.5) W / w - 0.5, ...), the convention of
    :meth:`PinholeCamera.scaled`; the source pixel containing it is ``floor((u' + 0.5) W / w)``.
    """
    h0, w0 = depth.shape
    if (h0, w0) == (height, width):
        return depth
    rows = np.minimum(((np.arange(height) + 0.5) * h0 / height).astype(np.int64), h0 - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * w0 / width).astype(np.int64), w0 - 1)
    return depth[rows[:, None], cols[None, :]]


# --------------------------------------------------------------------------------------------- dataset

@dataclasses.dataclass(frozen=True)
class DatasetConfig:
    """How items are made (the motion model and source are passed separately)."""

    resolution_hw: tuple[int, int] | None = None
    """Output (height, width) in pixels; None keeps the source resolution."""
    loop_fraction: float = 0.0
    """Probability that a motion is drawn from the loop distribution (needs a loop model)."""
    zbuffer: bool = False
    """Also mark flow hidden by a nearer point in the moved view as invalid (slower)."""

    def __post_init__(self):
        if self.resolution_hw is not None:
            h, w = self.resolution_hw
            if int(h) < 2 or int(w) < 2:
                raise ValueError(f"resolution must be at least 2x2, got {h}x{w}")
            object.__setattr__(self, "resolution_hw", (int(h), int(w)))
        if not 0.0 <= self.loop_fraction <= 1.0:
            raise ValueError(f"loop_fraction must be in [0, 1], got {self.loop_fraction}")


def item_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of item ``index``: ``default_rng(SeedSequence([seed, index]))``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))


class SyntheticFlowDataset(torch.utils.data.Dataset):
    """Map-style dataset of synthesized (flow, 6DoF target) pairs; see the module docstring.

    Args:
        frames: a :class:`DepthFrames` source (:func:`open_depth_frames`, :class:`ArrayDepthFrames`).
        motion: the motion model to draw ``cam1_from_cam0`` from.
        num_samples: length of the dataset (items are drawn, so any length works).
        seed: base seed; item i depends on (seed, i) only.
        config: output resolution, loop fraction, z-buffer.
        depth_cache_frames: how many depth maps (at the output resolution) to keep in memory.
    """

    def __init__(self, frames: DepthFrames, motion: MotionModel, num_samples: int, seed: int = 0,
                 config: DatasetConfig = DatasetConfig(), depth_cache_frames: int = 4096):
        if len(frames) == 0:
            raise ValueError("no frames to draw from")
        if num_samples < 0:
            raise ValueError(f"num_samples must be >= 0, got {num_samples}")
        if config.loop_fraction > 0 and motion.loop is None:
            raise ValueError("loop_fraction > 0 needs a motion model with a loop distribution (fit-motion --loops)")
        self.frames = frames
        self.motion = motion
        self.num_samples = int(num_samples)
        self.seed = int(seed)
        self.config = config
        h, w = config.resolution_hw or (frames.camera.height, frames.camera.width)
        self.camera = frames.camera.scaled(w, h)
        """Camera at the output resolution."""
        self.depth_cache_frames = int(depth_cache_frames)
        """Resampled depth maps kept in memory (frames are drawn again and again)."""
        self._depth_cache: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return self.num_samples

    @property
    def intrinsics(self) -> np.ndarray:
        """(4,) float32 fx, fy, cx, cy at the output resolution."""
        c = self.camera
        return c.intrinsics(np.float32)

    def _draw(self, index: int) -> tuple[int, np.ndarray, bool]:
        if not 0 <= index < self.num_samples:
            raise IndexError(f"index {index} out of range for {self.num_samples} samples")
        rng = item_rng(self.seed, index)
        frame = int(rng.integers(len(self.frames)))
        vec, is_loop = self.motion.sample(1, rng, self.config.loop_fraction)
        return frame, vec[0], bool(is_loop[0])

    def plan(self, index: int) -> tuple[int, np.ndarray, bool]:
        """(source frame, cam1_from_cam0 (4, 4) float64, is_loop) of item ``index`` (cheap: no depth)."""
        frame, vec, is_loop = self._draw(index)
        return frame, se3.from_euler6(vec), is_loop

    def depth_at_output(self, frame: int) -> np.ndarray:
        """(h, w) float32 depth of a source frame resampled to the output resolution (cached, read-only)."""
        cached = self._depth_cache.get(frame)
        if cached is None:
            cached = resample_nearest(self.frames.depth(frame), self.camera.height, self.camera.width)
            cached = np.ascontiguousarray(cached, dtype=np.float32)
            cached.flags.writeable = False
            if len(self._depth_cache) >= self.depth_cache_frames:
                self._depth_cache.pop(next(iter(self._depth_cache)))
            self._depth_cache[frame] = cached
        return cached

    def get_batch(self, indices: Iterable[int]) -> dict[str, torch.Tensor]:
        """Items ``indices`` stacked along a leading axis, synthesized in one batched call."""
        indices = [int(i) for i in indices]
        draws = [self._draw(i) for i in indices]
        n = len(indices)
        h, w = self.camera.height, self.camera.width
        if n == 0:
            return {"flow": torch.zeros(0, 2, h, w), "valid": torch.zeros(0, h, w, dtype=torch.bool),
                    "target": torch.zeros(0, 6), "intrinsics": torch.zeros(0, 4),
                    "frame": torch.zeros(0, dtype=torch.int64), "loop": torch.zeros(0, dtype=torch.bool),
                    "index": torch.zeros(0, dtype=torch.int64)}
        depth = np.empty((n, h, w), dtype=np.float32)
        for k, (frame, _, _) in enumerate(draws):
            depth[k] = self.depth_at_output(frame)
        motions = se3.from_euler6(np.stack([d[1] for d in draws]))
        flow, valid = synthesize_for_dataset(depth, self.camera, motions, self.config.zbuffer)
        return {
            "flow": flow.permute(0, 3, 1, 2).contiguous(),
            "valid": valid,
            "target": torch.from_numpy(se3.to_euler6(motions).astype(np.float32)),
            "intrinsics": torch.from_numpy(np.tile(self.intrinsics, (n, 1))),
            "frame": torch.tensor([d[0] for d in draws], dtype=torch.int64),
            "loop": torch.tensor([d[2] for d in draws], dtype=torch.bool),
            "index": torch.tensor(indices, dtype=torch.int64),
        }

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        if isinstance(index, torch.Tensor):
            index = int(index)
        if index < 0:
            index += self.num_samples
        batch = self.get_batch([index])
        return {k: v[0] for k, v in batch.items()}


def synthesize_for_dataset(depth: np.ndarray, camera: PinholeCamera, motions: np.ndarray, zbuffer: bool):
    """:func:`gen.flow.synthesize` as the dataset and the shard writer call it (one place)."""
    return synthesize(torch.from_numpy(depth), camera, motions, zbuffer=zbuffer)
