"""The examples in examples/ run as a user runs them: the plug-in in ``deepslam vo``, the pytest suite with
``deepslam.testing``, and the torch DataLoader over a rendered sequence."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def quick(tmp_path_factory) -> Path:
    from deepslam.cli import main

    out = tmp_path_factory.mktemp("examples") / "quick"
    assert main(["render", "--scene", "street", "--frames", "8", "--width", "160", "--moving-objects", "3",
                 "--seed", "5", "--out", str(out), "--quiet"]) == 0
    return out


def test_user_pytest_suite_passes():
    env = {**os.environ, "PYTHONPATH": str(EXAMPLES)}
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"], cwd=EXAMPLES, env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "2 passed" in r.stdout


def test_plugin_example_in_vo(quick, tmp_path, capsys, monkeypatch):
    from deepslam.cli import main

    monkeypatch.syspath_prepend(str(EXAMPLES))
    rc = main(["vo", "--sequence", str(quick), "--odometry", "my_odometry:make", "--out", str(tmp_path / "t.txt")])
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert (tmp_path / "t.txt").is_file() and "ATE" in out.out


def test_dataloader_example(quick, monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLES))
    import torch_dataloader

    shapes = torch_dataloader.main(str(quick))
    assert shapes["image0"] == (4, 3, 48, 160) and shapes["flow"] == (4, 2, 48, 160)
    assert shapes["cam1_from_cam0"] == (4, 4, 4) and shapes["intrinsics"] == (4, 4)
