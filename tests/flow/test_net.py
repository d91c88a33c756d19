"""The learned flow estimator's parts (flow.net): cost volume, warping, loss, metrics, files, training."""
import dataclasses
import json

import numpy as np
import pytest
import torch

from deepslam.core.errors import InputError
from deepslam.flow.metrics import endpoint_error
from deepslam.flow.net import FlowNet, FlowNetConfig, LearnedFlow, correlation, load_flow_model, warp
from deepslam.flow.train import FlowTrainConfig, multiscale_loss, train_flow
from deepslam.runtime.device import cpu_has_native_bf16
from tests.textures import shifted_texture_batch

SMALL = FlowNetConfig(channels=(8, 12, 16), estimator_channels=(16,), finest_level=1, work_width=128, search_px=2)


@pytest.mark.parametrize("dx,dy", [(0, 0), (1, 0), (-2, 1), (2, -2)])
def test_correlation_peaks_at_the_shift(dx, dy):
    g = torch.Generator().manual_seed(0)
    f1 = torch.randn(1, 8, 12, 16, generator=g)
    f2 = torch.roll(f1, shifts=(dy, dx), dims=(2, 3))  # f2(x + d) = f1(x)
    c = correlation(f1, f2, 2)[0, :, 4:-4, 4:-4].mean((1, 2))
    k = int(torch.argmax(c))
    assert (k // 5 - 2, k % 5 - 2) == (dy, dx)


def test_warp_by_an_integer_flow_shifts_the_image():
    x = torch.arange(5 * 7, dtype=torch.float32).view(1, 1, 5, 7)
    flow = torch.zeros(1, 2, 5, 7)
    flow[:, 0] = 2.0  # sample two pixels to the right
    out = warp(x, flow)
    assert torch.equal(out[0, 0, :, :5], x[0, 0, :, 2:])
    assert (out[0, 0, :, 5:] == 0).all()


def test_endpoint_error_and_fl_all_follow_kitti_2015():
    gt = np.zeros((2, 2, 2), np.float32)
    gt[..., 0] = 100.0
    pred = gt.copy()
    pred[0, 0, 0] += 4.0   # 4 px: > 3 px but only 4 % of 100 px: not an outlier
    pred[0, 1, 0] += 6.0   # 6 px and 6 %: an outlier
    gt[1, 1] = np.nan      # no label
    r = endpoint_error(pred, gt)
    assert r["pixels"] == 3 and r["fl_all"] == pytest.approx(1 / 3) and r["epe"] == pytest.approx(10 / 3)


def test_loss_is_zero_for_the_label_and_skips_nan_labels():
    gt = torch.randn(2, 2, 32, 64)
    outs = [torch.nn.functional.avg_pool2d(gt, 4) / 4, torch.nn.functional.avg_pool2d(gt, 2) / 2]
    assert float(multiscale_loss(outs, gt, (1.0, 1.0))) < 1e-2
    gt_nan = gt.clone()
    gt_nan[:, :, :16] = float("nan")
    assert torch.isfinite(multiscale_loss(outs, gt_nan, (1.0, 1.0)))


class _Shifted:
    """Pairs of random texture shifted by a known (du, dv): a flow the network can learn in seconds."""

    def __init__(self):
        self.rng = np.random.default_rng(0)

    def __len__(self):
        return 1

    def batch(self, rng, n, crop):
        return shifted_texture_batch(rng, n, crop, 3)


def test_training_learns_a_translation_and_the_model_file_loads(tmp_path):
    # bf16 where this CPU computes it natively (train-flow's auto): emulated, it trains ~10x slower
    cfg = FlowTrainConfig(net=SMALL, crop=(64, 128), batch_size=8, lr=1e-3, max_steps=600, level_weights=(1.0, 0.5, 0.25),
                          checkpoint_steps=200, threads=2, bf16=cpu_has_native_bf16())
    path = train_flow(cfg, _Shifted(), tmp_path / "run", progress=False)
    model, meta = load_flow_model(path)
    assert meta["steps"] == 600
    b = _Shifted().batch(np.random.default_rng(99), 8, (64, 128))
    with torch.no_grad():
        pred = model(b["img0"], b["img1"])[-1]
    gt = torch.nn.functional.avg_pool2d(b["flow"], 2) / 2
    err = (pred - gt)[:, :, 4:-4, 4:-4].norm(dim=1).mean()
    zero = gt[:, :, 4:-4, 4:-4].norm(dim=1).mean()
    assert float(err) < 0.6 * float(zero)
    # the estimator interface: full-resolution (H, W, 2) float32 px for two uint8 images
    est = LearnedFlow(path)
    img = (np.random.default_rng(1).random((60, 150)) * 255).astype(np.uint8)
    f = est.estimate(img, img)
    assert f.shape == (60, 150, 2) and f.dtype == np.float32
    # resume continues the same run; a finished run is refused without --resume
    with pytest.raises(InputError):
        train_flow(cfg, _Shifted(), tmp_path / "run", progress=False)
    hist = json.loads((tmp_path / "run" / "history.json").read_text())
    assert [h["step"] for h in hist] == [200, 400, 600]
    # fine-tuning starts from the trained weights (from a random start 20 tiny steps learn nothing)
    for init, want_good in ((str(path), True), ("", False)):
        tune = dataclasses.replace(cfg, max_steps=20, lr=1e-7, checkpoint_steps=20, init=init)
        tuned, _ = load_flow_model(train_flow(tune, _Shifted(), tmp_path / f"tune{bool(init)}", progress=False))
        with torch.no_grad():
            e = (tuned(b["img0"], b["img1"])[-1] - gt)[:, :, 4:-4, 4:-4].norm(dim=1).mean()
        assert (float(e) < 0.6 * float(zero)) == want_good
    other = dataclasses.replace(cfg, net=dataclasses.replace(SMALL, search_px=3), init=str(path))
    with pytest.raises(InputError, match="its network differs"):
        train_flow(other, _Shifted(), tmp_path / "other", progress=False)


def test_a_pickle_is_refused_as_a_flow_model(tmp_path):
    p = tmp_path / "evil.safetensors"
    torch.save({"net": {}}, p)
    with pytest.raises(InputError):
        load_flow_model(p)


def test_the_shipped_estimator_is_registered():
    from deepslam.flow import registry as flow_registry

    assert "learned" in flow_registry.names()


def test_a_crop_larger_than_the_frames_is_refused_before_anything_is_written(tmp_path):
    class _Tiny(_Shifted):
        def min_size(self):
            return (60, 200)

    with pytest.raises(InputError, match="crop"):
        train_flow(FlowTrainConfig(net=SMALL, crop=(64, 128)), _Tiny(), tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_flow_pairs_keep_flow_float16_cannot_hold_as_nan(plane_sequence):
    """A flow beyond float16's range (a point nearly in the camera plane) is stored as NaN, silently,
    and so left out of the loss like any non-finite flow; the rest is kept."""
    import warnings

    from deepslam.core.readers import open_sequence
    from deepslam.flow.train import FlowPairs

    pairs = FlowPairs([open_sequence(plane_sequence)], progress=False)
    g = np.zeros((4, 5), np.uint8)
    flow = np.full((4, 5, 2), 2.5, np.float32)
    flow[1, 2] = (1e6, -3.0)
    flow[3, 4] = (np.inf, 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pairs._add(g, g, flow, "test")
    kept = pairs.flow[-1].astype(np.float32)
    assert np.isnan(kept[1, 2]).sum() == 1 and kept[1, 2, 1] == -3.0
    assert np.isnan(kept[3, 4, 0]) and kept[3, 4, 1] == 1.0
    assert (kept[0] == 2.5).all()


class _StartAt:
    """Stands in for the network in LearnedDISFlow: a constant flow as DIS's start."""

    def __init__(self, du: float, dv: float):
        self.du, self.dv = du, dv

    def estimate(self, g0, g1):
        f = np.zeros((*g0.shape, 2), np.float32)
        f[..., 0], f[..., 1] = self.du, self.dv
        return f


def _textured(h: int, w: int, seed: int = 0) -> np.ndarray:
    import cv2

    noise = np.random.default_rng(seed).random((h, w)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 2.0) * 255 * 4 - 400, 0, 255).astype(np.uint8)


def test_learned_dis_starts_dis_from_the_learned_flow_and_refines_it():
    """A 64 px shift that DIS misses from a zero start: from a start 1.5 px off it recovers the shift to a
    tenth of a pixel (the refinement ran), and the estimator is registered beside DIS."""
    from deepslam.flow import registry as flow_registry
    from deepslam.flow.net import LearnedDISFlow

    big = _textured(160, 544)
    img0, img1 = big[:, 64:], big[:, :480]  # the scene moves right by 64 px
    inner = (slice(16, -16), slice(80, -80))
    plain = flow_registry.make("dis", preset="medium").estimate(img0, img1)
    assert np.median(np.abs(plain[inner][..., 0] - 64.0)) > 5.0  # beyond DIS's reach from zero
    est = flow_registry.make("learned-dis")
    assert isinstance(est, LearnedDISFlow) and est.name == "learned-dis"
    est.learned = _StartAt(65.5, -1.0)
    flow = est.estimate(img0, img1)
    assert flow.shape == (160, 480, 2) and flow.dtype == np.float32
    err = np.hypot(flow[inner][..., 0] - 64.0, flow[inner][..., 1])
    assert np.median(err) < 0.1
    with pytest.raises(InputError, match="no learned flow model"):
        flow_registry.make("learned-dis", path="/nonexistent/flow.safetensors")


def test_learned_dis_is_read_by_the_dis_models():
    from deepslam.vo.modelfiles import models

    assert models.flow_variant("learned-dis") == "dis"
    assert models.shipped_path("kitti", "cons", "learned-dis").name == "kitti_cons_dis.safetensors"
    assert models.shipped_path("kitti", "cons", "learned").name == "kitti_cons_learned.safetensors"


@pytest.mark.parametrize("name", ["learned", "learned-dis"])
def test_learned_estimators_run_on_several_workers_with_the_same_flows(plane_sequence, name):
    """A replica shares the network (not copied) and the decoded images, and gives the same flows; with
    replicas the prefetch runs one worker a core and hands out what one thread computes."""
    from deepslam.core.readers import open_sequence
    from deepslam.flow import registry as flow_registry
    from deepslam.vo.data.prefetch import PairInputs

    seq = open_sequence(plane_sequence)
    est = flow_registry.make(name)
    twin = est.replica()
    inner = (lambda e: e.learned) if name == "learned-dis" else (lambda e: e)
    assert twin is not est and inner(twin).model is inner(est).model and twin._grey is est._grey
    np.testing.assert_array_equal(twin.pair_flow(seq, 3, 4), flow_registry.make(name).pair_flow(seq, 3, 4))
    pairs = [(k, k + 1) for k in range(6)]
    serial = list(PairInputs(seq, pairs, flow_registry.make(name), 80, 24, workers=1))
    inputs = PairInputs(seq, pairs, flow_registry.make(name), 80, 24, workers=2)
    assert inputs.workers == 2
    for (a, _), (b, _) in zip(list(inputs), serial, strict=True):
        np.testing.assert_array_equal(a, b)


def test_loader_workers_give_the_batches_of_the_training_process():
    """Each step's batch comes from the step's own seed stream: built ahead by two worker processes or
    in the training process, the tensors are the same, in step order, from any starting step."""
    from deepslam.flow.train import step_batches

    cfg = FlowTrainConfig(net=SMALL, crop=(64, 128), batch_size=3, seed=5)
    here = list(step_batches(_Shifted(), cfg, 7, 12))
    ahead = list(step_batches(_Shifted(), dataclasses.replace(cfg, loader_workers=2), 7, 12))
    assert len(here) == len(ahead) == 5
    for a, b in zip(here, ahead):
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    # a run stopped early (time cap) closes the generator and its workers
    gen = step_batches(_Shifted(), dataclasses.replace(cfg, loader_workers=2), 0, 100)
    next(gen)
    gen.close()


_NO_CUDA = "no CUDA device on this machine (the CPU path is tested above)"


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason=_NO_CUDA)
def test_flow_network_on_cuda_agrees_with_the_cpu():
    """The same weights in float32: the GPU's flow equals the CPU's to a small fraction of a pixel;
    under bf16 autocast (how training runs) it stays within a tenth of the flow's size."""
    torch.manual_seed(0)
    net = FlowNet(SMALL).eval()
    b = _Shifted().batch(np.random.default_rng(3), 4, (64, 128))
    with torch.no_grad():
        cpu = net(b["img0"], b["img1"])[-1]
        gpu_net = net.to("cuda")
        torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
        gpu = gpu_net(b["img0"].cuda(), b["img1"].cuda())[-1].float().cpu()
        with torch.autocast("cuda", dtype=torch.bfloat16):
            bf = gpu_net(b["img0"].cuda(), b["img1"].cuda())[-1].float().cpu()
    assert torch.allclose(gpu, cpu, atol=1e-3, rtol=1e-3)
    assert float((bf - cpu).norm(dim=1).mean()) < 0.1 * float(cpu.norm(dim=1).mean()) + 0.05


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason=_NO_CUDA)
def test_flow_training_on_cuda_with_loader_workers_learns_and_loads_on_the_cpu(tmp_path):
    cfg = FlowTrainConfig(net=SMALL, crop=(64, 128), batch_size=16, lr=1e-3, max_steps=300,
                          level_weights=(1.0, 0.5, 0.25), checkpoint_steps=100, device="cuda", loader_workers=2)
    path = train_flow(cfg, _Shifted(), tmp_path / "run", progress=False)
    model, meta = load_flow_model(path)
    assert meta["steps"] == 300 and next(model.parameters()).device.type == "cpu"
    b = _Shifted().batch(np.random.default_rng(99), 8, (64, 128))
    with torch.no_grad():
        pred = model(b["img0"], b["img1"])[-1]
    gt = torch.nn.functional.avg_pool2d(b["flow"], 2) / 2
    err = (pred - gt)[:, :, 4:-4, 4:-4].norm(dim=1).mean()
    assert float(err) < 0.6 * float(gt[:, :, 4:-4, 4:-4].norm(dim=1).mean())
