"""Where things sit in a VO model file's tree, readable without torch.

A VO model file (:mod:`models.modelfile`: safetensors, its JSON tree in the header under ``tree``, the
file's kind under ``deepslam``) holds one of three layouts:

- a model (``deepslam-vo-model``): ``net`` (:class:`vo.net.NetConfig` as a dict), ``state_dict``, ``meta``;
- an ensemble (``deepslam-vo-model`` with ``ensemble``: a list of member trees, each ``net``,
  ``state_dict`` and its own ``meta``; :mod:`vo.ensemble`), and the ensemble's ``meta``;
- a training checkpoint (``deepslam-vo-checkpoint``): ``config`` (a :class:`vo.train.TrainConfig` dict,
  its ``net`` inside), ``model`` (the weights), ``meta`` and the optimiser's state.

:func:`net_config` and :func:`meta` find the network's shape and the training record in any of them:
:func:`vo.train.load_model` builds the network from the first, and ``deepslam vo`` reads both from the
header before it imports torch (:func:`read_header_tree`; the flows start meanwhile: :mod:`vo.data.prefetch`).

This module does not import torch.
"""
from __future__ import annotations

import json
from pathlib import Path

from safetensors import safe_open

from deepslam.core.textio import json_depth


def net_config(tree: dict) -> dict:
    """The network's shape (a :class:`vo.net.NetConfig` dict) of a model, ensemble (its first member:
    all members share the input) or checkpoint tree. KeyError / TypeError / IndexError when the tree
    has none."""
    if "ensemble" in tree:
        return tree["ensemble"][0]["net"]
    if "net" in tree:
        return tree["net"]
    return tree["config"]["net"]


def meta(tree: dict) -> dict:
    """What the file records about its training (``meta``; {} where it records nothing)."""
    m = tree.get("meta")
    return m if isinstance(m, dict) else {}


def read_header_tree(path: str | Path) -> dict:
    """The tree of the model file at ``path`` from its header alone (no torch, no weights read; the
    tensors appear as the references :mod:`models.modelfile` wrote). Raises OSError, ValueError (incl.
    JSON errors), KeyError or safetensors' error on a missing or unreadable file: callers that only peek
    catch them and leave the report to :func:`models.modelfile.load`."""
    with safe_open(str(path), framework="numpy") as f:
        text = (f.metadata() or {})["tree"]
    # bounded (models.modelfile.MAX_TREE_DEPTH): a deep tree would end json.loads in a RecursionError
    if len(text) > 16 * 1024 * 1024 or json_depth(text) > 64:
        raise ValueError(f"{path}: the model file's tree is too large or nested too deeply")
    tree = json.loads(text)
    if not isinstance(tree, dict):
        raise ValueError(f"{path}: the model file's tree is not an object")
    return tree
