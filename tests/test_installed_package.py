"""deepslam installed (not editable) into a fresh virtualenv, used from a folder outside the checkout.

The virtualenv reuses this environment's dependencies through a ``.pth`` line (nothing is
downloaded; the editable install's finder is not loaded there, because .pth files of a directory
named in a .pth line are not processed), and deepslam itself is built from a copy of the checkout
with ``pip install --no-deps --no-build-isolation``.
"""
from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
import venv
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
IGNORED = shutil.ignore_patterns(".venv", ".git", "out", "build", "*.egg-info", "__pycache__", ".pytest_cache",
                                 "tests", "bench")


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> dict:
    """{"python": the fresh venv's interpreter, "site": its site-packages, "work": a folder outside the checkout}."""
    root = tmp_path_factory.mktemp("install")
    src = root / "src"
    shutil.copytree(REPO, src, ignore=IGNORED)
    env_dir = root / "venv"
    venv.EnvBuilder(with_pip=False, symlinks=True).create(env_dir)
    py = env_dir / "bin" / "python"
    site_dir = Path(subprocess.check_output([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                                            text=True).strip())
    (site_dir / "_deepslam_test_deps.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    r = subprocess.run([py, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--no-index", str(src)],
                       capture_output=True, text=True, cwd=root)
    assert r.returncode == 0, r.stderr[-3000:]
    work = root / "work"
    work.mkdir()
    return {"python": py, "site": site_dir, "work": work}


def _run(installed: dict, *args: str, extra_env: dict | None = None, **kw) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env.update(MUJOCO_GL="egl", PYOPENGL_PLATFORM="egl", DEEPSLAM_PROGRESS="0", **(extra_env or {}))
    return subprocess.run([str(installed["python"]), *args], capture_output=True, text=True, cwd=installed["work"],
                          env=env, timeout=600, **kw)


@pytest.mark.slow
def test_one_top_level_name_and_models_as_package_data(installed):
    top = sorted(p.name for p in installed["site"].iterdir() if not p.name.startswith(("_", ".")))
    assert [t for t in top if not t.endswith((".dist-info", ".pth"))] == ["deepslam"], top
    for generic in ("core", "sim", "gen", "vo", "slam", "scenes", "bench", "tests"):
        r = _run(installed, "-c", f"import {generic}")
        assert r.returncode != 0, f"a top-level package {generic!r} is importable from the install"
    r = _run(installed, "-c", "import deepslam.core.se3 as m, deepslam.vo.modelfiles.models as vm; print(m.__file__); "
                              "print(vm.models_dir()); print(vm.shipped_path('kitti'))")
    assert r.returncode == 0, r.stderr
    se3_file, models, kitti = r.stdout.split()
    assert se3_file.startswith(str(installed["site"])) and models.startswith(str(installed["site"]))
    assert Path(kitti).is_file() and Path(kitti).name == "kitti_cons.safetensors"


@pytest.mark.slow
def test_render_then_vo_with_the_shipped_model_from_any_folder(installed):
    r = _run(installed, "-m", "deepslam", "render", "--scene", "street", "--frames", "6", "--width", "320",
             "--out", "seq", "--quiet")
    assert r.returncode == 0, r.stderr
    r = _run(installed, "-m", "deepslam", "vo", "--sequence", "seq", "--out", "vo.txt", "--quiet")
    assert r.returncode == 0, r.stderr
    rows = [ln for ln in (installed["work"] / "vo.txt").read_text().splitlines() if not ln.startswith("#")]
    assert len(rows) == 6
    r = _run(installed, "-m", "deepslam", "vo", "--sequence", "missing", "--out", "vo2.txt")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr


USER_CONFTEST = 'pytest_plugins = ["deepslam.testing"]\n'
USER_TEST = '''
from deepslam.testing import assert_trajectory_close

def test_ground_truth_against_itself(sim_sequence):
    seq = sim_sequence(scene="street", frames=3, width=96, seed=2)
    assert len(seq) == 3 and seq.depth(0).shape == (seq.camera.height, 96)
    assert_trajectory_close(seq.gt.world_from_cam, seq.gt.world_from_cam, ate_m=1e-9)
'''
USER_ODOMETRY = """
import numpy as np
from deepslam.core import se3

class Gt:
    name = "user-gt"
    def predict(self, seq, pairs):
        p = np.asarray(pairs).reshape(-1, 2); w = seq.gt.world_from_cam
        return se3.to_euler6(se3.relative(w[p[:, 1]], w[p[:, 0]])).reshape(-1, 6), np.full((len(p), 6), 0.01)

def make():
    return Gt()
"""
USER_COMMAND = """
import sys
from pathlib import Path
Path(sys.argv[2]).write_text((Path(sys.argv[1]) / "poses.txt").read_text())
"""


@pytest.mark.slow
def test_a_user_project_against_the_install(installed):
    """The pytest plugin, a Python odometry plug-in and an external command, from a user's folder."""
    work = installed["work"]
    (work / "conftest.py").write_text(USER_CONFTEST)
    (work / "test_user.py").write_text(USER_TEST)
    (work / "user_odometry.py").write_text(USER_ODOMETRY)
    (work / "writer.py").write_text(USER_COMMAND)
    r = _run(installed, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_user.py")
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    if not (work / "seq").exists():
        assert _run(installed, "-m", "deepslam", "render", "--scene", "street", "--frames", "6", "--width", "320",
                    "--out", "seq", "--quiet").returncode == 0
    env_py = {"PYTHONPATH": str(work)}
    r = _run(installed, "-m", "deepslam", "vo", "--sequence", "seq", "--odometry", "user_odometry:make",
             "--out", "plugin.txt", "--json", extra_env=env_py)
    assert r.returncode == 0, r.stderr
    import json

    assert json.loads(r.stdout)["metrics"]["ate_m"] < 1e-9
    cmd = f"{installed['python']} writer.py {{sequence}} {{out}}"
    r = _run(installed, "-m", "deepslam", "vo", "--sequence", "seq", "--odometry-command", cmd, "--out", "cmd.txt")
    assert r.returncode == 0 and "ATE 0.000 m" in r.stdout, r.stderr
    r = _run(installed, "-m", "deepslam", "stress", "--quick", "--frames", "30", "--objects", "0", "--deform", "0",
             "--size-objects", "0", "--no-loops", "--odometry", "rigid-fit", "--odometry", "user_odometry:make",
             "--out", "stress", "--json", extra_env=env_py)
    assert r.returncode == 0, r.stderr[-2000:]
    assert '"odometry_key": "user-gt"' in r.stdout
