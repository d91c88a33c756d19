"""The network: the paper's architecture, shapes, normalisation, coord channels, memory formats."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from deepslam.vo.net import FlowPoseNet, NetConfig, PAPER, count_parameters, gaussian_nll, pose_loss


def test_paper_architecture_layers_and_feature_shape():
    net = FlowPoseNet(PAPER)
    convs = [m for m in net.conv if isinstance(m, torch.nn.Conv2d)]
    assert [c.kernel_size[0] for c in convs] == [7, 5, 3, 3, 3, 3]
    assert [c.stride[0] for c in convs] == [2, 1, 4, 1, 2, 1]
    assert all(c.out_channels == 64 for c in convs) and convs[0].in_channels == 2
    assert sum(isinstance(m, torch.nn.ReLU) for m in net.conv) == 6
    # 96x320 / (2 * 4 * 2) = 6x20
    assert PAPER.feature_shape() == (64, 6, 20)
    x = net.conv(torch.zeros(1, 2, 96, 320))
    assert tuple(x.shape) == (1, 64, 6, 20)
    for branch in (net.rot_fc, net.trans_fc):
        lin = [m for m in branch if isinstance(m, torch.nn.Linear)]
        assert [(m.in_features, m.out_features) for m in lin] == [(64 * 6 * 20, 500), (500, 500)]
    assert net.rot_mean.out_features == net.trans_mean.out_features == 3
    assert net.rot_log_std.out_features == net.trans_log_std.out_features == 3


def test_forward_shapes_and_dtype():
    cfg = NetConfig(24, 80, filters=8, hidden_units=16)
    net = FlowPoseNet(cfg)
    mean, log_std = net(torch.randn(5, 2, 24, 80), torch.tensor([[40.0, 40.0, 39.5, 11.5]] * 5))
    assert mean.shape == (5, 6) and log_std.shape == (5, 6)
    assert mean.dtype == torch.float32
    # log-std heads start at zero: std = 1
    assert torch.all(log_std == 0)


def test_input_normalisation_is_flow_over_size():
    cfg = NetConfig(24, 80, filters=4, hidden_units=8)
    net = FlowPoseNet(cfg)
    flow = torch.zeros(1, 2, 24, 80)
    flow[:, 0] = 8.0   # du = 8 px -> 8 / 80
    flow[:, 1] = 12.0  # dv = 12 px -> 12 / 24
    x = net.prepare_input(flow)
    assert torch.allclose(x[:, 0], torch.full((1, 24, 80), 0.1))
    assert torch.allclose(x[:, 1], torch.full((1, 24, 80), 0.5))
    scaled = FlowPoseNet(NetConfig(24, 80, filters=4, hidden_units=8, flow_scale=10.0)).prepare_input(flow)
    assert torch.allclose(scaled, 10 * x)


def test_coord_channels_hold_normalised_pixel_coordinates():
    cfg = NetConfig(6, 10, filters=4, hidden_units=8, coord_channels=True, kernels=(3,), strides=(1,))
    net = FlowPoseNet(cfg)
    assert net.conv[0].in_channels == 4
    k = torch.tensor([[5.0, 4.0, 4.5, 2.5], [10.0, 10.0, 0.0, 0.0]])
    x = net.prepare_input(torch.zeros(2, 2, 6, 10), k)
    u, v = np.meshgrid(np.arange(10.0), np.arange(6.0))
    for b in range(2):
        fx, fy, cx, cy = k[b].tolist()
        np.testing.assert_allclose(x[b, 2].numpy(), (u - cx) / fx, atol=1e-6)
        np.testing.assert_allclose(x[b, 3].numpy(), (v - cy) / fy, atol=1e-6)
    with pytest.raises(ValueError):
        net.prepare_input(torch.zeros(1, 2, 6, 10))


def test_wrong_input_size_is_rejected():
    net = FlowPoseNet(NetConfig(24, 80, filters=4, hidden_units=8))
    with pytest.raises(ValueError, match="24, 80"):
        net(torch.zeros(1, 2, 20, 80))


def test_channels_last_gives_the_same_output():
    torch.manual_seed(0)
    cfg = NetConfig(24, 80, filters=8, hidden_units=16)
    a = FlowPoseNet(cfg).eval()
    b = FlowPoseNet(cfg).eval()
    b.load_state_dict(a.state_dict())
    b.set_channels_last(True)
    x = torch.randn(3, 2, 24, 80)
    with torch.no_grad():
        ma, _ = a(x)
        mb, _ = b(x)
    torch.testing.assert_close(ma, mb, rtol=1e-4, atol=1e-6)


def test_parameter_split_and_losses():
    net = FlowPoseNet(NetConfig(24, 80, filters=4, hidden_units=8))
    unc, mot = net.uncertainty_parameters(), net.motion_parameters()
    assert len(unc) == 4 and len(unc) + len(mot) == len(list(net.parameters()))
    assert count_parameters(net) == sum(p.numel() for p in unc + mot)
    mean = torch.zeros(2, 6)
    target = torch.tensor([[0.1, 0, 0, 1.0, 0, 0], [0, 0, 0, 0, 0, 0]])
    # the paper's L1: 50 * mean(|0.1|, 0, 0) over (B, 3) + mean(|1|, 0, 0) over (B, 3)
    assert pose_loss(mean, target) == pytest.approx(50 * 0.1 / 6 + 1.0 / 6)
    # the squared error: 50 * mean(0.01, 0, 0, 0, 0, 0) + mean(1, 0, 0, 0, 0, 0)
    assert pose_loss(mean, target, kind="mse") == pytest.approx(50 * 0.01 / 6 + 1.0 / 6)
    # the rotation weight scales the euler part only
    assert pose_loss(mean, target, rot_weight=1.0) == pytest.approx(0.1 / 6 + 1.0 / 6)
    with pytest.raises(ValueError, match="loss must be one of"):
        pose_loss(mean, target, kind="huber")
    # NLL at sigma = 1: 0.5 * mean(z^2)
    assert gaussian_nll(mean, torch.zeros(2, 6), target) == pytest.approx(0.5 * (0.01 + 1.0) / 12)


def test_depth_channel_is_the_inverse_depth_and_is_required():
    from deepslam.vo.net import inverse_depth_input

    cfg = NetConfig(6, 10, filters=4, hidden_units=8, depth_channel=True, kernels=(3,), strides=(1,))
    net = FlowPoseNet(cfg)
    assert net.conv[0].in_channels == 3 and NetConfig.from_dict(cfg.to_dict()) == cfg
    depth = np.full((12, 20), 2.0, np.float32)
    depth[:2, :2] = 0.0                                   # unknown: 0, never a made-up depth
    depth[:2, 2:4] = np.nan
    depth[2:4, :2] = 4.0
    inv = inverse_depth_input(depth, 10, 6)             # 2 x 2 blocks averaged
    assert inv.shape == (1, 6, 10) and inv.dtype == np.float32
    assert inv[0, 0, 0] == 0.0 and inv[0, 0, 1] == 0.0 and inv[0, 1, 0] == pytest.approx(0.25)
    assert inv[0, 3, 5] == pytest.approx(0.5)
    x = net.prepare_input(torch.zeros(1, 2, 6, 10), None, torch.from_numpy(inv[None]))
    assert torch.equal(x[0, 2], torch.from_numpy(inv[0]))
    with pytest.raises(ValueError, match="inverse depth"):
        net.prepare_input(torch.zeros(1, 2, 6, 10))
    with pytest.raises(ValueError, match="inverse depth"):
        net.prepare_input(torch.zeros(1, 2, 6, 10), None, torch.zeros(1, 1, 5, 10))


@pytest.mark.parametrize("valid_channel", [False, True])
def test_unknown_flow_reads_as_zero_and_the_valid_channel_marks_it(valid_channel):
    """NaN / inf flow (unknown) enters as 0 either way; with valid_channel a last channel is 1 where
    both components are known, 0 elsewhere, after the depth channel; the output stays finite."""
    cfg = NetConfig(6, 10, filters=4, hidden_units=8, kernels=(3,), strides=(1,), depth_channel=True,
                    valid_channel=valid_channel)
    assert cfg.in_channels == 3 + valid_channel and NetConfig.from_dict(cfg.to_dict()) == cfg
    assert cfg.unknown_flow == ("nan" if valid_channel else "zero")
    net = FlowPoseNet(cfg)
    flow = torch.full((2, 2, 6, 10), 5.0)
    flow[0, :, 1, 2] = float("nan")
    flow[1, 0, 3, 4] = float("inf")  # one bad component: the vector is unknown
    inv = torch.full((2, 1, 6, 10), 0.5)
    x = net.prepare_input(flow, None, inv)
    assert x.shape == (2, cfg.in_channels, 6, 10) and torch.isfinite(x).all()
    assert x[0, :2, 1, 2].eq(0).all() and x[1, :2, 3, 4].eq(0).all() and x[0, 0, 0, 0] > 0
    assert torch.equal(x[:, 2], inv[:, 0])
    if valid_channel:
        known = torch.ones(2, 6, 10)
        known[0, 1, 2] = known[1, 3, 4] = 0
        assert torch.equal(x[:, 3], known)
    mean, log_std = net(flow, None, inv)
    assert torch.isfinite(mean).all() and torch.isfinite(log_std).all()


def test_train_config_loss_default_and_older_records():
    from deepslam.vo.trainconfig import TrainConfig

    assert TrainConfig().loss == "l1"  # the paper's published code
    assert TrainConfig.from_dict(TrainConfig().to_dict()).loss == "l1"
    old = TrainConfig().to_dict()
    del old["loss"]  # a file recorded before the loss was a setting was trained with the MSE
    assert TrainConfig.from_dict(old).loss == "mse"
    with pytest.raises(ValueError, match="loss must be one of"):
        TrainConfig(loss="huber")
