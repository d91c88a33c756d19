"""``deepslam eval`` against evo (the reference tool) on the published trajectories of ``../shared/data``.

For each reference pair (ORB-SLAM2 and S-PTAM on KITTI 00: KITTI format, matched by index; an estimate on
EuRoC V1_02 against the ASL ground truth, and OpenVINS on V1_01 against TUM ground truth: associated by
time), each alignment (none, se3, sim3) and RPE deltas of 1 and 10 frames, the figures ``deepslam eval
--json`` prints equal evo's (``evo.core.sync.associate_trajectories`` with ``max_diff=0.01``,
``PoseTrajectory3D.align``, ``evo.core.metrics.APE`` / ``RPE`` in frames with ``all_pairs=False``, RMSE):

- ATE RMSE (evo: APE of the translation part) and RPE translation RMSE: relative difference <= 1e-9;
- RPE rotation RMSE in degrees: <= 1e-9 on the timestamped pairs, <= 1e-6 on KITTI. KITTI's files print
  about 9 significant digits, so their rotations are orthonormal only to ~1e-9; evo takes the angle of
  the nearest rotation (scipy's ``Rotation.from_matrix``), deepslam the angle of the stored matrix (as the
  KITTI devkit does). The two differ by ~3e-8 relative on KITTI 00, far below the data's precision.
- the number of matched poses is equal.

One difference is by design: an estimate with two poses at the same timestamp (evo's own V102.txt has
four such repeats) keeps its first pose in deepslam and both in evo, which then pairs one ground-truth
pose twice and scores a zero-time "motion" between the repeats (RPE rotation 0.358 deg instead of
0.259 deg at delta 1). evo is fed the same de-duplicated estimate here (docs/formats.md, "Trajectory
files").

evo has no KITTI segment metric (t_err / r_err over 100..800 m segments): those are checked against a
literal port of the devkit and the published ORB-SLAM2 figure in tests/core/test_metrics.py. What evo
can check of them is the relative-pose definition they share with RPE, which the figures above cover.

evo is GPL-3: a test dependency only (the ``test`` extra), never imported by the package.
"""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from deepslam.cli import main
from deepslam.core.trajio import read_trajectory
from deepslam.slam.synthetic import write_loop_sequence

evo_metrics = pytest.importorskip("evo.core.metrics", reason="evo (the test extra) is not installed")
from evo.core import sync  # noqa: E402  (after the importorskip above)
from evo.core.trajectory import PoseTrajectory3D  # noqa: E402
from evo.tools import file_interface  # noqa: E402

CASES = {
    "kitti00_orb": ("kitti/poses/00.txt", "reference/KITTI_00_ORB.txt"),
    "kitti00_sptam": ("kitti/poses/00.txt", "reference/KITTI_00_SPTAM.txt"),
    "euroc_v102": ("reference/V102_groundtruth.csv", "reference/V102.txt"),
    "euroc_v101_openvins": ("reference/V101_gt.txt", "reference/V101_openvins.txt"),
}
REL_TOL = 1e-9
KITTI_ROT_REL_TOL = 1e-6


def _evo_pair(gt_path, est_path):
    """The (gt, est) evo trajectories as `evo_ape` / `evo_rpe` would pair them."""
    if gt_path.parent.name == "poses":  # KITTI: no timestamps, matched by index
        return file_interface.read_kitti_poses_file(gt_path), file_interface.read_kitti_poses_file(est_path)
    if gt_path.suffix == ".csv":
        gt = file_interface.read_euroc_csv_trajectory(gt_path)
    else:
        gt = file_interface.read_tum_trajectory_file(gt_path)
    est = file_interface.read_tum_trajectory_file(est_path)
    # deepslam keeps the first pose of a repeated timestamp (see the module docstring)
    est.reduce_to_ids(np.flatnonzero(np.concatenate([[True], np.diff(est.timestamps) > 0])))
    return sync.associate_trajectories(gt, est, max_diff=0.01)


def _evo_figures(gt, est, align: str, delta: int) -> dict:
    est = copy.deepcopy(est)
    if align != "none":
        est.align(gt, correct_scale=(align == "sim3"))
    m = evo_metrics
    ape = m.APE(m.PoseRelation.translation_part)
    rpe_t = m.RPE(m.PoseRelation.translation_part, delta, m.Unit.frames, all_pairs=False)
    rpe_r = m.RPE(m.PoseRelation.rotation_angle_deg, delta, m.Unit.frames, all_pairs=False)
    for metric in (ape, rpe_t, rpe_r):
        metric.process_data((gt, est))
    rmse = m.StatisticsType.rmse
    return {"ate_m": ape.get_statistic(rmse), "rpe_t_m": rpe_t.get_statistic(rmse),
            "rpe_r_deg": rpe_r.get_statistic(rmse), "n_matched": gt.num_poses}


@pytest.mark.parametrize("case", sorted(CASES))
def test_eval_equals_evo(shared_data, case, capsys):
    gt_path, est_path = (shared_data / p for p in CASES[case])
    evo_gt, evo_est = _evo_pair(gt_path, est_path)
    for align in ("none", "se3", "sim3"):
        for delta in (1, 10):
            assert main(["eval", "--gt", str(gt_path), "--est", str(est_path), "--align", align,
                         "--rpe-delta", str(delta), "--json"]) == 0
            ours = json.loads(capsys.readouterr().out)
            ref = _evo_figures(evo_gt, evo_est, align, delta)
            where = f"{case} align={align} delta={delta}"
            assert ours["n_matched"] == ref["n_matched"], where
            assert ours["ate_m"] == pytest.approx(ref["ate_m"], rel=REL_TOL), where
            assert ours["rpe_t_m"] == pytest.approx(ref["rpe_t_m"], rel=REL_TOL), where
            rot_tol = KITTI_ROT_REL_TOL if case.startswith("kitti") else REL_TOL
            assert ours["rpe_r_deg"] == pytest.approx(ref["rpe_r_deg"], rel=rot_tol), where


def test_slam_default_output_reads_in_evo_and_eval(tmp_path, capsys):
    """`deepslam slam` writes TUM rows on a timestamped sequence by default; evo and `deepslam eval` read them."""
    seq = tmp_path / "seq"
    write_loop_sequence(seq, n_frames=40, laps=1.5, lap_offset_m=0.2, seed=3)
    out = tmp_path / "run" / "slam.txt"
    assert main(["slam", "--sequence", str(seq), "--odometry", "gt-noisy", "--out", str(out), "--quiet"]) == 0
    capsys.readouterr()
    ours = read_trajectory(out)
    evo_est = file_interface.read_tum_trajectory_file(out)
    np.testing.assert_array_equal(evo_est.timestamps, ours.timestamps_s)
    np.testing.assert_allclose(evo_est.poses_se3, ours.world_from_cam, atol=1e-12)
    # KITTI ground truth (no times) against the TUM estimate: matched by index on both sides
    assert main(["eval", "--gt", str(seq / "poses.txt"), "--est", str(out), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert (r["matched_by"], r["n_matched"], r["est_format"]) == ("index", 40, "tum")
    evo_gt = PoseTrajectory3D(poses_se3=list(file_interface.read_kitti_poses_file(seq / "poses.txt").poses_se3),
                              timestamps=evo_est.timestamps)
    assert r["ate_m"] == pytest.approx(_evo_figures(evo_gt, evo_est, "se3", 1)["ate_m"], rel=REL_TOL)
