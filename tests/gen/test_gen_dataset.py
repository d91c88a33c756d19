"""SyntheticFlowDataset: item layout, units at the output resolution, determinism, sources."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.gen.dataset import (ArrayDepthFrames, DatasetConfig, SyntheticFlowDataset, open_depth_frames,
                         resample_nearest)
from deepslam.gen.flow_reference import synthesize_reference
from deepslam.gen.motion import MotionModel, SixDof, StudentT
from gen_scenes import box_scene, ground_scene

CAM = PinholeCamera(160, 120, 120.0, 118.0, 80.3, 59.1)


def _motion(loop: bool = False) -> MotionModel:
    def six(rot, trans, tz_loc):
        return SixDof(tuple([StudentT(4.0, 0.0, rot, -10 * rot, 10 * rot)] * 3
                            + [StudentT(4.0, 0.0, trans, -10 * trans, 10 * trans)] * 2
                            + [StudentT(4.0, tz_loc, trans, tz_loc - 10 * trans, tz_loc + 10 * trans)]), 100)
    from deepslam.gen.motion import LoopConfig

    return MotionModel(1, six(0.005, 0.05, -0.8), six(0.02, 1.0, 0.0) if loop else None,
                       LoopConfig() if loop else None)


@pytest.fixture(scope="module")
def frames():
    depths = np.stack([box_scene(CAM, 12.0, 4.0), ground_scene(CAM), box_scene(CAM, 30.0, 2.0)])
    return ArrayDepthFrames(depths, CAM, "analytic")


def test_item_layout_and_units(frames):
    ds = SyntheticFlowDataset(frames, _motion(), 50, seed=1, config=DatasetConfig(resolution_hw=(30, 40)))
    item = ds[7]
    assert set(item) == {"flow", "valid", "target", "intrinsics", "frame", "loop", "index"}
    assert item["flow"].shape == (2, 30, 40) and item["flow"].dtype == torch.float32
    assert item["valid"].shape == (30, 40) and item["valid"].dtype == torch.bool
    assert item["target"].shape == (6,) and item["target"].dtype == torch.float32
    assert item["intrinsics"].dtype == torch.float32 and int(item["index"]) == 7
    scaled = CAM.scaled(40, 30)
    np.testing.assert_allclose(item["intrinsics"].numpy(), [scaled.fx, scaled.fy, scaled.cx, scaled.cy], rtol=1e-6)
    # The flow is the flow at the output resolution: the reference on the resampled depth with the
    # scaled camera and the planned motion gives the same pixels.
    frame, motion, _ = ds.plan(7)
    assert int(item["frame"]) == frame
    depth = resample_nearest(frames.depth(frame), 30, 40)
    ref, ref_valid, _ = synthesize_reference(depth, scaled, motion)
    v = item["valid"].numpy()
    assert (v == ref_valid).mean() > 0.995 and v.mean() > 0.3
    np.testing.assert_allclose(item["flow"].numpy().transpose(1, 2, 0)[v & ref_valid], ref[v & ref_valid], atol=1e-3)
    np.testing.assert_allclose(item["target"].numpy(), se3.to_euler6(motion), atol=1e-6)
    # Full-resolution flow at the same motion is about 4x larger (160/40 and 120/30).
    full = SyntheticFlowDataset(frames, _motion(), 50, seed=1)
    big = full[7]
    ratio = np.median(np.abs(big["flow"][0].numpy()[big["valid"].numpy()])) / np.median(np.abs(item["flow"][0].numpy()[v]))
    assert 3.5 < ratio < 4.5


def test_determinism_and_batches(frames):
    cfg = DatasetConfig(resolution_hw=(24, 32), loop_fraction=0.3)
    ds = SyntheticFlowDataset(frames, _motion(loop=True), 40, seed=5, config=cfg)
    again = SyntheticFlowDataset(frames, _motion(loop=True), 40, seed=5, config=cfg)
    other = SyntheticFlowDataset(frames, _motion(loop=True), 40, seed=6, config=cfg)
    batch = ds.get_batch(range(40))
    for i in (0, 13, 39):
        a, b = ds[i], again[i]
        for k in a:
            assert torch.equal(a[k], b[k]), k
            assert torch.equal(a[k], batch[k][i]), k
    assert not torch.equal(ds[3]["target"], other[3]["target"])
    assert 0 < int(batch["loop"].sum()) < 40
    assert torch.equal(ds[-1]["target"], ds[39]["target"])
    with pytest.raises(IndexError):
        ds.plan(40)


def test_dataloader_with_workers_gives_the_same_items(frames):
    ds = SyntheticFlowDataset(frames, _motion(), 8, seed=2, config=DatasetConfig(resolution_hw=(24, 32)))
    loader = torch.utils.data.DataLoader(ds, batch_size=4, num_workers=2, shuffle=False)
    got = torch.cat([b["target"] for b in loader])
    want = ds.get_batch(range(8))["target"]
    assert torch.equal(got, want)


def test_zbuffer_and_loop_options(frames):
    with pytest.raises(ValueError):
        SyntheticFlowDataset(frames, _motion(), 10, config=DatasetConfig(loop_fraction=0.5))
    ds = SyntheticFlowDataset(frames, _motion(), 10, seed=3, config=DatasetConfig(zbuffer=True))
    plain = SyntheticFlowDataset(frames, _motion(), 10, seed=3)
    a, b = ds.get_batch(range(10)), plain.get_batch(range(10))
    assert torch.equal(a["target"], b["target"])
    assert bool((a["valid"] <= b["valid"]).all())  # the z-buffer only removes pixels


def test_resample_nearest_picks_containing_pixel():
    d = np.arange(12 * 16, dtype=np.float32).reshape(12, 16)
    r = resample_nearest(d, 3, 4)
    # output pixel (0, 0) covers source rows 0..3 and columns 0..3; its centre lies in row 2, column 2
    assert r[0, 0] == d[2, 2] and r[2, 3] == d[10, 14]
    assert resample_nearest(d, 12, 16) is d


def test_sources_from_folders(depth_sequence, shared_data):
    frames = open_depth_frames(depth_sequence)
    assert len(frames) == 6 and frames.describe()["kind"] == "ours"
    with pytest.raises(InputError, match="no depth"):
        open_depth_frames(shared_data / "kitti" / "sequences" / "06")
    stereo = open_depth_frames(shared_data / "kitti" / "sequences" / "06", depth_from_stereo="dis")
    d = stereo.depth(0)
    assert d.shape == (370, 1226) and 0.5 < (d > 0).mean() < 0.95
    assert stereo.depth(0) is d  # cached
