"""The command line shared by the results scripts (``bench/results_*.py``): options, errors, output."""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Callable

from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.core.lock import output_lock
from deepslam.core.paths import out_dir, shared_data_dir


def results_main(name: str, doc: str, config, quick_config, out_name: str,
                 run: Callable[[object, Path, Path], dict], markdown: Callable[[dict], str],
                 argv: list[str] | None = None) -> int:
    """Parse ``--out``, ``--data``, ``--quick``; run; print the markdown table; InputError -> one line, exit 2.

    Args:
        name: program name (``results_vo``).
        doc: the script's docstring (its first paragraph is the description).
        config / quick_config: the full and the smoke-run configuration.
        out_name: default output folder under ``out/results/`` (``_quick`` appended for --quick).
        run: (config, out folder, shared data folder) -> report dict.
        markdown: report -> markdown text.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
    ap = argparse.ArgumentParser(prog=f"python -m bench.{name}", description=doc.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help=f"output folder (default: out/results/{out_name})")
    ap.add_argument("--data", type=Path, default=None, help="shared data folder (default: ../shared/data)")
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    args = ap.parse_args(argv)
    out = args.out or out_dir() / "results" / (f"{out_name}_quick" if args.quick else out_name)
    try:
        with output_lock(out):  # one writer per results folder
            report = run(quick_config if args.quick else config, out, args.data or shared_data_dir())
    except InputError as e:
        print(f"{name}: error: {e.message()}", file=sys.stderr)
        return 2
    print(markdown(report))
    print(f"wrote {out / 'results.json'} and {out / 'results.md'}")
    return 0


def reuse_only_with_same_settings(out: Path, settings: dict) -> None:
    """Guard of a results folder whose script reuses what an earlier run left there (trained models,
    per-case records: that is how a killed run resumes). The first run, in an empty folder, writes
    ``out/settings.json``; a later run whose settings differ, or a folder holding anything without a
    ``settings.json`` (made before settings were recorded), is refused before it reads or writes
    anything, since it would report the earlier run's figures as its own.

    Args:
        out: the results folder.
        settings: JSON-able description of everything the reused files depend on (the config, digests
            of input files).

    Raises:
        InputError: naming ``settings.json`` and the keys that differ.
    """
    path = Path(out) / "settings.json"
    now = json.loads(json.dumps(settings))
    if path.is_file():
        try:
            before = json.loads(path.read_text())
        except ValueError:
            raise InputError(path, "is not JSON; remove the folder or choose another --out") from None
        if before != now:
            keys = sorted(k for k in set(before) | set(now) if before.get(k) != now.get(k))
            sub = [f"{k}.{j}" for k in keys if isinstance(before.get(k), dict) and isinstance(now.get(k), dict)
                   for j in sorted(set(before[k]) | set(now[k])) if before[k].get(j) != now[k].get(j)]
            raise InputError(path, f"this folder holds results made with other settings ({', '.join(sub or keys)}); "
                             "its models and records would be reused: choose another --out or remove the folder")
        return
    Path(out).mkdir(parents=True, exist_ok=True)
    if any(Path(out).iterdir()):  # made before settings were recorded: nothing says what it holds
        raise InputError(out, "holds results from a run that recorded no settings.json; its models and records "
                         "would be reused: choose another --out or remove the folder")
    atomic.write_json(path, now)


def parse_model_specs(specs: list[str], flows: tuple[str, ...]) -> list[tuple[str, str, str]]:
    """``--model NAME=PATH[@FLOW]`` options as (name, model path or shipped spec, flow); FLOW defaults to
    ``dis`` and must be one of ``flows``. InputError (one line) on a malformed spec."""
    out = []
    for spec in specs:
        name, _, rest = spec.partition("=")
        path, _, flow = rest.partition("@")
        flow = flow or "dis"
        if not name or not path or flow not in flows:
            raise InputError(None, f"--model {spec!r}: expected NAME=PATH[@{'|@'.join(flows)}]")
        out.append((name, path, flow))
    return out


def write_report(out: Path, report: dict, markdown: Callable[[dict], str]) -> None:
    """``results.json``, ``results.md`` (the report's markdown table) and ``stamp.json`` (date, commit,
    machine: :mod:`bench.stamp`) into ``out``, atomically."""
    from bench.stamp import write_stamp

    out.mkdir(parents=True, exist_ok=True)
    atomic.write_json(out / "results.json", report)
    atomic.write_text(out / "results.md", markdown(report))
    write_stamp(out)


def run_locked(name: str, out: Path, work: Callable[[], dict], markdown: Callable[[dict], str]) -> int:
    """``work()`` under the results folder's lock (one writer per folder), its markdown printed; an
    InputError raised by ``work`` (a bad --model, a missing slice) is one line naming ``name``, exit 2."""
    try:
        with output_lock(out):
            report = work()
    except InputError as e:
        print(f"{name}: error: {e.message()}", file=sys.stderr)
        return 2
    print(markdown(report))
    return 0


def candidate_parser(name: str, doc: str, flows: tuple[str, ...]) -> argparse.ArgumentParser:
    """The command line of a results script that scores the shipped models and ``--model`` candidates:
    ``--model NAME=PATH[@FLOW]`` (repeatable; :func:`parse_model_specs`), ``--no-shipped``, ``--out``, ``--data``."""
    ap = argparse.ArgumentParser(prog=f"python -m bench.{name}", description=doc.split("\n\n")[0])
    ap.add_argument("--model", action="append", default=[], metavar="NAME=PATH[@FLOW]",
                    help=f"a candidate model beside the shipped ones (repeatable; FLOW one of {', '.join(flows)}, "
                         "default dis)")
    ap.add_argument("--no-shipped", action="store_true", help="measure only the --model candidates")
    ap.add_argument("--out", type=Path, default=None, help=f"output folder (default out/results/{name.split('_')[-1]})")
    ap.add_argument("--data", type=Path, default=None, help="shared data folder (default ../shared/data)")
    return ap
