"""deepslam.data.SequencePairs: pairs of a tiny render as tensors, equal to what the reader serves, the
relative motion right, the same items through a DataLoader with 2 workers."""
from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.data import SequencePairs
from deepslam.scenes import SceneConfig
from deepslam.sim import RenderConfig, SimConfig, TrajectoryConfig, render_sequence


def _cfg():
    return SimConfig(SceneConfig(name="room", seed=5, moving_objects=1, texture_px_per_m=20),
                     TrajectoryConfig(frames=4), RenderConfig(width=160, stereo_baseline_m=0.0))


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    root = tmp_path_factory.mktemp("pairs")
    return {fmt: render_sequence(_cfg(), root / fmt, fmt=fmt, progress=False) for fmt in ("ours", "tum", "euroc")}


def _np(t: torch.Tensor) -> np.ndarray:
    return t.numpy()


def test_items_have_the_documented_shapes_and_the_readers_values(renders):
    seq = open_sequence(renders["ours"])
    ds = SequencePairs(renders["ours"])
    h, w = seq.camera.height, seq.camera.width
    assert len(ds) == len(seq) - 1 == 3
    want = {"image0": (torch.float32, (3, h, w)), "image1": (torch.float32, (3, h, w)),
            "depth0": (torch.float32, (1, h, w)), "flow": (torch.float32, (2, h, w)),
            "flow_backward": (torch.float32, (2, h, w)), "occlusion": (torch.bool, (1, h, w)),
            "mask0": (torch.int64, (1, h, w)), "cam1_from_cam0": (torch.float64, (4, 4)),
            "intrinsics": (torch.float32, (4,))}
    for k in range(len(ds)):
        item = ds[k]
        assert list(item) == list(ds.keys) == list(want)
        for key, (dtype, shape) in want.items():
            assert item[key].dtype == dtype and tuple(item[key].shape) == shape, key
        assert 0.0 <= float(item["image0"].min()) and float(item["image0"].max()) <= 1.0
        assert np.array_equal(np.round(_np(item["image0"]).transpose(1, 2, 0) * 255).astype(np.uint8), seq.image(k))
        assert np.array_equal(np.round(_np(item["image1"]).transpose(1, 2, 0) * 255).astype(np.uint8), seq.image(k + 1))
        assert np.array_equal(_np(item["depth0"])[0], seq.depth(k))
        assert np.array_equal(_np(item["flow"]).transpose(1, 2, 0), seq.flow(k), equal_nan=True)
        assert np.array_equal(_np(item["flow_backward"]).transpose(1, 2, 0), seq.flow_backward(k + 1), equal_nan=True)
        assert np.array_equal(_np(item["occlusion"])[0], seq.occlusion(k))
        assert np.array_equal(_np(item["mask0"])[0], seq.mask(k).astype(np.int64))
        np.testing.assert_array_equal(_np(item["intrinsics"]), np.float32([seq.camera.fx, seq.camera.fy,
                                                                           seq.camera.cx, seq.camera.cy]))
    assert np.array_equal(_np(ds[-1]["image0"]), _np(ds[len(ds) - 1]["image0"]))
    with pytest.raises(IndexError):
        ds[len(ds)]


@pytest.mark.parametrize("step", [1, 2])
def test_relative_motion_moves_points_from_frame_k_into_frame_k_plus_step(renders, step):
    seq = open_sequence(renders["ours"])
    ds = SequencePairs(renders["ours"], step=step)
    assert len(ds) == len(seq) - step
    p_cam0 = np.array([[0.3, -0.2, 2.0, 1.0], [-1.0, 0.5, 4.0, 1.0]]).T
    for k in range(len(ds)):
        cam1_from_cam0 = _np(ds[k]["cam1_from_cam0"])
        w0, w1 = seq.gt.world_from_cam[k], seq.gt.world_from_cam[k + step]
        np.testing.assert_allclose(cam1_from_cam0, np.linalg.inv(w1) @ w0, atol=1e-12)
        # the same world point: seen from cam0, moved into cam1, equals seeing it from cam1
        np.testing.assert_allclose(cam1_from_cam0 @ p_cam0, se3.inverse(w1) @ (w0 @ p_cam0), atol=1e-12)
    keys = set(ds.keys)
    if step == 1:
        # with the stored flow, the motion moves a static, visible pixel where the flow says
        item = ds[0]
        depth, flow, mask = _np(item["depth0"])[0], _np(item["flow"]).transpose(1, 2, 0), _np(item["mask0"])[0]
        cam = seq.camera
        v, u = np.nonzero((depth > 0) & (mask == 0) & ~_np(item["occlusion"])[0])
        p = np.stack([(u - cam.cx) / cam.fx * depth[v, u], (v - cam.cy) / cam.fy * depth[v, u], depth[v, u], np.ones(len(u))])
        q = _np(item["cam1_from_cam0"]) @ p
        np.testing.assert_allclose(cam.fx * q[0] / q[2] + cam.cx - u, flow[v, u, 0], atol=2e-3)
        np.testing.assert_allclose(cam.fy * q[1] / q[2] + cam.cy - v, flow[v, u, 1], atol=2e-3)
    else:
        assert not keys & {"flow", "flow_backward", "occlusion"}
        assert {"image0", "image1", "depth0", "mask0", "cam1_from_cam0", "intrinsics"} <= keys


def test_other_layouts(renders):
    tum = SequencePairs(renders["tum"])
    seq = open_sequence(renders["tum"])
    assert {"flow", "flow_backward", "occlusion", "mask0"} <= set(tum.keys)  # a render's TUM export keeps its flow
    assert np.array_equal(_np(tum[0]["flow"]).transpose(1, 2, 0), open_sequence(renders["ours"]).flow(0))
    assert np.array_equal(_np(tum[1]["depth0"])[0], seq.depth(1))
    euroc = SequencePairs(renders["euroc"])
    item = euroc[0]
    assert item["image0"].shape[0] == 3 and torch.equal(item["image0"][0], item["image0"][2])  # grey, repeated
    assert {"flow", "flow_backward", "occlusion", "mask0", "depth0"} <= set(euroc.keys)


def test_bad_input_is_one_clear_error(tmp_path, renders):
    with pytest.raises(InputError, match="does not exist"):
        SequencePairs(tmp_path / "nothing")
    for step in (0, -1, 1.5, True):
        with pytest.raises(InputError, match="step"):
            SequencePairs(renders["ours"], step=step)
    assert len(SequencePairs(renders["ours"], step=9)) == 0


def _same(a: dict, b: dict) -> None:
    assert list(a) == list(b)
    for key in a:
        assert a[key].dtype == b[key].dtype and torch.equal(torch.nan_to_num(a[key]), torch.nan_to_num(b[key])), key


def test_dataloader_with_two_workers_gives_the_same_items(renders):
    ds = SequencePairs(renders["ours"])
    single = list(DataLoader(ds, batch_size=2, num_workers=0))
    multi = list(DataLoader(ds, batch_size=2, num_workers=2))
    assert len(single) == len(multi) == 2
    for a, b in zip(single, multi):
        _same(a, b)
    # pickled (as spawn sends it to a worker): the sequence is opened again where it is used
    clone = pickle.loads(pickle.dumps(ds))
    assert clone._seq is None
    _same(clone[1], ds[1])
    euroc = SequencePairs(renders["euroc"])  # readers with functions inside (undistortion) stay picklable
    _same(pickle.loads(pickle.dumps(euroc))[0], euroc[0])
