"""On-the-fly synthetic training sources: the paper's data, single frames with depth + a motion model.

- :class:`SyntheticSource`: the flow that the sampled motion would cause, synthesized from the frame's
  depth (:func:`gen.flow.synthesize_flow`, batched in torch).
- :class:`EstimatedFlowSource`: the flow a real estimator gives between the frame and a second view
  rendered from it (:func:`gen.novel_view.render_novel_view`).

Both yield the batches described in :mod:`vo.data.samples`; batch b of epoch e is a function of (seed, e, b) only.
"""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Iterator

import numpy as np
import torch
from tqdm import tqdm

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.flow import estimators as flow_estimators, registry as flow_registry
from deepslam.gen.flow import pool_flow, synthesize_flow
from deepslam.gen.novel_view import render_novel_view
from deepslam.gen.rotate_view import rotate_depth, rotate_image
from deepslam.vo.data.frames import Frames, ImageFrames
from deepslam.vo.data.motion import CameraTilt, SceneScale, tilted
from deepslam.vo.data.samples import Batch, TensorSamples, epoch_seed
from deepslam.vo.net import inverse_depth_input

class _OnTheFlySource:
    """Batches made on the fly by ``make_batch(rng, n)``; batch b of epoch e is seeded by (seed, e, b)."""

    samples_per_epoch: int
    seed: int

    def make_batch(self, rng: np.random.Generator, n: int) -> Batch:
        raise NotImplementedError

    def batches(self, epoch: int, batch_size: int, rank: int = 0, world: int = 1) -> Iterator[Batch]:
        """The epoch's batches; with ``world`` > 1 this rank makes only its share of each batch
        (``len(range(rank, n, world))`` samples) from its own stream, seeded by (seed, epoch, batch,
        rank, world): no rank draws another's samples (a last batch smaller than ``world`` is dropped)."""
        n_batches = -(-self.samples_per_epoch // batch_size)
        for b in range(n_batches):
            n = min(batch_size, self.samples_per_epoch - b * batch_size)
            if world <= 1:
                yield self.make_batch(np.random.default_rng(epoch_seed(self.seed, epoch, b)), n)
            elif n >= world:
                yield self.make_batch(np.random.default_rng(epoch_seed(self.seed, epoch, b, rank, world)),
                                      len(range(rank, n, world)))

    def materialize(self, n: int, seed: int, progress: bool = False) -> TensorSamples:
        """A fixed set of ``n`` samples (a validation / NLL set, or a pool to train on), in order."""
        rng = np.random.default_rng(epoch_seed(seed, 0, 0xA11))
        parts = [self.make_batch(rng, min(256, n - s)) for s in
                 tqdm(range(0, n, 256), desc="samples", unit="batch", disable=not progress, leave=False)]
        def cat(key):
            return torch.cat([p[key] for p in parts]).cpu().numpy()

        inv = cat("inv_depth") if "inv_depth" in parts[0] else None
        return TensorSamples(cat("flow"), cat("intrinsics"), cat("target"), seed=seed, inv_depth=inv)


class SyntheticSource(_OnTheFlySource):
    """The paper's training data: a random frame, a random motion from the model, the flow that motion
    would cause (:func:`synthesize_flow` on the frame's depth), batched and made on the fly.

    Batch b of epoch e is a function of (seed, e, b) only. Flow is synthesized at ``synth_factor``
    times the network resolution and averaged down (as a full-resolution flow estimate is resized to
    the network input) by :func:`synthesize_flow`: points leaving the image keep their flow, pixels
    without depth see a point at infinity (``missing_depth``), points behind the camera get flow 0.

    Args:
        frames: :class:`Frames` at the synthesis resolution (``synth_factor`` x network size).
        sample_motion: ``(n, rng) -> (n, 6)`` paper vectors of cam1_from_cam0.
        samples_per_epoch: samples per epoch.
        seed: data seed.
        synth_factor: synthesis resolution / network resolution (integer).
        missing_depth: ``infinity`` (default) or ``invalid``, see :func:`synthesize_flow`.
        synthesize: replaces :func:`synthesize_flow`: ``(depth (B, H, W) tensor, intrinsics (B, 4),
            cam1_from_cam0 (B, 4, 4)) -> (flow (B, 2, H, W), valid (B, H, W))``.
        tilt: a :class:`CameraTilt` applied to each sample's frame and motion (None: the frames as they are).
        inv_depth: also give each sample's inverse depth at the network resolution (``"inv_depth"``).
        scene_scale: a :class:`SceneScale` applied to each sample's depth (None: the depth as it is).
        unknown: ``zero`` (flow 0 where no pixel of a network pixel is valid) or ``nan`` (NaN there:
            for a network with a validity channel; :data:`flow.estimators.UNKNOWN_FLOW`).
        device: torch device that holds the frames' depth and synthesizes the flow (``cpu``, or the training
            GPU: one core makes ~1,600 samples/s at 96 x 320, where a training process on an H100 took
            ~10,000 samples/s with the flow made there); a batch's ``flow`` is on it, the rest on the CPU.
            The samples drawn (frames, motions) do not depend on it; the flow's last bits do.
    """

    def __init__(self, frames: Frames, sample_motion, samples_per_epoch: int, seed: int = 0, synth_factor: int = 1,
                 missing_depth: str = "infinity", synthesize=None, tilt: CameraTilt | None = None,
                 inv_depth: bool = False, scene_scale: SceneScale | None = None, unknown: str = "zero",
                 device: str | torch.device = "cpu"):
        self.unknown = flow_estimators.check_unknown(unknown)
        self.inv_depth = bool(inv_depth)
        self.scene_scale = scene_scale
        self.frames = frames
        self.sample_motion = sample_motion
        self.samples_per_epoch = int(samples_per_epoch)
        self.seed = int(seed)
        self.synth_factor = int(synth_factor)
        self.missing_depth = missing_depth
        self.synthesize = synthesize
        self.tilt = tilt
        self.device = torch.device(device)
        self._depth = torch.from_numpy(np.ascontiguousarray(frames.depth_z)).to(self.device)
        hs, ws = frames.depth_z.shape[1:]
        if hs % self.synth_factor or ws % self.synth_factor:
            raise ValueError(f"frames {hs}x{ws} are not a multiple of synth_factor {self.synth_factor}")
        self._k_synth = np.array([c.intrinsics() for c in frames.cameras])
        self._k_out = np.array([c.intrinsics() for c in
                                (c.scaled(ws // self.synth_factor, hs // self.synth_factor) for c in frames.cameras)], np.float32)

    def __len__(self) -> int:
        return self.samples_per_epoch

    def make_batch(self, rng: np.random.Generator, n: int) -> Batch:
        idx = rng.integers(0, len(self.frames), n)
        vec6 = np.asarray(self.sample_motion(n, rng), dtype=np.float64).reshape(n, 6)
        cams = self.frames.camera_index[idx]
        depth = self._depth[torch.from_numpy(idx).to(self.device)]
        motion = se3.from_euler6(vec6)
        if self.tilt is not None:
            rot = self.tilt.sample(n, rng)
            depth = torch.from_numpy(np.stack([rotate_depth(d, self.frames.cameras[c], r, outside="nearest")
                                               for d, c, r in zip(depth.cpu().numpy(), cams, rot)])).to(self.device)
            motion = tilted(rot, motion)
            vec6 = se3.to_euler6(motion)
        if self.scene_scale is not None:
            scale = torch.from_numpy(self.scene_scale.sample(n, rng).astype(np.float32)).to(self.device)
            depth = depth * scale.view(n, 1, 1)
        if self.synthesize is None:
            flow, valid = synthesize_flow(depth, self._k_synth[cams], motion, self.missing_depth,
                                          pool=self.synth_factor)
        else:
            flow, valid = self.synthesize(depth, self._k_synth[cams], motion)
            flow, valid = pool_flow(flow, valid, self.synth_factor)
        if self.unknown == "nan":
            flow = flow.masked_fill(~valid[:, None], float("nan"))
        batch = {"flow": flow.contiguous(), "intrinsics": torch.from_numpy(self._k_out[cams]),
                 "target": torch.from_numpy(vec6.astype(np.float32))}
        if self.inv_depth:
            h, w = flow.shape[2:]
            batch["inv_depth"] = torch.from_numpy(np.stack([inverse_depth_input(d, w, h) for d in depth.cpu().numpy()]))
        return batch


def crop_views(images, camera: PinholeCamera, window: tuple[int, int], place: tuple[float, float]):
    """``images`` (arrays (H, W, ...) of one camera, e.g. a frame, its second view and its depth) cut to a window of
    ``window`` = (width, height) px, with the camera of that window: ``(cut images, camera)``. ``place`` = (x, y) in
    [0, 1) picks the window's first column and row uniformly among the ``W - width + 1`` and ``H - height + 1``
    possible; the camera keeps its focal length and its principal point moves by the window's offset."""
    w, h = window
    left = min(int(place[0] * (camera.width - w + 1)), camera.width - w)
    top = min(int(place[1] * (camera.height - h + 1)), camera.height - h)
    cut = tuple(None if a is None else np.ascontiguousarray(a[top:top + h, left:left + w]) for a in images)
    return cut, PinholeCamera(w, h, camera.fx, camera.fy, camera.cx - left, camera.cy - top)


class EstimatedFlowSource(_OnTheFlySource):
    """The paper's synthetic samples, but with the flow a real estimator gives: for a random frame and
    a motion from the model, the second view is rendered from that single frame
    (:func:`gen.novel_view.render_novel_view`), the estimator runs on the pair at the frame's own
    resolution and its flow is resized to the network input (:func:`flow.estimators.to_network_input`,
    exactly as at test time). The target is the sampled motion; no pose of any frame is used.

    Batch b of epoch e is a function of (seed, e, b) only (the estimators are deterministic; each
    worker thread has its own estimator object).

    Args:
        frames: :class:`ImageFrames`.
        sample_motion: ``(n, rng) -> (n, 6)`` paper vectors of cam1_from_cam0.
        estimator: a :mod:`flow.estimators` name (e.g. ``dis``) that can ``estimate(img0, img1)``.
        width, height: network input size.
        samples_per_epoch: samples per epoch.
        seed: data seed.
        threads: worker threads (OpenCV and numba release the GIL).
        estimator_options: options of the estimator's factory (e.g. ``{"preset": "medium"}``).
        appearance_noise: std (grey levels) of Gaussian noise added to the rendered view: a view
            resampled from the first frame keeps its appearance exactly, a real next frame does not
            (sensor noise, exposure; in a renderer, texture filtering at the new viewpoint), and the
            estimator's errors depend on that. 0: none.
        tilt: a :class:`CameraTilt` applied to each sample's frame (image and depth) and motion.
        inv_depth: also give each sample's inverse depth at the network resolution (``"inv_depth"``).
        scene_scale: a :class:`SceneScale` applied to each sample's depth (None: the depth as it is).
        unknown: how the estimator's unknown flow (NaN) is resized to the network input
            (:data:`flow.estimators.UNKNOWN_FLOW`: ``nan`` for a network with a validity channel).
        crop_window: (width, height) px: each sample's frame and second view are cut to a window of that
            size, placed uniformly at random in the frame (after any tilt, before the estimator), with its
            camera's principal point moved accordingly, so that the samples' principal points spread over
            the frame's margin as real cameras' do (KITTI's lies 0.87 % of the width left of its image
            centre). Frames rendered wider than the test camera's image at its focal length keep the test
            field of view. A network with ``coord_channels`` is told where each sample's principal point
            lies; one without can only average over them. None: the whole frame.
    """

    def __init__(self, frames: ImageFrames, sample_motion, estimator: str, width: int, height: int,
                 samples_per_epoch: int, seed: int = 0, threads: int = 2, estimator_options: dict | None = None,
                 appearance_noise: float = 0.0, tilt: CameraTilt | None = None, inv_depth: bool = False,
                 scene_scale: SceneScale | None = None, unknown: str = "zero",
                 crop_window: tuple[int, int] | None = None):
        self.unknown = flow_estimators.check_unknown(unknown)
        self.crop_window = None if crop_window is None else (int(crop_window[0]), int(crop_window[1]))
        if self.crop_window is not None:
            w, h = self.crop_window
            if min(w, h) < 8 or any(c.width < w or c.height < h for c in frames.cameras):
                sizes = ", ".join(sorted({f"{c.width}x{c.height}" for c in frames.cameras}))
                raise InputError(None, f"crop window {w}x{h} must be at least 8x8 px and fit every frame ({sizes})")
        self.inv_depth = bool(inv_depth)
        self.scene_scale = scene_scale
        self.frames = frames
        self.sample_motion = sample_motion
        self.estimator = estimator
        self.estimator_options = dict(estimator_options or {})
        self.estimator_name = flow_registry.make(estimator, **self.estimator_options).name  # fails early on a bad name
        self.width, self.height = int(width), int(height)
        self.samples_per_epoch = int(samples_per_epoch)
        self.seed = int(seed)
        self.threads = max(1, int(threads))
        if not (np.isfinite(appearance_noise) and appearance_noise >= 0):
            raise InputError(None, f"appearance noise must be a non-negative number, got {appearance_noise}")
        self.appearance_noise = float(appearance_noise)
        self.tilt = tilt
        self._local = threading.local()

    def __len__(self) -> int:
        return self.samples_per_epoch

    def _one(self, k: int, motion: np.ndarray, noise_seed: int, rot: np.ndarray | None,
             scale: float = 1.0, place: tuple[float, float] = (0.5, 0.5)) -> tuple[np.ndarray, ...]:
        est = getattr(self._local, "est", None)
        if est is None:
            est = self._local.est = flow_registry.make(self.estimator, **self.estimator_options)
        cam = self.frames.cameras[self.frames.camera_index[k]]
        grey0, depth0, seen0 = self.frames.grey[k], self.frames.depth_z[k], self.frames.network_depth(k)
        if rot is not None:
            grey0, depth0 = rotate_image(grey0, cam, rot), rotate_depth(depth0, cam, rot, outside="nearest")
            seen0 = depth0 if seen0 is self.frames.depth_z[k] else rotate_depth(seen0, cam, rot, outside="nearest")
        if scale != 1.0:
            depth0, seen0 = depth0 * np.float32(scale), seen0 * np.float32(scale)
        grey1, _ = render_novel_view(grey0, depth0, cam, motion)
        if self.appearance_noise > 0:
            noise = np.random.default_rng(noise_seed).normal(0.0, self.appearance_noise, grey1.shape)
            grey1 = np.clip(np.rint(grey1 + noise), 0, 255).astype(np.uint8)
        if self.crop_window is not None:
            (grey0, grey1, seen0), cam = crop_views((grey0, grey1, seen0), cam, self.crop_window, place)
        flow, intr = flow_estimators.to_network_input(est.estimate(grey0, grey1), cam, self.width, self.height,
                                                     self.unknown)
        return flow, intr, (inverse_depth_input(seen0, self.width, self.height) if self.inv_depth else None)

    def make_batch(self, rng: np.random.Generator, n: int) -> Batch:
        idx = rng.integers(0, len(self.frames), n)
        vec6 = np.asarray(self.sample_motion(n, rng), dtype=np.float64).reshape(n, 6)
        seeds = rng.integers(0, 2 ** 63, n) if self.appearance_noise > 0 else np.zeros(n, np.int64)
        motion = se3.from_euler6(vec6)
        rots = [None] * n
        if self.tilt is not None:
            rots = list(self.tilt.sample(n, rng))
            motion = tilted(np.stack(rots), motion)
            vec6 = se3.to_euler6(motion)
        scales = self.scene_scale.sample(n, rng) if self.scene_scale is not None else np.ones(n)
        places = rng.random((n, 2)) if self.crop_window is not None else np.full((n, 2), 0.5)
        args = ([int(k) for k in idx], list(motion), [int(z) for z in seeds], rots, [float(sc) for sc in scales],
                [tuple(pl) for pl in places])
        if self.threads == 1:
            out = list(map(self._one, *args))
        else:
            with ThreadPoolExecutor(self.threads) as pool:
                out = list(pool.map(self._one, *args))
        batch = {"flow": torch.from_numpy(np.stack([o[0] for o in out])),
                 "intrinsics": torch.from_numpy(np.stack([o[1] for o in out])),
                 "target": torch.from_numpy(vec6.astype(np.float32))}
        if self.inv_depth:
            batch["inv_depth"] = torch.from_numpy(np.stack([o[2] for o in out]))
        return batch
