"""``deepslam gen`` shards: open format, byte-identical reruns, SIGKILL + --resume, Ray = local, bad input."""
from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import numpy as np
import pytest

from deepslam.cli import main
from deepslam.gen.motion import MotionModel
from deepslam.gen.shards import GenConfig, generate, make_dataset, read_shard, verify

REPO = Path(__file__).resolve().parents[2]


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def config(depth_sequence, motion_json) -> GenConfig:
    motion = MotionModel.load(motion_json).to_dict()
    return GenConfig(source=str(depth_sequence), motion=motion, num_samples=10, seed=3, resolution_hw=(24, 32),
                     samples_per_shard=4)


def test_shards_are_open_and_deterministic(config, tmp_path):
    manifest = generate(config, tmp_path / "a", progress=False)
    generate(config, tmp_path / "b", workers=2, progress=False)
    a, b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert sorted(a) == ["manifest.json", "run.json", "shard-000000.tar", "shard-000001.tar", "shard-000002.tar"]
    assert a == b  # same bytes with one or two worker processes
    assert manifest["num_samples"] == 10 and [s["num_samples"] for s in manifest["shards"]] == [4, 4, 2]
    for s in manifest["shards"]:
        assert hashlib.sha256(a[s["name"]]).hexdigest() == s["sha256"]
    verify(tmp_path / "a")
    # Plain tarfile + numpy read it; members are fixed (mtime 0, root, 0644) and in sample order.
    with tarfile.open(tmp_path / "a" / "shard-000001.tar") as tar:
        members = tar.getmembers()
    assert [m.name for m in members[:5]] == ["000000004.flow.npy", "000000004.valid.npy", "000000004.target.npy",
                                            "000000004.intrinsics.npy", "000000004.json"]
    assert all(m.mtime == 0 and m.uid == 0 and m.gid == 0 and m.uname == "" and m.mode == 0o644 for m in members)
    samples = list(read_shard(tmp_path / "a" / "shard-000001.tar"))
    assert [s["meta"]["index"] for s in samples] == [4, 5, 6, 7]
    ds = make_dataset(config)
    item = ds[5]
    s = samples[1]
    assert s["flow"].shape == (24, 32, 2) and s["flow"].dtype == np.float32
    assert s["valid"].dtype == bool and s["target"].dtype == np.float32 and s["intrinsics"].shape == (4,)
    np.testing.assert_array_equal(s["flow"], item["flow"].numpy().transpose(1, 2, 0))
    np.testing.assert_array_equal(s["valid"], item["valid"].numpy())
    np.testing.assert_array_equal(s["target"], item["target"].numpy())
    assert s["meta"] == {"index": 5, "frame": int(item["frame"]), "loop": False}
    # Another seed gives other samples.
    other = generate(GenConfig(**{**config.__dict__, "seed": 4}), tmp_path / "c", progress=False)
    assert other["shards"][0]["sha256"] != manifest["shards"][0]["sha256"]


def test_tampered_shard_fails_verification(config, tmp_path):
    from deepslam.core.errors import InputError

    generate(config, tmp_path / "a", progress=False)
    shard = tmp_path / "a" / "shard-000002.tar"
    data = bytearray(shard.read_bytes())
    data[700] ^= 1
    shard.write_bytes(bytes(data))
    with pytest.raises(InputError, match="sha256"):
        verify(tmp_path / "a")


def _gen_cmd(source, motion, out, extra=()):
    return [sys.executable, "-m", "deepslam", "gen", "--source", str(source), "--motion", str(motion),
            "--samples", "60", "--out", str(out), "--resolution", "96x128", "--shard-size", "3", "--seed", "9",
            "--zbuffer", *extra]


@pytest.mark.slow
def test_sigkill_then_resume_gives_the_uninterrupted_shards(depth_sequence, motion_json, tmp_path):
    env = {**os.environ, "DEEPSLAM_PROGRESS": "0"}
    ref = tmp_path / "ref"  # the uninterrupted run, in this process: the same config as the command line's
    generate(GenConfig(source=str(depth_sequence), motion=MotionModel.load(motion_json).to_dict(),
                       num_samples=60, seed=9, resolution_hw=(96, 128), samples_per_shard=3, zbuffer=True),
             ref, progress=False)
    out = tmp_path / "killed"
    proc = subprocess.Popen(_gen_cmd(depth_sequence, motion_json, out), env=env, cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not (out / "shard-000002.tar").exists():
        assert proc.poll() is None and time.monotonic() < deadline, "gen ended before it could be killed"
        time.sleep(0.002)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "manifest.json").exists()  # it really was interrupted
    done_before = len(list(out.glob("shard-*.tar")))
    assert done_before < 20
    res = subprocess.run(_gen_cmd(depth_sequence, motion_json, out, ["--resume"]), env=env, cwd=REPO,
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert _files(out) == _files(ref)


@pytest.mark.slow
def test_ray_backend_writes_the_same_bytes(config, tmp_path):
    ray = pytest.importorskip("ray")
    generate(config, tmp_path / "local", progress=False)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        generate(config, tmp_path / "ray", workers=2, backend="ray", progress=False)
    finally:
        ray.shutdown()
    assert _files(tmp_path / "ray") == _files(tmp_path / "local")


def _no_depth_sequence(root: Path) -> Path:
    from deepslam.core.camera import PinholeCamera
    from deepslam.core.ours import OursWriter

    cam = PinholeCamera.from_fov_y(16, 12, 60.0)
    w = OursWriter(root, {"num_frames": 2, "rate_hz": 10.0, "camera": cam.to_dict(), "stereo_baseline_m": None,
                          "has": {"rgb_right": False, "depth": False, "flow": False, "mask": False}})
    for i in range(2):
        w.write_frame(i, i / 10.0, np.eye(4), np.zeros((12, 16, 3), np.uint8))
    w.finish()
    return root


def test_cli_bad_input_is_one_line_and_exit_2(depth_sequence, motion_json, tmp_path, capsys):
    def run(args):
        code = main(["gen", *args])
        err = capsys.readouterr().err.strip().splitlines()
        return code, err

    base = ["--source", str(depth_sequence), "--samples", "4", "--resolution", "12x16"]
    bad = tmp_path / "bad.json"
    d = json.loads(Path(motion_json).read_text())
    d["consecutive"]["dofs"]["t_z"]["scale"] = -1.0
    bad.write_text(json.dumps(d))
    code, err = run([*base, "--motion", str(bad), "--out", str(tmp_path / "o1")])
    assert code == 2 and len(err) == 1 and "bad.json" in err[0] and "scale" in err[0]
    code, err = run(["--source", str(_no_depth_sequence(tmp_path / "nodepth")), "--samples", "4",
                     "--motion", str(motion_json), "--out", str(tmp_path / "o2")])
    assert code == 2 and len(err) == 1 and "no depth" in err[0]
    assert not (tmp_path / "o2").exists()
    code, err = run(["--source", str(tmp_path / "absent"), "--samples", "4", "--motion", str(motion_json),
                     "--out", str(tmp_path / "o5")])
    assert code == 2 and len(err) == 1 and "absent" in err[0]
    code, err = run([*base, "--motion", str(motion_json), "--out", str(tmp_path / "o3"), "--resolution", "12by16"])
    assert code == 2 and len(err) == 1
    # A finished folder: rerun refuses without --resume; --resume with other settings refuses too.
    assert run([*base, "--motion", str(motion_json), "--out", str(tmp_path / "o4")])[0] == 0
    code, err = run([*base, "--motion", str(motion_json), "--out", str(tmp_path / "o4")])
    assert code == 2 and len(err) == 1 and "not empty" in err[0]
    code, err = run([*base, "--motion", str(motion_json), "--out", str(tmp_path / "o4"), "--resume", "--seed", "1"])
    assert code == 2 and len(err) == 1 and "seed" in err[0]
    code, err = run([*base, "--motion", str(motion_json), "--out", str(tmp_path / "o4"), "--resume"])
    assert code == 0


def test_bad_depth_file_in_a_worker_is_one_input_error(motion_json, tmp_path):
    """A truncated depth file met inside a worker process comes back as the same InputError."""
    from deepslam.core.errors import InputError
    from gen_scenes import write_depth_sequence

    src = write_depth_sequence(tmp_path / "src", n=2)
    bad = src / "depth" / "000001.npy"
    bad.write_bytes(bad.read_bytes()[:100])
    cfg = GenConfig(source=str(src), motion=MotionModel.load(motion_json).to_dict(), num_samples=8, seed=0,
                    resolution_hw=(12, 16), samples_per_shard=4)
    with pytest.raises(InputError, match="000001.npy"):
        generate(cfg, tmp_path / "out", workers=2, progress=False)
    assert not (tmp_path / "out" / "manifest.json").exists()


def test_train_reads_gen_shards_and_a_plain_dataloader_does_too(depth_sequence, motion_json, tmp_path, capsys):
    """One pipeline: what `deepslam gen` writes, `deepslam train --shards` trains on and a plain
    torch DataLoader loads; a damaged shard is refused by both (the manifest's sha256)."""
    import torch

    from deepslam.cli import main
    from deepslam.gen.shards import ShardDataset

    shards = tmp_path / "shards"
    assert main(["gen", "--source", str(depth_sequence), "--motion", str(motion_json), "--samples", "48",
                 "--resolution", "24x80", "--shard-size", "16", "--seed", "1", "--out", str(shards)]) == 0
    ds = ShardDataset(shards)
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=8, shuffle=False)))
    assert batch["flow"].shape == (8, 2, 24, 80) and batch["target"].shape == (8, 6)
    assert batch["intrinsics"].dtype == torch.float32 and batch["valid"].dtype == torch.bool
    out = tmp_path / "model"
    assert main(["train", "--mode", "synthetic", "--shards", str(shards), "--net", "tiny", "--batch", "8",
                 "--max-epochs", "2", "--nll-epochs", "1", "--bf16", "off", "--quiet", "--out", str(out)]) == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["data"]["data"]["shards"] == str(shards) and cfg["data"]["data"]["n_train"] > 0
    capsys.readouterr()
    assert main(["train", "--mode", "synthetic", "--shards", str(shards), "--net", "paper", "--quiet",
                 "--out", str(tmp_path / "m2")]) == 2
    assert "96x320" in capsys.readouterr().err  # the network's size differs from the shards'
    first = sorted(shards.glob("shard-*.tar"))[0]
    data = bytearray(first.read_bytes())
    data[2000] ^= 0xFF
    first.write_bytes(bytes(data))
    assert main(["train", "--mode", "synthetic", "--shards", str(shards), "--net", "tiny", "--quiet",
                 "--out", str(tmp_path / "m3")]) == 2
    assert "sha256 differs" in capsys.readouterr().err


@pytest.mark.parametrize("damage", ["flip-a-byte", "truncate", "foreign-shard", "unrecorded"])
def test_resume_rebuilds_damaged_shards_instead_of_keeping_them(config, tmp_path, damage):
    """A resumed run verifies what it keeps: each shard's bytes against the sha256 recorded when it
    was written (the ledger while unfinished, the manifest once finished); anything else is rebuilt,
    and the result equals an undisturbed run byte for byte."""
    ref = tmp_path / "ref"
    generate(config, ref, progress=False)
    out = tmp_path / "out"
    generate(config, out, progress=False)
    shard = out / "shard-000001.tar"
    if damage == "flip-a-byte":
        data = bytearray(shard.read_bytes())
        data[700] ^= 0x01
        shard.write_bytes(bytes(data))
    elif damage == "truncate":
        shard.write_bytes(shard.read_bytes()[:1024])
    elif damage == "foreign-shard":  # a valid shard of another seed under the same name
        other = generate(GenConfig(**{**config.__dict__, "seed": 99}), tmp_path / "other", progress=False)
        shard.write_bytes((tmp_path / "other" / other["shards"][1]["name"]).read_bytes())
    else:  # written by something else while the run was unfinished: no ledger record, no manifest
        (out / "manifest.json").unlink()
    generate(config, out, resume=True, progress=False)
    assert _files(out) == _files(ref)
    verify(out)


def test_resume_from_a_source_whose_content_changed_is_refused(depth_sequence, config, tmp_path):
    """Same path, other bytes: the interrupted run's shards came from the old content, so resuming
    would mix two sources in one dataset."""
    import shutil

    from deepslam.core.errors import InputError

    src = tmp_path / "src"
    shutil.copytree(depth_sequence, src)
    cfg = GenConfig(**{**config.__dict__, "source": str(src)})
    out = tmp_path / "out"
    generate(cfg, out, progress=False)
    (out / "manifest.json").unlink()  # as if interrupted before the end
    generate(cfg, out, resume=True, progress=False)  # unchanged source: resumes
    depth = sorted((src / "depth").glob("*.npy"))[0]
    arr = np.load(depth)
    np.save(depth, arr * 1.01)
    with pytest.raises(InputError, match="content changed"):
        generate(cfg, out, resume=True, progress=False)
