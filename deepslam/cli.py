"""``deepslam <subcommand>``: parses arguments and dispatches; bad input becomes one line and exit 2."""
from __future__ import annotations

import argparse
import errno
import importlib
import os
import pkgutil
import sys

import deepslam.commands as _commands
from deepslam.core.errors import InputError


def _discover():
    mods = []
    for info in sorted(pkgutil.iter_modules(_commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"deepslam.commands.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            mods.append(mod)
    return mods


_ENVIRONMENT_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS, errno.EIO, errno.EISDIR,
                       errno.ENOTDIR, errno.ENOENT, errno.ENAMETOOLONG, errno.EMFILE}
"""errno values that mean the file system refused, not that deepslam is broken."""


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="deepslam", description="Training deep SLAM on single frames: simulator, "
                     "flow generator, learned odometry, SLAM and metrics.")
    sub = parser.add_subparsers(dest="command", metavar="<command>", parser_class=_Parser)
    sub.required = True
    for mod in _discover():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


class _Parser(argparse.ArgumentParser):
    """argparse that exits with status 2 and one line on a usage error (its default already is 2)."""

    def error(self, message: str):  # noqa: D401
        self.exit(2, f"{self.prog}: error: {message}\n")


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
    args = build_parser().parse_args(argv)
    try:
        rc = int(args._run(args) or 0)
        sys.stdout.flush()  # a reader gone away shows here, not in Python's own flush at exit
        return rc
    except InputError as e:
        print(f"deepslam {args.command}: error: {e.message()}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader of stdout went away (`deepslam vo ... | head -1`): stop quietly, as a shell tool does;
        # stdout is pointed at devnull so that Python's own flush at exit does not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as e:
        # The file system refused (a full disk, no permission, a read-only or failing device, a folder
        # where a file should be): the environment, not a bug. One line naming the file, exit 2;
        # every output is written atomically, so nothing half-written is left behind.
        if e.errno not in _ENVIRONMENT_ERRNOS:
            raise
        where = f"{e.filename}: " if e.filename else ""
        print(f"deepslam {args.command}: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"deepslam {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
