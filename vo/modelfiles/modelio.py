"""VO model files: writing and reading a network (single, ensemble, or training checkpoint) as a
:mod:`deepslam.models.modelfile` file (safetensors + a JSON tree, nothing executable), and building the
network a file describes (:func:`make_net`).

Kinds: ``deepslam-vo-model`` (:data:`MODEL_FORMAT`, version :data:`MODEL_VERSION`; an ensemble is a model
file whose tree holds ``ensemble``, :mod:`vo.ensemble`) and ``deepslam-vo-checkpoint``
(:data:`CHECKPOINT_FORMAT`, :mod:`vo.train`). Where things sit in the tree: :mod:`vo.modelfiles.modeltree`.
"""
from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path
from typing import Sequence

import torch

from deepslam.core.errors import InputError
from deepslam.models import modelfile
from deepslam.vo.ensemble import EnsemblePoseNet, input_key, same_input
from deepslam.vo.geometry.posesolve import FlowSolvePoseNet
from deepslam.vo.modelfiles import modeltree
from deepslam.vo.net import FlowPoseNet, NetConfig, PAPER, PoseNet
from deepslam.vo.trainconfig import TrainConfig
MODEL_FORMAT = "deepslam-vo-model"
MODEL_VERSION = 2
CHECKPOINT_FORMAT = "deepslam-vo-checkpoint"


def save_checkpoint(path: Path, state: dict) -> None:
    """Write a training checkpoint atomically (safetensors + JSON tree, :mod:`models.modelfile`)."""
    modelfile.save(path, CHECKPOINT_FORMAT, state)


def load_checkpoint(path: Path) -> dict:
    """A checkpoint written by :func:`save_checkpoint`; InputError for anything else (nothing in the
    file is executed)."""
    return modelfile.load(path, (CHECKPOINT_FORMAT,))[1]


def model_tree(model: PoseNet, meta: dict, half: bool = False) -> dict:
    """What a model file holds: format, version, net config, weights (float16 with ``half``), meta."""
    sd = {k: (v.half() if half and v.is_floating_point() else v).contiguous() for k, v in model.state_dict().items()}
    return {"format": MODEL_FORMAT, "version": MODEL_VERSION, "net": model.cfg.to_dict(), "state_dict": sd,
            "meta": meta}


def save_model(path: Path, model: PoseNet, meta: dict, half: bool = False) -> None:
    """The inference artifact: net config + weights (+ meta: training summary, data description).

    ``half``: store the weights as float16 (half the size; loaded back as float32).
    """
    modelfile.save(path, MODEL_FORMAT, model_tree(model, meta, half))


def load_model(path: str | Path) -> tuple[torch.nn.Module, dict]:
    """(model in eval mode, float32; meta) from a ``model.safetensors`` or a ``checkpoint.safetensors``
    (:mod:`models.modelfile`: nothing in the file is executed). The model is a :class:`vo.net.PoseNet` (either pose head),
    or for an ensemble file (:mod:`vo.ensemble`) an :class:`vo.ensemble.EnsemblePoseNet`; both map
    ``(flow, intrinsics, inv_depth)`` to ``(mean6, log_std6)`` and carry the input's ``cfg``."""
    path = Path(path)
    _, d = modelfile.load(path, (MODEL_FORMAT, CHECKPOINT_FORMAT))
    if d.get("format") == MODEL_FORMAT and "ensemble" in d:
        return _load_ensemble(path, d)
    return _model_from_tree(path, d), d.get("meta", {})


MAX_ENSEMBLE = 32
"""Most networks an ensemble file may hold."""


def _load_ensemble(path: Path, d: dict):
    """(:class:`vo.ensemble.EnsemblePoseNet` in eval mode, meta) from an ensemble file's tree."""
    parts = d["ensemble"]
    if not isinstance(parts, list) or len(parts) < 2 or not all(isinstance(t, dict) for t in parts):
        raise InputError(path, "malformed VO ensemble (its 'ensemble' is not a list of two or more networks)")
    if len(parts) > MAX_ENSEMBLE:
        raise InputError(path, f"malformed VO ensemble ({len(parts)} networks; at most {MAX_ENSEMBLE})")
    members = [_model_from_tree(path, {"format": MODEL_FORMAT, **t}) for t in parts]
    try:
        model = EnsemblePoseNet(members)
    except ValueError as e:
        raise InputError(path, f"malformed VO ensemble ({e})") from None
    return model.eval(), d.get("meta", {})


def _model_from_tree(path: Path, d: dict) -> PoseNet:
    """The network a model or checkpoint tree describes (InputError naming ``path`` when it does not fit)."""
    try:
        if d.get("format") == MODEL_FORMAT:
            sd = d["state_dict"]
        elif "model" in d and "config" in d:
            TrainConfig.from_dict(d["config"])  # a checkpoint's whole config must parse, not only its net
            sd = d["model"]
        else:
            raise InputError(path, "not a deepslam VO model (no format/net/state_dict)")
        net_cfg = NetConfig.from_dict(modeltree.net_config(d))
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(path, f"malformed VO model ({type(e).__name__}: {e})") from None
    if not isinstance(sd, dict) or not all(torch.is_tensor(v) for v in sd.values()):
        raise InputError(path, "malformed VO model (its weights are not a dict of tensors)")
    # the network the config describes, built without memory first: a small file whose config asks for a huge
    # network is refused before any allocation
    try:
        with torch.device("meta"):
            shapes = {k: tuple(v.shape) for k, v in make_net(net_cfg).state_dict().items()}
    except (ValueError, RuntimeError) as e:
        raise InputError(path, f"malformed VO model (its network config cannot be built: {str(e)[:80]})") from None
    stored = {k: tuple(v.shape) for k, v in sd.items()}
    if shapes != stored:
        bad = sorted(set(shapes) ^ set(stored)) or sorted(k for k in shapes if shapes[k] != stored[k])
        raise InputError(path, f"weights do not fit the stored network config (first difference: {bad[0][:60]})")
    model = make_net(net_cfg)
    try:
        model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in sd.items()})
    except RuntimeError as e:
        raise InputError(path, f"weights do not fit the stored network config ({str(e).splitlines()[0]})") from None
    return model.eval()


def ensemble_tree(member_trees: Sequence[dict], meta: dict) -> dict:
    """The model-file tree of an ensemble (see the module doc) from members' model trees."""
    return {"format": MODEL_FORMAT, "version": MODEL_VERSION,
            "ensemble": [{"net": t["net"], "state_dict": t["state_dict"], "meta": t.get("meta", {})}
                         for t in member_trees],
            "meta": meta}


def write_ensemble(paths: Sequence[str | Path], out: str | Path) -> dict:
    """Join the single-network model files ``paths`` into one ensemble file ``out`` (written atomically).

    The ensemble's meta lists each member's file name, sha256 and training seed (each member's own meta
    stays in its part of the tree); its data description is the members' when they share it (seeds of
    one recipe), else the union of the frame folders and sequences any member saw.

    Returns: the ensemble's meta.

    Raises:
        InputError: fewer than two files, a file that is not a single-network VO model, or members that
            read different inputs or were trained on differently set-up flow (``meta.flow``; named by file).
    """
    paths = [Path(p) for p in paths]
    if len(paths) < 2:
        raise InputError(paths[0] if paths else None, "an ensemble needs at least two model files")
    trees, first = [], None
    for p in paths:
        model, meta = load_model(p)
        if isinstance(model, EnsemblePoseNet):
            raise InputError(p, "is an ensemble already; give its members' files")
        if first is None:
            first = model.cfg
        elif not same_input(first, model.cfg):
            raise InputError(p, f"reads another input than {paths[0]} ({input_key(model.cfg)} against {input_key(first)})")
        trees.append(model_tree(model, meta))
    metas = [t["meta"] for t in trees]
    for p, m in zip(paths[1:], metas[1:]):  # one flow set-up for all: vo/slam give the ensemble one estimator
        if m.get("flow") != metas[0].get("flow"):
            raise InputError(p, f"was trained on other flow than {paths[0]} (meta.flow {m.get('flow')!r} against "
                                f"{metas[0].get('flow')!r})")
    meta = {"ensemble_of": [{"file": str(p), "sha256": hashlib.sha256(p.read_bytes()).hexdigest(),
                             "seed": (m.get("train") or {}).get("seed")} for p, m in zip(paths, metas)]}
    datas = [m.get("data") or {} for m in metas]
    if all(d == datas[0] for d in datas):
        meta["data"] = datas[0]
    else:  # what any member saw: the union of their frame folders and supervised sequences
        frames = sorted({str(f) for d in datas for f in d.get("frames", []) or []})
        seqs = sorted({str(f) for d in datas for f in (d.get("sequences") or {})})
        meta["data"] = {"frames": frames, "sequences": {s: None for s in seqs}, "members_differ": True}
    if metas[0].get("flow") is not None:
        meta["flow"] = metas[0]["flow"]  # what vo.modelfiles.models.flow_for_model reads
    poses = {m.get("pose", "net") for m in metas}
    if poses != {"net"}:  # a pose mode the members record (deepslam set-pose) carries over when they agree
        if len(poses) > 1:
            raise InputError(paths[0], f"the members record different pose modes ({', '.join(sorted(poses))}); "
                                       "set one with deepslam set-pose first")
        meta["pose"] = poses.pop()
    modelfile.save(out, MODEL_FORMAT, ensemble_tree(trees, meta))
    return meta


def write_with_solve_kernel(path, out, robust: str, iterations: int | None = None) -> dict:
    """Write the solve-head model file ``path`` to ``out`` (atomically) with the solve's kernel set to
    ``robust`` (:data:`ROBUST_KERNELS`) and, when given, ``iterations`` Gauss-Newton steps: the same
    learned weights and stage-2 calibration, a test-time change of the solve only. The file's meta keeps
    everything it recorded and adds ``solve_changed``: the kernel and steps it was trained with and the
    ones it now has.

    Returns: the new file's meta.

    Raises:
        InputError: naming ``path`` when it is not a single-network solve-head VO model, or the
            kernel or steps are not ones the head takes.
    """
    model, meta = load_model(path)
    if not isinstance(model, FlowSolvePoseNet):
        raise InputError(Path(path), "is not a single-network model with the solve pose head "
                                     "(train --pose-head solve); its solve cannot be changed")
    old = model.cfg
    try:
        cfg = dataclasses.replace(old, solve_robust=robust,
                                  solve_iterations=old.solve_iterations if iterations is None else int(iterations))
    except ValueError as e:
        raise InputError(Path(path), f"cannot set its solve: {e}") from None
    changed = FlowSolvePoseNet(cfg)
    changed.load_state_dict(model.state_dict())
    previous = meta.get("solve_changed", {}).get("trained_with",
                                                 {"robust": old.solve_robust, "iterations": old.solve_iterations})
    meta = {**meta, "solve_changed": {"trained_with": previous,
                                      "now": {"robust": cfg.solve_robust, "iterations": cfg.solve_iterations}}}
    save_model(Path(out), changed.eval(), meta)
    return meta


def make_net(cfg: NetConfig = PAPER) -> PoseNet:
    """The network ``cfg`` describes: :class:`FlowPoseNet` (``pose_head="regress"``) or
    :class:`vo.geometry.posesolve.FlowSolvePoseNet` (``"solve"``); both map ``(flow, intrinsics, inv_depth)`` to
    ``(mean6, log_std6)`` and train in :mod:`vo.train`'s two stages."""
    if cfg.pose_head == "solve":
        return FlowSolvePoseNet(cfg)
    return FlowPoseNet(cfg)
