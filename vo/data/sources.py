"""The training and held-out sources of ``deepslam train``, from what its data flags name: gen shards on disk,
toy plane samples, single frames with depth (:func:`vo.data.recipe.synthetic_sources`, the paper's data) or
real frame pairs with ground-truth poses (:func:`supervised_sources`). Each returns ``(training source,
held-out source, meta)``, ``meta["data"]`` recording what the samples were made of (config.json and the
model file keep it).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from deepslam.core.camera import KITTI_00_CAMERA
from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.core.sequence import check_read_width, read_for_estimated_flow
from deepslam.flow import registry as flow_registry
from deepslam.vo.data import frames, samples, supervised, toy
from deepslam.vo.net import NetConfig


def shard_sources(shards, net: NetConfig, holdout: float, seed: int):
    """Samples written by ``deepslam gen`` in folder ``shards``, split into training and held-out (fraction
    ``holdout``, by ``seed``) at the network's input size."""
    if net.valid_channel:  # shards hold flow resized with unknown = 0: nothing left to mark
        raise InputError(None, "--valid-channel needs flows made for it: --source or supervised pairs, not --shards")
    train_src, hold_src = samples.shard_samples(shards, holdout, seed, net.input_height, net.input_width)
    return train_src, hold_src, {"data": {"shards": str(shards), "n_train": len(train_src), "n_holdout": len(hold_src)}}


def toy_sources(n: int, net: NetConfig, holdout: float, seed: int):
    """``n`` toy ground-plane samples (:func:`vo.data.toy.toy_plane_samples`) seen by the KITTI 00 camera scaled
    to the network's input, split as :func:`shard_sources`."""
    cam = KITTI_00_CAMERA.scaled(net.input_width, net.input_height)
    s = toy.toy_plane_samples(n, cam, np.random.default_rng(seed))
    train_src, hold_src = samples.TensorSamples(s["flow"], s["intrinsics"], s["target"], seed=seed).split(holdout, seed)
    return train_src, hold_src, {"data": {"toy_samples": n, "camera": cam.to_dict()}}


@dataclasses.dataclass(frozen=True)
class SupervisedData:
    """What the supervised training samples are made of (the ``deepslam train --mode supervised`` flags)."""

    sequences: tuple[str, ...]
    """Sequence folders with ground-truth poses whose frame pairs are the samples."""
    pairs: supervised.PairSpec = supervised.PairSpec()
    """Which frame pairs (strides, consecutive or loop pairs, a cap)."""
    flow: str = "dis"
    """Flow estimator between the pair's frames (a :func:`flow.registry.make` name; ``gt``: the renders' exact flow)."""
    flow_options: tuple[tuple[str, object], ...] = ()
    """That estimator's options (:func:`flow.registry.estimator_options`), as (name, value) pairs."""
    holdout: float = 0.1
    """Fraction of the samples held out."""
    read_width_px: int = 0
    """Frames narrower than this are read upsampled to it (:class:`core.sequence.UpsampledView`) before an estimated
    flow is made between them, as ``deepslam vo --read-width`` reads them at test time; 0: as recorded. Exact flow
    (``gt``) and networks that read depth take the frames as recorded, as ``vo`` does."""


def supervised_sources(spec: SupervisedData, net: NetConfig, seed: int, progress: bool):
    """The frame pairs of ``spec.sequences`` with the estimator's flow at the network's input and their
    ground-truth relative poses (and each pair's first-frame depth for a depth-channel network), split into
    training and held-out by ``seed``. ``meta`` holds ``flow`` (the estimator and its options) and ``data``
    (pairs per sequence, strides, flow)."""
    if not spec.sequences:
        raise InputError(None, "supervised mode needs --sequence DIR...")
    check_read_width(spec.read_width_px)
    options = dict(spec.flow_options)
    est = flow_registry.make(spec.flow, **options)
    parts, counts, read_at = [], {}, {}
    for d in spec.sequences:
        seq = open_sequence(d)
        if seq.gt is None:
            raise InputError(seq.root, "supervised training needs ground-truth poses; this sequence has none")
        pairs = supervised.frame_pairs(seq.gt.world_from_cam, spec.pairs)  # rows of the ground truth
        if seq.gt_frames is not None:  # ... as frame indices where it does not cover every frame (TUM)
            pairs = np.asarray(seq.gt_frames)[pairs]
        if net.depth_channel:  # a sequence with no depth to read fails here, before its flow is made
            frames.depth_source(seq, "auto")
        view = read_for_estimated_flow(seq, spec.read_width_px, spec.flow, lambda: net.depth_channel)
        if view is not seq:
            seq = view
            read_at[str(seq.root)] = spec.read_width_px
        counts[str(seq.root)] = int(len(pairs))
        if len(pairs):
            parts.append(supervised.supervised_samples(seq, pairs, est, net.input_width, net.input_height, progress,
                                                       unknown=net.unknown_flow, inv_depth=net.depth_channel))
    if not parts:
        raise InputError(None, "no frame pairs to train on (sequences too short for the strides, or no loops)")
    s = samples.concat_samples(parts)
    train_src, hold_src = samples.TensorSamples(s["flow"], s["intrinsics"], s["target"], seed=seed,
                                                inv_depth=s.get("inv_depth")).split(spec.holdout, seed)
    meta = {"flow": {"estimator": spec.flow, "options": options},
            "data": {"sequences": counts, "pairs": spec.pairs.kind, "strides": list(spec.pairs.strides),
                     "flow": est.name, "n_pairs": int(sum(counts.values())),
                     "read_at_px": read_at}}
    return train_src, hold_src, meta
