"""``deepslam dataset``: a plan from a seed, a manifest that matches the files, resumption, Ray = local."""
import json
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from deepslam.core.errors import InputError
from deepslam.sim.dataset import DatasetConfig, build, plan, tree_digest

TINY = DatasetConfig(sequences=2, frames=3, width=64, moving_objects=(1, 2))


def test_plan_is_seeded_and_a_longer_plan_extends_a_shorter_one():
    a, b = plan(TINY), plan(TINY)
    assert a == b
    longer = plan(DatasetConfig(sequences=5, frames=3, width=64, moving_objects=(1, 2)))
    assert longer[:2] == a
    assert [e.sim["scene"]["name"] for e in longer] == ["street", "room", "street", "room", "street"]
    assert all(1 <= e.sim["scene"]["moving_objects"] <= 2 for e in longer)
    other = plan(DatasetConfig(sequences=2, frames=3, width=64, moving_objects=(1, 2), seed=1))
    assert [e.sim["scene"]["seed"] for e in other] != [e.sim["scene"]["seed"] for e in a]


def test_lighting_and_rolling_shutter_draws_leave_the_other_settings_as_they_were():
    base = plan(DatasetConfig(sequences=6, frames=3, width=64))
    varied = plan(DatasetConfig(sequences=6, frames=3, width=64, random_lighting_fraction=0.5,
                                rolling_shutter_ms=(10.0, 30.0), narrow_layout_fraction=1.0,
                                grainy_road_fraction=1.0))
    new = ("random_lighting", "narrow_layout", "grainy_road")
    for a, b in zip(base, varied):
        assert {k: v for k, v in a.sim["scene"].items() if k not in new} == \
            {k: v for k, v in b.sim["scene"].items() if k not in new}
        assert b.sim["scene"]["narrow_layout"] == (b.sim["scene"]["name"] == "street" and not b.sim["scene"]["varied_layout"])
        assert b.sim["scene"]["grainy_road"] == (b.sim["scene"]["name"] == "street") and not a.sim["scene"]["grainy_road"]
        assert not a.sim["scene"]["random_lighting"] and a.sim["render"]["rolling_shutter_ms"] == 0.0
        assert 10.0 <= b.sim["render"]["rolling_shutter_ms"] <= 30.0
    assert 0 < sum(e.sim["scene"]["random_lighting"] for e in varied) < 6


@pytest.mark.parametrize("field,value", [("scenes", ("street", "moon")), ("scenes", ()), ("sequences", 0),
                                         ("frames", 1), ("moving_objects", (3, 1)), ("moving_objects", (0, 100)),
                                         ("deform_amplitude_m", (0.0, 2.0)), ("varied_layout_fraction", 1.5),
                                         ("format", "tartanair"), ("render_backend", "blender"),
                                         ("random_lighting_fraction", -0.1), ("rolling_shutter_ms", (30.0, 10.0)),
                                         ("narrow_layout_fraction", 2.0), ("grainy_road_fraction", -0.5)])
def test_bad_configs_are_refused(field, value):
    with pytest.raises(InputError):
        DatasetConfig(**{field: value}).validate()


def test_manifest_matches_the_files_and_resume_rebuilds_what_was_lost(tmp_path):
    out = tmp_path / "ds"
    m = build(TINY, out, backend="local", progress=False)
    assert [r["name"] for r in m["sequences"]] == ["seq_0000", "seq_0001"]
    for r in m["sequences"]:
        assert tree_digest(out / r["name"])[0] == r["sha256"]
        assert r["frames"] == 3 and r["files"] > 10 and r["peak_rss_mib"] > 0
    assert json.loads((out / "manifest.json").read_text())["sha256"] == m["sha256"]
    # a killed run: one sequence lost its record and a frame, another has a damaged file
    (out / "records" / "seq_0001.json").unlink()
    for p in (out / "seq_0001" / "frames").glob("000002.json"):
        p.unlink()
    damaged = next((out / "seq_0000" / "depth").glob("*.npy"))
    damaged.write_bytes(damaged.read_bytes()[:-7] + b"garbage")
    again = build(TINY, out, backend="local", resume=True, progress=False)
    assert again["sha256"] == m["sha256"]
    with pytest.raises(InputError, match="not empty"):
        build(TINY, out, backend="local", progress=False)
    with pytest.raises(InputError, match="config differs"):
        build(DatasetConfig(sequences=2, frames=3, width=64, seed=9), out, backend="local", resume=True, progress=False)


def test_cli_bad_config_file_is_one_line_and_exit_2(tmp_path):
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps({"sequences": 2, "fog": True}))
    r = subprocess.run([sys.executable, "-m", "deepslam", "dataset", "--config", str(cfg), "--out", str(tmp_path / "o"),
                        "--backend", "local", "--quiet"], capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    assert str(cfg) in r.stderr and "fog" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()


def _ray_worker_pids() -> list[int]:
    out = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
    return [int(line.split()[0]) for line in out.splitlines() if "ray::render_planned" in line]


def test_ray_gives_the_local_bytes_and_retries_a_worker_that_dies(tmp_path):
    """Two Ray workers make the same bytes as one local process; a worker killed mid-sequence is retried."""
    cfg = DatasetConfig(sequences=2, frames=24, width=64, moving_objects=(1, 2))
    local = build(cfg, tmp_path / "local", backend="local", progress=False)
    killed: list[int] = []

    def kill_one():
        t_end = time.time() + 60
        while time.time() < t_end and not killed:
            pids = _ray_worker_pids()
            if pids and any((tmp_path / "ray" / n / "frames").glob("*.json") for n in ("seq_0000", "seq_0001")):
                os.kill(pids[0], signal.SIGKILL)
                killed.append(pids[0])
            time.sleep(0.05)

    killer = threading.Thread(target=kill_one, daemon=True)
    killer.start()
    remote = build(cfg, tmp_path / "ray", backend="ray", workers=2, progress=False)
    killer.join(1)
    assert killed, "no Ray worker was seen running a sequence"
    assert remote["sha256"] == local["sha256"]
    assert [r["sha256"] for r in remote["sequences"]] == [r["sha256"] for r in local["sequences"]]
