"""vo.attribution: the mirrored input is the mirrored scene's flow; integrated gradients add up to the reading."""
import numpy as np
import pytest
import torch

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.gen.flow import synthesize
from deepslam.gen.motion import mirrored_vectors
from deepslam.vo.attribution import integrated_gradients, mirror_input, region_sums
from deepslam.vo.net import FlowPoseNet, NetConfig


def _exact_flow(depth_z, camera, vec6):
    flow, _ = synthesize(depth_z[None].astype(np.float32), camera, se3.from_euler6(np.asarray(vec6))[None])
    return np.asarray(flow)[0].transpose(2, 0, 1)  # (2, H, W)


def test_mirror_input_is_the_mirrored_scene_under_the_mirrored_motion():
    # an asymmetric scene (a wall near on the left, far on the right) and a motion with every DoF
    cam = PinholeCamera(40, 24, 30.0, 30.0, 17.3, 11.6)
    u = np.arange(cam.width)
    depth = np.tile(4.0 + 0.3 * u, (cam.height, 1)) + 0.05 * np.arange(cam.height)[:, None]
    vec6 = np.array([0.01, 0.03, -0.02, 0.2, -0.05, 0.6])
    flow = _exact_flow(depth, cam, vec6)
    mirrored, intr = mirror_input(flow[None], cam.intrinsics(np.float32)[None])
    expected = _exact_flow(depth[:, ::-1].copy(), cam.mirrored(), mirrored_vectors(vec6[None])[0])
    inner = (slice(None), slice(3, -3), slice(3, -3))  # away from the borders, where points leave the image
    np.testing.assert_allclose(mirrored[0][inner], expected[inner], atol=2e-3)
    np.testing.assert_allclose(intr[0], cam.mirrored().intrinsics(np.float32))
    twice, intr2 = mirror_input(*mirror_input(flow[None], cam.intrinsics(np.float32)[None]))
    np.testing.assert_array_equal(twice, flow[None])
    np.testing.assert_allclose(intr2[0], cam.intrinsics(np.float32))


class _Linear(torch.nn.Module):
    """mean[:, d] = sum(weight[d] * flow) + bias[d]: integrated gradients are weight * flow exactly."""

    def __init__(self, h, w):
        super().__init__()
        g = torch.Generator().manual_seed(0)
        self.weight = torch.nn.Parameter(torch.randn(6, 2, h, w, generator=g))
        self.bias = torch.nn.Parameter(torch.randn(6, generator=g))

    def forward(self, flow, intrinsics, inv_depth=None):
        mean = torch.einsum("bchw,dchw->bd", flow, self.weight) + self.bias
        return mean, torch.zeros_like(mean)


def test_integrated_gradients_of_a_linear_network_are_weight_times_flow():
    rng = np.random.default_rng(1)
    flow = rng.normal(size=(3, 2, 6, 10)).astype(np.float32)
    net = _Linear(6, 10)
    attr, at_zero = integrated_gradients(net, flow, np.zeros((3, 4), np.float32), output=5, steps=4)
    expected = (net.weight[5].detach().numpy()[None] * flow).sum(1)
    np.testing.assert_allclose(attr, expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(at_zero, net.bias[5].item(), rtol=1e-6)


def test_integrated_gradients_add_up_to_the_reading_of_a_posenet():
    torch.manual_seed(0)
    cfg = NetConfig(input_height=24, input_width=80, filters=8, hidden_units=16)
    net = FlowPoseNet(cfg).eval()
    with torch.no_grad():  # weights large enough that the reading depends on the flow well beyond float32's noise
        for p in net.motion_parameters():
            p.normal_(0.0, 0.3)
    rng = np.random.default_rng(2)
    flow = rng.normal(scale=3.0, size=(5, 2, 24, 80)).astype(np.float32)
    intr = np.tile(np.float32([60, 60, 40, 12]), (5, 1))
    attr, at_zero = integrated_gradients(net, flow, intr, output=5, steps=64, batch=2)
    with torch.no_grad():
        reading = net(torch.from_numpy(flow), torch.from_numpy(intr), None)[0][:, 5].double().numpy()
    spread = np.abs(reading - at_zero).max()
    assert spread > 1e-3  # the test would pass vacuously on a network that ignores its input
    np.testing.assert_allclose(attr.sum((1, 2)) + at_zero, reading, atol=0.02 * spread)
    with pytest.raises(ValueError, match="output"):
        integrated_gradients(net, flow, intr, output=6)


def test_region_sums_keep_the_total_and_split_unevenly():
    a = np.arange(2 * 7 * 10, dtype=np.float64).reshape(2, 7, 10)
    g = region_sums(a, 3, 4)
    assert g.shape == (2, 3, 4)
    np.testing.assert_allclose(g.sum((1, 2)), a.sum((1, 2)))
    np.testing.assert_allclose(g[:, 0, 0], a[:, :2, :2].sum((1, 2)))  # rows 0-1 of 0, 2, 4, 7; columns 0-1
    with pytest.raises(ValueError, match="grid"):
        region_sums(a, 8, 4)


def test_the_mirror_average_reads_a_scene_and_its_mirror_image_as_mirrored_motions():
    """VOPredictor.mirror_average: whatever the network, the averaged reading of a flow's mirror image is the averaged
    reading of the flow, mirrored (MIRROR_SIGNS); without it the reading is the network's own, unchanged."""
    from deepslam.gen.motion import MIRROR_SIGNS
    from deepslam.vo.infer import VOPredictor

    torch.manual_seed(0)
    cfg = NetConfig(input_height=24, input_width=40, filters=8, kernels=(3, 3), strides=(2, 2), hidden_units=16)
    net = FlowPoseNet(cfg)
    rng = np.random.default_rng(0)
    flow = rng.normal(0.0, 2.0, (3, 2, 24, 40)).astype(np.float32)
    intr = np.tile(np.float32([30.0, 30.0, 17.3, 11.6]), (3, 1))  # an off-centre principal point
    once = VOPredictor(net, channels_last=False, bf16=False)
    both = VOPredictor(net, channels_last=False, bf16=False, mirror_average=True)
    mean, std = once.predict(flow, intr)
    m_mean, _ = once.predict(*mirror_input(flow, intr))
    assert not np.allclose(m_mean * MIRROR_SIGNS, mean, atol=1e-4)  # a random network reads the two differently
    avg, avg_std = both.predict(flow, intr)
    np.testing.assert_allclose(avg, 0.5 * (mean + m_mean * MIRROR_SIGNS), atol=1e-12)
    mirrored_avg, mirrored_std = both.predict(*mirror_input(flow, intr))
    np.testing.assert_allclose(mirrored_avg * MIRROR_SIGNS, avg, atol=1e-6)
    np.testing.assert_allclose(mirrored_std, avg_std, rtol=1e-6)
    assert (avg_std > 0).all()
    with torch.inference_mode():
        m, ls = net(torch.from_numpy(flow), torch.from_numpy(intr), None)
    np.testing.assert_array_equal(mean, m.double().numpy())  # off: the network's reading, byte for byte
    np.testing.assert_array_equal(std, ls.double().exp().numpy())


def test_auto_mirror_average_is_for_models_trained_on_mirrored_frames_read_with_their_own_pose():
    from deepslam.commands import _odometry_flags
    from deepslam.vo.modelfiles import models

    mirrored, plain = {"data": {"mirror_frames": True}}, {"data": {}}
    assert models.mirror_average("auto", mirrored, net_pose=True)
    assert not models.mirror_average("auto", mirrored, net_pose=False)
    assert not models.mirror_average("auto", plain, net_pose=True)
    assert models.mirror_average("on", plain, net_pose=False) and not models.mirror_average("off", mirrored, True)
    with pytest.raises(ValueError, match="mirror_average must be one of"):
        models.mirror_average("yes", plain, True)
    assert _odometry_flags.MIRROR_AVERAGE_CHOICES == models.MIRROR_AVERAGE
    assert _odometry_flags.MIRROR_AVERAGE_DEFAULT == models.MIRROR_AVERAGE_DEFAULT
