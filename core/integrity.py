"""Checksums that let a resumed run trust what an interrupted one left: sha256 of files as written,
recorded beside them, checked before anything is kept (renders, shards)."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_digests(paths, root: str | Path) -> dict[str, str]:
    """{path relative to ``root`` (posix): sha256} of files just written."""
    root = Path(root)
    return {Path(p).relative_to(root).as_posix(): sha256_file(p) for p in paths}


def record_files_match(record_path: str | Path, root: str | Path) -> bool:
    """True when the JSON record at ``record_path`` parses and every file its ``"files"`` lists
    (relative to ``root``) still hashes to the digest recorded; a record without ``"files"`` (written
    by an older version) counts as matching. A missing or unreadable record or file: False."""
    try:
        rec = json.loads(Path(record_path).read_text())
    except (OSError, ValueError, RecursionError):
        return False
    if not isinstance(rec, dict):
        return False
    files = rec.get("files")
    if files is None:
        return True
    try:
        return all(sha256_file(Path(root) / rel) == sha for rel, sha in files.items())
    except OSError:
        return False
