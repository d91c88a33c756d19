"""Seed ensembles (vo.ensemble): the mixture's moments, the file round trip, and bad input."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from deepslam.core.errors import InputError
from deepslam.models import modelfile
from deepslam.vo.data.prefetch import model_input
from deepslam.vo.ensemble import EnsemblePoseNet, mixture_moments
from deepslam.vo.infer import VOPredictor
from deepslam.vo.modelfiles.modelio import write_ensemble
from deepslam.vo.modelfiles.modelio import MODEL_FORMAT, load_model, save_model
from deepslam.vo.net import FlowPoseNet, LOG_STD_MAX, LOG_STD_MIN, NetConfig

SMALL = NetConfig(input_height=24, input_width=80, filters=8, hidden_units=16, flow_scale=10.0)


def _net(seed: int, cfg: NetConfig = SMALL) -> FlowPoseNet:
    torch.manual_seed(seed)
    net = FlowPoseNet(cfg)
    with torch.no_grad():  # non-zero log-std heads, so the members' own uncertainty differs too
        for head in (net.rot_log_std, net.trans_log_std):
            head.weight.normal_(0.0, 0.05)
            head.bias.normal_(-2.0, 0.3)
    return net.eval()


def _files(tmp_path: Path, seeds=(0, 1, 2), cfg: NetConfig = SMALL) -> list[Path]:
    paths = []
    for s in seeds:
        p = tmp_path / f"m{s}.safetensors"
        save_model(p, _net(s, cfg), {"train": {"seed": s}, "data": {"frames": ["a", "b"]}})
        paths.append(p)
    return paths


@pytest.mark.parametrize("case", ["identical", "spread", "one_dof_apart", "tiny_std", "huge_std"])
def test_mixture_moments_match_sampled_mixture(case):
    rng = np.random.default_rng(3)
    n, b = 4, 3
    means = rng.normal(0, 0.2, (n, b, 6))
    log_stds = np.log(rng.uniform(0.01, 0.1, (n, b, 6)))
    if case == "identical":
        means[:] = means[0]
        log_stds[:] = log_stds[0]
    elif case == "one_dof_apart":
        means[:] = means[0]
        log_stds[:] = log_stds[0]
        means[:, :, 5] = np.arange(n)[:, None]
    elif case == "tiny_std":
        log_stds[:] = np.log(1e-4)
    elif case == "huge_std":
        log_stds[:] = np.log(50.0)
    mean, log_std = mixture_moments(torch.as_tensor(means), torch.as_tensor(log_stds))
    # the mixture's moments in closed form: law of total variance
    want_mean = means.mean(0)
    want_var = np.exp(2 * log_stds).mean(0) + means.var(0)
    np.testing.assert_allclose(mean.numpy(), want_mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(log_std.numpy(), np.clip(0.5 * np.log(want_var), LOG_STD_MIN, LOG_STD_MAX), atol=1e-5)
    if case == "identical":  # an ensemble of one network, repeated, is that network
        np.testing.assert_allclose(log_std.numpy(), log_stds[0], atol=1e-5)
    if case == "one_dof_apart":  # disagreement raises only that DoF's uncertainty
        assert np.all(log_std.numpy()[:, 5] > log_stds[0, :, 5] + 1.0)
        np.testing.assert_allclose(log_std.numpy()[:, :5], log_stds[0, :, :5], atol=1e-5)
    # and against samples drawn from the mixture itself
    k = rng.integers(0, n, 200_000)
    x = means[k, 0] + np.exp(log_stds[k, 0]) * rng.standard_normal((len(k), 6))
    np.testing.assert_allclose(x.mean(0), want_mean[0], atol=4 * np.sqrt(want_var[0] / len(k)).max() + 1e-6)
    np.testing.assert_allclose(x.std(0), np.sqrt(want_var[0]), rtol=0.02)


def test_ensemble_file_round_trip_and_predictor(tmp_path):
    paths = _files(tmp_path)
    out = tmp_path / "ens.safetensors"
    meta = write_ensemble(paths, out)
    assert [m["seed"] for m in meta["ensemble_of"]] == [0, 1, 2]
    assert meta["data"] == {"frames": ["a", "b"]}
    model, meta2 = load_model(out)
    assert isinstance(model, EnsemblePoseNet) and len(model.members) == 3
    assert meta2["ensemble_of"] == meta["ensemble_of"]
    rng = np.random.default_rng(0)
    flow = rng.normal(0, 3, (5, 2, 24, 80)).astype(np.float32)
    intr = np.tile(np.float32([[70, 70, 40, 12]]), (5, 1))
    ens = VOPredictor.from_file(out, bf16=False)
    mean, std = ens.predict(flow, intr)
    singles = [VOPredictor.from_file(p, bf16=False).predict(flow, intr) for p in paths]
    m_i = np.stack([s[0] for s in singles])
    v_i = np.stack([s[1] for s in singles]) ** 2
    np.testing.assert_allclose(mean, m_i.mean(0), rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(std ** 2, v_i.mean(0) + m_i.var(0), rtol=1e-3)
    assert np.all(std >= np.sqrt(v_i.min(0)) * (1 - 1e-4))
    assert ens.input_size == (24, 80)
    assert model_input(out) == (24, 80, "zero")  # what deepslam vo reads before it loads torch


def test_members_seeing_different_frames_report_the_union(tmp_path):
    a, b = tmp_path / "a.safetensors", tmp_path / "b.safetensors"
    save_model(a, _net(0), {"train": {"seed": 0}, "data": {"frames": ["x"]}})
    save_model(b, _net(1), {"train": {"seed": 1}, "data": {"frames": ["y"], "sequences": {"z": 3}}})
    meta = write_ensemble([a, b], tmp_path / "e.safetensors")
    assert meta["data"]["frames"] == ["x", "y"] and list(meta["data"]["sequences"]) == ["z"]


def test_the_members_flow_record_becomes_the_ensembles(tmp_path):
    """Members trained on one DIS set-up: the ensemble records it, so vo/slam set DIS up for it as for them."""
    from deepslam.vo.modelfiles import models

    flow = {"estimator": "dis", "options": {"preset": "medium", "min_texture": 0.5}}
    paths = []
    for s in (0, 1):
        paths.append(tmp_path / f"t{s}.safetensors")
        save_model(paths[-1], _net(s), {"train": {"seed": s}, "flow": flow})
    meta = write_ensemble(paths, tmp_path / "e.safetensors")
    assert meta["flow"] == flow
    assert models.flow_for_model("dis", tmp_path / "e.safetensors").name == "dis-medium-tex0.5"
    assert "flow" not in write_ensemble(_files(tmp_path), tmp_path / "plain.safetensors")


def test_the_members_pose_mode_becomes_the_ensembles(tmp_path):
    """Members that record the epipolar pose (deepslam set-pose): so does their ensemble; members that disagree
    are refused, naming the first file; members that record none give an ensemble that records none."""
    from deepslam.core.errors import InputError
    from deepslam.vo.modelfiles import models

    paths = []
    for s in (0, 1):
        paths.append(tmp_path / f"p{s}.safetensors")
        save_model(paths[-1], _net(s), {"train": {"seed": s}, "pose": "epipolar"})
    assert write_ensemble(paths, tmp_path / "e.safetensors")["pose"] == "epipolar"
    assert models.recorded_pose(tmp_path / "e.safetensors") == "epipolar"
    save_model(paths[1], _net(1), {"train": {"seed": 1}})
    with pytest.raises(InputError, match="different pose modes") as e:
        write_ensemble(paths, tmp_path / "mixed.safetensors")
    assert e.value.path == str(paths[0]) and not (tmp_path / "mixed.safetensors").exists()
    assert "pose" not in write_ensemble(_files(tmp_path), tmp_path / "plain.safetensors")


@pytest.mark.parametrize("bad", ["one_file", "other_input", "other_flow", "nested", "missing", "malformed_tree"])
def test_bad_ensembles_are_refused_with_the_file_named(bad, tmp_path, capsys, plane_sequence):
    from deepslam.cli import main

    paths = _files(tmp_path, seeds=(0, 1))
    out = tmp_path / "ens.safetensors"
    if bad == "one_file":
        argv, named = [str(paths[0])], paths[0]
    elif bad == "other_input":
        other = tmp_path / "wide.safetensors"
        save_model(other, _net(5, NetConfig(input_height=48, input_width=160, filters=8, hidden_units=16)), {})
        argv, named = [str(paths[0]), str(other)], other
    elif bad == "other_flow":  # trained on DIS with textureless pixels left out: one estimator cannot serve both
        other = tmp_path / "tex.safetensors"
        save_model(other, _net(5), {"flow": {"estimator": "dis", "options": {"preset": "medium", "min_texture": 0.5}}})
        argv, named = [str(paths[0]), str(other)], other
    elif bad == "nested":
        write_ensemble(paths, tmp_path / "inner.safetensors")
        argv, named = [str(tmp_path / "inner.safetensors"), str(paths[0])], tmp_path / "inner.safetensors"
    elif bad == "missing":
        argv, named = [str(paths[0]), str(tmp_path / "nope.safetensors")], tmp_path / "nope.safetensors"
    else:  # a hand-made ensemble file with one member: refused when opened
        _, tree = modelfile.load(paths[0], (MODEL_FORMAT,))
        modelfile.save(out, MODEL_FORMAT, {"format": MODEL_FORMAT, "ensemble": [tree]})
        with pytest.raises(InputError, match="malformed VO ensemble"):
            load_model(out)
        rc = main(["vo", "--sequence", str(plane_sequence), "--model", str(out), "--out", str(tmp_path / "t.txt"),
                   "--quiet"])
        err = capsys.readouterr().err
        assert rc == 2 and "malformed VO ensemble" in err and str(out) in err and len(err.strip().splitlines()) == 1
        return
    rc = main(["ensemble-model", *argv, "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and str(named) in err and "Traceback" not in err
    assert not out.exists()
