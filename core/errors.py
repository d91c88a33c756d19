"""The one exception type for bad input.

Every reader raises :class:`InputError` with the offending file (and line where there is one); the
command line turns it into one line on stderr and exit status 2, never a traceback.
"""
from __future__ import annotations

from pathlib import Path


class InputError(Exception):
    """Bad input the user can fix: a malformed file, a missing image, an unknown name.

    Args:
        path: the file or folder at fault (or None when the fault is an argument).
        what: what is wrong, as a short phrase.
        line: 1-based line number inside ``path`` where the fault is, if known.
    """

    def __init__(self, path: str | Path | None, what: str, line: int | None = None):
        self.path = None if path is None else str(path)
        self.what = what
        self.line = line
        super().__init__(self.message())

    def __reduce__(self):
        # Rebuild from the constructor's arguments, so the error crosses process boundaries
        # (multiprocessing, Ray) intact.
        return (InputError, (self.path, self.what, self.line))

    def message(self) -> str:
        if self.path is None:
            return self.what
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        return f"{where}: {self.what}"
