"""One meaning per flag name across commands (docs/install.md, "Command-line flags"), checked on the parsers
of every command.

- ``--frames`` is a count of frames to make (render, dataset, stress); a range of frames is ``--start A
  --end B`` (vo, validate-flow; validate-flow keeps ``--frames A:B`` hidden, its older spelling; train keeps
  ``--frames DIR`` hidden, the older spelling of ``--source DIR``).
- ``--sequence`` is an input sequence folder, ``--sequences`` a count, ``--source`` folders of single frames,
  ``--kitti-sequence`` the number of a KITTI layout written, ``--backend`` the renderer.
- ``--quiet`` means no progress bar and ``--json`` one JSON document on stdout, wherever they appear;
  every command is classed below, and the ones that run long or compute figures have them.
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


# every command, by what it owes: the ones that run long, those that compute figures, and the quick tools
NEEDS_QUIET_AND_JSON = ("adapt", "calibrate", "dataset", "gen", "render", "slam", "stress", "train", "train-flow", "tune-slam",
                        "validate-flow", "vo")
NEEDS_JSON = ("eval", "fit-motion", "info")
QUICK = ("convert-model", "ensemble-model", "set-pose", "set-solve", "view")


def _shown(parser: argparse.ArgumentParser, flag: str) -> argparse.Action | None:
    """The action of ``flag`` where the help shows it under that name (not a hidden older spelling)."""
    action = _option(parser, flag)
    return None if action is None or action.help == argparse.SUPPRESS else action


def test_every_command_is_classed():
    assert sorted(_commands()) == sorted(NEEDS_QUIET_AND_JSON + NEEDS_JSON + QUICK)


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
        action = _shown(parser, "--frames")
        assert action is None or action.type is int, f"{name} --frames is not a count"


def test_sequence_source_and_backend_mean_one_thing_everywhere():
    for name, parser in _commands().items():
        for flag in ("--sequence", "--source"):  # folders: paths, never a number with a default
            action = _shown(parser, flag)
            assert action is None or (action.type is None and not action.default), (name, flag)
        action = _shown(parser, "--sequences")
        assert action is None or action.type is int, f"{name} --sequences is not a count"
        action = _option(parser, "--backend")
        if action is not None and action.option_strings[0] == "--backend":  # elsewhere the older --executor
            assert "mujoco" in action.help and "pyrender" in action.help, f"{name} --backend is not the renderer"
        action = _option(parser, "--tensorboard")
        assert action is None or action.metavar == "DIR", name
        assert _option(parser, "--sequences") is None or name == "dataset", name


def test_quiet_and_json_are_switches_everywhere():
    for name, parser in _commands().items():
        for flag in ("--quiet", "--json"):
            action = _option(parser, flag)
            assert action is None or isinstance(action, argparse._StoreTrueAction), (name, flag)
        action = _option(parser, "--quiet")
        assert action is None or "progress" in action.help, name


def test_training_commands_take_folders_by_the_rule():
    commands = _commands()
    train = commands["train"]
    # train: --source DIR..., the older --frames DIR... hidden and the same list
    new = train.parse_args(["--mode", "synthetic", "--source", "a", "b", "--out", "o"])
    old = train.parse_args(["--mode", "synthetic", "--frames", "a", "b", "--out", "o"])
    assert new.source == old.source == ["a", "b"] and _shown(train, "--frames") is None
    # train-flow: --sequence DIR, listed or repeated; render: --kitti-sequence NN
    flow = commands["train-flow"]
    assert flow.parse_args(["--sequence", "a", "b", "--sequence", "c", "--out", "o"]).sequence == ["a", "b", "c"]
    assert commands["render"].parse_args(["--kitti-sequence", "07", "--out", "o"]).kitti_sequence == "07"
    for name, argv in (("train-flow", ["--sequences", "a", "--out", "o"]), ("render", ["--sequence", "07", "--out", "o"])):
        with pytest.raises(SystemExit):
            commands[name].parse_args(argv)
    for name in ("adapt", "train", "train-flow"):
        assert _option(commands[name], "--tensorboard") is not None, name


def test_render_kitti_sequence_and_json(tmp_path, capsys):
    out = tmp_path / "kitti"
    base = ["render", "--scene", "street", "--frames", "2", "--width", "64", "--seed", "1", "--out", str(out)]
    assert main([*base, "--kitti-sequence", "07"]) == 2  # not --format kitti
    assert "--format kitti" in capsys.readouterr().err
    assert main([*base, "--format", "kitti", "--kitti-sequence", "7"]) == 2
    assert "two digits" in capsys.readouterr().err and not out.exists()
    assert main([*base, "--format", "kitti", "--kitti-sequence", "07", "--json"]) == 0
    cap = capsys.readouterr()
    doc = json.loads(cap.out)
    assert doc["path"] == str(out / "sequences" / "07") and doc["frames"] == 2 and doc["seconds"] > 0
    assert set(doc["dynamic_fraction"]) == {"mean", "max"} and doc["preview"] is None
    assert (out / "poses" / "07.txt").is_file() and "render" not in cap.err  # no progress bar


def test_train_flow_json(tmp_path, capsys):
    seq = write_analytic_sequence(tmp_path / "seq")
    assert main(["train-flow", "--sequence", str(seq), "--out", str(tmp_path / "flow"), "--max-steps", "2",
                 "--batch", "1", "--crop", "32x64", "--json"]) == 0
    cap = capsys.readouterr()
    doc = json.loads(cap.out)
    assert doc["model"] == str(tmp_path / "flow" / "flow.safetensors") and doc["steps"] == 2
    assert doc["out"] == str(tmp_path / "flow") and doc["minutes"] >= 0 and "last" in doc
    assert "flow training" not in cap.err  # no progress bar


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


def test_train_json_ends_with_the_history_and_the_minutes(tmp_path, capsys):
    assert main(["train", "--mode", "synthetic", "--toy", "64", "--net", "tiny", "--batch", "16", "--max-epochs", "1",
                 "--nll-epochs", "1", "--bf16", "off", "--out", str(tmp_path / "m"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    history = json.loads((tmp_path / "m" / "history.json").read_text())
    assert doc["last"] == history[-1] and doc["last"]["stage"] == 2 and doc["minutes"] >= 0
    assert doc["out"] == str(tmp_path / "m") and doc["epochs"] == 1
