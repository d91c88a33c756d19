"""The training runner both trainings share (deepslam.runtime.training): caps, folder refusals, resume checks,
divergence that keeps the last good checkpoint, a killed run resumed equal to an uninterrupted one, and the
TensorBoard logger (scalars read back, trained bytes unchanged), through vo.train and flow.train."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from deepslam.core.camera import KITTI_00_CAMERA
from deepslam.core.errors import InputError
from deepslam.flow.net import FlowNetConfig
from deepslam.flow.train import FlowTrainConfig, train_flow
from deepslam.runtime.training import Caps, TrainingDiverged, check_finite, open_run, settings_differ
from deepslam.vo.data.samples import TensorSamples
from deepslam.vo.data.toy import toy_plane_samples
from deepslam.vo.modelfiles.modelio import load_checkpoint
from deepslam.vo.net import NetConfig
from deepslam.vo.train import CHECKPOINT, TrainConfig, train
from tests.textures import shifted_texture_batch

SMALL = FlowNetConfig(channels=(8, 12, 16), estimator_channels=(16,), finest_level=1, work_width=128, search_px=2)
FLOW_CFG = FlowTrainConfig(net=SMALL, crop=(32, 64), batch_size=2, max_steps=10, level_weights=(1.0, 0.5, 0.25),
                           checkpoint_steps=3, threads=1)
TINY = NetConfig(24, 80, filters=16, hidden_units=64, flow_scale=10.0)
CAM = KITTI_00_CAMERA.scaled(80, 24)


class _Pairs:
    """Random block texture shifted by a known integer flow; from the ``fail_at``-th batch on (counted
    from 0 in this object), ``fail`` happens: "nan" images, or "kill" (an exception, as a killed process)."""

    def __init__(self, fail_at: int | None = None, fail: str = "nan"):
        self.calls, self.fail_at, self.fail = 0, fail_at, fail

    def __len__(self):
        return 1

    def batch(self, rng, n, crop):
        b = shifted_texture_batch(rng, n, crop, 2)
        k, self.calls = self.calls, self.calls + 1
        if self.fail_at is not None and k >= self.fail_at:
            if self.fail == "kill":
                raise KeyboardInterrupt("killed")
            b["img0"] = torch.full_like(b["img0"], float("nan"))
        return b


def _tensors_equal(a, b) -> bool:
    ta, tb = load_file(a), load_file(b)
    return ta.keys() == tb.keys() and all(torch.equal(ta[k], tb[k]) for k in ta)


# ---------------------------------------------------------------- the runner's parts


def test_caps_are_reported_in_order_and_none_is_no_cap():
    caps = Caps(max_epochs=3, max_steps=None, max_minutes=0.5, max_samples=100)
    assert caps.reached(0.0) == []
    assert caps.reached(30.0, epochs=3, samples=100) == ["max_epochs", "max_minutes", "max_samples"]
    assert caps.reached(29.9, epochs=2, steps=10 ** 9, samples=99) == []
    assert Caps(max_epochs=0).reached(0.0) == ["max_epochs"]  # a cap of 0 is reached before the first epoch
    assert Caps().limit_s == math.inf and Caps(max_minutes=2).limit_s == 120.0


def test_check_finite_names_where_and_what_to_try():
    check_finite(torch.tensor(1.0), "x loss", "at step 1", "try y")
    with pytest.raises(TrainingDiverged, match=r"^x loss is nan at step 3 \(learning rate 0.01\); try y; the last good "
                                               r"checkpoint is kept$"):
        check_finite(torch.tensor(float("nan")), "x loss", "at step 3", "try y", lr=0.01)
    with pytest.raises(TrainingDiverged, match="held-out loss is inf after epoch 2; try z"):
        check_finite(math.inf, "held-out loss", "after epoch 2", "try z")


def test_settings_compare_as_json_and_name_what_differs():
    old = {"a": [1, 2], "b": 1.0, "c": 5, "max_minutes": 1.0}
    assert settings_differ(old, {"a": (1, 2), "b": 1.0, "c": 5, "max_minutes": 9.0}, ("max_minutes",)) == []
    assert settings_differ(old, {"a": (1, 3), "b": 2.0, "c": 5, "max_minutes": 1.0}, ()) == ["a", "b"]
    new_field = {"a": [1, 2], "b": 1.0, "c": 5, "max_minutes": 1.0, "d": 0}
    assert settings_differ(old, new_field, ()) == ["d"]
    assert settings_differ(old, new_field, (), recorded_only=True) == []


def test_open_run_refuses_foreign_and_finished_folders_and_restores_threads(tmp_path):
    threads = torch.get_num_threads()
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="not empty"):
        with open_run(tmp_path / "foreign", Caps(), resume=False, checkpoint_name="c.safetensors", threads=1):
            pass
    done = tmp_path / "done"
    done.mkdir()
    (done / "c.safetensors").write_bytes(b"")
    with pytest.raises(InputError, match="--resume"):
        with open_run(done, Caps(), resume=False, checkpoint_name="c.safetensors", threads=1):
            pass
    with pytest.raises(RuntimeError, match="inside"):
        with open_run(tmp_path / "fresh", Caps(), resume=False, checkpoint_name="c.safetensors", threads=1) as run:
            assert torch.get_num_threads() == 1 and run.checkpoint_path == tmp_path / "fresh" / "c.safetensors"
            raise RuntimeError("inside")
    assert torch.get_num_threads() == threads


def test_a_run_resumed_at_a_later_clock_meets_its_time_cap(tmp_path):
    with open_run(tmp_path / "run", Caps(max_minutes=1.0, max_steps=5), resume=False,
                  checkpoint_name="c.safetensors", progress=False) as run:
        run.start(elapsed_s=0.0)
        assert run.reached(steps=4) == [] and run.time_left() > 59.0
        run.start(elapsed_s=60.0)  # a resumed run that had trained its minute already
        assert run.reached(steps=0) == ["max_minutes"] and run.time_left() <= 0.0


# ---------------------------------------------------------------- through the flow training


def test_flow_caps_stop_at_the_step_and_the_time_cap(tmp_path):
    path = train_flow(dataclasses.replace(FLOW_CFG, stop_after_steps=4), _Pairs(), tmp_path / "steps", progress=False)
    assert json.loads(path.with_name("history.json").read_text())[-1]["step"] == 3
    ck = load_file(tmp_path / "steps" / "checkpoint.safetensors")
    assert ck  # a checkpoint at the cap, beside the model file
    from deepslam.flow.net import load_flow_model

    assert load_flow_model(path)[1]["steps"] == 4
    # a time cap already spent: not one step (the model file is the initial network)
    timed = dataclasses.replace(FLOW_CFG, max_minutes=1e-9)
    assert load_flow_model(train_flow(timed, _Pairs(), tmp_path / "time", progress=False))[1]["steps"] == 0


def test_flow_divergence_raises_and_keeps_the_last_good_checkpoint(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(TrainingDiverged, match=r"flow loss is nan at step 8 .*lower --lr"):
        train_flow(FLOW_CFG, _Pairs(fail_at=7), out, progress=False)
    assert not (out / "flow.safetensors").exists()
    from deepslam.models import modelfile

    _, ck = modelfile.load(out / "checkpoint.safetensors", ("deepslam-flow-checkpoint",))
    assert ck["state"]["step"] == 6 and [h["step"] for h in json.loads((out / "history.json").read_text())] == [3, 6]


def test_flow_run_killed_between_checkpoints_resumes_to_the_uninterrupted_bytes(tmp_path):
    ref = train_flow(FLOW_CFG, _Pairs(), tmp_path / "ref", progress=False)
    with pytest.raises(KeyboardInterrupt):  # dies at step 8: steps 7-8 are lost, the checkpoint of step 6 stays
        train_flow(FLOW_CFG, _Pairs(fail_at=7, fail="kill"), tmp_path / "killed", progress=False)
    got = train_flow(FLOW_CFG, _Pairs(), tmp_path / "killed", resume=True, progress=False)
    assert _tensors_equal(ref, got)
    assert _tensors_equal(tmp_path / "ref" / "checkpoint.safetensors", tmp_path / "killed" / "checkpoint.safetensors")
    strip = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]  # noqa: E731
    assert strip(json.loads((tmp_path / "ref" / "history.json").read_text())) == \
        strip(json.loads((tmp_path / "killed" / "history.json").read_text()))


def test_flow_resume_refuses_other_settings(tmp_path):
    train_flow(dataclasses.replace(FLOW_CFG, stop_after_steps=3), _Pairs(), tmp_path / "run", progress=False)
    with pytest.raises(InputError, match=r"cannot resume: settings differ .*\(lr\)"):
        train_flow(dataclasses.replace(FLOW_CFG, lr=5e-4), _Pairs(), tmp_path / "run", resume=True, progress=False)


def test_tensorboard_scalars_of_flow_training_and_the_same_bytes(tmp_path):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    plain = train_flow(FLOW_CFG, _Pairs(), tmp_path / "plain", progress=False)
    logged = train_flow(FLOW_CFG, _Pairs(), tmp_path / "logged", progress=False, tensorboard=tmp_path / "tb")
    assert _tensors_equal(plain, logged)
    assert _tensors_equal(tmp_path / "plain" / "checkpoint.safetensors", tmp_path / "logged" / "checkpoint.safetensors")
    ev = EventAccumulator(str(tmp_path / "tb"))
    ev.Reload()
    tags = set(ev.Tags()["scalars"])
    assert {"flow/step/loss", "flow/step/lr", "flow/loss"} <= tags
    assert [e.step for e in ev.Scalars("flow/step/loss")] == list(range(1, 11))
    hist = json.loads((tmp_path / "logged" / "history.json").read_text())
    assert [(e.step, e.value) for e in ev.Scalars("flow/loss")] == \
        [(h["step"], pytest.approx(h["loss"], rel=1e-6)) for h in hist]
    lrs = [e.value for e in ev.Scalars("flow/step/lr")]
    assert lrs[0] < FLOW_CFG.lr and lrs == sorted(lrs, reverse=True)  # the cosine decay, after each step


# ---------------------------------------------------------------- through the VO training


class _Poisoned:
    """A toy source whose labels turn NaN from epoch ``bad_epoch`` on."""

    def __init__(self, base: TensorSamples, bad_epoch: int):
        self.base, self.bad_epoch = base, bad_epoch

    def __len__(self):
        return len(self.base)

    def batches(self, epoch, batch_size, rank=0, world=1):
        for b in self.base.batches(epoch, batch_size, rank, world):
            if epoch >= self.bad_epoch:
                b = {**b, "target": torch.full_like(b["target"], float("nan"))}
            yield b


@pytest.fixture(scope="module")
def toy():
    s = toy_plane_samples(240, CAM, np.random.default_rng(0))
    return TensorSamples(s["flow"], s["intrinsics"], s["target"], seed=0).split(0.2, 0)


def _vo_cfg(**kw) -> TrainConfig:
    base = dict(net=TINY, batch_size=32, lr_max=3e-3, max_epochs=2, nll_epochs=2, bf16=False, channels_last=False, seed=3,
                threads=1)
    return TrainConfig(**{**base, **kw})


def test_vo_divergence_raises_and_keeps_the_last_good_checkpoint(toy, tmp_path):
    train_src, hold = toy
    with pytest.raises(TrainingDiverged, match=r"stage-1 loss is nan at epoch 2, step 1 .*lower --lr-max"):
        train(_vo_cfg(max_epochs=3), _Poisoned(train_src, 1), hold, tmp_path, progress=False)
    st = load_checkpoint(tmp_path / CHECKPOINT)["train_state"]
    assert (st["stage"], st["epoch"], len(st["history"])) == (1, 1, 1)
    assert not (tmp_path / "model.safetensors").exists()


def test_vo_sample_cap_stops_mid_epoch_and_tensorboard_leaves_the_bytes(toy, tmp_path):
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    train_src, hold = toy
    cfg = _vo_cfg(max_samples=len(train_src) + 64)  # one epoch and two batches of the next
    plain = train(cfg, train_src, hold, tmp_path / "plain", progress=False)
    logged = train(cfg, train_src, hold, tmp_path / "logged", progress=False, tensorboard=tmp_path / "tb")
    assert plain.stop_reason == "max_samples"
    s1 = [h for h in logged.history if h["stage"] == 1]
    assert [h["samples"] for h in s1] == [len(train_src), 64] and s1[-1]["partial"]
    assert _tensors_equal(plain.model_path, logged.model_path)
    ev = EventAccumulator(str(tmp_path / "tb"))
    ev.Reload()
    tags = set(ev.Tags()["scalars"])
    assert {"stage1/step/loss", "stage1/step/lr", "stage1/train_loss", "stage1/val_loss", "stage1/lr_min",
            "stage1/val_rmse6/5", "stage2/holdout_nll"} <= tags
    assert [e.step for e in ev.Scalars("stage1/val_loss")] == [1, 2]
    assert [e.value for e in ev.Scalars("stage1/val_loss")] == [pytest.approx(h["val_loss"], rel=1e-6) for h in s1]
    assert ev.Scalars("stage1/step/loss")[-1].step == len(train_src) + 64  # x: training samples
    assert [e.step for e in ev.Scalars("stage2/holdout_nll")] == [1, 2]
