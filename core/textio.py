"""Reading the text files of the datasets, with every failure an InputError naming the file.

Calibration, timestamps, CSV lists, YAML and JSON headers all come through :func:`read_text`
(or :func:`read_json_object`): a missing file, a folder where a file should be, a file that cannot be
read (permissions, I/O error) or bytes that are not UTF-8 become one line naming the file, never a
traceback.
"""
from __future__ import annotations

import json
from pathlib import Path

from deepslam.core.errors import InputError


def read_text(path: str | Path, what: str = "file") -> str:
    """UTF-8 text of ``path`` (a BOM is dropped).

    Args:
        path: the file.
        what: what the file is, for the messages (e.g. ``"calibration file"``).
    """
    p = Path(path)
    if p.is_dir():
        raise InputError(p, f"is a folder, expected a {what}")
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise InputError(p, f"{what} is missing") from None
    except OSError as e:
        raise InputError(p, f"cannot read the {what} ({e.strerror or e})") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise InputError(p, f"not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start})", line=line) from None


def read_json_object(path: str | Path, what: str = "JSON file") -> dict:
    """The JSON object in ``path``; InputError for unreadable text, invalid JSON or a non-object."""
    p = Path(path)
    text = read_text(p, what)
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(p, f"not valid JSON ({e.msg})", line=e.lineno) from None
    if not isinstance(doc, dict):
        raise InputError(p, f"expected a JSON object, got {type(doc).__name__}")
    return doc
