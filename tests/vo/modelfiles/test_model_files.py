"""Model files cannot carry code: every command that opens one refuses a crafted file without running it.

Each crafted file, opened by a careless ``torch.load(weights_only=False)`` or ``pickle.load``, would
create a marker file. The checks: exit status 2, one line on stderr, no traceback, no marker.
"""
from __future__ import annotations

import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from deepslam.core.errors import InputError
from deepslam.models import modelfile
from deepslam.vo.modelfiles.modelio import CHECKPOINT_FORMAT, MODEL_FORMAT, load_model
from deepslam.vo.train import CHECKPOINT

REPO = Path(__file__).resolve().parents[3]


class _Payload:
    """Unpickling this calls ``open(marker, "w")``: the file appears iff the payload ran."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _torch_save_payload(path: Path, marker: Path) -> None:
    torch.save({"format": MODEL_FORMAT, "net": {}, "state_dict": {}, "evil": _Payload(marker)}, path)


def _raw_pickle_payload(path: Path, marker: Path) -> None:
    path.write_bytes(pickle.dumps({"evil": _Payload(marker)}, protocol=2))


def _safetensors_with_pickle_in_metadata(path: Path, marker: Path) -> None:
    """A valid safetensors file whose JSON tree smuggles a pickle as a string: it must stay a string."""
    from safetensors.torch import save

    blob = pickle.dumps(_Payload(marker)).hex()
    path.write_bytes(save({"w": torch.zeros(2)}, metadata={"deepslam": MODEL_FORMAT, "tree": f'{{"x": "{blob}"}}'}))


CRAFTED = {
    "torch-save-zip": _torch_save_payload,
    "raw-pickle": _raw_pickle_payload,
    "safetensors-smuggled-pickle": _safetensors_with_pickle_in_metadata,
}


@pytest.fixture(params=sorted(CRAFTED))
def crafted(request, tmp_path) -> tuple[Path, Path]:
    """(crafted model file, marker path that must never appear)."""
    marker = tmp_path / "PWNED"
    path = tmp_path / "evil" / "model.safetensors"
    path.parent.mkdir()
    CRAFTED[request.param](path, marker)
    assert not marker.exists()
    return path, marker


def _run_cli(argv: list[str], capsys) -> tuple[int, str]:
    from deepslam.cli import main

    rc = main(argv)
    return rc, capsys.readouterr().err


@pytest.mark.parametrize("command", ["vo", "slam-cons", "slam-loops", "stress", "train-resume", "convert"])
def test_crafted_model_file_never_runs(command, crafted, plane_sequence, tmp_path, capsys):
    path, marker = crafted
    out = tmp_path / "out"
    argv = {
        "vo": ["vo", "--sequence", str(plane_sequence), "--model", str(path), "--out", str(out / "t.txt"), "--quiet"],
        "slam-cons": ["slam", "--sequence", str(plane_sequence), "--model-cons", str(path), "--out", str(out / "t.txt")],
        "slam-loops": ["slam", "--sequence", str(plane_sequence), "--model-loops", str(path),
                       "--out", str(out / "t.txt")],
        "stress": ["stress", "--out", str(out), "--quick", "--model-cons", str(path)],
        "train-resume": ["train", "--mode", "synthetic", "--toy", "64", "--net", "tiny", "--quiet",
                         "--out", str(path.parent), "--resume"],
        "convert": ["convert-model", str(path), "--out", str(out / "converted.safetensors")],
    }[command]
    if command == "train-resume":
        shutil.move(path, path.parent / CHECKPOINT)
    rc, err = _run_cli(argv, capsys)
    assert not marker.exists(), "the payload in the model file ran"
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert not (out / "converted.safetensors").exists()


def test_tree_round_trip_keeps_types_and_tensors(tmp_path):
    opt_state = {"state": {0: {"step": torch.tensor(3.0), "exp_avg": torch.randn(4)}},
                 "param_groups": [{"params": [0], "betas": (0.9, 0.999), "lr": 1e-3, "amsgrad": True}]}
    w = torch.randn(3, 5)
    tree = {"a": w, "b": w, "opt": opt_state, "inf": float("inf"), "nan": float("nan"), "none": None,
            "np": np.float32(2.5), "rng": torch.get_rng_state(), "s": "text", "$odd": 1}
    modelfile.save(tmp_path / "f.safetensors", CHECKPOINT_FORMAT, tree)
    kind, back = modelfile.load(tmp_path / "f.safetensors", (CHECKPOINT_FORMAT,))
    assert kind == CHECKPOINT_FORMAT
    assert torch.equal(back["a"], w) and torch.equal(back["b"], w)
    assert list(back["opt"]["state"]) == [0] and back["opt"]["param_groups"][0]["betas"] == (0.9, 0.999)
    assert torch.equal(back["opt"]["state"][0]["exp_avg"], opt_state["state"][0]["exp_avg"])
    assert back["inf"] == float("inf") and np.isnan(back["nan"]) and back["none"] is None
    assert back["np"] == 2.5 and back["s"] == "text" and back["$odd"] == 1
    assert torch.equal(back["rng"], tree["rng"])


@pytest.mark.parametrize("content,what", [
    (b"", "not a deepslam model file"),
    (b"\x00" * 64, "not a deepslam model file"),
    (b"junk that is not a model", "not a deepslam model file"),
])
def test_malformed_files_are_refused(tmp_path, content, what):
    p = tmp_path / "m.safetensors"
    p.write_bytes(content)
    with pytest.raises(InputError, match=what):
        load_model(p)


def test_truncated_and_wrong_kind_files_are_refused(tmp_path):
    shipped = REPO / "models" / "kitti_cons.safetensors"
    data = shipped.read_bytes()
    (tmp_path / "cut.safetensors").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="not a deepslam model file"):
        load_model(tmp_path / "cut.safetensors")
    modelfile.save(tmp_path / "other.safetensors", "someone-elses-kind", {"x": torch.zeros(1)})
    with pytest.raises(InputError, match="kind"):
        load_model(tmp_path / "other.safetensors")
    with pytest.raises(InputError, match="folder"):
        load_model(tmp_path)


def test_shipped_models_load_and_legacy_conversion_round_trips(tmp_path):
    model, meta = load_model(REPO / "models" / "kitti_cons.safetensors")
    assert "train" in meta
    legacy = tmp_path / "old.pt"
    torch.save({"format": MODEL_FORMAT, "version": 1, "net": model.cfg.to_dict(), "state_dict": model.state_dict(),
                "meta": meta}, legacy)
    with pytest.raises(InputError, match="convert-model"):
        load_model(legacy)
    from deepslam.vo.modelfiles.convert import convert_legacy

    assert convert_legacy(legacy, tmp_path / "new.safetensors") == MODEL_FORMAT
    again, _ = load_model(tmp_path / "new.safetensors")
    for k, v in model.state_dict().items():
        assert torch.equal(v, again.state_dict()[k]), k


def test_the_payload_is_live(tmp_path):
    """The crafted files are real threats: an unsafe load does run them (so the tests above can fail)."""
    marker = tmp_path / "PWNED"
    _torch_save_payload(tmp_path / "m.pt", marker)
    torch.load(tmp_path / "m.pt", weights_only=False)
    assert marker.exists()


def test_the_fit_is_the_epipolar_poses_or_the_widening_geometrys_and_never_two():
    from deepslam.vo.geometry.epipolar import EpipolarConfig
    from deepslam.vo.modelfiles import models

    road, net_distance = EpipolarConfig(road_height_m=1.65, road_fill=True), EpipolarConfig()
    assert models.fit_config() is None
    assert models.fit_config(net_distance) is net_distance
    assert models.fit_config(None, road) is road and models.fit_config(road, road) is road
    with pytest.raises(ValueError, match="one configuration"):
        models.fit_config(net_distance, road)
