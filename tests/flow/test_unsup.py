"""Unsupervised fine-tuning of the learned flow on unlabelled pairs (flow.unsup): the census loss and
its basin, the occlusion mask, the smoothness term, the real-pair loader, and training with real pairs."""
import dataclasses

import numpy as np
import pytest
import torch

from deepslam.core.errors import InputError
from deepslam.flow.unsup import RealPairs, non_occluded, photometric_census_loss, smoothness_loss, unsupervised_loss
from deepslam.flow.net import FlowNetConfig, load_flow_model
from deepslam.flow.train import FlowTrainConfig, train_flow

SMALL = FlowNetConfig(channels=(8, 12, 16), estimator_channels=(16,), finest_level=1, work_width=128, search_px=2)


def _texture_pair(du: int, dv: int, gain: float = 1.0, h: int = 48, w: int = 96, seed: int = 0):
    """img1(x + (du, dv)) = gain * img0(x): a blocky random texture moved by a known flow."""
    base = np.random.default_rng(seed).random((h // 2 + 8, w // 2 + 8)).astype(np.float32)
    big = np.kron(base, np.ones((2, 2), np.float32))
    img0 = big[8:8 + h, 8:8 + w]
    img1 = np.clip(gain * big[8 - dv:8 - dv + h, 8 - du:8 - du + w], 0, 1)
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a))[None, None]  # noqa: E731
    flow = torch.zeros(1, 2, h, w)
    flow[:, 0], flow[:, 1] = float(du), float(dv)
    return t(img0), t(img1), flow


@pytest.mark.parametrize("du,dv,gain", [(3, 0, 1.0), (-2, 2, 1.0), (4, -1, 0.6), (0, 3, 1.3)])
def test_census_loss_is_lowest_at_the_true_flow_under_a_gain_change(du, dv, gain):
    img0, img1, flow = _texture_pair(du, dv, gain)
    mask = torch.ones(1, 1, *img0.shape[-2:])
    mask[..., :, :6] = mask[..., :, -6:] = 0  # landing outside for the shifts tried
    mask[..., :6, :] = mask[..., -6:, :] = 0
    at_truth = float(photometric_census_loss(img0, img1, flow, mask))
    for wrong in (torch.zeros_like(flow), flow + torch.tensor([1.0, 0.0]).view(1, 2, 1, 1),
                  flow + torch.tensor([0.0, -1.0]).view(1, 2, 1, 1)):
        assert at_truth < 0.6 * float(photometric_census_loss(img0, img1, wrong, mask))


def test_occlusion_mask_keeps_consistent_pixels_landing_inside():
    fw = torch.zeros(1, 2, 8, 10)
    fw[:, 0] = 2.0
    m = non_occluded(fw, -fw)
    assert (m[0, 0, :, :8] == 1).all() and (m[0, 0, :, 8:] == 0).all()  # the last two columns land outside
    assert not m.requires_grad
    bw = -fw.clone()
    bw[:, :, 5:] *= -1  # the backward flow does not bring rows 5-7 back: occluded
    m = non_occluded(fw, bw)
    assert (m[0, 0, :5, :8] == 1).all() and (m[0, 0, 5:] == 0).all()
    # inconsistent everywhere (an untrained network): the check is not used, the in-image mask is
    assert torch.equal(non_occluded(fw, fw), non_occluded(fw, -fw))


def test_smoothness_is_zero_for_a_constant_flow_and_spares_image_edges():
    img_flat = torch.full((1, 1, 16, 16), 0.5)
    img_edge = img_flat.clone()
    img_edge[..., :, 8:] = 0.9  # an image edge where the flow steps
    flow = torch.zeros(1, 2, 16, 16)
    assert float(smoothness_loss(flow + 3.0, img_flat)) == 0.0
    flow[:, 0, :, 8:] = 4.0
    assert float(smoothness_loss(flow, img_edge)) < 0.05 * float(smoothness_loss(flow, img_flat))


def test_second_order_smoothness_leaves_a_planes_linear_flow_free():
    img = torch.full((1, 1, 16, 16), 0.5)
    v = torch.arange(16, dtype=torch.float32)
    flow = torch.zeros(1, 2, 16, 16)
    flow[:, 1] = 0.3 * v.view(16, 1)  # dv grows linearly towards the bottom, as a road plane's does
    assert float(smoothness_loss(flow, img, order=1)) > 0.1
    assert float(smoothness_loss(flow, img, order=2)) == pytest.approx(0.0, abs=1e-6)
    flow[:, 1, 8:] += 2.0  # a step is not free in either order
    assert float(smoothness_loss(flow, img, order=2)) > 0.05
    with pytest.raises(ValueError):
        smoothness_loss(flow, img, order=3)


def test_real_pairs_cover_both_stereo_cameras_at_the_network_width(plane_sequence):
    from deepslam.core.readers import open_sequence

    seq = open_sequence(plane_sequence)
    rp = RealPairs([seq], 128, progress=False)
    assert len(rp) == (len(seq) - 1) * (2 if seq.has_stereo else 1)
    assert rp.min_size() == (40, 128)  # 256 x 80 resized to the network's 128 px width
    b = rp.batch(np.random.default_rng(0), 3, (32, 96))
    assert set(b) == {"img0", "img1", "aug0", "aug1"}
    assert all(v.shape == (3, 1, 32, 96) and v.dtype == torch.float32 for v in b.values())
    assert float(b["img0"].min()) >= 0 and float(b["img0"].max()) <= 1


def _blocky_pair(rng, h: int, w: int):
    """img1(x + d) = img0(x) for a random integer d in [-3, 3]^2 on 4x4-pixel random blocks; and d."""
    base = rng.random((h // 4 + 4, w // 4 + 4)).astype(np.float32)
    big = np.kron(base, np.ones((4, 4), np.float32))
    du, dv = int(rng.integers(-3, 4)), int(rng.integers(-3, 4))
    return big[8:8 + h, 8:8 + w], big[8 - dv:8 - dv + h, 8 - du:8 - du + w], (du, dv)


class _Unlabelled:
    """Blocky texture pairs moved by a random shift, given to the loss without their flow."""

    def __len__(self):
        return 1

    def batch(self, rng, n, crop):
        a, b, _ = zip(*(_blocky_pair(rng, *crop) for _ in range(n)))
        t0, t1 = (torch.from_numpy(np.stack(x)[:, None]) for x in (a, b))
        return {"img0": t0, "img1": t1, "aug0": t0, "aug1": t1}


class _NoLabels(_Unlabelled):
    """The supervised source with every label missing: the supervised loss is zero."""

    def batch(self, rng, n, crop):
        b = super().batch(rng, n, crop)
        return {"img0": b["img0"], "img1": b["img1"], "flow": torch.full((n, 2, *crop), float("nan"))}


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_descending_the_census_loss_from_zero_flow_finds_the_shift(seed):
    """The census loss, minimised over a translation (no network) from zero flow, lands on the true
    shift: its minimum is the right flow and its basin reaches from 0 to 3 px (a smooth texture: on
    hard-edged blocks the basin is a cliff half a pixel wide)."""
    import cv2

    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.random((64, 112)).astype(np.float32), (0, 0), 1.5)
    base = (base - base.min()) / (base.max() - base.min())
    du, dv = int(rng.integers(-3, 4)), int(rng.integers(-3, 4))
    a, b = base[8:56, 8:104], base[8 - dv:56 - dv, 8 - du:104 - du]  # img1(x + d) = img0(x)
    img0, img1 = (torch.from_numpy(np.ascontiguousarray(x))[None, None] for x in (a, b))
    shift = torch.zeros(2, requires_grad=True)
    opt = torch.optim.Adam([shift], lr=0.1)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda k: 1.0 - k / 200)
    for _ in range(200):
        flow = shift.view(1, 2, 1, 1).expand(1, 2, 48, 96)
        loss = photometric_census_loss(img0, img1, flow, non_occluded(flow.detach(), -flow.detach()))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    shift = shift.detach()
    assert float(shift[0]) == pytest.approx(du, abs=0.1) and float(shift[1]) == pytest.approx(dv, abs=0.1)


def test_training_with_real_pairs_logs_their_loss_and_resumes(tmp_path):
    import json

    cfg = FlowTrainConfig(net=SMALL, crop=(48, 96), batch_size=2, max_steps=6, level_weights=(1.0, 0.5, 0.25),
                          checkpoint_steps=2, threads=2, real_batch_size=2, stop_after_steps=4)
    train_flow(cfg, _NoLabels(), tmp_path / "run", progress=False, real_pairs=_Unlabelled())
    path = train_flow(dataclasses.replace(cfg, stop_after_steps=0), _NoLabels(), tmp_path / "run", resume=True,
                      progress=False, real_pairs=_Unlabelled())
    hist = json.loads((tmp_path / "run" / "history.json").read_text())
    assert [h["step"] for h in hist] == [2, 4, 6] and all(h["real_census"] > 0 for h in hist)
    assert load_flow_model(path)[1]["train"]["real_batch_size"] == 2
    with pytest.raises(InputError, match="cannot resume"):  # another unsupervised weight is another run
        train_flow(dataclasses.replace(cfg, real_weight=2.0), _NoLabels(), tmp_path / "run", resume=True,
                   progress=False, real_pairs=_Unlabelled())


def test_the_unsupervised_loss_scores_both_directions():
    torch.manual_seed(0)
    from deepslam.flow.net import FlowNet

    model = FlowNet(SMALL)
    img0, img1, _ = _texture_pair(2, 1, h=64, w=128)
    loss, parts = unsupervised_loss(model, img0, img1, img0, img1, 1.0)
    loss.backward()
    assert torch.isfinite(loss) and set(parts) == {"census", "smooth", "non_occluded"}
    assert all(p.grad is not None for p in model.parameters() if p.requires_grad)
