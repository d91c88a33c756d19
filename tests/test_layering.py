"""The layering of docs/api.md ("Package layout") and "no import circle" as contracts (import-linter,
``[tool.importlinter]`` in pyproject.toml), checked over the installed names: the folders sit at the repository root and packaging maps
them to ``deepslam.*``, so the check runs on a mirror of the installed tree (the ``.py`` files copied by the
same mapping), where import-linter sees every import, those inside functions too."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _mirror(dest: Path) -> Path:
    """The package tree as installed (``deepslam/``, ``deepslam/core/`` ...) under ``dest``, .py files only."""
    tool = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    dirs = tool["package-dir"]
    for package in tool["packages"]:
        # setuptools' rule: the longest mapped parent gives the folder (deepslam.vo.data -> vo/data)
        parent = max((p for p in dirs if package == p or package.startswith(p + ".")), key=len)
        src = REPO / dirs[parent] / package[len(parent) + 1:].replace(".", "/")
        out = dest / package.replace(".", "/")
        out.mkdir(parents=True, exist_ok=True)
        for f in src.glob("*.py"):
            shutil.copy2(f, out / f.name)
    return dest


def _lint(root: Path, config: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(root), "PYTHONSAFEPATH": "1"}
    return subprocess.run([sys.executable, "-c", "import sys; from importlinter.cli import lint_imports_command; "
                                                 "sys.argv = ['lint-imports', sys.argv[1], '--no-cache']; "
                                                 "lint_imports_command()", str(config)],
                          capture_output=True, text=True, cwd=root, env=env, timeout=300)


def test_the_package_keeps_its_layers_and_has_no_import_circle(tmp_path):
    root = _mirror(tmp_path / "site")
    r = _lint(root, REPO / "pyproject.toml")
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    assert "Contracts: 9 kept, 0 broken" in r.stdout, r.stdout[-2000:]


@pytest.mark.parametrize("module,line,broken", [
    ("core/se3.py", "from deepslam.vo import net", "core imports no other layer"),
    ("flow/estimators.py", "from deepslam.vo import train", "the learning stack: core <- runtime <- gen <- flow <- vo <- slam"),
    ("gen/motion.py", "from deepslam.gen import dataset", "no import circle between modules"),
    ("runtime/device.py", "from deepslam.gen import flow", "the learning stack: core <- runtime <- gen <- flow <- vo <- slam"),
])
def test_a_broken_rule_is_reported(tmp_path, module, line, broken):
    """Each kind of contract fails when the rule is broken (an upward import, a circle)."""
    root = _mirror(tmp_path / "site")
    package, name = module.split("/")
    target = root / "deepslam" / package / name
    target.write_text(target.read_text() + f"\n{line}  # noqa\n")
    if "circle" in broken:  # gen.dataset imports gen.motion already: close the circle the other way
        assert "deepslam.gen.motion" in (root / "deepslam" / "gen" / "dataset.py").read_text() or \
            "from deepslam.gen import motion" in (root / "deepslam" / "gen" / "dataset.py").read_text()
    r = _lint(root, REPO / "pyproject.toml")
    assert r.returncode != 0 and "BROKEN" in r.stdout, r.stdout[-3000:]
    assert broken in r.stdout
