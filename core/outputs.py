"""Outputs that never clobber inputs, and side files that are never someone else's.

Every command that writes files follows three rules, checked before it computes anything:

1. **An output is never an input.** :func:`check_output_not_input` refuses an output path that is one
   of the command's inputs, or lies inside an input folder (a trajectory written into the sequence it
   was estimated from, ``eval --plot`` onto ``--gt``). Paths are compared resolved, symbolic links
   followed, and an existing output that is the same file as an input by another name (a hard link)
   counts as that input.
2. **Two outputs of one run are two files.** :func:`check_distinct_outputs` refuses a run whose
   outputs coincide (``vo --out traj.png`` would write the trajectory and then its plot ``traj.png``
   onto it; ``slam --out run.json`` its record onto its trajectory).
3. **Side files are overwritten only when an earlier run of the same command wrote them.** Commands
   that write files *beside* the one the user named (``vo``: ``X.motions.csv``, ``X.config.json``,
   ``X.metrics.json``, ``X.png``; ``slam``: ``X_vo.txt``, ``X.json``) keep an ownership record, one of
   those side files (``X.config.json`` / ``X.json``), holding ``"written_by"`` (the command) and
   ``"files"`` (each side file's name and the sha256 of the bytes written). :func:`check_side_files`
   refuses the run, naming the file, when a side file exists and the record does not show it as the
   command's own: no record, a record written by something else, a file the record does not list, or
   a file whose bytes changed since (the user edited or replaced it). The file the user named
   (``--out``, ``--plot``) may be overwritten: it was asked for. A record written before records held
   digests (no ``"files"``) owns the side files of the same ``--out``. :func:`write_side_files` claims
   the names in the record before writing them (digest ``null``: a run killed meanwhile leaves files its
   rerun may replace), then records their digests.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Iterable

from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.core.integrity import sha256_file
from deepslam.core.textio import loads_json

Named = Iterable[tuple[str, "str | Path | None"]]
"""(flag or description, path) pairs; a None path is skipped."""


def _resolved(p: str | Path) -> Path:
    return Path(p).expanduser().resolve()


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def same_path(a: str | Path | None, b: str | Path | None) -> bool:
    """Whether two paths name the same place (resolved, symbolic links followed); False for a None."""
    if a is None or b is None or str(a) == "" or str(b) == "":
        return False
    try:
        return _resolved(a) == _resolved(b)
    except (OSError, RuntimeError, ValueError):
        return False


def check_output_not_input(out: str | Path | None, inputs: Named, what: str = "--out") -> None:
    """InputError naming ``out`` when it is one of ``inputs`` or lies inside one of them (a folder).

    Args:
        out: the output path (file or folder); None: nothing to check.
        inputs: (flag, path) of the command's inputs; None paths, and paths where nothing exists (a
            shipped model's name, a file the command will report missing), are skipped.
        what: the output's flag, for the message.
    """
    if out is None:
        return
    o = _resolved(out)
    for flag, inp in inputs:
        if inp is None or str(inp) == "" or not os.path.lexists(Path(inp).expanduser()):
            continue
        i = _resolved(inp)
        if o == i or _same_file(o, i):
            raise InputError(out, f"{what} is the input {flag} ({inp}): refusing to overwrite an input; choose another {what}")
        if i in o.parents:
            raise InputError(out, f"{what} lies inside the input {flag} ({inp}): refusing to write into an input; "
                                  f"choose another {what}")


NAME_MAX_BYTES = 255
"""Longest file name most file systems take (bytes of one path component)."""
SIDE_SUFFIX_BYTES = 32
"""Room left in an output's name for the suffixes of the files written beside it (``.metrics.json``,
``.motions.csv``, and a temporary file's ``.`` prefix and ``.XXXXXXXX.tmp`` infix)."""


def check_writable(out: str | Path | None, what: str = "--out") -> None:
    """InputError naming ``out`` before any work when it could not be written where it is asked for: a
    component of its path longer than :data:`NAME_MAX_BYTES` (its own name: minus
    :data:`SIDE_SUFFIX_BYTES`), or its nearest existing folder not a folder or not writable (checked with
    ``os.access``: a read-only file system, a folder without write permission). A folder the command
    will create below an existing one passes; the command creates it."""
    if out is None or str(out) == "":
        return
    path = Path(out).expanduser()
    for i, part in enumerate(path.parts):
        n = len(os.fsencode(part))
        room = NAME_MAX_BYTES - (SIDE_SUFFIX_BYTES if i == len(path.parts) - 1 else 0)
        if n > room:
            raise InputError(out, f"{what}: the name {part[:40]!r}... is {n} bytes long; at most {room} "
                                  "(file systems take 255 bytes a name, and the files written beside it add a suffix)")
    parent = path.absolute().parent
    while not os.path.lexists(parent) and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(out, f"{what}: cannot create it: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(out, f"{what}: cannot write into {parent} (no permission, or a read-only file system)")


def check_distinct_outputs(outputs: Named) -> None:
    """InputError when two of a run's outputs are the same file (resolved)."""
    seen: dict[Path, str] = {}
    for flag, p in outputs:
        if p is None:
            continue
        r = _resolved(p)
        if r in seen:
            raise InputError(p, f"{flag} and {seen[r]} are the same file; choose another name")
        seen[r] = flag


def check_run_outputs(outputs: Named, inputs: Named, record: str | Path, side: Iterable[str | Path], command: str,
                      legacy_owner: Callable[[dict], bool] | None = None) -> None:
    """All three rules for one run, before it computes anything: no output in ``outputs`` (flag, path) is or
    lies inside one of ``inputs``, no two outputs coincide, and the ``side`` files beside the ownership
    ``record`` are ``command``'s own (:func:`check_side_files`)."""
    outputs = list(outputs)
    inputs = list(inputs)
    for flag, p in outputs:
        check_output_not_input(p, inputs, flag)
    check_distinct_outputs(outputs)
    check_side_files(record, side, command, legacy_owner)


def _read_record(record: Path) -> dict | None:
    """The record's JSON object, or None when it is not a readable JSON object (bounded parse)."""
    try:
        text = record.read_text(encoding="utf-8")
        doc = loads_json(text, record, "record")
    except (OSError, UnicodeDecodeError, InputError):
        return None
    return doc if isinstance(doc, dict) else None


def check_side_files(record: str | Path, side: Iterable[str | Path], command: str,
                     legacy_owner: Callable[[dict], bool] | None = None) -> None:
    """InputError naming the first side file that exists and is not ``command``'s own (module rule 3).

    Args:
        record: the ownership record (itself one of the side files).
        side: the other side files the run will write.
        command: e.g. ``"deepslam vo"``; the record's ``written_by`` must equal it.
        legacy_owner: for a record without ``written_by`` (written by an older version): a test on its
            content saying whether it was this command's record of this output; it then owns the side
            files (their digests were not recorded).
    """
    record = Path(record)
    side = [Path(p) for p in side]
    rec = _read_record(record) if record.exists() else None
    if record.exists():
        ours = rec is not None and (rec.get("written_by") == command
                                    or ("written_by" not in rec and legacy_owner is not None and legacy_owner(rec)))
        if not ours:
            raise InputError(record, f"exists and is not a record of an earlier `{command}` run into this output; "
                                     "refusing to overwrite it (move it away or choose another --out)")
    for p in side:
        if not p.exists():
            continue
        if rec is None:
            raise InputError(p, f"exists and no record ({record.name}) shows an earlier `{command}` run wrote it; "
                                "refusing to overwrite it (move it away or choose another --out)")
        files = rec.get("files")
        if files is None and rec.get("written_by") != command:
            continue  # a legacy record: it owns its output's side files
        digest = files.get(p.name, False) if isinstance(files, dict) else False
        if digest is None:
            continue  # claimed by a run that was stopped before it recorded the digest
        if digest is False:
            raise InputError(p, f"exists and {record.name} does not list it as written by `{command}`; refusing to "
                                "overwrite it (move it away or choose another --out)")
        try:
            same = sha256_file(p) == digest
        except OSError:
            same = False
        if not same:
            raise InputError(p, f"was changed since `{command}` wrote it (its bytes no longer match {record.name}); "
                                "refusing to overwrite it (move it away or choose another --out)")


def write_side_files(record: str | Path, content: dict, command: str,
                     writers: Iterable[tuple[str | Path, Callable[[Path], None]]]) -> None:
    """Write side files and their ownership record (module rule 3).

    The record ``content`` + ``written_by`` + ``files`` (names claimed, digest null) is written first,
    then each ``writer(path)``, then the record again with the files' sha256. Side files an earlier run
    recorded and this one does not write (a plot against ground truth the sequence no longer has) stay
    listed while their bytes are unchanged, so they remain the command's own.
    """
    record = Path(record)
    writers = [(Path(p), w) for p, w in writers]
    old = _read_record(record) if record.exists() else None
    kept: dict[str, str] = {}
    if old is not None and old.get("written_by") == command and isinstance(old.get("files"), dict):
        for name, digest in old["files"].items():
            p = record.parent / str(name)
            if isinstance(digest, str) and all(p.name != q.name for q, _ in writers) and p.is_file():
                try:
                    if sha256_file(p) == digest:
                        kept[p.name] = digest
                except OSError:
                    pass
    claim = {**content, "written_by": command, "files": {**kept, **{p.name: None for p, _ in writers}}}
    atomic.write_json(record, claim)
    for p, write in writers:
        write(p)
    done = {**content, "written_by": command, "files": {**kept, **{p.name: sha256_file(p) for p, _ in writers}}}
    atomic.write_json(record, done)
