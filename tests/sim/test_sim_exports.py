"""Writers: our format, KITTI and EuRoC exports read back with core.readers.open_sequence;
determinism; resume after SIGKILL; bad input on the command line."""
from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from deepslam.core.readers import open_sequence
from deepslam.scenes import SceneConfig
from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig, render_sequence

REPO = Path(__file__).resolve().parents[2]


def _cfg(scene="street", frames=4, width=96, k=1, deform=0.1, backend="mujoco", baseline=None):
    return SimConfig(SceneConfig(name=scene, seed=2, moving_objects=k, deform_amplitude_m=deform,
                                 texture_px_per_m=4 if scene == "street" else 20),
                     TrajectoryConfig(frames=frames), RenderConfig(backend=backend, width=width, stereo_baseline_m=baseline))


def _tree(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def reference():
    """Frames rendered in memory, to compare the files with."""
    out = {}
    for scene in ("street", "room"):
        with Simulator(_cfg(scene)) as sim:
            out[scene] = (sim, [sim.frame(i) for i in range(sim.num_frames)], sim.trajectory)
    return out


def _check(seq, sim, frames, traj, grey: bool, gt_atol: float):
    n = len(frames)
    assert len(seq) == n
    assert seq.camera == sim.camera
    assert seq.baseline_m == pytest.approx(sim.baseline_m, abs=1e-9)
    np.testing.assert_allclose(seq.gt.world_from_cam, traj.world_from_cam, atol=gt_atol, rtol=0)
    np.testing.assert_allclose(np.diff(seq.timestamps_s), 1.0 / sim.rate_hz, atol=1e-6)
    for i, f in enumerate(frames):
        img = seq.image(i)
        want = cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY) if grey else f.rgb
        assert np.array_equal(img, want)
        right = seq.image_right(i)
        assert np.array_equal(right, cv2.cvtColor(f.rgb_right, cv2.COLOR_RGB2GRAY) if grey else f.rgb_right)
        assert np.array_equal(seq.depth(i), f.depth_z)
        assert np.array_equal(seq.mask(i), f.mask)
        if i < n - 1:
            assert np.array_equal(seq.flow(i), f.flow, equal_nan=True)
        else:
            assert seq.flow(i) is None


def test_ours_reads_back(tmp_path, reference):
    sim, frames, traj = reference["street"]
    path = render_sequence(_cfg("street"), tmp_path / "ours", fmt="ours", progress=False)
    seq = open_sequence(path)
    assert seq.kind == "ours"
    _check(seq, sim, frames, traj, grey=False, gt_atol=1e-9)
    assert seq.meta["config"]["scene"]["moving_objects"] == 1


def test_kitti_export_reads_back(tmp_path, reference):
    sim, frames, traj = reference["street"]
    path = render_sequence(_cfg("street"), tmp_path / "kitti", fmt="kitti", progress=False, sequence="07")
    assert path == tmp_path / "kitti" / "sequences" / "07"
    assert (tmp_path / "kitti" / "poses" / "07.txt").is_file()
    for d in ("image_0", "image_1", "image_2", "image_3", "depth", "flow", "mask"):
        assert (path / d).is_dir()
    assert sorted(p.name for p in (path / "flow").iterdir()) == [f"{i:06d}.npy" for i in range(3)]
    assert not (path / ".deepslam_frames").exists() and (path / "deepslam.json").is_file()
    seq = open_sequence(path)
    assert seq.kind == "kitti"
    _check(seq, sim, frames, traj, grey=True, gt_atol=1e-9)
    # the colour pair is there too, at the same place
    assert np.array_equal(cv2.imread(str(path / "image_2" / "000001.png"))[..., ::-1], frames[1].rgb)
    calib = (path / "calib.txt").read_text().splitlines()
    assert [line.split(":")[0] for line in calib] == ["P0", "P1", "P2", "P3", "Tr"]


def test_euroc_export_reads_back_with_its_body_frame(tmp_path, reference):
    sim, frames, traj = reference["room"]
    path = render_sequence(_cfg("room"), tmp_path / "euroc", fmt="euroc", progress=False)
    mav = path / "mav0"
    for f in ("cam0/data.csv", "cam0/sensor.yaml", "cam1/data.csv", "cam1/sensor.yaml", "body.yaml",
              "state_groundtruth_estimate0/data.csv", "state_groundtruth_estimate0/sensor.yaml"):
        assert (mav / f).is_file(), f
    assert (mav / "cam0" / "data.csv").read_text().startswith("#timestamp [ns],filename\n")
    seq = open_sequence(path)
    assert seq.kind == "euroc" and seq.postprocess is None     # served as rendered: already rectified
    body_from_cam0 = np.array(seq.meta["body_from_cam0"])
    assert np.abs(body_from_cam0[:3, :3] - np.eye(3)).max() > 0.5   # a real rotation between body and camera
    _check(seq, sim, frames, traj, grey=True, gt_atol=1e-6)
    gt_rows = (mav / "state_groundtruth_estimate0" / "data.csv").read_text().splitlines()
    assert gt_rows[0].startswith("#timestamp, p_RS_R_x [m]") and len(gt_rows[1].split(",")) == 17
    assert len(gt_rows) - 1 > 8 * len(frames)   # 200 Hz, more than the 20 Hz frames


def test_renders_are_deterministic(tmp_path):
    a = render_sequence(_cfg("room", frames=3, k=2), tmp_path / "a", progress=False)
    b = render_sequence(_cfg("room", frames=3, k=2), tmp_path / "b", progress=False)
    ta, tb = _tree(a), _tree(b)
    assert ta == tb and len(ta) > 10


def _cli(args, **kw):
    env = dict(os.environ, MUJOCO_GL="egl", PYOPENGL_PLATFORM="egl")
    return subprocess.Popen([sys.executable, "-m", "deepslam", "render", *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["kitti", "ours"])
def test_resume_after_sigkill_gives_the_same_bytes(tmp_path, fmt):
    from deepslam.core.errors import InputError

    args = ["--scene", "street", "--frames", "12", "--width", "128", "--texture-density", "4", "--moving-objects", "1",
            "--deform", "0.1", "--seed", "5", "--format", fmt, "--quiet"]
    cfg = SimConfig(SceneConfig(name="street", seed=5, moving_objects=1, deform_amplitude_m=0.1, texture_px_per_m=4.0),
                    TrajectoryConfig(frames=12), RenderConfig(width=128))
    killed = _cli([*args, "--out", str(tmp_path / "killed")])
    records = (tmp_path / "killed" / "sequences" / "00" / ".deepslam_frames") if fmt == "kitti" else (tmp_path / "killed" / "frames")
    deadline = time.time() + 120
    while time.time() < deadline and (not records.is_dir() or len(list(records.glob("*.json"))) < 3):
        assert killed.poll() is None, killed.communicate()
        time.sleep(0.02)
    killed.send_signal(signal.SIGKILL)
    killed.wait()
    done = len(list(records.glob("*.json")))
    assert 3 <= done < 12, done
    # the uninterrupted reference, rendered in this process through the API with the same settings
    render_sequence(cfg, tmp_path / "full", fmt=fmt, progress=False)
    # without resume the folder is refused; with other settings too
    with pytest.raises(InputError, match="not empty"):
        render_sequence(cfg, tmp_path / "killed", fmt=fmt, progress=False)
    other = SimConfig(cfg.scene, TrajectoryConfig(frames=12, seed=9), cfg.render)
    with pytest.raises(InputError, match="differ"):
        render_sequence(other, tmp_path / "killed", fmt=fmt, resume=True, progress=False)
    resumed = _cli([*args, "--out", str(tmp_path / "killed"), "--resume"])
    assert resumed.wait(timeout=300) == 0, resumed.communicate()
    # same bytes as the uninterrupted run, and no temporary files left behind
    a, b = _tree(tmp_path / "killed"), _tree(tmp_path / "full")
    assert a == b, sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))[:10]
    assert not [p for p in (tmp_path / "killed").rglob("*") if ".tmp" in p.name]
    # resuming a finished render changes nothing
    render_sequence(cfg, tmp_path / "killed", fmt=fmt, resume=True, progress=False)
    assert _tree(tmp_path / "killed") == b


@pytest.mark.parametrize("args,what", [
    (["--scene", "moon"], "unknown scene"),
    (["--trajectory", "boat"], "unknown trajectory"),
    (["--width", "0"], "width"),
    (["--height", "0"], "height"),
    (["--scene", "room", "--trajectory", "car"], "needs roads"),
    (["--format", "bmp"], "unknown format"),
    (["--backend", "vulkan"], "unknown backend"),
    (["--moving-objects", "-1"], "moving objects"),
    (["--deform", "5"], "deform"),
])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, args, what):
    from deepslam.cli import main

    out = tmp_path / "out"
    rc = main(["render", "--out", str(out), "--frames", "2", *args])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and what in err, err
    assert not out.exists()


def test_unusable_output_folders(tmp_path, capsys):
    from deepslam.cli import main

    afile = tmp_path / "afile"
    afile.write_text("x")
    nonempty = tmp_path / "full"
    nonempty.mkdir()
    (nonempty / "keep.txt").write_text("mine")
    for out, what in ((afile / "out", "cannot create"), (afile, "not a folder"), (nonempty, "not empty")):
        rc = main(["render", "--out", str(out), "--frames", "2", "--width", "32"])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and len(err.splitlines()) == 1 and what in err, err
    assert [p.name for p in nonempty.iterdir()] == ["keep.txt"] and afile.read_text() == "x"
