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
in the file is executed. Before the library opens the file and before any tensor is allocated,
:func:`check_header` reads the header itself and refuses, as one :class:`InputError`, a header over
:data:`MAX_HEADER_BYTES`, more than :data:`MAX_TENSORS` tensors, a tensor of more than
:data:`MAX_TENSOR_DIMS` dimensions or whose declared shape does not match its bytes in the file, and a
tree nested deeper than :data:`MAX_TREE_DEPTH` or referring to a tensor that is absent or referred to
twice (the writer stores every tensor once), so a small crafted file cannot make a reader allocate more
than the file holds. Old pickle-based files are refused with a pointer to
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
from safetensors import SafetensorError, safe_open
from safetensors.torch import save as safetensors_save

from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.core.textio import loads_json

MAX_HEADER_BYTES = 16 * 1024 * 1024
"""Largest safetensors header read (bytes); a VO checkpoint's is ~35 kB, a model's ~7 kB."""
MAX_TENSORS = 10_000
"""Most tensors in one model file (a checkpoint holds ~200, an ensemble 28 per member)."""
MAX_TENSOR_DIMS = 8
"""Most dimensions of one tensor."""
MAX_TREE_DEPTH = 64
"""Deepest nesting of the JSON tree (the files written here nest at most ~10 levels)."""
_DTYPE_BYTES = {"BOOL": 1, "U8": 1, "I8": 1, "F8_E5M2": 1, "F8_E4M3": 1, "I16": 2, "U16": 2, "F16": 2, "BF16": 2,
                "I32": 4, "U32": 4, "F32": 4, "I64": 8, "U64": 8, "F64": 8}

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
    tensors: dict[str, torch.Tensor] = {}
    doc = _encode(tree, tensors, "")
    return canonical_header(safetensors_save(tensors, metadata={"deepslam": kind,
                                                                "tree": json.dumps(doc, separators=(",", ":"))}))


def canonical_header(data: bytes) -> bytes:
    """``data`` (safetensors bytes) with its JSON header's keys in sorted order, same length (padded with
    spaces as safetensors pads it): the library writes the header's maps in an order that changes from
    process to process, and a file must be the same bytes for the same content (same seed, same bytes).
    The tensors' offsets are relative to the data that follows the header, so they stay valid."""
    n = int.from_bytes(data[:8], "little")
    text = json.dumps(json.loads(data[8:8 + n]), sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()
    if len(text) > n:  # another escaping than the library's; leave the file as written
        return data
    return data[:8] + text + b" " * (n - len(text)) + data[8 + n:]


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


def check_header(path: str | Path) -> tuple[dict, dict]:
    """(tensor entries, ``__metadata__``) of the safetensors header of ``path``, read and checked within
    bounds (see the module docstring) without the safetensors library and without reading any tensor.

    Raises:
        InputError: "not a deepslam model file (...)" naming what is out of bounds or inconsistent.
    """
    path = Path(path)

    def bad(what: str) -> InputError:
        return InputError(path, f"not a deepslam model file ({what})")

    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(8)
            if len(head) < 8:
                raise bad("shorter than a safetensors header")
            n = int.from_bytes(head, "little")
            if n > MAX_HEADER_BYTES:
                raise bad(f"a header of {n} bytes; at most {MAX_HEADER_BYTES}")
            if 8 + n > size:
                raise bad(f"its header of {n} bytes is longer than the file")
            raw = f.read(n)
    except OSError as e:
        raise InputError(path, f"cannot read the model file ({e.strerror or e})") from None
    try:
        header = loads_json(raw.rstrip(b" "), path, "model file header", max_depth=4, max_bytes=MAX_HEADER_BYTES)
    except InputError as e:
        raise bad(e.what) from None
    if not isinstance(header, dict):
        raise bad("the header is not a JSON object")
    meta = header.get("__metadata__") or {}
    if not isinstance(meta, dict) or not all(isinstance(v, str) for v in meta.values()):
        raise bad("its __metadata__ is not a map of strings")
    entries = {k: v for k, v in header.items() if k != "__metadata__"}
    if len(entries) > MAX_TENSORS:
        raise bad(f"{len(entries)} tensors; at most {MAX_TENSORS}")
    data_bytes = size - 8 - n
    for name, e in entries.items():
        where = f"tensor {name[:60]!r}"
        if not isinstance(e, dict) or e.get("dtype") not in _DTYPE_BYTES:
            raise bad(f"{where} has no known dtype")
        shape, offsets = e.get("shape"), e.get("data_offsets")
        if (not isinstance(shape, list) or len(shape) > MAX_TENSOR_DIMS
                or not all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in shape)):
            raise bad(f"{where} declares shape {str(shape)[:60]} (at most {MAX_TENSOR_DIMS} non-negative sizes)")
        if (not isinstance(offsets, list) or len(offsets) != 2
                or not all(isinstance(o, int) and not isinstance(o, bool) for o in offsets)
                or not 0 <= offsets[0] <= offsets[1] <= data_bytes):
            raise bad(f"{where} has data offsets {str(offsets)[:60]} outside the file's {data_bytes} data bytes")
        count = math.prod(shape)
        if count * _DTYPE_BYTES[e["dtype"]] != offsets[1] - offsets[0]:
            raise bad(f"{where} declares shape {shape} ({count} values) but holds {offsets[1] - offsets[0]} bytes")
    return entries, meta


def _tensor_refs(node: Any, out: list) -> None:
    """Append the tensor keys the tree refers to (``{"$t": key}``), without recursion."""
    stack = [node]
    while stack:
        x = stack.pop()
        if isinstance(x, list):
            stack.extend(x)
        elif isinstance(x, dict):
            if len(x) == 1 and "$t" in x:
                out.append(x["$t"])
            else:
                stack.extend(x.values())


def load(path: str | Path, kinds: tuple[str, ...]) -> tuple[str, dict]:
    """(kind, tree) of a deepslam safetensors file whose kind is one of ``kinds``.

    Raises:
        InputError: missing, unreadable, pickle-based (never unpickled), not safetensors, another
            kind of file, or a malformed tree.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(path, "is a folder, not a model file")
    if not path.is_file():
        raise InputError(path, "model file is missing")
    try:
        if is_pickle_file(path):
            raise InputError(path, "a pickle-based model file (it could run code when opened, so it is not "
                             f"opened); convert a file you trust once with `deepslam convert-model {path}`")
    except OSError as e:
        raise InputError(path, f"cannot read the model file ({e.strerror or e})") from None
    # bounds first: nothing below allocates more than the file holds
    entries, header = check_header(path)
    kind = header.get("deepslam")
    if kind not in kinds:
        raise InputError(path, f"not a deepslam model file of kind {' or '.join(kinds)} (its kind: {str(kind)[:60]!r})")
    if "tree" not in header:
        raise InputError(path, "malformed model file tree (the header has no tree)")
    doc = loads_json(header["tree"], path, "model file tree", max_depth=MAX_TREE_DEPTH, max_bytes=MAX_HEADER_BYTES)
    refs: list = []
    _tensor_refs(doc, refs)
    if len(refs) != len(set(map(str, refs))) or not all(isinstance(r, str) and r in entries for r in refs):
        raise InputError(path, "malformed model file tree (it refers to a tensor that is absent, or to one twice)")
    try:
        with safe_open(str(path), framework="pt", device="cpu") as f:
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except (SafetensorError, OSError, ValueError, RuntimeError) as e:
        first = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(path, f"not a deepslam model file ({first[:200]})") from None
    try:
        tree = _decode(doc, tensors)
    except (KeyError, ValueError, TypeError) as e:
        raise InputError(path, f"malformed model file tree ({type(e).__name__}: {str(e)[:80]})") from None
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
