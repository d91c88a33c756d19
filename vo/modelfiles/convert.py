"""One-time conversion of old pickle-based VO files (``torch.save``) into :mod:`models.modelfile` files."""
from __future__ import annotations

from pathlib import Path

from deepslam.core.errors import InputError
from deepslam.models import modelfile
from deepslam.vo.modelfiles.modelio import CHECKPOINT_FORMAT, MODEL_FORMAT, MODEL_VERSION


def convert_legacy(src: str | Path, dst: str | Path) -> str:
    """Read ``src`` with torch's restricted unpickler and write it to ``dst`` as safetensors.

    Returns:
        The kind written: ``deepslam-vo-model`` or ``deepslam-vo-checkpoint``.

    Raises:
        InputError: ``src`` missing, not a plain-tensor torch file, not a deepslam VO file, or
            ``dst`` already exists.
    """
    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise InputError(src, "model file is missing")
    if dst.exists():
        raise InputError(dst, "already exists; choose another --out")
    tree = modelfile.load_legacy_pickle(src)
    if not isinstance(tree, dict):
        raise InputError(src, "not a deepslam VO model or checkpoint")
    if tree.get("format") == MODEL_FORMAT:
        kind = MODEL_FORMAT
        tree = {**tree, "version": MODEL_VERSION}
    elif "model" in tree and "config" in tree and "train_state" in tree:
        kind = CHECKPOINT_FORMAT
    else:
        raise InputError(src, "not a deepslam VO model or checkpoint (no format/net/state_dict)")
    try:
        modelfile.save(dst, kind, tree)
    except TypeError as e:
        raise InputError(src, f"cannot convert: {e}") from None
    return kind
