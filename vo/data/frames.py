"""Single training frames: depth (and grey image) of sequence frames at a chosen resolution, from the
sequence's depth maps or its stereo pair (holes filled), optionally mirrored; the inputs of the synthetic
sources (:mod:`vo.data.synthetic`) and the depth channel a network reads at test time (:func:`frame_inverse_depth`).
"""
from __future__ import annotations

import dataclasses
from typing import Sequence as Seq

import cv2
import numpy as np
from scipy import ndimage
from tqdm import tqdm

from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.flow.images import to_grey
from deepslam.gen import stereo
from deepslam.vo.data.samples import holdout_mask
from deepslam.vo.net import inverse_depth_input

def resize_depth(depth_z: np.ndarray, width: int, height: int) -> np.ndarray:
    """depth_z (H, W) float32 -> (height, width) by nearest neighbour (no mixing of foreground and
    background depths at edges; 0 = unknown stays 0; non-finite values become 0)."""
    d = np.nan_to_num(np.asarray(depth_z, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    d[d < 0] = 0.0
    if d.shape == (height, width):
        return d
    return cv2.resize(d, (width, height), interpolation=cv2.INTER_NEAREST)


@dataclasses.dataclass
class Frames:
    """Single frames for synthetic training, held at the synthesis resolution.

    Attributes:
        depth_z: (N, Hs, Ws) float32 metres (0 = unknown).
        camera_index: (N,) int index into ``cameras`` per frame.
        cameras: the distinct cameras (at Hs x Ws).
        names: (N,) "sequence:frame" labels.
    """

    depth_z: np.ndarray
    camera_index: np.ndarray
    cameras: list[PinholeCamera]
    names: list[str]

    def __len__(self) -> int:
        return len(self.depth_z)

    def subset(self, idx) -> "Frames":
        idx = np.asarray(idx, dtype=np.int64)
        return Frames(self.depth_z[idx], self.camera_index[idx], self.cameras, [self.names[i] for i in idx])

    def split(self, holdout_fraction: float, seed: int) -> tuple["Frames", "Frames"]:
        """(train, holdout) frames by a seeded permutation (held-out frames are never trained on)."""
        hold = holdout_mask(list(range(len(self))), holdout_fraction, seed)
        return self.subset(np.flatnonzero(~hold)), self.subset(np.flatnonzero(hold))


def fill_depth_holes(depth_z: np.ndarray, keep_sky: bool = False) -> np.ndarray:
    """Fill unknown depth (0 or non-finite) with the depth of the nearest known pixel (Euclidean
    nearest, scipy.ndimage.distance_transform_edt), e.g. the band at the left border where stereo
    matching has no disparity range, occlusion shadows, textureless road. A flow estimator reports
    flow there, so the synthetic flow should have some too.

    ``keep_sky``: holes connected to the top image border are the sky (no disparity because it is at
    infinity, not because matching failed) and stay 0, a point at infinity. That is the right
    geometry (a sim-only network read the exact flow of KITTI 06's filled frames at 1.47x the motion,
    1.15x with the sky open), but not the default: DIS propagates the flow of nearby trees and roofs
    into a real sky much as the fill does, and a DIS-trained model with 06's sky left open read 06 at
    1.07 (filled: 1.01) and unseen 07 no better (1.41 either way).

    depth_z: (H, W) float32 metres. Returns (H, W) float32 (unchanged where known; all zeros stays zeros).
    """
    d = np.asarray(depth_z, dtype=np.float32)
    hole = ~(np.isfinite(d) & (d > 0))
    if not hole.any() or hole.all():
        return np.where(hole, 0.0, d).astype(np.float32)
    idx = ndimage.distance_transform_edt(hole, return_distances=False, return_indices=True)
    out = d[idx[0], idx[1]].astype(np.float32)
    if keep_sky:
        labels, _ = ndimage.label(hole)
        sky_labels = np.unique(labels[0][labels[0] > 0])
        out[np.isin(labels, sky_labels)] = 0.0
    return out


def depth_source(seq, depth: str) -> str:
    """Where frame depth comes from for ``seq``: ``rendered`` (its depth maps: a render or an RGB-D sensor) or
    ``stereo`` (its rectified pair); ``depth`` is ``auto`` (depth maps when present), ``rendered`` or ``stereo``.
    InputError where the sequence has not got that source."""
    how = depth
    if how == "auto":
        how = "rendered" if seq.has_depth else "stereo"
    if how == "rendered" and not seq.has_depth:
        raise InputError(seq.root, "sequence has no depth maps (use --depth stereo for a stereo sequence)")
    if how == "stereo" and not seq.has_stereo:
        raise InputError(seq.root, "sequence has neither depth maps nor a rectified stereo pair")
    if how not in ("rendered", "stereo"):
        raise InputError(None, f"unknown depth source {depth!r} (auto, rendered or stereo)")
    return how


def _frame_indices(seq, frame_step: int, max_frames: int) -> list[int]:
    idx = list(range(0, len(seq), max(1, frame_step)))
    return idx[:max_frames] if max_frames else idx


def _frame_depth(seq, i: int, how: str, fill_stereo_holes: bool, width: int, height: int) -> np.ndarray:
    """depth_z (height, width) float32 of frame i (nearest-neighbour resized), 0 = none; stereo holes
    filled at that resolution."""
    d = seq.depth(i) if how == "rendered" else stereo_depth(seq, i)
    d = resize_depth(d, width, height)  # also cleans NaN / inf / negative to 0
    if how == "stereo" and fill_stereo_holes:
        d = fill_depth_holes(d)
    return d


def load_frames(sequences: Seq, width: int, height: int, frame_step: int = 1, depth: str = "auto",
                max_frames: int = 0, progress: bool = True, fill_stereo_holes: bool = True) -> Frames:
    """Depth of every ``frame_step``-th frame of each sequence, resized to ``width`` x ``height``.

    Args:
        sequences: :class:`core.sequence.Sequence` objects.
        width, height: synthesis resolution.
        frame_step: take frames 0, step, 2 step, ...
        depth: ``rendered`` (the sequence's depth maps, e.g. our format), ``stereo`` (from the
            rectified stereo pair via :mod:`gen.stereo`) or ``auto`` (rendered when present, else stereo).
        max_frames: at most this many frames per sequence (0 = all).
        fill_stereo_holes: fill the unknown pixels of stereo depth (:func:`fill_depth_holes`);
            rendered depth keeps its zeros (nothing there: sky, a point at infinity).
    """
    depths, cam_idx, cams, names = [], [], [], []
    for seq in sequences:
        how = depth_source(seq, depth)
        cam = seq.camera.scaled(width, height)
        if cam not in cams:
            cams.append(cam)
        ci = cams.index(cam)
        for i in tqdm(_frame_indices(seq, frame_step, max_frames), desc=f"depth {seq.name} ({how})", unit="frame",
                      disable=not progress, leave=False):
            depths.append(_frame_depth(seq, i, how, fill_stereo_holes, width, height))
            cam_idx.append(ci)
            names.append(f"{seq.name}:{i}")
    if not depths:
        raise InputError(None, "no frames to train on")
    return Frames(np.stack(depths), np.array(cam_idx, dtype=np.int64), cams, names)


def frame_inverse_depth(seq, i: int, width: int, height: int) -> np.ndarray:
    """The depth channel of frame i as a network with one reads it at test time: (1, height, width)
    float32 1/m (0 = unknown), from the sequence's depth maps (sensor or rendered) or else its stereo
    pair (holes filled, as in training); InputError for a sequence with neither."""
    how = depth_source(seq, "auto")
    d = seq.depth(i) if how == "rendered" else fill_depth_holes(stereo_depth(seq, i))
    return inverse_depth_input(d, width, height)


def stereo_depth(seq, i: int) -> np.ndarray:
    """depth_z (H, W) float32 of frame i from its rectified stereo pair (gen.stereo, SGBM), 0 = unknown."""
    return np.asarray(stereo.sequence_depth(seq, i), dtype=np.float32)


@dataclasses.dataclass
class ImageFrames:
    """Single frames with their image, for training on an estimator's flow (:class:`EstimatedFlowSource`).

    Held at each sequence's own resolution, because an estimator's errors depend on it (the network
    later sees flow estimated at that resolution, then resized).

    Attributes:
        grey: N arrays (H_k, W_k) uint8.
        depth_z: N arrays (H_k, W_k) float32 metres (0 = unknown / sky): the geometry the second view
            is rendered from.
        camera_index: (N,) int index into ``cameras``.
        cameras: the distinct cameras (each at its frames' H_k x W_k).
        names: N "sequence:frame" labels.
        depth_sensor: N arrays (H_k, W_k) float32 metres (0 = no reading) or None per frame: the depth a
            network's depth channel reads where it is not ``depth_z`` (a render with a simulated sensor,
            ``--depth-noise``: the view comes from the true surfaces, the network sees what the sensor
            reports, as on a real RGB-D camera); None (default): ``depth_z``.
    """

    grey: list
    depth_z: list
    camera_index: np.ndarray
    cameras: list[PinholeCamera]
    names: list[str]
    depth_sensor: list | None = None

    def __len__(self) -> int:
        return len(self.grey)

    def network_depth(self, k: int) -> np.ndarray:
        """Frame k's depth as the network reads it: (H_k, W_k) float32 metres, 0 = unknown."""
        sensor = None if self.depth_sensor is None else self.depth_sensor[k]
        return self.depth_z[k] if sensor is None else sensor

    def subset(self, idx) -> "ImageFrames":
        idx = np.asarray(idx, dtype=np.int64)
        return ImageFrames([self.grey[i] for i in idx], [self.depth_z[i] for i in idx], self.camera_index[idx],
                           self.cameras, [self.names[i] for i in idx],
                           None if self.depth_sensor is None else [self.depth_sensor[i] for i in idx])

    def split(self, holdout_fraction: float, seed: int) -> tuple["ImageFrames", "ImageFrames"]:
        """(train, holdout) by a seeded permutation of the source frames (as :meth:`Frames.split`); the
        downscaled copies of a frame (names ``seq:i@WxH``) go where the frame goes."""
        hold = holdout_mask([name.split("@")[0] for name in self.names], holdout_fraction, seed)
        return self.subset(np.flatnonzero(~hold)), self.subset(np.flatnonzero(hold))


def load_image_frames(sequences: Seq, frame_step: int = 1, depth: str = "auto", max_frames: int = 0,
                      progress: bool = True, fill_stereo_holes: bool = True, scales: Seq[float] = (1.0,)) -> ImageFrames:
    """Grey image and depth of every ``frame_step``-th frame, at each sequence's resolution times each
    of ``scales`` (other arguments as :func:`load_frames`).

    ``scales`` below 1 add the frame downscaled (image INTER_AREA, depth nearest, the camera scaled): an
    estimator errs differently at another resolution (DIS under-reads a road more on a smaller image),
    so a network that will see several resolutions should be trained on them. ``scales`` above 1 add it
    upsampled (image bicubic, depth nearest) exactly as ``deepslam vo --read-width`` reads a narrow
    frame (:class:`core.sequence.UpsampledView`): a 414 px render at 640 / 414 is what DIS is given at test.

    A render with a simulated depth sensor (``render --depth-noise``; :meth:`core.sequence.Sequence.depth_exact`)
    gives its exact depth as ``depth_z`` and the sensor's as ``depth_sensor``.
    """
    if not scales or any(not (0.05 <= float(sc) <= 4.0) for sc in scales):
        raise InputError(None, f"frame scales must be in [0.05, 4], got {list(scales)}")
    greys, depths, sensors, cam_idx, cams, names = [], [], [], [], [], []
    for seq in sequences:
        how = depth_source(seq, depth)
        simulated_sensor = how == "rendered" and seq.depth_exact_paths is not None
        for i in tqdm(_frame_indices(seq, frame_step, max_frames), desc=f"frames {seq.name} ({how})", unit="frame",
                      disable=not progress, leave=False):
            image = seq.image(i)
            grey = to_grey(image)
            d = _frame_depth(seq, i, how, fill_stereo_holes, seq.camera.width, seq.camera.height)
            sensor = None
            if simulated_sensor:
                d, sensor = resize_depth(seq.depth_exact(i), seq.camera.width, seq.camera.height), d
            for sc in scales:
                w, h = max(8, round(seq.camera.width * sc)), max(8, round(seq.camera.height * sc))
                cam = seq.camera.scaled(w, h)
                if cam not in cams:
                    cams.append(cam)
                same = (w, h) == (seq.camera.width, seq.camera.height)
                if same:
                    greys.append(grey)
                elif w < seq.camera.width:
                    greys.append(cv2.resize(grey, (w, h), interpolation=cv2.INTER_AREA))
                else:  # the colour image upsampled, then grey: what the estimator gets from UpsampledView
                    greys.append(to_grey(cv2.resize(image, (w, h), interpolation=cv2.INTER_CUBIC)))
                depths.append(d if same else resize_depth(d, w, h))
                sensors.append(sensor if same or sensor is None else resize_depth(sensor, w, h))
                cam_idx.append(cams.index(cam))
                names.append(f"{seq.name}:{i}" + ("" if same else f"@{w}x{h}"))
    if not greys:
        raise InputError(None, "no frames to train on")
    return ImageFrames(greys, depths, np.array(cam_idx, dtype=np.int64), cams, names,
                       sensors if any(x is not None for x in sensors) else None)


def with_mirrored(frames, keep_original: bool = True):
    """``frames`` (:class:`Frames` or :class:`ImageFrames`) followed by each frame flipped left-right, with
    its camera mirrored (:meth:`core.camera.PinholeCamera.mirrored`); only the flipped frames with
    ``keep_original=False``.

    A mirrored single frame is a valid scene of its own (the world seen in a mirror: traffic on the other
    side, the near kerb on the other hand), so the paper's training takes it as one more frame; the
    motions are drawn for it as for any other. Names get ``:mirror``. Mirror after a train / hold-out
    split, so that a frame and its mirror stay on the same side.
    """
    cams = list(frames.cameras) if keep_original else []
    for c in frames.cameras:
        if c.mirrored() not in cams:
            cams.append(c.mirrored())
    mirror_idx = np.array([cams.index(frames.cameras[i].mirrored()) for i in frames.camera_index], dtype=np.int64)
    kept = [np.asarray(frames.camera_index, dtype=np.int64)] if keep_original else []
    idx = np.concatenate(kept + [mirror_idx])
    names = (list(frames.names) if keep_original else []) + [f"{n}:mirror" for n in frames.names]
    if isinstance(frames, Frames):
        flipped = frames.depth_z[:, :, ::-1]
        return Frames(np.concatenate([frames.depth_z, flipped]) if keep_original else flipped.copy(), idx, cams, names)

    def flip(arrays):
        out = [None if a is None else np.ascontiguousarray(a[:, ::-1]) for a in arrays]
        return (list(arrays) + out) if keep_original else out

    return ImageFrames(flip(frames.grey), flip(frames.depth_z), idx, cams, names,
                       None if frames.depth_sensor is None else flip(frames.depth_sensor))
