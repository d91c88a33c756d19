"""A render in the TUM RGB-D layout reads back with its flow, backward flow, occlusion and masks, equal to
the same render in our layout."""
from __future__ import annotations

import numpy as np

from deepslam.cli import main
from deepslam.core.readers import open_sequence


def test_tum_export_reads_back_its_ground_truth(tmp_path):
    args = ["render", "--scene", "street", "--frames", "3", "--width", "96", "--moving-objects", "2",
            "--stereo-baseline", "0", "--quiet"]
    assert main([*args, "--format", "tum", "--out", str(tmp_path / "tum")]) == 0
    assert main([*args, "--out", str(tmp_path / "ours")]) == 0
    tum, ours = open_sequence(tmp_path / "tum"), open_sequence(tmp_path / "ours")
    assert tum.kind == "tum" and len(tum) == len(ours) == 3
    for i in range(2):
        np.testing.assert_array_equal(tum.flow(i), ours.flow(i))
        np.testing.assert_array_equal(tum.occlusion(i), ours.occlusion(i))
    np.testing.assert_array_equal(tum.flow_backward(1), ours.flow_backward(1))
    np.testing.assert_array_equal(tum.mask(0), ours.mask(0))
    assert tum.flow_paths[-1] is None and tum.flow_backward_paths[0] is None


def test_a_real_tum_folder_has_no_flow(shared_data):
    seq = open_sequence(shared_data / "tum" / "rgbd_dataset_freiburg3_teddy")
    assert seq.flow_paths is None and seq.mask_paths is None and seq.depth_paths[0].suffix == ".png"
