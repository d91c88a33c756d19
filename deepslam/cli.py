"""``deepslam <subcommand>``: parses arguments and dispatches; bad input becomes one line and exit 2."""
from __future__ import annotations

import argparse
import errno
import importlib
import importlib.util
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


EXTRA_OF_MODULE = {"mujoco": "sim", "pyrender": "sim", "OpenGL": "sim", "trimesh": "sim", "ray": "ray",
                   "rerun": "viz", "tensorboard": "train"}
"""Top-level module -> the optional extra of pyproject.toml that installs it."""


def missing_extra(e: ModuleNotFoundError) -> str | None:
    """The one-line message for a module of an optional extra that is not installed, or None when the
    missing module belongs to no extra (then it is a broken installation, not a choice)."""
    top = (e.name or "").split(".")[0]
    extra = EXTRA_OF_MODULE.get(top)
    if extra is None:
        return None
    return f"this needs the optional module {top!r} of the [{extra}] extra: pip install 'deepslam[{extra}]'"


_ENVIRONMENT_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS, errno.EIO, errno.EISDIR,
                       errno.ENOTDIR, errno.ENOENT, errno.ENAMETOOLONG, errno.EMFILE}
"""errno values that mean the file system refused, not that deepslam is broken."""


OUTPUT_OPTIONS = {"out": "--out", "plot": "--plot", "tensorboard": "--tensorboard", "save": "--save",
                  "preview": "--preview", "save_vocabulary": "--save-vocabulary"}
"""Options (argparse dest -> flag) that name something a command writes, in any command."""
INPUT_OPTIONS = {"sequence": "--sequence", "sequences": "--sequences", "source": "--source", "model": "--model",
                 "models": "MODEL", "model_cons": "--model-cons", "model_loops": "--model-loops", "params": "--params",
                 "motion": "--motion", "poses": "--poses", "config": "--config", "real": "--real", "shards": "--shards",
                 "init": "--init", "gt": "--gt", "est": "--est", "vocabulary": "--vocabulary", "path": "PATH",
                 "scene": "--scene", "trajectory": "--trajectory"}
"""Options (argparse dest -> flag) that name something a command reads."""


def _paths(dest: str, value) -> list[str]:
    """The paths option ``dest``'s value names: a list's items as they are, and for ``motion`` each
    ``FILE[:loops][@WEIGHT]`` spec cut to FILE (no other option's path is cut at an ``@`` or ``:``)."""
    items = value if isinstance(value, (list, tuple)) else [value]
    paths = [str(v) for v in items if isinstance(v, (str, os.PathLike)) and str(v)]
    if dest == "motion":
        paths = [p.rsplit("@", 1)[0].removesuffix(":loops") for p in paths]
    return paths


SEED_RANGE = (0, 2**32 - 1)
"""Seeds every command takes (numpy's and torch's generators take these)."""


def check_extras(args: argparse.Namespace) -> None:
    """InputError naming the extra when a module the command always needs (its module's ``NEEDS``, a
    callable of the parsed arguments returning module names) is not installed: found before any work, so
    that nothing is created first. A module needed only on some paths is reported where it is imported
    (:func:`missing_extra`)."""
    for name in args._needs(args):
        try:
            missing = importlib.util.find_spec(name) is None
        except (ImportError, ValueError):  # a parent package missing, or a module blocked as None
            missing = True
        if missing:
            raise InputError(None, missing_extra(ModuleNotFoundError(name=name)) or f"needs the module {name!r}")


def check_before_work(args: argparse.Namespace) -> None:
    """What every command checks before any work: the optional modules it needs (:func:`check_extras`),
    ``--seed`` within :data:`SEED_RANGE`, and its paths (:func:`check_paths`). InputError naming the option."""
    check_extras(args)
    seed = getattr(args, "seed", None)
    if isinstance(seed, int) and not SEED_RANGE[0] <= seed <= SEED_RANGE[1]:
        raise InputError(None, f"--seed must be in {SEED_RANGE[0]}..{SEED_RANGE[1]}, got {seed}")
    check_paths(args)


def check_paths(args: argparse.Namespace) -> None:
    """Before any work, for every output-like option of ``args`` (:data:`OUTPUT_OPTIONS`): it is not and does
    not lie inside an input (:data:`INPUT_OPTIONS`), no two outputs coincide, and it can be created where
    it is asked for (:func:`core.outputs.check_writable`: names of at most 255 bytes with room for the side
    files' suffixes, an existing folder to put it in that is writable). InputError naming the option."""
    # deferred: core.outputs imports numpy, which `deepslam --help` and a usage error need not load
    from deepslam.core.outputs import check_distinct_outputs, check_output_not_input, check_writable

    given = vars(args)
    inputs = [(flag, p) for dest, flag in INPUT_OPTIONS.items() for p in _paths(dest, given.get(dest))]
    outputs = [(flag, p) for dest, flag in OUTPUT_OPTIONS.items() for p in _paths(dest, given.get(dest))]
    for flag, p in outputs:
        check_output_not_input(p, inputs, flag)
        check_writable(p, flag)
    check_distinct_outputs(outputs)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="deepslam", description="Training deep SLAM on single frames: simulator, "
                     "flow generator, learned odometry, SLAM and metrics.")
    sub = parser.add_subparsers(dest="command", metavar="<command>", parser_class=_Parser)
    sub.required = True
    for mod in _discover():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run, _needs=getattr(mod, "NEEDS", lambda args: ()))
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
        check_before_work(args)  # every output-like option and the seed, before any work
        rc = int(args._run(args) or 0)
        sys.stdout.flush()  # a reader gone away shows here, not in Python's own flush at exit
        return rc
    except InputError as e:
        print(f"deepslam {args.command}: error: {e.message()}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as e:
        line = missing_extra(e)
        if line is None:
            raise
        print(f"deepslam {args.command}: error: {line}", file=sys.stderr)
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
        # an error without a file name (a full disk while a library writes) names the run's output instead
        named = e.filename or next((getattr(args, d) for d in OUTPUT_OPTIONS if getattr(args, d, None)), None)
        where = f"{named}: " if named else ""
        print(f"deepslam {args.command}: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"deepslam {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
