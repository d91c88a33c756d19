"""Training samples for the flow -> 6DoF network, as deterministic batches per epoch.

A *source* yields batches ``{"flow": (B, 2, h, w) float32 px at network resolution,
"intrinsics": (B, 4) float32 fx, fy, cx, cy at network resolution, "target": (B, 6) float32 paper
vector of cam_{t+k}_from_cam_t}`` (and, for a network with a depth channel, ``"inv_depth": (B, 1, h, w)
float32`` 1/m of the first frame, :func:`vo.net.inverse_depth_input`) through ``batches(epoch, batch_size)``; the same epoch gives the
same batches (seeded from the source's seed and the epoch number, never a global RNG), which is what
makes ``--resume`` reproduce an uninterrupted run bit for bit.

Sources here:

- :class:`TensorSamples`: samples held in memory (supervised pairs, a fixed validation set),
  shuffled per epoch.
- :class:`SyntheticSource`: the paper's synthetic data: single frames with depth + a motion model
  (:mod:`gen.motion`) -> flow synthesized on the fly (:func:`synthesize_flow`, batched in torch,
  gen.flow's algebra).
- :func:`toy_plane_samples`: flows of known motions over random planes, computed with
  :mod:`core.camera` alone (tests, benchmarks, smoke runs).
- :func:`supervised_samples`: flow between real frames (estimated or ground truth) + ground-truth
  relative poses.
"""
from __future__ import annotations

import dataclasses
from typing import Callable, Iterator, Sequence as Seq

import numpy as np
import torch

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.gen.flow import pool_flow, synthesize_flow
from deepslam.vo.net import inverse_depth_input

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


# ----------------------------------------------------------------------------------------------------
# toy data: flow of known motions over planes, from core.camera alone


def plane_depth(camera: PinholeCamera, normal_cam: np.ndarray, distance_m: float) -> np.ndarray:
    """depth_z (H, W) float32 of the plane ``{p : normal . p = distance}`` seen by ``camera``.

    normal_cam: (3,) unit normal in camera axes pointing away from the camera (e.g. (0, 0, 1) for a
    fronto-parallel wall, (0, 1, 0) for a floor below). Pixels whose ray misses the plane get 0.
    """
    g = camera.pixel_grid()
    rays = np.stack([(g[..., 0] - camera.cx) / camera.fx, (g[..., 1] - camera.cy) / camera.fy,
                     np.ones(g.shape[:2])], axis=-1)
    denom = rays @ np.asarray(normal_cam, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(denom > 1e-6, distance_m / denom, 0.0)
    return z.astype(np.float32)


def flow_from_depth_np(camera: PinholeCamera, depth_z: np.ndarray, cam1_from_cam0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference flow (H, W, 2) float32 px and valid (H, W) bool from one depth map and one motion.

    Unproject with depth_z (m, 0 = none), move by ``cam1_from_cam0`` (4, 4), reproject, subtract the
    grid; invalid (no depth, behind the camera, outside the image) pixels get flow 0.
    """
    g = camera.pixel_grid()
    p0 = camera.unproject(g, depth_z)
    p1 = p0 @ cam1_from_cam0[:3, :3].T + cam1_from_cam0[:3, 3]
    uv1, z1 = camera.project(p1)
    flow = uv1 - g
    valid = (depth_z > 0) & (z1 > 1e-6) & np.isfinite(flow).all(-1)
    valid &= (uv1[..., 0] >= -0.5) & (uv1[..., 0] <= camera.width - 0.5)
    valid &= (uv1[..., 1] >= -0.5) & (uv1[..., 1] <= camera.height - 0.5)
    flow = np.where(valid[..., None], flow, 0.0)
    return flow.astype(np.float32), valid


def toy_motion_sampler(rot_std_rad: float = 0.01, trans_std_m: float = 0.1, forward_m: tuple[float, float] = (0.0, 1.0)):
    """A simple motion model: euler ~ N(0, rot_std), t_x, t_y ~ N(0, trans_std), t_z ~ -U(forward_m).

    Returns ``sample(n, rng) -> (n, 6) float64`` paper vectors of cam1_from_cam0 (the camera moves
    forward, so scene points move towards it: t_z of cam1_from_cam0 is negative).
    """

    def sample(n: int, rng: np.random.Generator) -> np.ndarray:
        out = np.empty((n, 6))
        out[:, :3] = rng.normal(0.0, rot_std_rad, (n, 3))
        out[:, 3:5] = rng.normal(0.0, trans_std_m, (n, 2))
        out[:, 5] = -rng.uniform(*forward_m, n)
        return out

    return sample


def toy_plane_samples(n: int, camera: PinholeCamera, rng: np.random.Generator,
                      sample_motion: Callable[[int, np.random.Generator], np.ndarray] | None = None,
                      camera_height_m: tuple[float, float] = (1.5, 1.8), tilt_std_rad: float = 0.03) -> dict[str, np.ndarray]:
    """``n`` samples of flow over a ground plane (a car's view of a flat road) for random motions.

    The plane lies ``camera_height_m`` below the camera (a narrow range, so that the flow fixes the
    metric scale, as the road does for a car), its normal tilted by ``tilt_std_rad``; the pixels
    above the horizon see nothing (flow 0, invalid).

    Args:
        n: number of samples.
        camera: the network-resolution camera (flows are computed at its size directly).
        rng: the generator all randomness comes from.
        sample_motion: ``(n, rng) -> (n, 6)`` paper vectors of cam1_from_cam0; :func:`toy_motion_sampler` by default.

    Returns dict of numpy arrays: ``flow`` (n, 2, H, W) float32 px, ``valid`` (n, H, W) bool,
    ``intrinsics`` (n, 4) float32, ``target`` (n, 6) float32.
    """
    sample_motion = sample_motion or toy_motion_sampler()
    vec6 = sample_motion(n, rng)
    motions = se3.from_euler6(vec6)
    flows = np.zeros((n, 2, camera.height, camera.width), np.float32)
    valid = np.zeros((n, camera.height, camera.width), bool)
    for i in range(n):
        normal = np.array([rng.normal(0, tilt_std_rad), 1.0, rng.normal(0, tilt_std_rad)])
        normal /= np.linalg.norm(normal)
        depth = plane_depth(camera, normal, rng.uniform(*camera_height_m))
        depth[depth > 200.0] = 0.0  # near the horizon: too far to matter
        f, v = flow_from_depth_np(camera, depth, motions[i])
        flows[i] = f.transpose(2, 0, 1)
        valid[i] = v
    k = np.array([camera.fx, camera.fy, camera.cx, camera.cy], np.float32)
    return {"flow": flows, "valid": valid, "intrinsics": np.tile(k, (n, 1)), "target": vec6.astype(np.float32)}


# ----------------------------------------------------------------------------------------------------
# supervised: flow between real frames + ground-truth poses


@dataclasses.dataclass(frozen=True)
class PairSpec:
    """Which frame pairs of a sequence become supervised samples."""

    strides: tuple[int, ...] = (1,)
    """Frame gaps k of the pairs (i, i + k) (``consecutive`` mode); several = a mixture."""
    kind: str = "consecutive"
    """``consecutive`` (pairs i, i + k) or ``loops`` (pairs far apart in time that see the same place)."""
    loop_min_gap_frames: int = 20
    """Loops: the two frames are at least this many frames apart."""
    loop_max_distance_m: float = 3.0
    """Loops: camera centres at most this far apart, metres."""
    loop_max_angle_deg: float = 20.0
    """Loops: relative rotation at most this, degrees."""
    max_pairs: int = 0
    """Keep at most this many pairs per sequence (evenly spaced; 0 = all)."""


def frame_pairs(gt_world_from_cam: np.ndarray, spec: PairSpec) -> np.ndarray:
    """(P, 2) int frame index pairs (i, j), i < j, of one sequence per ``spec``."""
    n = len(gt_world_from_cam)
    if spec.kind == "consecutive":
        pairs = [(i, i + k) for k in spec.strides for i in range(n - k)]
    elif spec.kind == "loops":
        pos = gt_world_from_cam[:, :3, 3]
        pairs = []
        for i in range(n):
            j = np.arange(i + spec.loop_min_gap_frames, n)
            if not len(j):
                break
            near = np.linalg.norm(pos[j] - pos[i], axis=1) <= spec.loop_max_distance_m
            j = j[near]
            if len(j):
                ang = np.rad2deg(se3.rotation_angle(se3.relative(gt_world_from_cam[j], gt_world_from_cam[i][None])))
                pairs += [(i, int(jj)) for jj in j[ang <= spec.loop_max_angle_deg]]
    else:
        raise InputError(None, f"unknown pair kind {spec.kind!r} (consecutive or loops)")
    pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    if spec.max_pairs and len(pairs) > spec.max_pairs:
        pairs = pairs[np.linspace(0, len(pairs) - 1, spec.max_pairs).round().astype(int)]
    return pairs


def supervised_samples(seq, pairs: np.ndarray, estimator, width: int, height: int, progress: bool = True,
                       unknown: str = "zero") -> dict[str, np.ndarray]:
    """Flow between frame pairs of a sequence with ground truth, at network resolution, + targets.

    Args:
        seq: :class:`core.sequence.Sequence` with ``gt``.
        pairs: (P, 2) frame indices (i, j).
        estimator: a :mod:`flow.estimators` estimator (``pair_flow(seq, i, j)``).
        width, height: network input size.
        unknown: how unknown flow is resized (:data:`flow.estimators.UNKNOWN_FLOW`: ``nan`` for a
            network with a validity channel).

    Returns ``flow`` (P, 2, height, width) float32 px (NaN where unknown, with ``nan``), ``intrinsics`` (P, 4) float32, ``target``
    (P, 6) float32 = to_euler6(cam_j_from_cam_i).
    """
    from tqdm import tqdm

    from deepslam.flow.estimators import to_network_input

    if seq.gt is None:
        raise InputError(seq.root, "supervised training needs ground-truth poses; this sequence has none")
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    flows = np.zeros((len(pairs), 2, height, width), np.float32)
    intr = np.zeros((len(pairs), 4), np.float32)
    for p, (i, j) in enumerate(tqdm(pairs, desc=f"flow {seq.name}", unit="pair", disable=not progress, leave=False)):
        flows[p], intr[p] = to_network_input(estimator.pair_flow(seq, int(i), int(j)), seq.camera, width, height,
                                                unknown)
    w = seq.gt.world_from_cam
    target = se3.to_euler6(se3.relative(w[pairs[:, 1]], w[pairs[:, 0]])) if len(pairs) else np.zeros((0, 6))
    return {"flow": flows, "intrinsics": intr, "target": target.astype(np.float32)}


def concat_samples(parts: Seq[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    keys = ("flow", "intrinsics", "target")
    return {k: np.concatenate([p[k] for p in parts], axis=0) for k in keys}


# ----------------------------------------------------------------------------------------------------
# synthetic: single frames with depth + a motion model -> flow on the fly (the paper's method)


def resize_depth(depth_z: np.ndarray, width: int, height: int) -> np.ndarray:
    """depth_z (H, W) float32 -> (height, width) by nearest neighbour (no mixing of foreground and
    background depths at edges; 0 = unknown stays 0; non-finite values become 0)."""
    import cv2

    d = np.nan_to_num(np.asarray(depth_z, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    d[d < 0] = 0.0
    if d.shape == (height, width):
        return d
    return cv2.resize(d, (width, height), interpolation=cv2.INTER_NEAREST)


def _holdout_mask(groups: list, holdout_fraction: float, seed: int) -> np.ndarray:
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
    from deepslam.gen.shards import load_samples

    s = load_samples(out_dir)
    h, w = s["flow"].shape[2:]
    if (h, w) != (height, width):
        raise InputError(out_dir, f"shards hold {h}x{w} flow, the network takes {height}x{width} "
                                  f"(make them with deepslam gen --resolution {height}x{width})")
    held = _holdout_mask(s["frame"].tolist(), holdout_fraction, seed)
    every = TensorSamples(s["flow"], s["intrinsics"], s["target"], seed=seed)
    return every.subset(np.flatnonzero(~held)), every.subset(np.flatnonzero(held))


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
        hold = _holdout_mask(list(range(len(self))), holdout_fraction, seed)
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
    from scipy import ndimage

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


def _depth_source(seq, depth: str) -> str:
    """``rendered`` or ``stereo`` for ``seq`` (``auto``: rendered when present); InputError otherwise."""
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
    from tqdm import tqdm

    depths, cam_idx, cams, names = [], [], [], []
    for seq in sequences:
        how = _depth_source(seq, depth)
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
    how = _depth_source(seq, "auto")
    d = seq.depth(i) if how == "rendered" else fill_depth_holes(stereo_depth(seq, i))
    return inverse_depth_input(d, width, height)


def stereo_depth(seq, i: int) -> np.ndarray:
    """depth_z (H, W) float32 of frame i from its rectified stereo pair (gen.stereo, SGBM), 0 = unknown."""
    from deepslam.gen import stereo

    return np.asarray(stereo.sequence_depth(seq, i), dtype=np.float32)


def motion_sampler(model, loops: bool = False):
    """``(n, rng) -> (n, 6)`` from a :class:`gen.motion.MotionModel`: its consecutive distribution, or
    with ``loops`` its loop distribution (NN_loops)."""
    if loops and model.loop is None:
        raise InputError(None, "the motion model has no loop distribution (fit it with --loops)")
    frac = 1.0 if loops else 0.0
    return lambda n, rng: model.sample(n, rng, frac)[0]


class MotionMixture:
    """Several motion samplers mixed with weights (strides 1, 2, 3..., or consecutive + loops).

    Args:
        samplers: callables ``(n, rng) -> (n, 6)`` paper vectors of cam1_from_cam0 (e.g. the
            ``sample`` method of a gen.motion model).
        weights: mixing weights (normalised here); equal by default.
        names: labels for the resolved config.
    """

    def __init__(self, samplers, weights=None, names=None):
        self.samplers = list(samplers)
        w = np.ones(len(self.samplers)) if weights is None else np.asarray(weights, dtype=np.float64)
        if len(w) != len(self.samplers) or (w < 0).any() or w.sum() <= 0:
            raise InputError(None, f"bad motion mixture weights {list(w)}")
        self.weights = w / w.sum()
        self.names = list(names) if names else [f"motion{k}" for k in range(len(self.samplers))]

    def __call__(self, n: int, rng: np.random.Generator) -> np.ndarray:
        which = rng.choice(len(self.samplers), size=n, p=self.weights)
        out = np.zeros((n, 6))
        for k, s in enumerate(self.samplers):
            m = which == k
            if m.any():
                out[m] = np.asarray(s(int(m.sum()), rng), dtype=np.float64).reshape(-1, 6)
        return out


class FlatSpeed:
    """A motion sampler whose forward speed is uniform over a range instead of the fitted prior, for
    all of its motions or for a fraction of them.

    The fitted Student-t of t_z (KITTI: about 9 m/s, scale 3 m/s) teaches a network a speed prior:
    it reads slow driving too fast and the highway too slow. This keeps every other DoF of ``base``
    and draws the forward motion per frame uniformly in ``[min_mps, max_mps] / rate_hz``, so the
    flow is the only cue to the speed. Forward is -t_z of cam1_from_cam0 (the paper's vector).
    With ``fraction`` < 1 only that share of the motions (each chosen with probability ``fraction``)
    gets the flat speed and the rest keep ``base``'s: a prior with a flat tail, which shows the
    network the speeds its fitted prior all but never draws (KITTI's: under 2 % above 20 m/s, none
    above 27 m/s) while keeping the prior's help at the speeds it covers.

    Args:
        base: ``(n, rng) -> (n, 6)`` sampler (its t_z is replaced).
        min_mps, max_mps: speed range, m/s (0 <= min < max).
        rate_hz: frame rate of the motions (KITTI 10 Hz; a stride-k model: 10 / k).
        fraction: share of the motions drawn with the flat speed, in (0, 1]. At 1 (the default) no
            choice is drawn, so the draws are those of the sampler before this option existed.
    """

    def __init__(self, base, min_mps: float, max_mps: float, rate_hz: float, fraction: float = 1.0):
        if not (np.isfinite([min_mps, max_mps, rate_hz]).all() and 0 <= min_mps < max_mps and rate_hz > 0):
            raise InputError(None, f"bad speed range {min_mps}:{max_mps} m/s at {rate_hz} Hz (need 0 <= min < max)")
        if not (np.isfinite(fraction) and 0 < fraction <= 1):
            raise InputError(None, f"bad flat-speed fraction {fraction} (need 0 < fraction <= 1)")
        self.base, self.min_mps, self.max_mps, self.rate_hz = base, float(min_mps), float(max_mps), float(rate_hz)
        self.fraction = float(fraction)

    def __call__(self, n: int, rng: np.random.Generator) -> np.ndarray:
        out = np.array(self.base(n, rng), dtype=np.float64).reshape(n, 6)
        flat = -rng.uniform(self.min_mps, self.max_mps, n) / self.rate_hz
        if self.fraction >= 1.0:
            out[:, 5] = flat
        else:
            chosen = rng.random(n) < self.fraction
            out[chosen, 5] = flat[chosen]
        return out

    @classmethod
    def parse(cls, base, text: str, rate_hz: float) -> "FlatSpeed":
        """From ``MIN:MAX[@FRACTION]`` m/s (the ``train --speed-range`` flag); InputError naming the flag."""
        rng_text, _, frac_text = text.partition("@")
        try:
            lo, hi = (float(x) for x in rng_text.split(":"))
            fraction = float(frac_text) if frac_text else 1.0
        except ValueError:
            raise InputError(None, f"--speed-range must be MIN:MAX[@FRACTION] (m/s; a fraction in (0, 1]), "
                                   f"got {text!r}") from None
        return cls(base, lo, hi, rate_hz, fraction)


class CameraTilt:
    """Random rotations of the training frames' cameras about their centres (pitch and roll), exact
    from the single frame (:mod:`gen.rotate_view`): the road then sits at other image rows, as it does
    under another camera mounting, a loaded car or a braking one.

    Why: a network reads metric translation largely from where the road lies in the image. The
    simulated car's camera is level, KITTI's is pitched down by about a degree, and a model trained on
    level renders read KITTI 06's exact flow (stereo depth + ground-truth motion) at 1.175x the motion,
    1.03x once the frames were levelled by 0.95 degrees (14 % per degree).

    The sampled motion is the car's, in the level camera; the sample's motion and target are that motion
    seen from the rotated camera (``R m R^T``), so the car still drives along its road.

    Args:
        pitch_deg: (min, max) pitch, degrees, positive = looking further down; uniform.
        roll_deg: roll drawn uniformly in (-roll_deg, roll_deg), degrees.
    """

    def __init__(self, pitch_deg: tuple[float, float], roll_deg: float = 0.0):
        lo, hi = (float(x) for x in pitch_deg)
        if not (np.isfinite([lo, hi, roll_deg]).all() and -30 <= lo <= hi <= 30 and 0 <= roll_deg <= 30):
            raise InputError(None, f"bad camera tilt: pitch {lo}:{hi} deg, roll {roll_deg} deg "
                                   "(need -30 <= min <= max <= 30, 0 <= roll <= 30)")
        self.pitch_deg, self.roll_deg = (lo, hi), float(roll_deg)

    @classmethod
    def parse(cls, text: str) -> "CameraTilt":
        """From ``PMIN:PMAX[:ROLL]`` degrees (the ``--camera-tilt-deg`` flag)."""
        try:
            parts = [float(x) for x in text.split(":")]
            if len(parts) not in (2, 3):
                raise ValueError
        except ValueError:
            raise InputError(None, f"--camera-tilt-deg must be PMIN:PMAX[:ROLL] in degrees, got {text!r}") from None
        return cls((parts[0], parts[1]), parts[2] if len(parts) == 3 else 0.0)

    def to_dict(self) -> dict:
        return {"pitch_deg": list(self.pitch_deg), "roll_deg": self.roll_deg}

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, 3, 3) float64 cam_new_from_cam rotations."""
        from deepslam.gen.rotate_view import rotation_from_pitch_roll

        pitch = np.radians(rng.uniform(*self.pitch_deg, n))
        roll = np.radians(rng.uniform(-self.roll_deg, self.roll_deg, n))
        return np.stack([rotation_from_pitch_roll(p, r) for p, r in zip(pitch, roll)]) if n else np.zeros((0, 3, 3))


class SceneScale:
    """A random scale of each training frame's depth (the whole scene, log-uniform in [min, max]): the
    same image then stands for a smaller or larger world, so the same motion makes more or less
    parallax. The flow (exact, or the estimator's on a view rendered from the scaled depth) and the
    depth channel follow the scaled depth; the motion and target stay metric.

    Why: a network reads translation from the parallax of the geometry it was shown. The simulated
    rooms' nearest tenth of the pixels lies 2-2.5 m away, the TUM fr3/teddy slice's 0.8 m (median depth
    3-4.5 m against 2.5 m); at the same hand-held motion the real scene's parallax is two to three times
    any training frame's.

    Args:
        lo, hi: the factor's range (0.05 <= lo <= hi <= 20).
    """

    def __init__(self, lo: float, hi: float):
        lo, hi = float(lo), float(hi)
        if not (np.isfinite([lo, hi]).all() and 0.05 <= lo <= hi <= 20):
            raise InputError(None, f"bad scene scale {lo}:{hi} (need 0.05 <= min <= max <= 20)")
        self.lo, self.hi = lo, hi

    @classmethod
    def parse(cls, text: str) -> "SceneScale":
        """From ``MIN:MAX`` (the ``--scene-scale`` flag)."""
        try:
            lo, hi = (float(x) for x in text.split(":"))
        except ValueError:
            raise InputError(None, f"--scene-scale must be MIN:MAX (factors), got {text!r}") from None
        return cls(lo, hi)

    def to_dict(self) -> dict:
        return {"min": self.lo, "max": self.hi}

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n,) float64 factors, log-uniform."""
        return np.exp(rng.uniform(np.log(self.lo), np.log(self.hi), n))


def _tilted(rot: np.ndarray, cam1_from_cam0: np.ndarray) -> np.ndarray:
    """(n, 4, 4) motions seen from cameras rotated by ``rot`` (n, 3, 3): ``R m R^T``."""
    from deepslam.gen.rotate_view import rotate_motion

    return np.stack([rotate_motion(m, r) for m, r in zip(cam1_from_cam0, rot)])


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
        from tqdm import tqdm

        rng = np.random.default_rng(epoch_seed(seed, 0, 0xA11))
        parts = [self.make_batch(rng, min(256, n - s)) for s in
                 tqdm(range(0, n, 256), desc="samples", unit="batch", disable=not progress, leave=False)]
        inv = torch.cat([p["inv_depth"] for p in parts]).numpy() if "inv_depth" in parts[0] else None
        return TensorSamples(torch.cat([p["flow"] for p in parts]).numpy(), torch.cat([p["intrinsics"] for p in parts]).numpy(),
                             torch.cat([p["target"] for p in parts]).numpy(), seed=seed, inv_depth=inv)


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
    """

    def __init__(self, frames: Frames, sample_motion, samples_per_epoch: int, seed: int = 0, synth_factor: int = 1,
                 missing_depth: str = "infinity", synthesize=None, tilt: CameraTilt | None = None,
                 inv_depth: bool = False, scene_scale: SceneScale | None = None, unknown: str = "zero"):
        from deepslam.flow.estimators import check_unknown

        self.unknown = check_unknown(unknown)
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
        self._depth = torch.from_numpy(np.ascontiguousarray(frames.depth_z))
        hs, ws = frames.depth_z.shape[1:]
        if hs % self.synth_factor or ws % self.synth_factor:
            raise ValueError(f"frames {hs}x{ws} are not a multiple of synth_factor {self.synth_factor}")
        self._k_synth = np.array([[c.fx, c.fy, c.cx, c.cy] for c in frames.cameras], np.float64)
        self._k_out = np.array([[c.fx, c.fy, c.cx, c.cy] for c in
                                (c.scaled(ws // self.synth_factor, hs // self.synth_factor) for c in frames.cameras)], np.float32)

    def __len__(self) -> int:
        return self.samples_per_epoch

    def make_batch(self, rng: np.random.Generator, n: int) -> Batch:
        idx = rng.integers(0, len(self.frames), n)
        vec6 = np.asarray(self.sample_motion(n, rng), dtype=np.float64).reshape(n, 6)
        cams = self.frames.camera_index[idx]
        depth = self._depth[torch.from_numpy(idx)]
        motion = se3.from_euler6(vec6)
        if self.tilt is not None:
            from deepslam.gen.rotate_view import rotate_depth

            rot = self.tilt.sample(n, rng)
            depth = torch.from_numpy(np.stack([rotate_depth(d, self.frames.cameras[c], r, outside="nearest")
                                               for d, c, r in zip(depth.numpy(), cams, rot)]))
            motion = _tilted(rot, motion)
            vec6 = se3.to_euler6(motion)
        if self.scene_scale is not None:
            depth = depth * torch.from_numpy(self.scene_scale.sample(n, rng).astype(np.float32)).view(n, 1, 1)
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
            batch["inv_depth"] = torch.from_numpy(np.stack([inverse_depth_input(d, w, h) for d in depth.numpy()]))
        return batch




# ----------------------------------------------------------------------------------------------------
# synthetic, as an estimator sees it: single frame -> rendered second view -> estimated flow


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
        hold = _holdout_mask([name.split("@")[0] for name in self.names], holdout_fraction, seed)
        return self.subset(np.flatnonzero(~hold)), self.subset(np.flatnonzero(hold))


def load_image_frames(sequences: Seq, frame_step: int = 1, depth: str = "auto", max_frames: int = 0,
                      progress: bool = True, fill_stereo_holes: bool = True, scales: Seq[float] = (1.0,)) -> ImageFrames:
    """Grey image and depth of every ``frame_step``-th frame, at each sequence's resolution times each
    of ``scales`` (other arguments as :func:`load_frames`).

    ``scales`` below 1 add the frame downscaled (image INTER_AREA, depth nearest, the camera scaled): an
    estimator errs differently at another resolution (DIS under-reads a road more on a smaller image),
    so a network that will see several resolutions should be trained on them.

    A render with a simulated depth sensor (``render --depth-noise``; :meth:`core.sequence.Sequence.depth_exact`)
    gives its exact depth as ``depth_z`` and the sensor's as ``depth_sensor``.
    """
    import cv2
    from tqdm import tqdm

    from deepslam.flow.estimators import to_grey

    if not scales or any(not (0.05 <= float(sc) <= 1.0) for sc in scales):
        raise InputError(None, f"frame scales must be in [0.05, 1], got {list(scales)}")
    greys, depths, sensors, cam_idx, cams, names = [], [], [], [], [], []
    for seq in sequences:
        how = _depth_source(seq, depth)
        simulated_sensor = how == "rendered" and seq.depth_exact_paths is not None
        for i in tqdm(_frame_indices(seq, frame_step, max_frames), desc=f"frames {seq.name} ({how})", unit="frame",
                      disable=not progress, leave=False):
            grey = to_grey(seq.image(i))
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
                greys.append(grey if same else cv2.resize(grey, (w, h), interpolation=cv2.INTER_AREA))
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
    """

    def __init__(self, frames: ImageFrames, sample_motion, estimator: str, width: int, height: int,
                 samples_per_epoch: int, seed: int = 0, threads: int = 2, estimator_options: dict | None = None,
                 appearance_noise: float = 0.0, tilt: CameraTilt | None = None, inv_depth: bool = False,
                 scene_scale: SceneScale | None = None, unknown: str = "zero"):
        import threading

        from deepslam.flow.estimators import check_unknown

        self.unknown = check_unknown(unknown)
        self.inv_depth = bool(inv_depth)
        self.scene_scale = scene_scale
        from deepslam.flow import registry as flow_registry

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
             scale: float = 1.0) -> tuple[np.ndarray, ...]:
        from deepslam.gen.novel_view import render_novel_view
        from deepslam.flow import estimators as flow_estimators, registry as flow_registry

        est = getattr(self._local, "est", None)
        if est is None:
            est = self._local.est = flow_registry.make(self.estimator, **self.estimator_options)
        cam = self.frames.cameras[self.frames.camera_index[k]]
        grey0, depth0, seen0 = self.frames.grey[k], self.frames.depth_z[k], self.frames.network_depth(k)
        if rot is not None:
            from deepslam.gen.rotate_view import rotate_depth, rotate_image

            grey0, depth0 = rotate_image(grey0, cam, rot), rotate_depth(depth0, cam, rot, outside="nearest")
            seen0 = depth0 if seen0 is self.frames.depth_z[k] else rotate_depth(seen0, cam, rot, outside="nearest")
        if scale != 1.0:
            depth0, seen0 = depth0 * np.float32(scale), seen0 * np.float32(scale)
        grey1, _ = render_novel_view(grey0, depth0, cam, motion)
        if self.appearance_noise > 0:
            noise = np.random.default_rng(noise_seed).normal(0.0, self.appearance_noise, grey1.shape)
            grey1 = np.clip(np.rint(grey1 + noise), 0, 255).astype(np.uint8)
        flow, intr = flow_estimators.to_network_input(est.estimate(grey0, grey1), cam, self.width, self.height,
                                                     self.unknown)
        return flow, intr, (inverse_depth_input(seen0, self.width, self.height) if self.inv_depth else None)

    def make_batch(self, rng: np.random.Generator, n: int) -> Batch:
        from concurrent.futures import ThreadPoolExecutor

        idx = rng.integers(0, len(self.frames), n)
        vec6 = np.asarray(self.sample_motion(n, rng), dtype=np.float64).reshape(n, 6)
        seeds = rng.integers(0, 2 ** 63, n) if self.appearance_noise > 0 else np.zeros(n, np.int64)
        motion = se3.from_euler6(vec6)
        rots = [None] * n
        if self.tilt is not None:
            rots = list(self.tilt.sample(n, rng))
            motion = _tilted(np.stack(rots), motion)
            vec6 = se3.to_euler6(motion)
        scales = self.scene_scale.sample(n, rng) if self.scene_scale is not None else np.ones(n)
        args = ([int(k) for k in idx], list(motion), [int(z) for z in seeds], rots, [float(sc) for sc in scales])
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
