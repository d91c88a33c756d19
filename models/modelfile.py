"""Model and checkpoint files that cannot carry code: safetensors plus a JSON tree.

A pickle-based file (``torch.save``) runs code when it is loaded with ``weights_only=False``; users
exchange model files, so deepslam never unpickles one. Every model and training checkpoint is one
`safetensors <https://github.com/huggingface/safetensors>`_ file: the tensors, and under the
header's ``__metadata__`` two strings,

``deepslam`` = the file kind (``"deepslam-vo-model"`` or ``"deepslam-vo-checkpoint"``), and
``tree`` = a JSON document of the nested state in which every tensor is replaced by
``{"$t": "<key>"}``. Dicts whose keys are not all strings (an optimizer's per-parameter state)
are written ``{"$d": [[key, value], ...]}`` and tuples ``{"$tuple": [...]}``.

Reading one parses a JSON header and copies raw tensor bytes (``safetensors.safe_open``); nothing
in the file is executed. Old pickle-based files are refused with a pointer to
``deepslam convert-model``, which reads them once with torch's restricted unpickler
(``torch.load(weights_only=True)``: tensors and plain containers only, no arbitrary globals) and
writes the safetensors form.
"""
from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepslam.core import atomic
from deepslam.core.errors import InputError

def _encode(node: Any, tensors: dict[str, torch.Tensor], path: str) -> Any:
    if torch.is_tensor(node):
        key = path or "root"
        # clone: safetensors refuses tensors that share storage (a state dict and its best copy)
        tensors[key] = node.detach().to("cpu").contiguous().clone()
        return {"$t": key}
    if isinstance(node, dict):
        if all(isinstance(k, str) and not k.startswith("$") for k in node):
            return {k: _encode(v, tensors, f"{path}/{k}") for k, v in node.items()}
        return {"$d": [[_encode(k, tensors, f"{path}/$k{i}"), _encode(v, tensors, f"{path}/{i}")]
                       for i, (k, v) in enumerate(node.items())]}
    if isinstance(node, tuple):
        return {"$tuple": [_encode(v, tensors, f"{path}/{i}") for i, v in enumerate(node)]}
    if isinstance(node, list):
        return [_encode(v, tensors, f"{path}/{i}") for i, v in enumerate(node)]
    if isinstance(node, np.generic):
        node = node.item()
    if isinstance(node, Path):
        node = str(node)
    if node is None or isinstance(node, (bool, int, str)):
        return node
    if isinstance(node, float):
        return node if math.isfinite(node) else {"$f": repr(node)}
    raise TypeError(f"cannot store {type(node).__name__} at {path or '/'} in a model file")


def _decode(node: Any, tensors: dict[str, torch.Tensor]) -> Any:
    if isinstance(node, list):
        return [_decode(v, tensors) for v in node]
    if not isinstance(node, dict):
        return node
    if len(node) == 1:
        (tag, value), = node.items()
        if tag == "$t":
            return tensors[value]
        if tag == "$d":
            return {_decode(k, tensors): _decode(v, tensors) for k, v in value}
        if tag == "$tuple":
            return tuple(_decode(v, tensors) for v in value)
        if tag == "$f":
            return float(value)
    return {k: _decode(v, tensors) for k, v in node.items()}


def to_bytes(kind: str, tree: dict) -> bytes:
    """The safetensors bytes of ``tree`` (nested dicts/lists/tuples of tensors, numbers, strings,
    bools and None), tagged with the file ``kind``."""
    from safetensors.torch import save

    tensors: dict[str, torch.Tensor] = {}
    doc = _encode(tree, tensors, "")
    return save(tensors, metadata={"deepslam": kind, "tree": json.dumps(doc, separators=(",", ":"))})


def save(path: str | Path, kind: str, tree: dict) -> None:
    """Write ``tree`` to ``path`` atomically (see :func:`to_bytes`)."""
    atomic.write_bytes(path, to_bytes(kind, tree))


def looks_like_safetensors(path: Path) -> bool:
    """True when the file starts like safetensors: an 8-byte little-endian header length that fits the
    file, then a JSON object."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(9)
    if len(head) < 9:
        return False
    n = int.from_bytes(head[:8], "little")
    return 8 + n <= size and head[8:9] == b"{"


def is_pickle_file(path: Path) -> bool:
    """True for a ``torch.save`` file (a zip archive) or a raw pickle (protocol 2+), judged by its first
    bytes; never unpickles anything."""
    if looks_like_safetensors(path):
        return False
    with open(path, "rb") as f:
        head = f.read(2)
    return zipfile.is_zipfile(path) or (len(head) == 2 and head[0] == 0x80 and 2 <= head[1] <= 5)


def load(path: str | Path, kinds: tuple[str, ...]) -> tuple[str, dict]:
    """(kind, tree) of a deepslam safetensors file whose kind is one of ``kinds``.

    Raises:
        InputError: missing, unreadable, pickle-based (never unpickled), not safetensors, another
            kind of file, or a malformed tree.
    """
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    if path.is_dir():
        raise InputError(path, "is a folder, not a model file")
    if not path.is_file():
        raise InputError(path, "model file is missing")
    try:
        if is_pickle_file(path):
            raise InputError(path, "a pickle-based model file (it could run code when opened, so it is not "
                             f"opened); convert a file you trust once with `deepslam convert-model {path}`")
        with safe_open(str(path), framework="pt", device="cpu") as f:
            header = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except InputError:
        raise
    except (SafetensorError, OSError, ValueError, RuntimeError) as e:
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(path, f"not a deepslam model file ({first})") from None
    kind = header.get("deepslam")
    if kind not in kinds:
        raise InputError(path, f"not a deepslam model file of kind {' or '.join(kinds)} (its kind: {kind!r})")
    try:
        tree = _decode(json.loads(header["tree"]), tensors)
    except (KeyError, ValueError, TypeError) as e:
        raise InputError(path, f"malformed model file tree ({type(e).__name__}: {e})") from None
    if not isinstance(tree, dict):
        raise InputError(path, "malformed model file tree (not an object)")
    return kind, tree


def load_legacy_pickle(path: str | Path) -> Any:
    """Read an old ``torch.save`` file with torch's restricted unpickler (``weights_only=True``:
    tensors, plain containers and numbers; any other global is refused, nothing runs)."""
    path = Path(path)
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - a foreign or crafted file, reported as such
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(path, f"cannot convert: not a plain-tensor torch file ({type(e).__name__}: {first[:200]})") from None
