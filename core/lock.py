"""One writer per output folder: an exclusive ``flock`` on the folder itself for the whole run.

The lock is taken on the folder's own file descriptor (no lock file, so an empty output folder stays
empty and "is it empty?" checks are unchanged). The kernel drops it when the holder exits, however it
exits: a killed run leaves no stale lock, and ``--resume`` simply takes the folder over. A second
run into a held folder is refused with :class:`~deepslam.core.errors.InputError` naming the holder's
PID (read from ``/proc/locks``).
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import os
from pathlib import Path
from typing import Iterator

from deepslam.core.errors import InputError


def lock_holder(path: Path) -> int | None:
    """PID of the process holding a ``flock`` on ``path`` (from /proc/locks), or None if unknown."""
    try:
        ino = os.stat(path).st_ino
        text = Path("/proc/locks").read_text()
    except OSError:
        return None
    for line in text.splitlines():
        parts = line.split()
        if "->" in parts or len(parts) < 6 or parts[1] != "FLOCK":
            continue
        try:
            if int(parts[5].split(":")[-1]) == ino:
                return int(parts[4])
        except ValueError:
            continue
    return None


@contextlib.contextmanager
def output_lock(out: str | Path, flag: str = "--out") -> Iterator[Path]:
    """Create ``out`` if needed and hold an exclusive lock on it until the block ends.

    A folder this call created and that is still empty when the block raises is removed again, so a
    run that fails early leaves nothing behind.

    Raises:
        InputError: ``out`` is a file, cannot be created, or another process holds its lock.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(out, f"{flag} exists and is not a folder")
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = os.open(out, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as e:
        raise InputError(out, f"cannot create or open the output folder ({e.strerror})") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise InputError(out, f"cannot lock the output folder ({e.strerror})") from None
            pid = lock_holder(out)
            who = f"process {pid}" if pid is not None else "another process"
            raise InputError(out, f"another deepslam run ({who}) is writing this folder; wait for it to finish "
                                  f"or choose another {flag}") from None
        try:
            yield out
        except BaseException:
            if created:
                with contextlib.suppress(OSError):
                    out.rmdir()  # only succeeds when nothing was written
            raise
    finally:
        os.close(fd)
