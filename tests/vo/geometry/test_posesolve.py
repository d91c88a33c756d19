"""The solve pose head (vo.geometry.posesolve): Gauss-Newton pose from flow and depth, its weights and gradient."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from deepslam.core import se3
from deepslam.vo.geometry.posesolve import FlowSolvePoseNet, euler6, so3_exp, solve_pose, unit_weight_net
from deepslam.vo.modelfiles.modelio import make_net
from deepslam.vo.net import NetConfig

H, W = 24, 32
K = (30.0, 28.0, 15.5, 11.5)


def flow_field(cam1_from_cam0: np.ndarray, depth: np.ndarray, k=K) -> np.ndarray:
    """(2, h, w) float64 exact flow of a depth map (h, w) metres under cam1_from_cam0 (4, 4)."""
    fx, fy, cx, cy = k
    v, u = np.mgrid[0:depth.shape[0], 0:depth.shape[1]].astype(float)
    p = np.stack([(u - cx) / fx * depth, (v - cy) / fy * depth, depth], -1)
    q = p @ cam1_from_cam0[:3, :3].T + cam1_from_cam0[:3, 3]
    return np.stack([q[..., 0] / q[..., 2] * fx + cx - u, q[..., 1] / q[..., 2] * fy + cy - v])


def scene(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.8, 4.0, (H, W))


def tensors(flow: np.ndarray, depth: np.ndarray):
    inv = np.where(depth > 0, 1.0 / np.where(depth > 0, depth, 1.0), 0.0)
    return (torch.tensor(flow[None], dtype=torch.float32), torch.tensor(inv[None, None], dtype=torch.float32),
            torch.tensor([K], dtype=torch.float32))


MOTIONS = {
    "still": [0, 0, 0, 0, 0, 0],
    "pure rotation": [0.01, -0.02, 0.015, 0, 0, 0],
    "forward": [0, 0, 0, 0, 0, 0.05],
    "sideways": [0, 0, 0, 0.03, -0.01, 0],
    "hand-held": [0.004, -0.012, 0.003, 0.011, -0.004, 0.006],
    "car-like, large": [0.002, 0.05, 0.001, 0.02, -0.01, 1.2],
}


@pytest.mark.parametrize("name", MOTIONS)
def test_unit_weights_recover_the_exact_motion(name):
    """Exact flow, known depth, every weight 1: the solve is the motion (holes in flow or depth ignored)."""
    vec = np.array(MOTIONS[name])
    depth = scene()
    flow = flow_field(se3.from_euler6(vec), depth)
    flow[:, 3:6, 4:9] = np.nan            # unknown flow
    depth[10:14, 20:30] = 0.0             # no depth reading (its flow is exact but cannot be used)
    f, inv, k = tensors(flow, depth)
    rot, t, hess = solve_pose(f, inv, k, torch.ones(1, 2, H, W), iterations=4)
    assert np.allclose(euler6(rot, t)[0].numpy(), vec, atol=2e-6)
    assert torch.all(torch.linalg.eigvalsh(hess) > 0)


def test_zero_weights_leave_a_corrupted_region_out():
    vec = np.array(MOTIONS["hand-held"])
    depth = scene(1)
    flow = flow_field(se3.from_euler6(vec), depth)
    flow[:, :8, :10] += 3.0                # a region whose flow is wrong by 3 px
    f, inv, k = tensors(flow, depth)
    w = torch.ones(1, 2, H, W)
    biased = euler6(*solve_pose(f, inv, k, w)[:2])[0].numpy()
    w[:, :, :8, :10] = 0.0
    clean = euler6(*solve_pose(f, inv, k, w)[:2])[0].numpy()
    assert np.abs(biased - vec).max() > 1e-3 and np.allclose(clean, vec, atol=2e-6)


@pytest.mark.parametrize("name", ["pure rotation", "forward", "hand-held", "car-like, large"])
def test_cauchy_kernel_keeps_the_exact_motion_and_leaves_wrong_flow_out(name):
    """With exact flow the robust solve is the motion; with a fifth of the pixels' flow wrong by 2-6 px
    (a moving object, occlusion) it stays within 1e-4 of it where least squares is pulled off by more."""
    vec = np.array(MOTIONS[name])
    depth = scene(6)
    flow = flow_field(se3.from_euler6(vec), depth)
    f, inv, k = tensors(flow, depth)
    ones = torch.ones(1, 2, H, W)
    exact = euler6(*solve_pose(f, inv, k, ones, iterations=6, robust="cauchy")[:2])[0].numpy()
    assert np.allclose(exact, vec, atol=2e-6)
    rng = np.random.default_rng(7)
    bad = rng.random((H, W)) < 0.2
    flow[:, bad] += rng.uniform(2.0, 6.0, (2, int(bad.sum()))) * rng.choice([-1, 1], (2, int(bad.sum())))
    flow[:, :, :2] = np.nan                                  # and some pixels unknown
    f, inv, k = tensors(flow, depth)
    plain = euler6(*solve_pose(f, inv, k, ones, iterations=6)[:2])[0].numpy()
    robust = euler6(*solve_pose(f, inv, k, ones, iterations=6, robust="cauchy")[:2])[0].numpy()
    assert np.abs(plain - vec).max() > 1e-3 and np.abs(robust - vec).max() < 1e-4
    with pytest.raises(ValueError, match="robust must be one of"):
        solve_pose(f, inv, k, ones, robust="huber")


def test_cauchy_solve_head_trains_through_its_last_step():
    """The reweighting factors are constants of the last step: the weights still get a finite gradient."""
    net = make_net(solve_cfg(solve_robust="cauchy", solve_iterations=5))
    vec = np.array(MOTIONS["hand-held"])
    depth = scene(8)
    flow = flow_field(se3.from_euler6(vec), depth) + np.random.default_rng(9).normal(0, 0.5, (2, H, W))
    f, inv, k = tensors(flow, depth)
    mean, _ = net(f, k, inv)
    mean[0, 3:].sum().backward()
    grads = [p.grad for p in net.motion_parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads) and any(g.abs().sum() > 0 for g in grads)


def test_nothing_usable_answers_the_identity():
    f = torch.full((2, 2, H, W), float("nan"))
    rot, t, hess = solve_pose(f, torch.ones(2, 1, H, W), torch.tensor([K, K]), torch.ones(2, 2, H, W))
    assert torch.equal(rot, torch.eye(3, dtype=torch.float64).expand(2, 3, 3)) and torch.equal(t, torch.zeros(2, 3,
                                                                                                       dtype=torch.float64))
    assert torch.count_nonzero(hess) == 0


def test_gradient_of_the_pose_by_the_weights_matches_finite_differences():
    """Only the last Gauss-Newton step is differentiated; at convergence that is the implicit gradient."""
    vec = np.array(MOTIONS["hand-held"])
    depth = scene(2)
    flow = flow_field(se3.from_euler6(vec), depth) + np.random.default_rng(3).normal(0, 0.3, (2, H, W))
    f, inv, k = tensors(flow, depth)
    log_w = torch.zeros(1, 2, H, W, dtype=torch.float32, requires_grad=True)
    pose = euler6(*solve_pose(f, inv, k, torch.exp(log_w), iterations=4)[:2])
    pose[0, 3].backward()                               # t_x
    pix = (0, 1, 5, 7)
    eps = 0.5

    def tx(delta):
        lw = torch.zeros(1, 2, H, W)
        lw[pix] = delta
        return float(euler6(*solve_pose(f, inv, k, torch.exp(lw), iterations=6)[:2])[0, 3])

    numeric = (tx(eps) - tx(-eps)) / (2 * eps)
    assert abs(numeric) > 1e-7 and float(log_w.grad[pix]) == pytest.approx(numeric, rel=0.05)


def test_euler6_and_so3_exp_agree_with_core_and_scipy():
    rng = np.random.default_rng(4)
    rotvec = rng.normal(0, 0.7, (20, 3))
    rotvec[0] = 0.0
    rotvec[1] = [1e-6, 0, -2e-6]
    rot = so3_exp(torch.tensor(rotvec))
    assert np.allclose(rot.numpy(), Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-12)
    t = torch.tensor(rng.normal(0, 1, (20, 3)))
    poses = np.tile(np.eye(4), (20, 1, 1))
    poses[:, :3, :3], poses[:, :3, 3] = rot.numpy(), t.numpy()
    assert np.allclose(euler6(rot, t).numpy(), se3.to_euler6(poses), atol=1e-12)


def solve_cfg(**kw) -> NetConfig:
    return NetConfig(H, W, filters=4, hidden_units=8, depth_channel=True, valid_channel=True, pose_head="solve", **kw)


def test_untrained_solve_network_is_the_plain_least_squares_fit():
    """The weight network starts at log-weight 0 everywhere: its pose is the unit-weight solve."""
    cfg = solve_cfg()
    net = make_net(cfg)
    assert isinstance(net, FlowSolvePoseNet) and NetConfig.from_dict(cfg.to_dict()) == cfg
    vec = np.array(MOTIONS["hand-held"])
    depth = scene(5)
    f, inv, k = tensors(flow_field(se3.from_euler6(vec), depth), depth)
    with torch.no_grad():
        mean, log_std = net(f, k, inv)
    assert mean.dtype == torch.float32 and mean.shape == log_std.shape == (1, 6)
    assert np.allclose(mean[0].numpy(), vec, atol=2e-5) and torch.isfinite(log_std).all()
    # stage 2 starts calibrated: mean log-std over a set equals log(rmse) per DoF
    with torch.no_grad():
        hr, ht = net.trunk(f.repeat(3, 1, 1, 1), k.repeat(3, 1), inv.repeat(3, 1, 1, 1))
    rmse = torch.tensor([1e-3, 2e-3, 3e-3, 1e-2, 2e-2, 3e-2])
    net.calibrate_log_std(ht, rmse)
    assert torch.allclose(net.log_std_head(hr, ht).mean(0), rmse.log(), atol=1e-5)
    assert len(net.uncertainty_parameters()) == 4 and all(
        id(p) not in {id(q) for q in net.uncertainty_parameters()} for p in net.motion_parameters())
    # from a regression network's config (the flow it reads, its size): the same untrained solve
    plain = unit_weight_net(NetConfig(H, W, filters=4, hidden_units=8))
    assert plain.cfg.pose_head == "solve" and plain.cfg.depth_channel and plain.cfg.valid_channel
    with torch.no_grad():
        assert np.allclose(plain(f, k, inv)[0][0].numpy(), vec, atol=2e-5)


@pytest.mark.parametrize("change, match", [
    ({"depth_channel": False}, "depth channel"), ({"valid_channel": False}, "validity channel"),
    ({"pose_head": "mlp"}, "pose_head must be"), ({"solve_iterations": 0}, "solve_iterations"),
    ({"solve_robust": "huber"}, "solve_robust must be")])
def test_solve_head_settings_that_cannot_work_are_refused(change, match):
    d = dataclasses.asdict(solve_cfg())
    d.update(change)
    with pytest.raises(ValueError, match=match):
        NetConfig(**d)


def test_old_model_configs_read_as_the_paper_head():
    d = NetConfig(H, W).to_dict()
    del d["pose_head"], d["solve_iterations"], d["solve_robust"]
    cfg = NetConfig.from_dict(d)
    assert cfg.pose_head == "regress" and cfg.solve_robust == "none"


def test_train_and_vo_with_the_solve_head(plane_sequence, motion_json, tmp_path, capsys):
    """`train --pose-head solve` trains a weight network (stage 1) and calibrates its uncertainty
    (stage 2); vo runs the model file with each frame's depth; without the channels it needs: one line, exit 2."""
    from deepslam.cli import main
    from deepslam.vo.modelfiles.modelio import load_model

    out = tmp_path / "solve"
    base = ["train", "--mode", "synthetic", "--source", str(plane_sequence), "--motion", str(motion_json),
            "--net", "tiny", "--batch", "16", "--samples-per-epoch", "32", "--max-epochs", "1", "--nll-epochs", "1",
            "--bf16", "off", "--threads", "1", "--quiet", "--pose-head", "solve"]
    assert main(base + ["--depth-channel", "--valid-channel", "--out", str(out)]) == 0
    model, meta = load_model(out / "model.safetensors")
    assert isinstance(model, FlowSolvePoseNet) and meta["train"]["net"]["pose_head"] == "solve"
    traj = tmp_path / "vo.txt"
    assert main(["vo", "--sequence", str(plane_sequence), "--model", str(out / "model.safetensors"), "--out",
                 str(traj), "--quiet"]) == 0
    est = np.array([ln.split() for ln in traj.read_text().splitlines() if not ln.startswith("#")], dtype=float)
    assert len(est) == 12 and np.isfinite(est).all()
    # the plane drives 0.8 m a frame forward (8.8 m): DIS's flow and the depth read it as a forward drive of
    # metres (x0.78 when written; the plane's bottom rows leave the view, where DIS errs most)
    assert est[-1, 3] > 5.0 and np.abs(est[-1, 1:3]).max() < 0.3 * est[-1, 3]
    capsys.readouterr()
    assert main(base + ["--depth-channel", "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--valid-channel" in err and not (tmp_path / "bad").exists()
    # set-solve: the same weights with the Cauchy kernel and 6 steps, recorded in the meta; the result
    # is the trained net with its config changed, nothing else
    capsys.readouterr()
    robust = tmp_path / "robust.safetensors"
    assert main(["set-solve", str(out / "model.safetensors"), "--robust", "cauchy", "--iterations", "6",
                 "--out", str(robust)]) == 0
    changed, changed_meta = load_model(robust)
    assert (changed.cfg.solve_robust, changed.cfg.solve_iterations) == ("cauchy", 6)
    assert changed_meta["solve_changed"] == {"trained_with": {"robust": "none", "iterations": 3},
                                             "now": {"robust": "cauchy", "iterations": 6}}
    assert changed_meta["train"] == meta["train"]
    assert all(torch.equal(a, b) for a, b in zip(model.state_dict().values(), changed.state_dict().values()))
    model.cfg = changed.cfg
    x = 3 * torch.randn(2, 2, model.cfg.input_height, model.cfg.input_width)
    k = torch.tensor([[20.0, 20.0, 16.0, 12.0]] * 2)
    inv = torch.rand(2, 1, model.cfg.input_height, model.cfg.input_width)
    with torch.no_grad():
        assert all(torch.equal(a, b) for a, b in zip(model(x, k, inv), changed(x, k, inv)))
    capsys.readouterr()
    regress = tmp_path / "regress"
    assert main([a for a in base if a != "solve" and a != "--pose-head"] + ["--out", str(regress)]) == 0
    capsys.readouterr()
    assert main(["set-solve", str(regress / "model.safetensors"), "--robust", "cauchy",
                 "--out", str(tmp_path / "x.safetensors")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "solve pose head" in err and not (tmp_path / "x.safetensors").exists()
