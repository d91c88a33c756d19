"""One meaning per flag name across commands (docs/install.md, "Command-line flags"), checked on the parsers.

- ``--frames`` is a count of frames to make (render, dataset, stress); a range of frames is ``--start A
  --end B`` (vo, validate-flow; validate-flow keeps ``--frames A:B`` hidden, its older spelling).
- ``--quiet`` means no progress bar and ``--json`` one JSON document on stdout, wherever they appear;
  the commands that run long or compute figures have them.
- ``--format`` names the on-disk format of the files a command writes or reads.
"""
from __future__ import annotations

import argparse
import json

import pytest

from deepslam.cli import build_parser, main
from tests.gen.test_gen_validate import write_analytic_sequence


def _commands() -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _option(parser: argparse.ArgumentParser, flag: str) -> argparse.Action | None:
    return next((a for a in parser._actions if flag in a.option_strings), None)


# the commands of this project that run long or compute figures
NEEDS_QUIET_AND_JSON = ("adapt", "dataset", "gen", "slam", "train", "tune-slam", "validate-flow", "vo")
NEEDS_JSON = ("eval", "fit-motion", "info", "stress")


@pytest.mark.parametrize("command", NEEDS_QUIET_AND_JSON)
def test_long_commands_have_quiet_and_json(command):
    parser = _commands()[command]
    for flag in ("--quiet", "--json"):
        action = _option(parser, flag)
        assert action is not None and isinstance(action, argparse._StoreTrueAction), (command, flag)


@pytest.mark.parametrize("command", NEEDS_JSON)
def test_figure_commands_have_json(command):
    assert isinstance(_option(_commands()[command], "--json"), argparse._StoreTrueAction), command


def test_frames_is_a_count_wherever_it_is_shown():
    for name, parser in _commands().items():
        action = _option(parser, "--frames")
        if action is None or action.help == argparse.SUPPRESS:
            continue
        if name == "train":  # another room's command: its --frames takes folders (docs/install.md lists it)
            continue
        assert action.type is int, f"{name} --frames is not a count"


def test_quiet_and_json_are_switches_everywhere():
    for name, parser in _commands().items():
        for flag in ("--quiet", "--json"):
            action = _option(parser, flag)
            assert action is None or isinstance(action, argparse._StoreTrueAction), (name, flag)


def test_validate_flow_start_end_equals_the_older_frames_range(tmp_path, capsys):
    seq = write_analytic_sequence(tmp_path / "seq")
    assert main(["validate-flow", "--sequence", str(seq), "--start", "1", "--end", "3", "--json"]) == 0
    new = json.loads(capsys.readouterr().out)
    assert main(["validate-flow", "--sequence", str(seq), "--frames", "1:3", "--json"]) == 0
    old = json.loads(capsys.readouterr().out)
    assert new["frames_compared"] == old["frames_compared"] == 2
    assert new["static_visible"] == old["static_visible"]
    assert main(["validate-flow", "--sequence", str(seq), "--start", "1", "--frames", "1:3"]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["validate-flow", "--sequence", str(seq), "--end", "9", "--quiet"]) == 2
    assert "outside" in capsys.readouterr().err


def test_executor_is_the_name_and_backend_still_works():
    commands = _commands()
    for name in ("gen", "dataset"):
        parser = commands[name]
        assert _option(parser, "--executor") is _option(parser, "--backend")
        ns = parser.parse_args(["--executor", "local", "--out", "x"] + (["--source", "s", "--motion", "m", "--samples", "1"]
                                                                         if name == "gen" else []))
        assert ns.backend == "local"
