"""Data-parallel training (torchrun + DDP, gloo on the CPU): the ranks split every batch, and two ranks
train the model one process trains (to float rounding)."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from deepslam.core.camera import PinholeCamera
from deepslam.vo.data.frames import Frames
from deepslam.vo.data.samples import TensorSamples
from deepslam.vo.data.synthetic import SyntheticSource
from deepslam.vo.data.toy import plane_depth


def _samples(n=70):
    rng = np.random.default_rng(0)
    return TensorSamples(rng.normal(size=(n, 2, 4, 8)).astype(np.float32), rng.normal(size=(n, 4)).astype(np.float32),
                         np.arange(n * 6, dtype=np.float32).reshape(n, 6), seed=3)


@pytest.mark.parametrize("world", [2, 3])
def test_ranks_split_each_batch_without_overlap(world):
    src = _samples()
    whole = [b["target"][:, 0].numpy() for b in src.batches(1, 16)]
    shares = [[b["target"][:, 0].numpy() for b in src.batches(1, 16, rank, world)] for rank in range(world)]
    n_batches = {len(s) for s in shares}
    assert len(n_batches) == 1  # every rank takes the same number of steps
    for b in range(n_batches.pop()):
        got = np.concatenate([shares[r][b] for r in range(world)])
        assert len(set(got.tolist())) == len(got)  # no sample twice
        assert sorted(got.tolist()) == sorted(whole[b].tolist())


def test_on_the_fly_ranks_make_their_own_share():
    cam = PinholeCamera(32, 16, 20.0, 20.0, 15.5, 7.5)
    frames = Frames(np.stack([plane_depth(cam, np.array([0.0, 1.0, 0.0]), 1.5)] * 4), np.zeros(4, np.int64), [cam],
                    [f"a:{i}" for i in range(4)])

    def sample(n, rng):
        return np.column_stack([np.zeros((n, 5)), -rng.uniform(0.5, 1.5, n)])

    src = SyntheticSource(frames, sample, 10, seed=1)
    r0 = [b["target"][:, 5].numpy() for b in src.batches(0, 4, 0, 2)]
    r1 = [b["target"][:, 5].numpy() for b in src.batches(0, 4, 1, 2)]
    assert [len(x) for x in r0] == [2, 2, 1] and [len(x) for x in r1] == [2, 2, 1]
    assert not any(np.intersect1d(a, b).size for a, b in zip(r0, r1))


def _train_argv(out):
    return ["--mode", "synthetic", "--toy", "600", "--net", "cpu", "--max-samples", "320", "--nll-epochs", "1",
            "--bf16", "off", "--threads", "1", "--batch", "32", "--quiet", "--out", str(out)]


def test_two_ranks_train_what_one_process_trains(tmp_path):
    from safetensors.numpy import load_file

    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    one = subprocess.run([sys.executable, "-m", "deepslam", "train", *_train_argv(tmp_path / "one")], env=env,
                         capture_output=True, text=True)
    assert one.returncode == 0, one.stderr[-2000:]
    two = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "-m", "deepslam",
                          "train", *_train_argv(tmp_path / "two")], env=env, capture_output=True, text=True)
    assert two.returncode == 0, two.stderr[-2000:]
    assert two.stdout.count("model:") == 1  # rank 0 reports and writes; rank 1 only trains
    a, b = load_file(tmp_path / "one" / "model.safetensors"), load_file(tmp_path / "two" / "model.safetensors")
    motion = [k for k in a if "log_std" not in k]
    assert max(float(np.abs(a[k].astype(np.float64) - b[k]).max()) for k in motion) < 1e-4
    assert json.loads((tmp_path / "two" / "config.json").read_text())["data_parallel_ranks"] == 2
    hist = json.loads((tmp_path / "two" / "history.json").read_text())
    assert sum(h.get("samples", 0) for h in hist if h["stage"] == 1) == 320  # the cap counts both ranks' samples
