"""Metrics against known answers: Umeyama, ATE, RPE, KITTI t_err/r_err (devkit), published results."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepslam.core import metrics, se3
from deepslam.core.errors import InputError
from deepslam.core.trajectory import Trajectory
from deepslam.core.trajio import read_trajectory


def _random_rotation(rng):
    return Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()


def _wiggly(rng, n=300, step_m=1.0) -> np.ndarray:
    """A car-like trajectory (N, 4, 4): forward along the camera z, slowly turning about y."""
    yaw = np.cumsum(rng.normal(0, 0.02, size=n))
    rot = Rotation.from_euler("y", yaw[:, None]).as_matrix()
    fwd = rot[:, :, 2] * step_m
    pos = np.concatenate([[np.zeros(3)], np.cumsum(fwd[:-1], axis=0)])
    pos[:, 1] += rng.normal(0, 0.05, size=n)
    return se3.from_rt(rot, pos)


def _straight(n: int, step_m: float) -> np.ndarray:
    """Straight line along +z (KITTI forward), identity rotations, ``step_m`` apart."""
    pos = np.zeros((n, 3))
    pos[:, 2] = np.arange(n) * step_m
    return se3.from_rt(np.broadcast_to(np.eye(3), (n, 3, 3)), pos)


# --- Umeyama ---------------------------------------------------------------------------------------

def test_umeyama_recovers_random_sim3_exactly():
    rng = np.random.default_rng(0)
    for _ in range(5):
        p = rng.normal(size=(50, 3)) * 10
        r, t, s = _random_rotation(rng), rng.normal(size=3) * 100, float(rng.uniform(0.1, 5.0))
        a = metrics.umeyama(p, s * p @ r.T + t, with_scale=True)
        np.testing.assert_allclose(a.rotation, r, atol=1e-10)
        np.testing.assert_allclose(a.translation, t, atol=1e-8)
        assert a.scale == pytest.approx(s, rel=1e-10)


def test_umeyama_se3_keeps_unit_scale_and_recovers_rigid_motion():
    rng = np.random.default_rng(1)
    p = rng.normal(size=(40, 3))
    r, t = _random_rotation(rng), rng.normal(size=3)
    a = metrics.umeyama(p, p @ r.T + t, with_scale=False)
    assert a.scale == 1.0
    np.testing.assert_allclose(a.rotation, r, atol=1e-10)
    np.testing.assert_allclose(a.translation, t, atol=1e-10)
    # a scaled copy: se3 cannot absorb the scale, sim3 can
    a_se3 = metrics.umeyama(p, 2.0 * p, with_scale=False)
    a_sim3 = metrics.umeyama(p, 2.0 * p, with_scale=True)
    assert a_se3.scale == 1.0 and a_sim3.scale == pytest.approx(2.0)


def test_umeyama_returns_a_rotation_for_mirrored_points():
    """A mirrored target is best fit by a reflection; Umeyama's fix must still return det R = +1."""
    rng = np.random.default_rng(2)
    p = rng.normal(size=(30, 3))
    a = metrics.umeyama(p, p * [1, 1, -1], with_scale=True)
    assert np.linalg.det(a.rotation) == pytest.approx(1.0)
    np.testing.assert_allclose(a.rotation.T @ a.rotation, np.eye(3), atol=1e-12)


# --- ATE -------------------------------------------------------------------------------------------

def test_ate_zero_for_identical_and_known_offset():
    gt = _wiggly(np.random.default_rng(3))
    for mode in metrics.ALIGN_MODES:
        assert metrics.ate(gt, gt, mode)["rmse_m"] == pytest.approx(0.0, abs=1e-9)
    shifted = gt.copy()
    shifted[:, :3, 3] += [1.0, 2.0, 2.0]  # |offset| = 3 m
    res = metrics.ate(gt, shifted, "none")
    assert res["rmse_m"] == pytest.approx(3.0) and res["max_m"] == pytest.approx(3.0)
    assert metrics.ate(gt, shifted, "se3")["rmse_m"] == pytest.approx(0.0, abs=1e-9)


def test_metrics_accept_trajectories_and_match_them_by_time():
    gt = _wiggly(np.random.default_rng(10), n=200)
    t = np.arange(200) * 0.1
    shifted = gt.copy()
    shifted[:, :3, 3] += [0.0, 0.0, 0.5]
    gt_traj, est_traj = Trajectory(gt, t), Trajectory(shifted[50:150], t[50:150] + 0.003)
    res = metrics.ate(gt_traj, est_traj, align="none")
    assert res["n"] == 100 and res["rmse_m"] == pytest.approx(0.5)
    assert metrics.rpe(gt_traj, est_traj)["t_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(ValueError, match="matched"):
        metrics.ate(gt, shifted[:10])


def test_ate_sim3_undoes_scale_rotation_translation():
    rng = np.random.default_rng(4)
    gt = _wiggly(rng)
    r, t, s = _random_rotation(rng), rng.normal(size=3) * 20, 0.37  # est world = gt world moved and scaled
    est = se3.from_rt(r @ gt[:, :3, :3], s * gt[:, :3, 3] @ r.T + t)
    res = metrics.ate(gt, est, "sim3")
    assert res["rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert res["alignment"].scale == pytest.approx(1 / s)
    assert metrics.ate(gt, est, "se3")["rmse_m"] > 1.0
    # the aligned poses equal the ground truth, rotations included
    aligned, _ = metrics.align(gt, est, "sim3")
    np.testing.assert_allclose(aligned, gt, atol=1e-9)


def test_ate_rmse_of_known_noise():
    gt = _wiggly(np.random.default_rng(5), n=400)
    est = gt.copy()
    # alternate +-0.1 m along x: every error is 0.1 m, mean zero so se3 alignment cannot remove it
    est[:, 0, 3] += 0.1 * (-1.0) ** np.arange(400)
    assert metrics.ate(gt, est, "none")["rmse_m"] == pytest.approx(0.1)
    assert metrics.ate(gt, est, "se3")["rmse_m"] == pytest.approx(0.1, rel=0.02)


# --- RPE -------------------------------------------------------------------------------------------

def test_rpe_known_step_errors():
    gt = _straight(101, 1.0)
    est = _straight(101, 1.1)
    r1 = metrics.rpe(gt, est, delta=1)
    assert r1["t_rmse_m"] == pytest.approx(0.1) and r1["r_rmse_deg"] == pytest.approx(0.0, abs=1e-9)
    assert r1["n"] == 100
    r5 = metrics.rpe(gt, est, delta=5)
    assert r5["t_rmse_m"] == pytest.approx(0.5) and r5["n"] == 20  # pairs (0,5), (5,10), ... as evo
    assert metrics.rpe(gt, est, delta=5, all_pairs=True)["n"] == 96
    # an extra yaw of 0.01 rad per frame: rotation error 0.01 rad per step
    yaw = Rotation.from_euler("y", 0.01 * np.arange(101)[:, None]).as_matrix()
    est_rot = se3.from_rt(yaw, gt[:, :3, 3])
    assert metrics.rpe(gt, est_rot, delta=1)["r_rmse_deg"] == pytest.approx(np.rad2deg(0.01))
    assert metrics.rpe(gt, est_rot, delta=3)["r_rmse_deg"] == pytest.approx(np.rad2deg(0.03))


def test_rpe_definition_matches_evo_formula():
    rng = np.random.default_rng(6)
    gt, est = _wiggly(rng, n=50), _wiggly(rng, n=50)
    errs = []
    for i in range(49):
        e = np.linalg.inv(np.linalg.inv(gt[i]) @ gt[i + 1]) @ (np.linalg.inv(est[i]) @ est[i + 1])
        errs.append(np.linalg.norm(e[:3, 3]))
    assert metrics.rpe(gt, est)["t_rmse_m"] == pytest.approx(math.sqrt(np.mean(np.square(errs))), rel=1e-12)


# --- KITTI odometry errors -------------------------------------------------------------------------

def _devkit_port(gt: np.ndarray, est: np.ndarray) -> tuple[float, float]:
    """A literal, loop-by-loop port of evaluate_odometry.cpp's calcSequenceErrors + saveStats."""
    lengths = [100, 200, 300, 400, 500, 600, 700, 800]
    dist = [0.0]
    for i in range(1, len(gt)):
        dist.append(dist[i - 1] + math.sqrt(sum((gt[i - 1][k][3] - gt[i][k][3]) ** 2 for k in range(3))))
    t_sum = r_sum = 0.0
    num = 0
    for first in range(0, len(gt), 10):
        for length in lengths:
            last = -1
            for i in range(first, len(dist)):
                if dist[i] > dist[first] + length:
                    last = i
                    break
            if last == -1:
                continue
            d_gt = np.linalg.inv(gt[first]) @ gt[last]
            d_res = np.linalg.inv(est[first]) @ est[last]
            err = np.linalg.inv(d_res) @ d_gt
            a, b, c = err[0][0], err[1][1], err[2][2]
            d = 0.5 * (a + b + c - 1.0)
            r_sum += math.acos(max(min(d, 1.0), -1.0)) / length
            t_sum += math.sqrt(err[0][3] ** 2 + err[1][3] ** 2 + err[2][3] ** 2) / length
            num += 1
    return t_sum / num * 100.0, r_sum / num * 180.0 / math.pi * 100.0


def test_kitti_scale_drift_gives_known_t_err():
    """Steps 1 % too long on a straight road: t_err = 1 % of the segment's travelled chord."""
    n, step = 2001, 0.5
    gt = _straight(n, step)
    est = _straight(n, step * 1.01)
    k = metrics.kitti_errors(gt, est)
    # segment [f, f + 2L + 1]: chord L + 0.5 m, error 0.01 (L + 0.5), divided by L
    expected, count = [], 0
    for f in range(0, n, 10):
        for length in metrics.KITTI_LENGTHS_M:
            if f + 2 * length + 1 <= n - 1:
                expected.append(0.01 * (length + 0.5) / length)
                count += 1
    assert k["n_segments"] == count
    assert k["t_err_pct"] == pytest.approx(100 * np.mean(expected), rel=1e-9)
    assert k["t_err_pct"] == pytest.approx(1.0, abs=0.01)
    assert k["r_err_deg_per_100m"] == pytest.approx(0.0, abs=1e-9)
    lengths = [row["length_m"] for row in k["per_length"]]
    assert lengths == list(metrics.KITTI_LENGTHS_M)
    assert k["per_length"][0]["t_err_pct"] == pytest.approx(100 * 0.01 * 100.5 / 100)


def test_kitti_yaw_rate_drift_gives_known_r_err():
    """A heading that drifts by w rad per metre: r_err = w (L + 0.5) / L rad/m per segment."""
    n, step, w = 2001, 0.5, 2e-4
    gt = _straight(n, step)
    s = np.arange(n) * step
    est = se3.from_rt(Rotation.from_euler("y", (w * s)[:, None]).as_matrix(), gt[:, :3, 3])
    k = metrics.kitti_errors(gt, est)
    expected = [w * (length + 0.5) / length for f in range(0, n, 10) for length in metrics.KITTI_LENGTHS_M
                if f + 2 * length + 1 <= n - 1]
    assert k["r_err_deg_per_100m"] == pytest.approx(np.mean(expected) * 180 / np.pi * 100, rel=1e-9)
    assert k["r_err_deg_per_100m"] == pytest.approx(np.rad2deg(w) * 100, rel=0.01)  # 1.146 deg/100 m


def test_kitti_is_invariant_to_rigid_alignment_and_none_when_short():
    rng = np.random.default_rng(7)
    gt = _wiggly(rng, n=400)
    est = _wiggly(rng, n=400)
    moved = se3.from_rt(_random_rotation(rng), rng.normal(size=3) * 50) @ est
    a, b = metrics.kitti_errors(gt, est), metrics.kitti_errors(gt, moved)
    assert a["t_err_pct"] == pytest.approx(b["t_err_pct"], rel=1e-9)
    assert a["r_err_deg_per_100m"] == pytest.approx(b["r_err_deg_per_100m"], rel=1e-9)
    assert metrics.kitti_errors(gt[:90], est[:90]) is None  # 89 m < 100 m


def test_kitti_matches_literal_devkit_port(shared_data):
    gt = read_trajectory(shared_data / "kitti/poses/00.txt").world_from_cam[:1200]
    est = read_trajectory(shared_data / "reference/KITTI_00_ORB.txt").world_from_cam[:1200]
    k = metrics.kitti_errors(gt, est)
    t_ref, r_ref = _devkit_port(gt, est)
    assert k["t_err_pct"] == pytest.approx(t_ref, rel=1e-9)
    assert k["r_err_deg_per_100m"] == pytest.approx(r_ref, rel=1e-9)


def test_kitti_00_orb_slam2_reproduces_published_result(shared_data):
    """ORB-SLAM2 stereo on KITTI 00 (Mur-Artal & Tardos 2017, Table II): 0.70 % and 0.25 deg/100 m."""
    gt = read_trajectory(shared_data / "kitti/poses/00.txt")
    est = read_trajectory(shared_data / "reference/KITTI_00_ORB.txt")
    res = metrics.evaluate(gt, est, align="none")
    assert res["kitti_t_err_pct"] == pytest.approx(0.70, abs=0.05)  # measured 0.6997
    assert res["kitti_r_err_deg_per_100m"] == pytest.approx(0.25, abs=0.03)  # measured 0.2533
    assert res["matched_by"] == "index" and res["n_matched"] == 4541
    se3_res = metrics.evaluate(gt, est, align="se3")
    assert se3_res["kitti_t_err_pct"] == pytest.approx(res["kitti_t_err_pct"], rel=1e-9)
    assert 0.5 < se3_res["ate_m"] < 3.0  # measured 1.30 m
    sptam = metrics.evaluate(gt, read_trajectory(shared_data / "reference/KITTI_00_SPTAM.txt"))
    assert sptam["kitti_t_err_pct"] > res["kitti_t_err_pct"]


@pytest.mark.parametrize("align,lo,hi", [("se3", 0.05, 0.2), ("sim3", 0.05, 0.2)])
def test_euroc_v102_associates_and_gives_plausible_ate(shared_data, align, lo, hi):
    gt = read_trajectory(shared_data / "reference/V102_groundtruth.csv")  # ASL csv, ns, 200 Hz
    est = read_trajectory(shared_data / "reference/V102.txt")  # TUM, s, ~10 Hz
    res = metrics.evaluate(gt, est, align=align)
    assert res["matched_by"] == "timestamps"
    assert res["n_matched"] >= 780  # of 803 poses
    assert lo < res["ate_m"] < hi  # measured 0.092 (se3), 0.084 (sim3)
    assert "kitti_t_err_pct" not in res  # 75.6 m of ground truth < 100 m
    assert metrics.evaluate(gt, est, align="none")["ate_m"] > 1.0  # different world frames


def test_euroc_v101_openvins(shared_data):
    res = metrics.evaluate(read_trajectory(shared_data / "reference/V101_gt.txt"),
                           read_trajectory(shared_data / "reference/V101_openvins.txt"), align="se3")
    assert res["n_matched"] > 2700
    assert 0.02 < res["ate_m"] < 0.12  # measured 0.052


# --- evaluate(): matching and errors ---------------------------------------------------------------

def test_evaluate_by_timestamps_with_offset_clock():
    gt = _wiggly(np.random.default_rng(8), n=1500, step_m=0.1)
    t = np.arange(1500) * 0.05
    gt_traj = Trajectory(gt, t)
    est_traj = Trajectory(gt[::2], t[::2] + 0.004)  # every other pose, 4 ms late
    res = metrics.evaluate(gt_traj, est_traj, align="se3", max_diff_s=0.01)
    assert res["n_matched"] == 750 and res["matched_by"] == "timestamps"
    assert res["ate_m"] == pytest.approx(0.0, abs=1e-9)
    assert res["gt_length_m"] > 100 and res["kitti_t_err_pct"] == pytest.approx(0.0, abs=1e-7)
    with pytest.raises(InputError, match="cannot be associated"):
        metrics.evaluate(gt_traj, est_traj, max_diff_s=0.001)


def test_evaluate_errors_name_both_files(tmp_path):
    gt = Trajectory(_straight(20, 1.0), np.arange(20.0))
    est = Trajectory(_straight(20, 1.0), np.arange(20.0) + 1000.0)
    with pytest.raises(InputError) as ei:
        metrics.evaluate(gt, est, gt_path=tmp_path / "gt.txt", est_path=tmp_path / "est.txt")
    msg = ei.value.message()
    assert "gt.txt" in msg and "est.txt" in msg and "0 poses match" in msg
    with pytest.raises(InputError, match="counts must be equal") as ei:
        metrics.evaluate(Trajectory(_straight(20, 1.0)), Trajectory(_straight(19, 1.0)),
                         gt_path="a.txt", est_path="b.txt")
    assert "a.txt" in ei.value.message() and "b.txt" in ei.value.message()
    with pytest.raises(InputError, match="at least 3"):
        metrics.evaluate(Trajectory(_straight(2, 1.0)), Trajectory(_straight(2, 1.0)))
    with pytest.raises(InputError, match="RPE delta"):
        metrics.evaluate(Trajectory(_straight(5, 1.0)), Trajectory(_straight(5, 1.0)), rpe_delta=5)


def test_evaluate_sim3_fixes_monocular_scale_for_kitti_numbers():
    gt = _wiggly(np.random.default_rng(9), n=400)
    est = gt.copy()
    est[:, :3, 3] *= 0.5  # a monocular estimate at half scale
    res = metrics.evaluate(Trajectory(gt), Trajectory(est), align="sim3")
    assert res["scale"] == pytest.approx(2.0)
    assert res["ate_m"] == pytest.approx(0.0, abs=1e-9)
    assert res["kitti_t_err_pct"] == pytest.approx(0.0, abs=1e-7)
    raw = metrics.evaluate(Trajectory(gt), Trajectory(est), align="se3")
    assert raw["kitti_t_err_pct"] == pytest.approx(50.0, abs=1.0)  # half of each segment's chord missing


@pytest.mark.parametrize("scale", [0.5, 0.88, 1.0, 1.41])
def test_drift_of_a_scaled_estimate_in_another_start_frame(scale):
    """A straight 100 m drive read at ``scale`` x: path ratio = scale, end-point drift |scale - 1| x 100 %,
    whatever world frame each trajectory starts in (the figures are relative to the first pose)."""
    n = 101
    gt = np.repeat(np.eye(4)[None], n, 0)
    gt[:, 2, 3] = np.linspace(0, 100, n)
    start = se3.from_euler6(np.array([0.1, -0.3, 0.2, 5.0, -2.0, 7.0]))
    est = start @ gt.copy()
    est[:, :3, 3] = start[:3, 3] + scale * (est[:, :3, 3] - start[:3, 3])
    d = metrics.drift(gt, est)
    assert d["path_length_ratio"] == pytest.approx(scale, rel=1e-9)
    assert d["endpoint_drift_pct"] == pytest.approx(abs(scale - 1) * 100, abs=1e-7)
    full = metrics.evaluate(Trajectory(gt, np.arange(n) * 0.1), Trajectory(est, np.arange(n) * 0.1))
    assert full["path_length_ratio"] == pytest.approx(scale, rel=1e-9)


def test_drift_sees_a_heading_error_that_keeps_the_length():
    n = 51
    gt = np.repeat(np.eye(4)[None], n, 0)
    gt[:, 2, 3] = np.linspace(0, 50, n)
    yaw = se3.from_euler6(np.array([0.0, math.radians(10), 0.0, 0.0, 0.0, 0.0]))
    est = gt.copy()
    est[:, :3, 3] = gt[:, :3, 3] @ yaw[:3, :3].T  # the path bends away by 10 degrees; the start pose is the same
    d = metrics.drift(gt, est)
    assert d["path_length_ratio"] == pytest.approx(1.0)
    assert d["endpoint_drift_m"] == pytest.approx(2 * 50 * math.sin(math.radians(5)), rel=1e-9)


def test_ate_parts_split_one_alignment_and_add_up_to_the_whole():
    rng = np.random.default_rng(3)
    n = 40
    gt = np.stack([se3.from_rt(np.eye(3), np.array([0.5 * k, 0.0, 0.0])) for k in range(n)])
    est = gt.copy()
    est[:, :3, 3] += np.cumsum(rng.normal(0, 0.03, (n, 3)), axis=0)
    ev = metrics.evaluate(Trajectory(gt, None), Trajectory(est, None))
    part = np.arange(n) % 3 == 0
    inside, elsewhere = metrics.ate_parts(ev["_gt_poses"], ev["_est_aligned_poses"], part)
    assert part.sum() * inside ** 2 + (~part).sum() * elsewhere ** 2 == pytest.approx(n * ev["ate_m"] ** 2)
    assert metrics.ate_parts(ev["_gt_poses"], ev["_est_aligned_poses"], np.ones(n, bool))[1] is None
    with pytest.raises(ValueError, match="39 entries for 40 poses"):
        metrics.ate_parts(ev["_gt_poses"], ev["_est_aligned_poses"], np.ones(n - 1, bool))


def test_evaluate_names_the_estimate_pose_of_each_match():
    # the estimate has poses at 0.0 .. 2.9 s, the ground truth from 1.0 s: matches are estimate poses 10..29
    times = np.arange(30) * 0.1
    poses = np.stack([se3.from_rt(np.eye(3), np.array([0.3 * k, 0.0, 0.0])) for k in range(30)])
    ev = metrics.evaluate(Trajectory(poses[10:], times[10:]), Trajectory(poses, times))
    assert ev["_est_index"].tolist() == list(range(10, 30))
