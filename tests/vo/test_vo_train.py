"""Training: a tiny net learns a known mapping, the NLL stage touches only the log-std heads and its
std follows injected noise, resume after a kill is bit-identical, a NaN loss stops cleanly."""
from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from deepslam.core.camera import KITTI_00_CAMERA
from deepslam.vo.data.samples import TensorSamples
from deepslam.vo.data.toy import toy_plane_samples
from deepslam.vo.infer import VOPredictor
from deepslam.vo.modelfiles.modelio import load_checkpoint, load_model
from deepslam.vo.net import NetConfig
from deepslam.vo.train import CHECKPOINT, TrainConfig, fit_uncertainty, stage1_loss_title, train

REPO = Path(__file__).resolve().parents[2]
CAM = KITTI_00_CAMERA.scaled(80, 24)
TINY = NetConfig(24, 80, filters=16, hidden_units=64, flow_scale=10.0)


def _cfg(**kw) -> TrainConfig:
    base = dict(net=TINY, batch_size=16, lr_max=3e-3, max_epochs=6, nll_epochs=0, bf16=False, channels_last=False, seed=3,
                threads=1, loss="mse")
    base.update(kw)
    return TrainConfig(**base)


@pytest.fixture(scope="module")
def toy():
    s = toy_plane_samples(700, CAM, np.random.default_rng(0))
    return TensorSamples(s["flow"], s["intrinsics"], s["target"], seed=0).split(0.1, 0)


@pytest.fixture(scope="module")
def trained(toy, tmp_path_factory):
    out = tmp_path_factory.mktemp("trained")
    res = train(_cfg(), *toy, out, progress=False)
    return res


def test_tiny_net_learns_motion_with_the_papers_l1_loss(toy, tmp_path):
    res = train(_cfg(loss="l1"), *toy, tmp_path / "l1", progress=False)
    hist = [h for h in res.history if h["stage"] == 1]
    _, hold = toy
    t = hold.target.numpy().astype(np.float64)
    dev = np.abs(t - np.median(t, axis=0))  # the L1 loss of always predicting the median motion
    baseline = 50 * dev[:, :3].mean() + dev[:, 3:].mean()
    assert res.best_val_loss < 0.75 * baseline and res.best_val_loss < hist[0]["val_loss"]


def test_tiny_net_learns_motion_from_plane_flow(trained, toy):
    hist = [h for h in trained.history if h["stage"] == 1]
    assert len(hist) == 6 and trained.stop_reason == "max_epochs"
    first_val = hist[0]["val_loss"]
    # the (squared-error) loss of always predicting the mean motion, for scale
    _, hold = toy
    t = hold.target.numpy().astype(np.float64)
    baseline = 50 * t[:, :3].var(0).mean() + t[:, 3:].var(0).mean()
    assert trained.best_val_loss < 0.4 * baseline
    assert trained.best_val_loss < first_val
    pred = VOPredictor.from_file(trained.model_path, bf16=False)
    test = toy_plane_samples(150, CAM, np.random.default_rng(5))
    mean, std = pred.predict(test["flow"], test["intrinsics"])
    assert mean.dtype == np.float64 and mean.shape == std.shape == (150, 6)
    corr = [np.corrcoef(mean[:, k], test["target"][:, k])[0, 1] for k in range(6)]
    print("correlations", np.round(corr, 3))
    assert corr[5] > 0.9  # forward motion t_z
    assert corr[1] > 0.6  # yaw
    assert corr[3] > 0.4  # sideways
    # (pitch and vertical translation look alike over a ground plane: not asserted)


def test_outputs_written(trained):
    out = trained.out_dir
    for name in ("config.json", "checkpoint.safetensors", "history.json", "model.safetensors", "summary.json", "loss.png"):
        assert (out / name).is_file(), name
    import json

    cfg = json.loads((out / "config.json").read_text())
    assert cfg["train"]["rot_weight"] == 50.0 and cfg["train"]["net"]["filters"] == 16
    # the header alone gives the input size of the model and of the checkpoint (their trees differ)
    from deepslam.vo.data.prefetch import model_input

    size = (cfg["train"]["net"]["input_height"], cfg["train"]["net"]["input_width"])
    assert model_input(out / "model.safetensors") == model_input(out / "checkpoint.safetensors") == (*size, "zero")


def test_nll_stage_changes_only_log_std_heads_and_std_follows_noise(trained):
    model, _ = load_model(trained.model_path)
    rng = np.random.default_rng(1)
    h = toy_plane_samples(600, CAM, rng)
    sigma = np.where(np.arange(600) % 2 == 0, 0.0, 3.0).astype(np.float32)
    noisy = h["flow"] + sigma[:, None, None, None] * rng.normal(size=h["flow"].shape).astype(np.float32)
    src = TensorSamples(noisy, h["intrinsics"], h["target"], seed=0)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    nll = fit_uncertainty(model, src, _cfg(nll_lr=1e-2), 25)
    assert nll[-1] < nll[0]
    after = model.state_dict()
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    assert changed == {"rot_log_std.weight", "rot_log_std.bias", "trans_log_std.weight", "trans_log_std.bias"}
    pred = VOPredictor(model, bf16=False)
    test = toy_plane_samples(200, CAM, np.random.default_rng(2))
    noise = np.random.default_rng(3).normal(size=test["flow"].shape).astype(np.float32)
    stds = [pred.predict(test["flow"] + s * noise, test["intrinsics"])[1].mean(0) for s in (0.0, 1.5, 3.0)]
    # the translations' std grows monotonically with the noise, forward translation's clearly
    for k in (3, 5):
        assert stds[0][k] < stds[1][k] < stds[2][k]
    assert stds[2][5] > 1.15 * stds[0][5]
    assert (stds[2] / stds[0]).mean() > 1.03


def test_resume_gives_identical_weights(toy, tmp_path):
    cfg2 = _cfg(max_epochs=2, nll_epochs=2)
    full = train(cfg2, *toy, tmp_path / "full", progress=False)
    # stop after one epoch (a cap), then resume to two
    train(dataclasses.replace(cfg2, max_epochs=1), *toy, tmp_path / "split", progress=False)
    assert load_checkpoint(tmp_path / "split" / CHECKPOINT)["train_state"]["epoch"] == 1
    resumed = train(cfg2, *toy, tmp_path / "split", resume=True, progress=False)
    a, _ = load_model(full.model_path)
    b, _ = load_model(resumed.model_path)
    for (ka, va), (kb, vb) in zip(a.state_dict().items(), b.state_dict().items()):
        assert ka == kb and torch.equal(va, vb), ka
    assert [h["val_loss"] for h in full.history if h["stage"] == 1] == [h["val_loss"] for h in resumed.history if h["stage"] == 1]


def test_resume_refuses_other_settings(toy, tmp_path):
    from deepslam.core.errors import InputError

    train(_cfg(max_epochs=1), *toy, tmp_path, progress=False)
    with pytest.raises(InputError, match="batch_size"):
        train(_cfg(max_epochs=2, batch_size=8), *toy, tmp_path, resume=True, progress=False)
    with pytest.raises(InputError, match="--resume"):  # never overwrite a run silently
        train(_cfg(max_epochs=1), *toy, tmp_path, progress=False)


def _cli(out, *extra):
    return [sys.executable, "-m", "deepslam", "train", "--mode", "synthetic", "--toy", "300", "--net", "tiny",
            "--batch", "32", "--nll-epochs", "2", "--bf16", "off", "--threads", "1", "--quiet", "--out", str(out), *extra]


def test_kill_and_resume_matches_uninterrupted_run(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    from deepslam.cli import main

    assert main(_cli(tmp_path / "ref", "--max-epochs", "3")[3:]) == 0  # in-process: the same code, one start less
    proc = subprocess.Popen(_cli(tmp_path / "killed", "--max-epochs", "3"), cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ckpt = tmp_path / "killed" / CHECKPOINT
    deadline = time.time() + 60
    while not ckpt.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert ckpt.exists(), "the run was killed before its first checkpoint"
    done = subprocess.run(_cli(tmp_path / "killed", "--max-epochs", "3", "--resume"), cwd=REPO, env=env,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    a, _ = load_model(tmp_path / "ref" / "model.safetensors")
    b, _ = load_model(tmp_path / "killed" / "model.safetensors")
    for k, v in a.state_dict().items():
        assert torch.equal(v, b.state_dict()[k]), k


def test_nan_loss_stops_with_one_line_and_status_2(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    r = subprocess.run(_cli(tmp_path, "--max-epochs", "2", "--lr-min", "1e11", "--lr-max", "1e12"), cwd=REPO, env=env,
                       capture_output=True, text=True)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("deepslam train: error:") and "nan" in lines[0].lower(), r.stderr
    assert not (tmp_path / "model.safetensors").exists()


class _SlowSource:
    """A huge epoch of toy batches, each taking at least ``delay_s``: only a time cap can end it early."""

    def __init__(self, base: TensorSamples, delay_s: float, epoch_samples: int = 10 ** 6):
        self.base, self.delay_s, self.n = base, delay_s, epoch_samples

    def __len__(self) -> int:
        return self.n

    def batches(self, epoch: int, batch_size: int):
        while True:
            for b in self.base.batches(epoch, batch_size):
                time.sleep(self.delay_s)
                yield b


def test_time_cap_is_checked_every_batch_in_both_stages(toy, tmp_path):
    train_src, hold = toy
    cap_min = 0.04  # 2.4 s of training, against an epoch that would take hours
    t0 = time.perf_counter()
    res = train(_cfg(max_minutes=cap_min, nll_epochs=10 ** 6), _SlowSource(train_src, 0.01), hold, tmp_path,
                progress=False)
    wall = time.perf_counter() - t0
    assert wall < 60 * cap_min + 3.0, wall
    assert res.stop_reason.startswith("max_minutes")
    s1 = [h for h in res.history if h["stage"] == 1]
    assert len(s1) == 1 and s1[0]["partial"] and 0 < s1[0]["samples"] < 10 ** 6
    assert np.isfinite(s1[0]["val_loss"])  # the cut epoch was evaluated and its weights kept
    s2 = [h for h in res.history if h["stage"] == 2]
    assert 0 < len(s2) < 10 ** 6  # stage 2 ran, and its cap ended it
    assert (tmp_path / "model.safetensors").is_file()


def test_sample_cap_stops_mid_epoch_deterministically_and_resumes(toy, tmp_path):
    cfg = _cfg(max_epochs=10, max_samples=200, nll_epochs=2)  # 630 samples per epoch, batches of 16
    a = train(cfg, *toy, tmp_path / "a", progress=False)
    b = train(cfg, *toy, tmp_path / "b", progress=False)
    assert a.stop_reason == "max_samples"
    s1 = [h for h in a.history if h["stage"] == 1]
    assert len(s1) == 1 and s1[0]["samples"] == 208 and s1[0]["partial"]  # 13 batches: the first to reach 200
    wa, wb = load_model(a.model_path)[0].state_dict(), load_model(b.model_path)[0].state_dict()
    assert all(torch.equal(wa[k], wb[k]) for k in wa)  # same weights (the meta holds the run's seconds)
    more = train(dataclasses.replace(cfg, max_samples=1000), *toy, tmp_path / "a", resume=True, progress=False)
    s1 = [h for h in more.history if h["stage"] == 1]
    assert more.stop_reason == "max_samples" and [h["samples"] for h in s1] == [208, 630, 176]


def test_cached_stage_two_figures_match_a_full_forward(trained, toy):
    from deepslam.vo.train import evaluate, evaluate_heads, head_inputs

    model, _ = load_model(trained.model_path)
    _, hold = toy
    cfg = _cfg()
    full, cached = evaluate(model, hold, cfg), evaluate_heads(model, head_inputs(model, hold, cfg), cfg)
    assert cached["loss"] == pytest.approx(full["loss"], rel=1e-5)
    assert cached["nll"] == pytest.approx(full["nll"], rel=1e-5, abs=1e-6)
    np.testing.assert_allclose(cached["rmse6"], full["rmse6"], rtol=1e-5)


def test_device_flag_resolves_and_refuses_what_is_not_here(capsys):
    from deepslam.cli import main
    from deepslam.core.errors import InputError
    from deepslam.runtime.device import resolve_device

    assert resolve_device("cpu").type == "cpu"
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(InputError, match="not auto, cpu, cuda or cuda:N"):
        resolve_device("tpu")
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is present: the refusal below is for machines without one")
    assert main(["train", "--mode", "synthetic", "--toy", "64", "--net", "tiny", "--device", "cuda", "--out", "x"]) == 2
    assert "no CUDA device here" in capsys.readouterr().err


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine (the CPU path is tested above)")
def test_cuda_training_matches_the_cpu_within_tolerance(toy, tmp_path):
    """The same seed on CPU and GPU: the same data and initial weights; float32 results agree to a few
    percent of the held-out loss (cuDNN and the CPU sum in different orders)."""
    cfg = _cfg(max_epochs=2, nll_epochs=1, bf16=False)
    cpu = train(cfg, *toy, tmp_path / "cpu", progress=False)
    gpu = train(dataclasses.replace(cfg, device="cuda"), *toy, tmp_path / "gpu", progress=False)
    assert gpu.best_val_loss == pytest.approx(cpu.best_val_loss, rel=0.05)
    a, _ = load_model(gpu.model_path)  # trained on the GPU, loads on the CPU
    assert next(a.parameters()).device.type == "cpu"


def test_the_loss_plot_names_the_loss_the_run_trained_on():
    assert stage1_loss_title("l1", 50.0) == "50 L1(euler) + L1(t)"
    assert stage1_loss_title("mse", 2.5) == "2.5 MSE(euler) + MSE(t)"
