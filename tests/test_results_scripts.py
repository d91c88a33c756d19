"""The results scripts' own arithmetic: loop-pair errors against known answers, mean ± std over seeds,
the tables they write (the full runs are `make results`; these check what they compute)."""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from bench import depth_channel_probe, results_slam, results_vo
from deepslam.core import metrics, se3
from deepslam.core.trajectory import Trajectory
from deepslam.vo.infer import VOPredictor
from deepslam.vo.modelfiles.modelio import make_net
from deepslam.vo.net import NetConfig


def _seq(world_from_cam: np.ndarray):
    return SimpleNamespace(gt=Trajectory(world_from_cam), name="toy", timestamps_s=None)


def test_pair_errors_known_answers():
    rng = np.random.default_rng(0)
    poses = se3.from_euler6(np.c_[rng.normal(0, 0.2, (10, 3)), rng.normal(0, 3.0, (10, 3))])
    seq = _seq(poses)
    pairs = np.array([[0, 5], [1, 7], [2, 9]])
    truth = se3.to_euler6(se3.relative(poses[pairs[:, 1]], poses[pairs[:, 0]]))  # cam_j_from_cam_i
    exact = results_vo.pair_errors(seq, pairs, truth)
    assert exact["t_rmse_m"] < 1e-9 and exact["r_rmse_deg"] < 1e-6 and exact["pairs"] == 3
    # a prediction off by a known translation of 0.3 m along z (in frame j) and nothing else
    off = se3.to_euler6(se3.from_rt(np.eye(3), [0, 0, 0.3]) @ se3.from_euler6(truth))
    err = results_vo.pair_errors(seq, pairs, off)
    assert err["t_rmse_m"] == pytest.approx(0.3, abs=1e-9) and err["r_rmse_deg"] < 1e-6
    # a pure 2-degree rotation error
    rot = se3.to_euler6(se3.from_euler6([0, np.radians(2.0), 0, 0, 0, 0]) @ se3.from_euler6(truth))
    assert results_vo.pair_errors(seq, pairs, rot)["r_rmse_deg"] == pytest.approx(2.0, abs=1e-6)


def _rec(t_err: float, ate: float, t_err_epipolar: float | None = None) -> dict:
    vo = {"ate_m": ate, "rpe_t_m": 0.1, "rpe_r_deg": 0.1, "kitti_t_err_pct": t_err, "kitti_r_err_deg_per_100m": 1.0}
    loops = {"pairs": 10, "t_rmse_m": 0.5, "r_rmse_deg": 1.0, "true_t_mean_m": 1.0}
    street = {"vo": vo, "slam": dict(vo, ate_m=ate / 2), "loops": loops, "loop_edges": 3}
    if t_err_epipolar is not None:
        street["vo_epipolar"] = dict(vo, kitti_t_err_pct=t_err_epipolar)
    return {"street_gt": street, "street_dis": street, "kitti06_dis": {k: vo[k] for k in ("ate_m", "rpe_t_m", "rpe_r_deg")}}


def test_summary_means_stds_and_the_headline_ratio():
    per_seed = {"synthetic": [_rec(6.0, 3.0, 3.0), _rec(10.0, 5.0, 3.0)], "supervised": [_rec(2.0, 1.0, 2.0), _rec(2.0, 1.0, 2.0)]}
    kitti_plus = [{"seed": 0, "kitti06_dis": _rec(1, 2.0)["kitti06_dis"]}]
    held = type("Held", (), {"name": "held", "__len__": lambda self: 300})()
    rep = results_vo.summarize(results_vo.ResultsVOConfig(), per_seed, kitti_plus, held)
    assert rep["ratio_synthetic_over_supervised_t_err"]["gt"] == pytest.approx(4.0)
    row = next(r for r in rep["table"] if r["measure"] == "NN_cons VO t_err [%]")
    assert row["synthetic"]["mean"] == pytest.approx(8.0) and row["synthetic"]["std"] == pytest.approx(np.std([6, 10], ddof=1))
    assert row["supervised"]["std"] == 0.0
    k06 = next(r for r in rep["table"] if r["data"].startswith("KITTI") and r["measure"].endswith("ATE [m]"))
    assert k06["synthetic + KITTI 06 frames"]["mean"] == pytest.approx(2.0)
    rep["commands"], rep["minutes"] = [], 1.0
    md = results_vo.markdown(rep)
    assert "8 ± 2.83" in md and "4.00 with exact flow" in md
    # the epipolar pose's own ratio (3 / 2), beside the network's
    assert rep["ratio_synthetic_over_supervised_t_err"]["gt_epipolar"] == pytest.approx(1.5)
    assert "epipolar pose" in md and "1.50 with exact flow" in md


def test_slam_table_marks_the_half_target():
    case = {"vo": {"ate_m": 2.0, "ate_sim3_m": 1.5, "kitti_t_err_pct": 3.0, "kitti_r_err_deg_per_100m": 1.0},
            "slam_default": {"ate_m": 1.5}, "slam_tuned": {"ate_m": 0.5, "ate_sim3_m": 0.4, "kitti_t_err_pct": 1.0,
                                                          "kitti_r_err_deg_per_100m": 0.5},
            "ratio_tuned": 0.25, "params_tuned": {"c_s": 3.0, "c_r": 1.0, "t_loop": 50},
            "loops_tuned": {"pairs": 7, "kept": 7, "candidates": 8, "t_rmse_m": 0.1, "r_rmse_deg": 0.2}}
    bad = dict(case, ratio_tuned=0.8, slam_tuned=dict(case["slam_tuned"], ate_m=1.6))
    md = results_slam.markdown({"config": dataclasses.asdict(results_slam.ResultsSlamConfig()), "minutes": 1.0,
                                "commands": [], "cases": {"street/gt": case, "room/dis": bad}})
    lines = [ln for ln in md.splitlines() if ln.startswith("| street") or ln.startswith("| room")]
    assert "| 0.25 | yes |" in lines[0] and "| 0.80 | no |" in lines[1]
    assert "3, 1, 50" in lines[0] and "7 of 8" in lines[0]
    assert "Unseen streets" not in md
    unseen = {"vo": {"ate_m": 2.0}, "slam": {"ate_m": 1.7}, "ratio": 0.85, "vo_path_ratio": 0.99, "loop_edges": 40,
              "loop_edges_kept": 39, "loops_not_rigid": 6, "loop_errors": {"t_rmse_m": 0.3, "r_rmse_deg": 0.25}}
    md = results_slam.markdown({"config": dataclasses.asdict(results_slam.ResultsSlamConfig()), "minutes": 1.0,
                                "commands": [], "cases": {"street/gt": case}, "unseen": {"7421": unseen}})
    row = [ln for ln in md.splitlines() if ln.startswith("| 7421")]
    assert row == ["| 7421 | 2 | 1.7 | 0.85 | no | n/a | 0.99 | 40 (39) | 6 | 0.3 / 0.25 | n/a | n/a / n/a | n/a / n/a |"]
    unseen.update(frames_in_loops_pct=62.0, vo={"ate_m": 2.0, "ate_in_loops_m": 1.5, "ate_elsewhere_m": 2.5},
                  slam={"ate_m": 1.7, "ate_in_loops_m": 0.5, "ate_elsewhere_m": 2.4})
    md = results_slam.markdown({"config": dataclasses.asdict(results_slam.ResultsSlamConfig()), "minutes": 1.0,
                                "commands": [], "cases": {"street/gt": case}, "unseen": {"7421": unseen}})
    row = [ln for ln in md.splitlines() if ln.startswith("| 7421")]
    assert row[0].endswith("| 62 | 1.5 / 0.5 | 2.5 / 2.4 |")
    unseen.update(slam_exact_revisits={"ate_m": 1.3}, ratio_exact_revisits=0.65)
    md = results_slam.markdown({"config": dataclasses.asdict(results_slam.ResultsSlamConfig()), "minutes": 1.0,
                                "commands": [], "cases": {"street/gt": case}, "unseen": {"7421": unseen}})
    assert "| 0.85 | no | 1.3 (x0.65) | 0.99 |" in [ln for ln in md.splitlines() if ln.startswith("| 7421")][0]


def test_the_ate_split_adds_up_to_the_whole_trajectorys_ate():
    n = 30
    rng = np.random.default_rng(0)
    gt = np.stack([se3.from_rt(np.eye(3), np.array([k * 1.0, 0.0, 0.0])) for k in range(n)])
    est = gt.copy()
    est[:, :3, 3] += np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0)    # a drift
    seq = SimpleNamespace(gt=Trajectory(gt, None), timestamps_s=None)
    covered = np.arange(n) < 12
    m = results_slam._metrics(seq, est, covered)
    inside, elsewhere = m["ate_in_loops_m"], m["ate_elsewhere_m"]
    whole = metrics.evaluate(seq.gt, Trajectory(est, None))["ate_m"]
    assert m["ate_m"] == pytest.approx(whole)
    assert 12 * inside ** 2 + 18 * elsewhere ** 2 == pytest.approx(n * whole ** 2)
    assert results_slam._metrics(seq, est, np.zeros(n, bool))["ate_in_loops_m"] is None
    assert "ate_in_loops_m" not in results_slam._metrics(seq, est)


def test_true_loop_edges_remove_the_drift_they_span():
    """The diagnostic graph of results_slam: true relative poses on the loop pairs (direction
    cam_j_from_cam_i, as the pose graph reads them) pull a drifting circle back onto the truth."""
    from types import SimpleNamespace

    from bench.results_slam import _with_true_loops
    from deepslam.core import se3
    from deepslam.slam.pipeline import SlamParams
    from deepslam.slam.posegraph import Edges, chain

    n = 80
    step = se3.from_euler6(np.array([0.0, 2 * np.pi / n, 0.0, 0.0, 0.0, 0.5]))
    gt = np.stack([np.linalg.matrix_power(step, k) for k in range(n)])
    biased = se3.to_euler6(se3.inverse(step @ se3.from_euler6(np.array([0.0, 0.004, 0.0, 0.0, 0.0, 0.0]))))
    cons = Edges(np.stack([np.arange(n - 1), np.arange(1, n)], 1), np.tile(biased, (n - 1, 1)), np.full((n - 1, 6), 0.01))
    prep = SimpleNamespace(seq=SimpleNamespace(gt=SimpleNamespace(world_from_cam=gt)), n=n, cons=cons)
    loops = Edges(np.array([[0, n - 1], [10, n - 11]]), np.zeros((2, 6)), np.full((2, 6), 0.01))
    fixed = _with_true_loops(prep, loops, SlamParams(), gt[0])
    drift = np.linalg.norm(chain(n, cons, gt[0])[:, :3, 3] - gt[:, :3, 3], axis=1).max()
    assert drift > 1.0
    assert np.linalg.norm(fixed[:, :3, 3] - gt[:, :3, 3], axis=1).max() < 0.2 * drift
    assert _with_true_loops(prep, Edges.empty(), SlamParams(), gt[0]) is None


def test_a_cached_render_of_other_settings_is_not_reused(tmp_path):
    """render_once reuses a complete render only when its frame count and width are the ones asked for."""
    from deepslam.core.camera import PinholeCamera
    from deepslam.core.errors import InputError
    from deepslam.core.ours import OursWriter
    from deepslam.studies.demo import render_once

    cam = PinholeCamera.from_fov_y(40, 30, 60.0)
    root = tmp_path / "street_s1"
    w = OursWriter(root, {"num_frames": 3, "rate_hz": 10.0, "camera": cam.to_dict(), "stereo_baseline_m": None,
                          "has": {"rgb_right": False, "depth": False, "flow": False, "mask": False}})
    for i in range(3):
        w.write_frame(i, i / 10.0, np.eye(4), np.zeros((30, 40, 3), np.uint8))
    w.finish()
    log: list[str] = []
    assert render_once("street", "car", 3, 40, 1, root, log) == root   # reused: nothing run, its command logged
    assert log == [f"deepslam render --scene street --trajectory car --frames 3 --width 40 --seed 1 --out {root}"]
    with pytest.raises(InputError, match="3 frames at 40 px, not 6 at 40"):
        render_once("street", "car", 6, 40, 1, root, log)


def test_real_slice_table_says_what_each_model_saw(shared_data, tmp_path):
    """results_real on the real KITTI slices: the shipped model saw 06's single frames (no poses) and
    none of 07; the drift figures are those of core.metrics (checked there)."""
    from bench import results_real

    epi = dataclasses.replace(results_real.SHIPPED[0], pose="epipolar")
    rep = results_real.run((*results_real.SHIPPED, epi), tmp_path, shared_data)
    assert len(rep["rows"]) == 2 * 3  # each shipped model (DIS and learned flow), and DIS with --pose epipolar, on 06 and 07
    for net, fused in ((rep["rows"][0], rep["rows"][2]), (rep["rows"][3], rep["rows"][5])):
        assert (net["pose"], fused["pose"]) == ("net", "epipolar") and net["slice"] == fused["slice"]
        # the distance is the network's: the same path length (to the float summation), another trajectory
        assert fused["path_length_ratio"] == pytest.approx(net["path_length_ratio"], rel=1e-6)
        assert fused["endpoint_drift_pct"] != net["endpoint_drift_pct"]
    for r in rep["rows"]:
        want = {"06": "single frames, no poses", "07": "none"}[r["slice"].split("/")[-1]]
        assert r["seen_in_training"] == want, r
        # the model file each shipped candidate names is the one scored (no silent fallback to another)
        assert r["model_file"] == r["model"].removeprefix("shipped "), r
    for r in rep["rows"]:
        assert r["path_length_ratio"] > 0 and r["endpoint_drift_pct"] >= 0
    md = (tmp_path / "results.md").read_text()
    assert "frames the model saw in training" in md and "KITTI 07 (160 frames" in md and "| epipolar |" in md
    assert results_real.main(["--pose", "net,flat", "--out", str(tmp_path / "b")]) == 2
    assert not (tmp_path / "b").exists()


def test_turn_table_measures_both_sets_and_refuses_a_bad_model_spec(shared_data, tmp_path, monkeypatch, capsys):
    """results_turn with few frames: the shipped DIS model on the held-out street and 06, each turn read
    without and with the slide; a malformed --model is one line, exit 2."""
    from bench import results_turn

    monkeypatch.setattr(results_turn, "SAMPLES", 3)
    monkeypatch.setattr(results_turn, "HELDOUT", ("street", "car", 8, 200, 7))
    rep = results_turn.run([("dis", "kitti", "dis")], tmp_path, shared_data)
    assert [r["frames"].split(" ")[0] for r in rep["rows"]] == ["simulated", "KITTI"]
    for r in rep["rows"]:
        assert r["model_file"] == "kitti_cons_dis" and len(r["reads"]) == 8
        assert [x["slide_m"] != 0 for x in r["reads"]] == [False, True] * 4
        assert all(0.5 < x["yaw_ratio_median"] < 1.5 for x in r["reads"]), r["reads"]
        assert np.isfinite(r["yaw_gain"]) and np.isfinite(r["slide_read_fraction"])
        assert set(r["straight_yaw"]) == {"as is", "mirrored"}
        assert all(abs(v["yaw_median_rad"]) < 0.02 for v in r["straight_yaw"].values())
    assert rep["slide_per_yaw_per_m"] == pytest.approx(0.88)
    assert "yaw gain from the slide" in (tmp_path / "results.md").read_text()
    capsys.readouterr()
    assert results_turn.main(["--no-shipped", "--model", "x=m.safetensors@raft", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "NAME=PATH[@dis|@learned]" in err[0] and not (tmp_path / "b").exists()


def test_speed_table_sweeps_each_candidate_on_both_sets_and_refuses_a_bad_model_spec(shared_data, tmp_path, capsys):
    """results_speed with few frames: a shipped model and a --model candidate (the same file, named) each swept on
    the held-out street and 06, with the flatness the decision rule reads; a malformed --model is
    one line, exit 2."""
    from bench import results_speed

    cfg = results_speed.ResultsSpeedConfig(width=200, heldout_frames=6, samples=3)
    rep = results_speed.run(cfg, tmp_path, shared_data, (("shipped", "kitti", "dis"), ("again", "kitti", "dis")))
    assert [k.split(" ")[0] for k in rep["sets"]] == ["simulated", "KITTI"]
    for rows in rep["sets"].values():
        assert list(rows) == ["shipped", "again"]
        a, b = rows["shipped"], rows["again"]
        assert a["model"] == "kitti_cons_dis" and a["flow"] == "dis" and a["reads"] == b["reads"]  # deterministic
        ratios = [r["ratio_median"] for r in a["reads"] if r["speed_mps"] >= 2.5]
        assert a["flatness"]["max_abs_dev"] == pytest.approx(max(abs(x - 1) for x in ratios))
        assert all(0.5 < x < 1.5 for x in ratios), ratios
        assert all(r["ratio_spread"] >= 0 and r["std_ratio_median"] > 0 for r in a["reads"] if r["speed_mps"] > 0)
    md = (tmp_path / "results.md").read_text()
    assert "largest abs(read/true - 1)" in md and "median predicted std" in md
    assert (tmp_path / "speed_sweep.png").stat().st_size > 0
    capsys.readouterr()
    assert results_speed.main(["--no-shipped", "--model", "x=m.safetensors@raft", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "@learned-dis" in err[0] and not (tmp_path / "b").exists()


def test_tum_results_quick_rows_and_baselines(shared_data, tmp_path):
    """results_tum --quick: every row scored, the standing-still baseline is the ground truth's spread,
    the classical baseline with sensor depth beats it."""
    from bench import results_tum

    rep = results_tum.run(results_tum.QUICK, tmp_path, shared_data)
    rows = {(r["odometry"].split(" ")[0], r["kind"]): r for r in rep["rows"]}
    assert {("standing", "baseline"), ("pnp", "VO"), ("tum_cons", "VO"), ("tum_cons", "SLAM"),
            ("tum_cons_teddy", "VO")} <= set(rows)
    classical = [r for r in rep["rows"] if r["odometry"].split(" ")[0] in ("pnp", "dense")]
    assert len(classical) == 3  # sparse, dense least squares, dense Cauchy-reweighted; all with the sensor depth
    for r in classical:
        assert r["kind"] == "VO" and r["ate_se3_m"] < rows[("standing", "baseline")]["ate_se3_m"]
    assert rows[("tum_cons_teddy", "VO")]["frames_seen_in_training"] == "single frames, no poses"
    # each model on the flow it was trained on: both leave DIS's textureless pixels out, the adapted one also
    # what fails the forward-backward check
    for name, flow in (("tum_cons", "(dis-medium-tex0.5)"), ("tum_cons_teddy", "(dis-medium-tex0.5-fb0.5)")):
        assert flow in rows[(name, "VO")]["odometry"]
    assert (tmp_path / "trajectories.png").stat().st_size > 0


def test_road_table_lists_each_flow_with_its_median_and_spread():
    from bench import results_road

    rep = {"true_height_m": 1.65, "sets": {"KITTI 07 (real)": {
        "dis": {"pairs": 3, "median_m": 3.3, "q25_m": 2.5, "q75_m": 4.9, "heights_m": [2.5, 3.3, 4.9]},
        "learned": {"pairs": 0, "median_m": None, "q25_m": None, "q75_m": None, "heights_m": []}}}}
    md = results_road.markdown(rep)
    assert "| KITTI 07 (real) | dis | 3 | 3.30 | 2.50-4.90 |" in md and "learned" not in md
    rep["roadside"] = {"KITTI 07 (real)": {"pairs": 5, "left_px_per_m": 98.1, "right_px_per_m": 62.7}}
    assert "| KITTI 07 (real) | 5 | 98 | 63 |" in results_road.markdown(rep)


def test_roadside_flow_per_metre_is_the_inverse_distance_of_a_wall_beside_the_camera():
    """Driving 0.4 m straight past walls 4 m to the left and 8 m to the right: the flow of a wall at
    lateral distance d is about f * x^2 / d per metre at normalised column x, so the left reads twice."""
    from bench import results_road
    from deepslam.core.camera import PinholeCamera
    from deepslam.gen.flow import synthesize

    cam = PinholeCamera(500, 150, 250.0, 250.0, 249.5, 74.5)
    u = np.arange(cam.width)[None, :] - cam.cx
    x = u / cam.fx
    depth = np.where(x < 0, 4.0 / np.maximum(-x, 1e-3), 8.0 / np.maximum(x, 1e-3)).astype(np.float32)
    depth = np.broadcast_to(np.clip(depth, 0, 200), (cam.height, cam.width)).copy()
    motion = se3.from_rt(np.eye(3), [0, 0, -0.4])
    flow, valid = synthesize(depth, cam, motion)
    flow = flow.numpy().copy()
    flow[~valid.numpy()] = np.nan                     # points that leave the view: unknown, not zero
    poses = np.stack([np.eye(4), se3.inverse(motion)])
    seq = type("S", (), {"camera": cam, "gt_pose": staticmethod(lambda i: poses[i]), "__len__": lambda self: 2})()
    r = results_road.roadside_flow(seq, lambda i: flow, results_road.ResultsRoadConfig(pair_step=1, min_motion_m=0.3))
    assert r["pairs"] == 1
    assert r["left_px_per_m"] > 1.8 * r["right_px_per_m"]   # the left wall is twice as near


def test_slam_case_cache_is_reused_only_with_the_same_model_files_and_commit(tmp_path):
    """A retrained default, or changed odometry code, must not be scored by a record made before it."""
    from bench.results_slam import cached_case

    path = tmp_path / "street_dis.json"
    used = {"kitti_cons_dis.safetensors": "a" * 64, "kitti_loops_dis.safetensors": "b" * 64}
    assert cached_case(path, used, "abc1234") is None            # nothing cached yet
    path.write_text(json.dumps({"vo": {"ate_m": 1.0}}))          # a record from before the digests
    assert cached_case(path, used, "abc1234") is None
    path.write_text(json.dumps({"vo": {"ate_m": 1.0}, "models_sha256": used}))  # ... before the commit
    assert cached_case(path, used, "abc1234") is None
    rec = {"vo": {"ate_m": 1.0}, "models_sha256": used, "commit": "abc1234"}
    path.write_text(json.dumps(rec))
    assert cached_case(path, used, "abc1234") == rec
    assert cached_case(path, {**used, "kitti_cons_dis.safetensors": "c" * 64}, "abc1234") is None
    assert cached_case(path, used, "def5678") is None
    path.write_text(json.dumps({**rec, "commit": "abc1234-dirty"}))
    assert cached_case(path, used, "abc1234-dirty") is None      # uncommitted code: never reused
    path.write_text("{ not json")
    assert cached_case(path, used, "abc1234") is None


def test_a_results_folder_is_reused_only_with_the_same_settings(tmp_path):
    from bench.results_common import reuse_only_with_same_settings
    from deepslam.core.errors import InputError

    cfg = dataclasses.asdict(results_vo.ResultsVOConfig())
    reuse_only_with_same_settings(tmp_path, {"config": cfg, "motion_sha256": "a"})
    reuse_only_with_same_settings(tmp_path, {"config": cfg, "motion_sha256": "a"})  # a resumed run
    with pytest.raises(InputError, match=r"settings\.json.*config\.seeds"):
        reuse_only_with_same_settings(tmp_path, {"config": {**cfg, "seeds": [5]}, "motion_sha256": "a"})
    with pytest.raises(InputError, match="motion_sha256"):
        reuse_only_with_same_settings(tmp_path, {"config": cfg, "motion_sha256": "b"})
    # results_vo refuses such a folder before it renders or trains anything
    with pytest.raises(InputError, match="other settings"):
        results_vo.run(dataclasses.replace(results_vo.ResultsVOConfig(), seeds=(9,)), tmp_path, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["settings.json"]
    old = tmp_path / "old"  # a folder from before settings were recorded
    (old / "models").mkdir(parents=True)
    with pytest.raises(InputError, match="recorded no settings"):
        reuse_only_with_same_settings(old, {"config": cfg, "motion_sha256": "a"})


@pytest.mark.slow
def test_agreement_table_runs_each_variant_on_sim_and_real(shared_data, tmp_path):
    """The quick agreement run: every (variant, data, stride) row holds a path ratio and a drift, the
    summary a mean deviation per side, and the table names what each real slice is."""
    from bench import results_agreement

    cfg = dataclasses.replace(results_agreement.QUICK, sim_frames=10, strides=(1,),
                              variants=results_agreement.ResultsAgreementConfig.variants[:3])
    rep = results_agreement.run(cfg, tmp_path / "agreement", shared_data)
    assert len(rep["rows"]) == 3 * 2  # 3 variants x (1 simulated street + KITTI 07) x stride 1
    assert all(np.isfinite(r["path_ratio"]) and np.isfinite(r["drift_pct"]) for r in rep["rows"])
    assert rep["spearman_rho"] is None or -1.0 <= rep["spearman_rho"] <= 1.0
    md = (tmp_path / "agreement" / "results.md").read_text()
    assert "KITTI 07: never trained on" in md and (tmp_path / "agreement" / "stamp.json").is_file()


def test_adapt_table_leaves_the_adapted_cells_empty_where_nothing_was_adapted():
    from bench import results_adapt

    rep = {"rows": [{"data": "teddy", "default_ate_m": 0.2, "dense_fit_ate_m": 0.05, "pnp_ate_m": 0.02,
                     "adapted_vo_ate_m": 0.04, "adapted_slam_ate_m": 0.039, "adapt_minutes_first_run": 14.8},
                    {"data": "room", "default_ate_m": 0.1, "dense_fit_ate_m": 0.2, "pnp_ate_m": 0.02}]}
    md = results_adapt.markdown(rep).splitlines()
    assert md[-2] == "| teddy | 0.200 | 0.050 | 0.020 | 0.040 | 0.039 | 14.8 |"
    assert md[-1] == "| room | 0.100 | 0.200 | 0.020 |  |  |  |"


def test_a_killed_agreement_run_resumes_with_the_rows_it_measured_at_the_same_commit(tmp_path, monkeypatch):
    """Rows go to rows.jsonl as they are measured; a second run at the same clean commit measures nothing
    again, one at another commit (or with uncommitted changes) measures everything; a line cut short by a
    kill is skipped. A strided row is the mean of the runs from every start frame."""
    from bench import results_agreement
    import deepslam.studies.demo as demo

    calls = []

    def fake_vo(seq, stride, extra, out, start=0):
        calls.append((str(seq), stride, extra, start))
        return {"path_length_ratio": 1.0 + 0.01 * stride + 0.1 * start, "endpoint_drift_pct": float(stride + start),
                "ate_m": 0.1}

    monkeypatch.setattr(results_agreement, "_vo", fake_vo)
    monkeypatch.setattr(results_agreement, "_dis_epe", lambda seq, stride: 1.0)
    monkeypatch.setattr(demo, "render_once", lambda *a, **k: tmp_path / "street")
    cfg = dataclasses.replace(results_agreement.QUICK, real=(), strides=(1, 2))
    out = tmp_path / "agreement"
    commit = {"commit": "abc1234"}
    monkeypatch.setattr(results_agreement, "stamp", lambda: dict(commit))
    first = results_agreement.run(cfg, out, tmp_path)
    # two variants x one street: stride 1 from frame 0, stride 2 from frames 0 and 1
    assert len(calls) == 6 and len((out / "rows.jsonl").read_text().splitlines()) == 4
    assert sorted({c[1:] for c in calls if c[2] == ()}) == [(1, (), 0), (2, (), 0), (2, (), 1)]
    strided = next(r for r in first["rows"] if r["stride"] == 2 and r["variant"] == first["config"]["variants"][0][0])
    assert strided["path_ratio"] == pytest.approx(1.07) and strided["drift_pct"] == pytest.approx(2.5)
    assert [r["start"] for r in strided["per_start"]] == [0, 1]
    assert "mean over the runs from start frames" in (out / "results.md").read_text()
    with open(out / "rows.jsonl", "a") as f:
        f.write('{"key": "[\\"abc1234\\", [], \\"sim')          # a kill in the middle of a line
    again = results_agreement.run(cfg, out, tmp_path)
    assert len(calls) == 6 and again["rows"] == first["rows"]
    for other in ("def5678", "abc1234-dirty"):
        commit["commit"] = other
        calls.clear()
        results_agreement.run(cfg, out, tmp_path)
        assert len(calls) == 6


def test_stress_results_run_the_study_in_a_folder_of_its_own(tmp_path, monkeypatch, capsys):
    """The results folder is locked by the results script; the study takes its own folder's lock."""
    from bench import results_stress
    import deepslam.studies.stress as stress
    from deepslam.core.lock import output_lock

    seen = {}

    def fake_run_stress(config, out, resume=False, progress=None):
        with output_lock(out):
            seen["config"], seen["resume"] = config, resume
            out.mkdir(parents=True, exist_ok=True)
            (out / "stress.md").write_text("| setting | dynamic pixels |\n|---|---|\n| static scene | 0 % |\n\n"
                                           "![VO ATE](stress_vo_ate.png)\n")
        return {}

    monkeypatch.setattr(stress, "run_stress", fake_run_stress)
    import bench.stamp

    commit = {"commit": "abc1234"}
    monkeypatch.setattr(bench.stamp, "stamp", lambda: {"date": "d", "machine": "m", **commit})
    monkeypatch.setattr(results_stress, "stamp", bench.stamp.stamp)
    assert results_stress.main(["--quick", "--out", str(tmp_path / "stress")]) == 0
    assert seen["resume"] is False                               # nothing measured at this commit yet
    assert results_stress.main(["--quick", "--out", str(tmp_path / "stress")]) == 0
    assert seen["resume"] is True                                # a rerun at the same commit resumes
    commit["commit"] = "def5678"
    (tmp_path / "stress" / "study" / "settings").mkdir()
    assert results_stress.main(["--quick", "--out", str(tmp_path / "stress")]) == 0
    assert seen["resume"] is False                               # other code: measured again, from scratch
    assert not (tmp_path / "stress" / "study" / "settings").exists()
    (tmp_path / "stress" / "study_commit.txt").unlink()          # a study folder this script did not make
    assert results_stress.main(["--quick", "--out", str(tmp_path / "stress")]) == 2
    assert "did not make" in capsys.readouterr().err
    md = (tmp_path / "stress" / "results.md").read_text()
    assert "| static scene | 0 % |" in md and (tmp_path / "stress" / "stamp.json").is_file()
    assert "![VO ATE](study/stress_vo_ate.png)" in md          # the figure, relative to the results folder
    assert seen["config"].frames == 100 and seen["config"].objects == (0, 8) and not seen["config"].combined
    assert seen["config"].plugins == ("pnp",)
    assert results_stress.ResultsStressConfig().plugins == ("network", "pnp")  # the default run names all three


def test_results_doc_copies_the_figures_a_table_links_and_drops_missing_ones(tmp_path, monkeypatch):
    from bench import results_doc

    slam = tmp_path / "out" / "results" / "slam"
    slam.mkdir(parents=True)
    (slam / "street_gt.png").write_bytes(b"\x89PNG fake")
    (slam / "results.md").write_text("| a |\n|---|\n| 1 |\n\n![street](street_gt.png) ![room](room_gt.png)\n")
    figures = {}
    text = results_doc.build(tmp_path / "out", figures)
    assert "![street](img/results/slam_street_gt.png)" in text and "room_gt.png" not in text
    assert figures == {"img/results/slam_street_gt.png": slam / "street_gt.png"}
    monkeypatch.setattr(results_doc, "out_dir", lambda: tmp_path / "out")
    doc = tmp_path / "docs" / "results.md"
    assert results_doc.main(["--out", str(doc)]) == 0
    assert (tmp_path / "docs" / "img" / "results" / "slam_street_gt.png").read_bytes() == b"\x89PNG fake"


def test_results_doc_keeps_the_previous_table_of_a_run_not_on_disk(tmp_path):
    from bench import results_doc

    slam = tmp_path / "out" / "results" / "slam"
    slam.mkdir(parents=True)
    (slam / "results.md").write_text("| new slam |\n|---|\n")
    previous = ("# Results\n\nold preamble\n\n## VO alone against SLAM\n\n| old slam |\n\n"
                "## Turns\n\nRotation read in turns.\n\n*Measured 2026-01-01, commit `abc`, on M.*\n\n| old turn |\n"
                "\n## Commands\n\n```\nx\n```\n\n## Some heading no run writes\n\ngone\n")
    text = results_doc.build(tmp_path / "out", {}, previous)
    assert "| new slam |" in text and "| old slam |" not in text        # measured again: the new table
    turn = text[text.index("## Turns"):]
    assert "*Measured 2026-01-01, commit `abc`, on M.*" in turn and "## Commands\n\n```\nx\n```" in turn
    assert "old preamble" not in text and "Some heading no run writes" in text   # inside the kept section
    assert results_doc.build(tmp_path / "out", {}, "").count("## ") == 1


def test_repro_learning_curve_fits_a_power_law_and_the_table_reads_it(tmp_path):
    import json

    from bench import results_repro

    samples = 20000
    rows = [{"stage": 1, "epoch": e + 1, "samples": samples, "lr_max": 1e-3,
             "val_rmse6": [0, 0.02 * (e + 1) ** -0.5, 0, 0, 0, 0.5 * (e + 1) ** -0.5]} for e in range(20)]
    rows.append({"stage": 2, "epoch": 1, "holdout_nll": -3.0})
    (tmp_path / "history.json").write_text(json.dumps(rows))
    curve = results_repro.learning_curve(tmp_path / "history.json")
    assert curve["samples"][-1] == 20 * samples
    fit = curve["t_z_m_fit"]
    assert fit["exponent"] == pytest.approx(-0.5, abs=1e-9)  # exactly a power law of the samples
    assert fit["at_2x"] == pytest.approx(fit["last"] / 2 ** 0.5, rel=1e-9)
    figures = {"ate_m": 1.0, "rpe_t_m": 0.1, "rpe_r_deg": 0.1, "kitti_t_err_pct": None, "kitti_r_err_deg_per_100m": None,
               "endpoint_drift_pct": 3.0, "path_length_ratio": 1.0}
    report = {"models": {"synthetic s0": {"file": "x", "samples": 400000, "stop": "max_samples"}}, "cases": ["street_exact"],
              "rows": {"synthetic": [{"seed": 0, "street_exact": figures}],
                       "supervised": [{"seed": 0, "street_exact": {**figures, "endpoint_drift_pct": 1.5}}],
                       "supervised_samepatience": []},
              "default": {}, "curves": {"synthetic s0": curve},
              "ratio_synthetic_over_supervised": {"synthetic/supervised": {"street_exact": 2.0},
                                                  "synthetic/supervised_samepatience": {"street_exact": None}}}
    md = results_repro.markdown(report)
    assert "| cpu preset, synthetic (n=1) | 1 |" in md and "at 2x" in md
    assert "- cpu preset, synthetic / cpu preset, supervised (t_err, or drift where the route is under 100 m): x2.00" in md
    report["rows"]["paper:synthetic"] = [{"seed": 0, "street_exact": figures}, {"seed": 1, "street_exact": figures}]
    report["ratio_synthetic_over_supervised"]["paper:synthetic/paper:supervised"] = {"street_exact": 0.5}
    md = results_repro.markdown(report)
    assert "| paper preset, synthetic (n=2) | 1 ± 0 |" in md
    assert "paper preset, synthetic / paper preset, supervised (t_err" in md and "x0.50" in md
    slam = {"vo_ate_m": 4.0, "slam_ate_m": 1.0, "slam_over_vo": 0.25, "loops": 500, "loops_kept": 480,
            "vo_path_ratio": 0.95}
    for r in report["rows"]["synthetic"]:
        r["slam_laps_dis"] = slam
    report["default"]["slam_laps_dis"] = {**slam, "vo_ate_m": 2.0, "slam_over_vo": 0.5}
    report["config"] = {"slam_seed": 7441, "slam_frames": 1900, "width": 414}
    md = results_repro.markdown(report)
    assert "| cpu preset, synthetic (n=1) | 4 | 1 | 0.25 | 0.950 | 500 (480) |" in md
    assert "| `deepslam slam`'s default | 2 | 1 | 0.50 | 0.950 | 500 (480) |" in md



def test_repro_table_splits_the_own_pose_drift_into_rotation_and_distance():
    from bench import results_repro

    def figures(drift, path=1.0):
        return {"ate_m": 1.0, "kitti_t_err_pct": None, "kitti_r_err_deg_per_100m": None, "endpoint_drift_pct": drift,
                "path_length_ratio": path}

    rec = {"seed": 0, "kitti07_dis": figures(20.0), "kitti07_dis_epipolar": figures(8.0, 1.09)}
    report = {"models": {}, "cases": ["kitti07_dis"], "curves": {},
              "rows": {"synthetic_dis": [rec], "paper:synthetic": [{"seed": 0, "kitti07_dis": figures(17.5)}]},
              "default": {"kitti07_dis": figures(1.0, 0.998)},
              "ratio_synthetic_over_supervised": {},
              "ratio_over_default": {"synthetic_dis": {"kitti07_dis": 20.0}, "paper:synthetic": {"kitti07_dis": 17.5}}}
    md = results_repro.markdown(report)
    assert "| cpu preset, synthetic on DIS flow of rendered views s0 | 20 -> 8 (x1.090) |" in md
    assert "| `deepslam vo`'s default (road scale) | 1 (x0.998) |" in md
    assert ("- the network's own pose / the default (the target: at most x2): cpu preset, synthetic on DIS "
            "flow of rendered views x20.0; paper preset, synthetic x17.5") in md
    assert md.count("paper preset, synthetic s0") == 0   # scored with its own pose only: no decomposition row
    fit = {"yaw": {"gain": 0.78, "rms": 0.42}, "forward": {"gain": 0.82, "rms": 0.18}}
    rec["kitti07_dis_fit"] = fit
    report["default"]["kitti07_dis_fit"] = {**fit, "yaw": {"gain": None, "rms": 0.016}}
    md = results_repro.markdown(report)
    assert "| cpu preset, synthetic on DIS flow of rendered views s0 | yaw x0.78, 0.420°; forward x0.82, 0.180 m |" in md
    assert "| `deepslam vo`'s default | yaw n/a, 0.016°; forward x0.82, 0.180 m |" in md
    rec["kitti07_dis_cal06"] = {**figures(20.0), "within_1_sigma": [0.6, 0.7, 0.65, 0.6, 0.7, 0.75]}
    md = results_repro.markdown(report)
    assert ("- cpu preset, synthetic on DIS flow of rendered views s0, KITTI 07 slice (real, never trained on), DIS "
            "flow, std calibrated on KITTI 06 (`deepslam calibrate`): 0.60, 0.70, 0.65, 0.60, 0.70, 0.75") in md


def test_repro_gains_split_the_turns_by_sign_and_the_table_shows_the_unseen_one():
    import numpy as np

    from bench import results_repro

    rng = np.random.default_rng(0)
    true6 = np.zeros((60, 6))
    true6[:20, 1] = rng.uniform(0.02, 0.05, 20)     # left turns
    true6[20:35, 1] = -rng.uniform(0.02, 0.05, 15)  # right turns
    true6[:, 5] = rng.uniform(0.5, 1.5, 60)
    read6 = true6.copy()
    read6[20:35, 1] *= 0.4    # the right turns read short ...
    read6[20:35, 5] *= 1.5    # ... and made up as distance
    g = results_repro.gains(read6, true6)
    assert g["left"] == {"n": 20, "yaw_gain": pytest.approx(1.0), "forward_gain": pytest.approx(1.0)}
    assert g["right"]["n"] == 15 and g["right"]["yaw_gain"] == pytest.approx(0.4)
    assert g["right"]["forward_gain"] == pytest.approx(1.5)
    assert 0.4 < g["yaw"]["gain"] < 1.0 and g["yaw"]["rms"] > 0
    straight = results_repro.gains(read6[35:], true6[35:])
    assert straight["left"]["yaw_gain"] is None and straight["right"]["n"] == 0
    report = {"cases": ["street_dis", "kitti07_dis"], "config": {"slam_seed": 7441},
              "rows": {"synthetic_dis": [{"seed": 0, "street_dis_fit": straight, "kitti07_dis_fit": g,
                                          "slam_laps_dis_fit": g}]},
              "default": {"kitti07_dis_fit": results_repro.gains(true6, true6)}}
    md = "\n".join(results_repro.turns_table(report))
    assert "KITTI 07 slice (real, never trained on), DIS flow: right (15)" in md and "town 7," not in md
    assert "loop street (town 7441, `--route laps`), DIS flow: left (20)" in md
    assert ("| cpu preset, synthetic on DIS flow of rendered views s0 | yaw x1.00, forward x1.00 | yaw x0.40, "
            "forward x1.50 | yaw x1.00, forward x1.00 | yaw x0.40, forward x1.50 |") in md
    assert "| `deepslam vo`'s default | yaw x1.00, forward x1.00 | yaw x1.00, forward x1.00 | n/a | n/a |" in md
    report["rows"]["synthetic_dis"][0].pop("kitti07_dis_fit")
    report["rows"]["synthetic_dis"][0].pop("slam_laps_dis_fit")
    report["default"] = {}
    assert results_repro.turns_table(report) == []
    # a synthetic model's ratio is taken against supervised training on the same kind of flow
    assert results_repro.compared_with("synthetic_dis_mirror") == ("supervised_dis",)
    assert results_repro.compared_with("synthetic") == ("supervised", "supervised_samepatience")


def test_repro_trajectory_fit_reads_each_frames_motion_against_the_ground_truth(tmp_path):
    import numpy as np

    from bench import results_repro
    from deepslam.core import se3
    from deepslam.core.camera import PinholeCamera
    from deepslam.core.ours import OursWriter
    from deepslam.core.trajectory import Trajectory
    from deepslam.core.trajio import write_trajectory

    true6 = np.zeros((30, 6))
    true6[:, 5] = -1.0                      # 1 m forward a frame (cam_{k+1}_from_cam_k: t_z = -1 m)
    true6[5:12, 1] = 0.05                   # a left turn ...
    true6[18:25, 1] = -0.05                 # ... and a right one
    gt = se3.chain_euler6(true6)
    camera = PinholeCamera(16, 8, 10.0, 10.0, 7.5, 3.5)
    header = {"num_frames": len(gt), "rate_hz": 10.0, "camera": camera.to_dict(), "stereo_baseline_m": None,
              "scene": "test", "trajectory": "drive", "seed": 0, "backend": "numpy", "config": {},
              "has": {"rgb_right": False, "depth": False, "flow": False, "mask": False}}
    w = OursWriter(tmp_path / "seq", header)
    for i, pose in enumerate(gt):
        w.write_frame(i, i / 10.0, pose, np.zeros((8, 16, 3), np.uint8))
    w.finish()
    read6 = true6.copy()
    read6[18:25, 1] *= 0.5                  # the right turn read at half its yaw
    est = se3.chain_euler6(read6)
    write_trajectory(tmp_path / "vo.txt", Trajectory(est, np.arange(len(est)) / 10.0), "tum")
    g = results_repro.trajectory_fit(tmp_path / "seq", tmp_path / "vo.txt")
    assert g["left"]["n"] == 7 and g["right"]["n"] == 7
    assert g["left"]["yaw_gain"] == pytest.approx(1.0) and g["right"]["yaw_gain"] == pytest.approx(0.5)
    assert g["forward"]["gain"] == pytest.approx(1.0)
    write_trajectory(tmp_path / "short.txt", Trajectory(est[:-1], np.arange(len(est) - 1) / 10.0), "tum")
    with pytest.raises(ValueError, match="poses for"):
        results_repro.trajectory_fit(tmp_path / "seq", tmp_path / "short.txt")


def test_the_loop_route_table_counts_loops_by_direction_and_marks_both_targets():
    laps = {"vo": {"ate_m": 3.0, "ate_sim3_m": 1.9, "path_length_ratio": 0.986},
            "slam": {"ate_m": 2.5, "ate_sim3_m": 1.0}, "ratio": 2.5 / 3.0, "vo_path_ratio": 0.986,
            "slam_exact_revisits": {"ate_m": 2.4}, "ratio_exact_revisits": 0.8,
            "slam_exact_both_ways": {"ate_m": 2.0}, "ratio_exact_both_ways": 2.0 / 3.0,
            "loops_by_direction": {"same": 540, "opposite": 0}, "loop_edges_kept": 540, "revisit_pairs": 551,
            "opposite_revisit_pairs": 1078}
    md = results_slam.markdown({"config": dataclasses.asdict(results_slam.ResultsSlamConfig()), "minutes": 1.0,
                                "commands": [], "cases": {}, "laps": {"7431": laps}})
    row = [ln for ln in md.splitlines() if ln.startswith("| 7431")][0]
    # SLAM/VO 0.83 misses the half; SLAM within 10 % of perfect same-way loops (2.5 / 2.4 = 1.04)
    assert "| 0.83 | no | 2.4 (x0.80) | 1.04 | yes | 2 (x0.67) | 540 / 0 (540) | 551 / 1078 |" in row
    assert row.endswith("| 1.9 / 1 (x0.53) |") and "opposite way" in md


def test_the_read_width_rule_v2():
    from bench import results_width

    def row(label, w, rw, path, ate):
        return {"sequence": label, "width": w, "read_width": rw, "model": "m", "path_length_ratio": path, "ate_m": ate,
                "endpoint_drift_pct": 1.0}
    good = [row("street 1", 320, 0, 1.07, 1.7), row("street 1", 320, 640, 1.001, 0.2),
            row("street 1", 1241, 0, 1.002, 0.1), row("street 1", 1241, 640, 1.002, 0.1),
            row("room 1", 376, 0, 0.9, 0.70), row("room 1", 376, 640, 0.9, 0.72),
            row("README quickstart", 320, 0, 1.020, 0.137), row("README quickstart", 320, 640, 1.021, 0.190),
            {**row("README quickstart", 320, None, 1.02, 0.135), "model": "pnp"}]
    cfg = results_width.ResultsWidthConfig()
    assert results_width.decide(good, cfg)["default_640"]       # 0.001 away from x1 is within the tolerance
    worse_room = good[:5] + [row("room 1", 376, 640, 0.9, 0.80)] + good[6:]
    assert not results_width.decide(worse_room, cfg)["default_640"]
    changed_wide = good[:3] + [row("street 1", 1241, 640, 1.003, 0.1)] + good[4:]
    assert "not narrower" in " ".join(results_width.decide(changed_wide, cfg)["why"])
    far_from_pnp = good[:7] + [row("README quickstart", 320, 640, 1.021, 0.30)] + good[8:]
    assert "2x pnp" in " ".join(results_width.decide(far_from_pnp, cfg)["why"])
    assert "640 px" in results_width.markdown({"rows": good, "decision": results_width.decide(good, cfg),
                                               "minutes": 1.0, "commands": []})


def test_the_extra_data_table_compares_real_with_real_plus_rendered():
    from bench import results_extra

    def scores(drift):
        m = {"endpoint_drift_pct": drift, "ate_m": 1.0, "path_length_ratio": 1.0}
        return {"KITTI 07 (real), DIS flow": m, "held-out street (town 7), exact flow": m}
    rows = [{"mix": "real", "seed": 0, "scores": scores(20.0)},
            {"mix": "real + rendered", "seed": 0, "scores": scores(10.0)}]
    md = results_extra.markdown({"config": dataclasses.asdict(results_extra.ResultsExtraConfig()), "rows": rows,
                                 "minutes": 1.0, "commands": []})
    assert "drift x0.50 (the renders help" in md and "| real + rendered | 10 / 1 / 1 |" in md


def test_keyframe_rule_and_loop_recall():
    """bench.results_keyframes: the recall counts keyframes revisiting a place the same way that got a loop edge;
    the rule keeps the largest stride within max(1.05 x, + 0.05 m) of stride 1's ATE and 0.9 x its recall."""
    from bench import results_keyframes as rk
    from deepslam.slam.synthetic import circle_trajectory

    poses = circle_trajectory(120, 10.0, 2.0, 0.0)  # two laps of 60 frames: frame j revisits j - 60
    kf = list(range(0, 120, 3))
    none = rk.loop_recall(poses, kf, np.zeros((0, 2), np.int64), t_loop=50)
    assert none["revisiting"] == 20 and none["found"] == 0 and none["recall"] == 0.0
    half = rk.loop_recall(poses, kf, np.array([(j - 60, j) for j in range(60, 90, 3)]), t_loop=50)
    assert half["found"] == 10 and half["recall"] == 0.5
    assert rk.loop_recall(poses, kf, np.array([(0, 60)]), t_loop=70)["revisiting"] == 0  # none more than 70 apart

    def row(ate, recall):
        return {"slam": {"ate_m": ate}, "recall": {"recall": recall}}

    rows = {"a": {"1": row(1.0, 0.9), "2": row(1.04, 0.85), "3": row(1.2, 0.9)},
            "b": {"1": row(0.2, None), "2": row(0.24, None), "3": row(0.2, None)}}
    assert rk.rule(rows, (1, 2, 3)) == {"met": {"1": True, "2": True, "3": False}, "chosen": 2}
    rows["a"]["2"] = row(1.04, 0.8)  # recall under 0.9 x
    assert rk.rule(rows, (1, 2, 3))["chosen"] == 1


def test_the_exact_flow_model_rule_needs_mean_rows_and_path_band():
    from bench import results_exact_model as rem

    cfg = dataclasses.replace(rem.ExactModelConfig(), candidates=(("base", "k"), ("good", "a"), ("banded", "b"),
                                                                  ("few", "c")), min_rows_better=2)

    def rec(t, p=1.0):
        return {"t_err_pct": t, "path_ratio": p}
    rows = [{"base": rec(5.0, 1.12), "good": rec(1.0), "banded": rec(0.5, 1.07), "few": rec(6.0)},
            {"base": rec(4.0, 1.10), "good": rec(1.5), "banded": rec(0.5), "few": rec(0.1)},
            {"base": rec(4.0, 1.10), "good": rec(4.5, 0.97), "banded": rec(0.5), "few": rec(4.5)}]
    v = rem.verdicts(cfg, rows)
    assert v["good"]["passes"] and v["good"]["rows_better"] == 2
    assert not v["banded"]["passes"] and not v["banded"]["path_in_band"]  # best t_err, but path x1.07 on a row
    assert not v["few"]["passes"] and v["few"]["rows_better"] == 1  # lower mean, better on one row only
    assert not v["base"]["passes"] and v["_chosen"] == "good"
    md = rem.markdown({"config": dataclasses.asdict(cfg), "rows": [{"seed": 1, "width": 320, "stride": 1, **r}
                                                                  for r in rows], "verdicts": v})
    assert "Chosen by the rule: **good**" in md and "| base | 4.333 | 0 of 3 | 1.100-1.120 | default |" in md


def test_repro_fit_reads_the_share_of_distance_and_turns_against_the_ground_truth(plane_sequence, tmp_path):
    from bench import results_repro
    from deepslam.core import se3
    from deepslam.core.readers import open_sequence

    gt = open_sequence(plane_sequence).gt.world_from_cam
    true6 = se3.to_euler6(se3.relative(gt[1:], gt[:-1])).reshape(-1, 6)
    read6 = true6 * np.array([1, 1, 1, 1, 1, 0.5])            # half the distance, the rest exact
    rows = [[i, i + 1, 0.0, 0.1, *read6[i], *[0.01] * 6] for i in range(len(read6))]
    csv = tmp_path / "run.motions.csv"
    np.savetxt(csv, np.array(rows), delimiter=",", header="i,j,t_i_s,t_j_s,e,e,e,t,t,t,s,s,s,s,s,s", comments="")
    fit = results_repro.yaw_and_forward_fit(plane_sequence, csv)
    assert fit["forward"]["gain"] == pytest.approx(0.5, abs=1e-9)
    assert fit["forward"]["rms"] == pytest.approx(0.5 * np.sqrt(np.mean(true6[:, 5] ** 2)), rel=1e-9)  # ~0.4 m
    assert fit["yaw"]["rms"] == pytest.approx(0.0, abs=1e-9)


def test_repro_reads_the_ground_truth_at_each_pairs_times_where_it_is_not_one_per_frame(shared_data, tmp_path):
    import numpy as np

    from bench import results_repro
    from deepslam.core import se3
    from deepslam.core.readers import open_sequence

    teddy = shared_data / "tum" / "rgbd_dataset_freiburg3_teddy"
    seq = open_sequence(teddy)
    gt = seq.gt
    assert len(gt) < len(seq)  # TUM: the ground truth does not cover every frame
    t = seq.timestamps_s
    pairs = [(k, k + 1) for k in range(len(seq) - 1)]
    csv = tmp_path / "run.motions.csv"
    csv.write_text("i,j,t_i_s,t_j_s,ex_rad,ey_rad,ez_rad,tx_m,ty_m,tz_m,std_ex_rad,std_ey_rad,std_ez_rad,std_tx_m,"
                   "std_ty_m,std_tz_m\n" + "".join(f"{i},{j},{float(t[i])!r},{float(t[j])!r}" + ",0" * 6 + ",1" * 6 + "\n"
                                                    for i, j in pairs))
    mean6, std6, true6 = results_repro._predicted_and_true(teddy, csv)
    inside = [(i, j) for i, j in pairs if t[i] >= gt.timestamps_s[0] and t[j] <= gt.timestamps_s[-1]]
    assert len(true6) == len(mean6) == len(std6) == len(inside) < len(pairs)
    at = {float(x): n for n, x in enumerate(gt.timestamps_s)}
    checked = 0
    for row, (i, j) in zip(true6, inside):
        if float(t[i]) in at and float(t[j]) in at:  # both frames have a pose of their own: the motion is theirs
            w = gt.world_from_cam
            np.testing.assert_allclose(row, se3.to_euler6(se3.relative(w[at[float(t[j])]], w[at[float(t[i])]])),
                                       atol=1e-9)
            checked += 1
    assert checked > 100
    assert np.abs(true6[:, 3:]).max() > 1e-3  # the camera moves: a zero motion would not pass for the truth


def test_repro_rgbd_table_rows_beside_and_ratio():
    from bench import results_repro_rgbd as rr

    def figures(ate, rpe):
        return {"ate_m": ate, "rpe_t_m": rpe, "rpe_r_deg": 0.5, "path_length_ratio": 1.0,
                "within_1_sigma": [0.7] * 6}

    report = {"config": {"room_seed": 51}, "models": {"room_synthetic_mirror s0": {"file": "a", "samples": 1000},
                                                      "room_supervised s0": {"file": "b", "samples": 500}},
              "cases": ["room_exact", "teddy_dis"],
              "rows": {"room_synthetic_mirror": [{"seed": 0, "room_exact": figures(0.2, 0.02),
                                                  "teddy_dis": figures(0.5, 0.03)}],
                       "room_supervised": [{"seed": 0, "room_exact": figures(0.1, 0.01),
                                            "teddy_dis": {**figures(0.4, None)}}]},
              "beside": {"pnp": {"room_exact": figures(0.01, 0.001)}}}
    report["ratio_synthetic_over_supervised"] = rr.ratios(report)
    assert report["ratio_synthetic_over_supervised"] == {
        "room_synthetic_mirror/room_supervised": {"room_exact": pytest.approx(2.0), "teddy_dis": None}}
    md = rr.markdown(report)
    assert "**unseen rendered room (room 51, Kinect-like depth, 30 Hz), exact flow**" in md
    assert ("| synthetic (single frames of the rooms, mirrored motions) (n=1) | 0.2 | 0.02 | 0.5 | 1.000 | "
            "0.70, 0.70, 0.70, 0.70, 0.70, 0.70 |") in md
    assert "| `pnp` (SIFT + PnP-RANSAC on the frame's depth; no flow) | 0.01 | 0.001 | 0.5 | 1.000 | |" in md
    assert md.count("(RPE translation): x2.00") == 1  # teddy's ratio is missing a figure: not stated


def test_repro_rgbd_rank_agreement_with_teddy():
    """rank_agreement: Spearman's rho of the rows' ATE against teddy's (networks, the default and pnp together) and
    the networks whose path ratio is on teddy's side of 1; the table states both."""
    from bench import results_repro_rgbd as rr

    def fig(ate, path):
        return {"ate_m": ate, "path_length_ratio": path}

    report = {"config": {"room_seed": 51, "handheld_frames": 200}, "models": {},
              "cases": ["room_dis", "handheld_dis", "teddy_dis"],
              "rows": {"room_synthetic_mirror": [{"room_dis": fig(0.1, 0.9), "handheld_dis": fig(0.3, 1.5),
                                                  "teddy_dis": fig(0.4, 2.4)}],
                       "room_supervised": [{"room_dis": fig(0.5, 0.7), "handheld_dis": fig(0.4, 1.2),
                                            "teddy_dis": fig(0.5, 2.2)}]},
              "beside": {"default": {"room_dis": fig(0.2, 0.8), "handheld_dis": fig(0.2, 1.1),
                                     "teddy_dis": fig(0.2, 1.1)},
                         "pnp": {"room_dis": fig(0.3, 1.0), "handheld_dis": fig(0.02, 1.0),
                                 "teddy_dis": fig(0.02, 1.0)}}}
    # teddy's order by ATE: pnp < default < synthetic < supervised; the hand-held room's the same, the drone room's
    # synthetic < default < pnp < supervised
    hand, drone = rr.rank_agreement(report, "handheld_dis"), rr.rank_agreement(report, "room_dis")
    assert hand == {"rho": pytest.approx(1.0), "rows": 4, "same_side": 2, "networks": 2}
    assert drone["rho"] == pytest.approx(0.2) and drone["same_side"] == 0 and drone["networks"] == 2
    report["agreement_with_teddy"] = {"room_dis": drone, "handheld_dis": hand}
    report["rows"]["room_supervised"][0]["teddy_dis_calhandheld"] = {"within_1_sigma": [0.6, 0.7, 0.75, 0.8, 0.5, 0.68]}
    md = rr.markdown(report)
    assert ("- supervised (the rooms' frame pairs, exact flow, poses), calibrated on the hand-held room: 0.60, 0.70, "
            "0.75, 0.80, 0.50, 0.68 (4 of 6 in 0.6-0.75)") in md
    assert "calibrated on the drone's room" not in md  # not scored: not stated
    assert ("- the same room walked hand-held (`--trajectory handheld`, 200 frames at 30 Hz), DIS flow: rho 1.00 "
            "over 4 rows; 2 of 2 networks on teddy's side") in md


def test_repro_scores_a_model_again_once_its_file_changes(tmp_path):
    from bench.results_repro import forget_if_retrained

    out, model = tmp_path / "repro", tmp_path / "model.safetensors"
    model.write_bytes(b"checkpoint at 480,000 samples")
    forget_if_retrained(out, "synthetic_s0", model)  # first use: the cache (empty here) is adopted
    for folder, name in (("eval", "synthetic_s0_street_dis.json"), ("runs", "synthetic_s0_street_dis.txt"),
                         ("eval", "synthetic_mirror_s0_street_dis.json"), ("eval", "synthetic_s1_street_dis.json")):
        (out / folder).mkdir(parents=True, exist_ok=True)
        (out / folder / name).write_text("{}")
    forget_if_retrained(out, "synthetic_s0", model)  # same file: kept
    assert (out / "eval" / "synthetic_s0_street_dis.json").is_file()
    model.write_bytes(b"model at 1,200,000 samples")
    forget_if_retrained(out, "synthetic_s0", model)  # trained further: its evaluations go, the others stay
    assert not (out / "eval" / "synthetic_s0_street_dis.json").exists()
    assert not (out / "runs" / "synthetic_s0_street_dis.txt").exists()
    assert (out / "eval" / "synthetic_mirror_s0_street_dis.json").is_file()
    assert (out / "eval" / "synthetic_s1_street_dis.json").is_file()


@pytest.mark.parametrize("env, message", [
    ({"SCENE": "room", "SYNTH_FLOW": "dis"}, "SCENE=room trains the exact-flow recipe only"),
    ({"SCENE": "room", "BODY": "1"}, "SCENE=room trains the exact-flow recipe only"),
    ({"DEPTH": "1"}, "DEPTH=1 is for SCENE=room"),
    ({"SCENE": "kitchen"}, "SCENE must be street or room"),
    ({"TRAJECTORY": "handheld"}, "TRAJECTORY=handheld is for SCENE=room"),
    ({"SCENE": "room", "TRAJECTORY": "car"}, "TRAJECTORY must be handheld or unset"),
    ({"SCENE": "room", "LEVER": "0.84"}, "LEVER is for SCENE=street"),
    ({"LEVER": "ahead"}, "LEVER must be metres ahead of the rear axle"),
])
def test_recipe_script_refuses_a_mix_it_cannot_train_before_writing(tmp_path, env, message):
    """scripts/train_paper_recipe.sh: a combination it does not train exits 2 with one line, its folder not made."""
    out = tmp_path / "recipe"
    script = Path(__file__).resolve().parents[1] / "scripts" / "train_paper_recipe.sh"
    p = subprocess.run(["bash", str(script), str(out), "1000", "0"], capture_output=True, text=True,
                       env={**os.environ, **env, "DS": "false"})
    assert p.returncode == 2 and message in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("env", [{}, {"LEVER": "0.84"}, {"LEVER": "0"}, {"SPEED_SCALE": "0.4,1.5"},
                                 {"MIRROR_FRAMES": "1", "SAMEPATIENCE": "0"},
                                 {"SYNTH_FLOW": "dis", "SPEED_SCALE": "0.4,1.5", "BODY": "1"},
                                 {"SCENE": "room", "DEPTH": "1"}, {"SCENE": "room", "TRAJECTORY": "handheld"}])
def test_recipe_script_runs_every_mix_it_trains_to_its_end(tmp_path, env):
    """scripts/train_paper_recipe.sh under ``set -e``: with ``true`` standing in for deepslam (every step succeeds
    and writes nothing) each mix it trains runs through its naming and steps to "done" (a name built from a failing
    test once stopped the street recipe silently)."""
    out = tmp_path / "recipe"
    script = Path(__file__).resolve().parents[1] / "scripts" / "train_paper_recipe.sh"
    p = subprocess.run(["bash", str(script), str(out), "1000", "0"], capture_output=True, text=True,
                       env={**os.environ, **env, "DS": "true"})
    assert p.returncode == 0 and f"done: {out}" in p.stdout, p.stderr


@pytest.mark.parametrize("env, lever, mirrored", [
    ({"LEVER": "0.0"}, False, True), ({"LEVER": "00", "MIRROR_FRAMES": "0"}, False, False), ({"LEVER": "0.84"}, True, True),
    ({"SYNTH_FLOW": "dis"}, True, True), ({"SYNTH_FLOW": "dis", "MIRROR_FRAMES": "0"}, True, False),
    ({"SCENE": "room"}, False, False), ({"SCENE": "room", "MIRROR_FRAMES": "1"}, False, True)])
def test_recipe_script_names_what_it_trains(tmp_path, env, lever, mirrored):
    """scripts/train_paper_recipe.sh with ``echo`` standing in for deepslam: any zero lever is the axle camera (no
    ``--camera-ahead``, no ``lever_`` names); the street recipe gives the synthetic model, and only it,
    ``--mirror-frames`` and the ``_mirrorframes`` name unless MIRROR_FRAMES=0; the rooms' only with MIRROR_FRAMES=1."""
    out = tmp_path / "recipe"
    script = Path(__file__).resolve().parents[1] / "scripts" / "train_paper_recipe.sh"
    p = subprocess.run(["bash", str(script), str(out), "1000", "0"], capture_output=True, text=True,
                       env={**os.environ, **env, "DS": "echo"})
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert any("--camera-ahead" in line for line in lines) == lever
    trains = [line for line in lines if line.startswith("train ")]
    assert trains and all(("/lever_" in line) == lever for line in trains)
    flipped = [line for line in trains if "--mirror-frames" in line]
    if mirrored:
        assert len(flipped) == 1 and "--mode synthetic" in flipped[0] and "_mirrorframes_cons_s0" in flipped[0]
    else:
        assert not flipped and not any("mirrorframes" in line for line in trains)


def test_depth_probe_reads_a_network_that_ignores_its_depth_as_one():
    """bench.depth_channel_probe: a network whose depth-channel weights are zero moves no translation when its
    inverse depth is doubled or zeroed (ratios exactly 1); with them random, the ratios move."""
    torch.manual_seed(0)
    net = make_net(NetConfig(6, 10, filters=4, hidden_units=8, depth_channel=True, kernels=(3,), strides=(1,)))
    with torch.no_grad():
        net.trans_mean.bias.fill_(1.0)  # a translation well away from zero
    pred = VOPredictor(net, bf16=False, channels_last=False)
    rng = np.random.default_rng(0)
    flows = rng.normal(0, 3, (5, 2, 6, 10)).astype(np.float32)
    intr = np.tile(np.float32([10, 10, 5, 3]), (5, 1))
    inv = rng.uniform(0.2, 1.0, (5, 1, 6, 10)).astype(np.float32)
    moved = depth_channel_probe.probe(pred, flows, intr, inv)
    assert abs(moved["x2"] - 1.0) > 1e-4
    with torch.no_grad():
        net.conv[0].weight[:, 2].zero_()  # the depth channel's weights
    still = depth_channel_probe.probe(pred, flows, intr, inv)
    assert still["x2"] == pytest.approx(1.0, abs=1e-6) and still["zero"] == pytest.approx(1.0, abs=1e-6)


def test_depth_probe_refuses_a_missing_room(tmp_path, capsys):

    assert depth_channel_probe.main(["--room", str(tmp_path / "nothing")]) == 2
    assert "no rendered room" in capsys.readouterr().err


def test_results_lever_turn_yaw_errors_and_true_rotation_drift():
    """bench.results_lever: a reading that overshoots every turn by 10 % shows a positive mean yaw error on the left
    turns and a negative one on the right, none on the straight; with the true rotation put back and the true
    translation kept the drift is zero, with the translation read 10 % long the path ratio is 1.1."""
    from bench import results_lever

    n = 30
    yaw = np.r_[np.full(10, 0.05), np.zeros(10), np.full(10, -0.05)]  # left, straight, right (rad a pair)
    true6 = np.c_[np.zeros(n), yaw, np.zeros(n), np.zeros(n), np.zeros(n), np.full(n, 0.8)]
    read6 = true6.copy()
    read6[:, 1] *= 1.1
    turns = results_lever.turn_yaw_errors(read6, true6)
    assert turns["left"]["n"] == 10 and turns["right"]["n"] == 10 and turns["straight"]["n"] == 10
    assert turns["left"]["mean_deg"] == pytest.approx(np.degrees(0.005))
    assert turns["right"]["mean_deg"] == pytest.approx(-np.degrees(0.005))
    assert turns["straight"]["mean_deg"] == 0.0
    assert results_lever.drift_with_true_rotation(read6, true6)["endpoint_drift_m"] == pytest.approx(0.0, abs=1e-9)
    long6 = read6.copy()
    long6[:, 5] *= 1.1
    assert results_lever.drift_with_true_rotation(long6, true6)["path_length_ratio"] == pytest.approx(1.1)


def test_results_lever_straight_forward_gain_by_stride():
    """bench.results_lever: a reading 10 % long on the straight pairs gives x1.1 whatever the turns read; a pair turning
    less than stride x TURN_RAD counts as straight at that stride; no straight pair gives None."""
    from bench import results_lever

    true6 = np.zeros((4, 6))
    true6[:, 5] = [0.5, 1.0, 1.5, 1.0]
    true6[3, 1] = 0.015  # a turn at stride 1, straight at stride 2 (under 2 x 0.01 rad)
    read6 = true6.copy()
    read6[:3, 5] *= 1.1
    read6[3, 5] *= 3.0
    one = results_lever.straight_forward_gain(read6, true6, stride=1)
    assert one["n"] == 3 and one["gain"] == pytest.approx(1.1) and one["true_m"] == pytest.approx(1.0)
    two = results_lever.straight_forward_gain(read6, true6, stride=2)
    assert two["n"] == 4 and two["gain"] > 1.3
    true6[:, 1] = 0.5
    assert results_lever.straight_forward_gain(read6, true6)["gain"] is None


def test_results_layout_straight_pairs_and_where_the_reading_comes_from():
    """bench.results_layout: only the pairs turning under TURN_RAD are straight; an attribution that sits in the
    bottom-left sixth of the image and adds up to the true forward motion reads 1.0 there and 0 elsewhere."""
    from bench import results_layout

    yaw = [0.0, 0.0, 0.02, 0.0]  # rad of each step; the third step turns
    world_from_cam = [np.eye(4)]
    for step_yaw in yaw:
        step = se3.from_euler6(np.array([0.0, step_yaw, 0.0, 0.0, 0.0, -1.0]))  # cam_j_from_cam_i, 1 m forward
        world_from_cam.append(world_from_cam[-1] @ se3.inverse(step))
    pairs, true6 = results_layout.straight_pairs(np.stack(world_from_cam))
    np.testing.assert_array_equal(pairs, [[0, 1], [1, 2], [3, 4]])
    np.testing.assert_allclose(-true6[:, 5], 1.0, atol=1e-9)

    forward = np.array([0.5, 2.0])
    attr = np.zeros((2, 6, 9))
    attr[:, 3:, :3] = forward[:, None, None] / 9.0  # the bottom-left sixth, adding up to the forward motion
    split = results_layout.attribution_split(results_layout.per_metre(attr, forward))
    assert split == pytest.approx({"top": 0.0, "bottom_left": 1.0, "bottom_centre": 0.0, "bottom_right": 0.0})


def test_results_lever_cross_calibration_carries_a_factor_from_one_sequence_to_another():
    """bench.results_lever.cross_calibrated: stds half the errors' spread on both sequences are scaled right by the
    first (about 0.68 within 1-sigma on the second); on a second sequence with errors three times larger, far fewer."""
    from bench import results_lever

    rng = np.random.default_rng(3)
    n = 4000
    true6 = rng.normal(size=(n, 6))
    std6 = np.full((n, 6), 0.1)
    fit = (true6 + rng.normal(scale=0.2, size=(n, 6)), std6, true6)
    alike = (true6 + rng.normal(scale=0.2, size=(n, 6)), std6, true6)
    wider = (true6 + rng.normal(scale=0.6, size=(n, 6)), std6, true6)
    assert results_lever.cross_calibrated(fit, alike) == pytest.approx([0.68] * 6, abs=0.03)
    assert max(results_lever.cross_calibrated(fit, wider)) < 0.35


def test_results_lever_scores_an_ensemble_once_its_members_are_finished(tmp_path):
    """bench.results_lever: an ensemble of seeds is written only when every member has a finished model file (a
    checkpoint does not count), and written again (its evaluations cleared) once a member changes."""
    from bench import results_lever
    from deepslam.vo.modelfiles.modelio import load_model, save_model
    from deepslam.vo.net import FlowPoseNet

    small = NetConfig(input_height=24, input_width=80, filters=8, hidden_units=16, flow_scale=10.0)

    def save(folder: Path, seed: int, name: str = "model.safetensors") -> None:
        torch.manual_seed(seed)
        folder.mkdir(parents=True, exist_ok=True)
        save_model(folder / name, FlowPoseNet(small).eval(), {"train": {"seed": seed}, "data": {"frames": ["a"]}})

    models, out = tmp_path / "models", tmp_path / "out"
    cfg = results_lever.LeverConfig(models=str(models), ensembles=(("e", ("a", "b")),))
    save(models / "a", 0)
    save(models / "b", 1, "checkpoint.safetensors")
    assert results_lever._ensembles(cfg, out) == []
    save(models / "b", 1)
    [(name, path)] = results_lever._ensembles(cfg, out)
    assert name == "e" and len(load_model(path)[0].members) == 2
    stale = out / "eval" / "e_kitti07_dis.json"
    stale.write_text("{}")
    results_lever._ensembles(cfg, out)  # the same members: the evaluation stays
    assert stale.is_file()
    save(models / "b", 2)  # a member trained again
    results_lever._ensembles(cfg, out)
    assert not stale.exists()


def test_results_lever_centred_ratios_read_each_model_both_ways():
    from bench import results_lever

    report = {"models": {"a": {"k": {"endpoint_drift_pct": 4.0}, "k_centred": {"endpoint_drift_pct": 2.0}},
                         "b": {"k": {"endpoint_drift_pct": 2.0}, "k_centred": {"endpoint_drift_pct": 2.2}},
                         "c": {"k": {"endpoint_drift_pct": 3.0}}}}
    assert results_lever.centred_ratios(report, "k") == pytest.approx({"a": 0.5, "b": 1.1})


def test_results_lever_band_distance_and_count():
    from bench import results_lever

    assert results_lever.band_distance([0.68] * 6) == 0.0
    assert results_lever.band_distance([0.58, 0.78, 0.68, 0.68, 0.68, 0.68]) == pytest.approx(0.2 / 6)
    assert results_lever.in_band([0.6, 0.75, 0.59, 0.76, 0.68, 1.0]) == 3


def test_results_lever_groups_the_seeds_of_one_recipe():
    from bench import results_lever

    groups = results_lever.seed_groups(["a_cons_s0", "b_cons_s0", "a_cons_s1", "a_cons_s0+s1", "c"])
    assert groups == {"a_cons": ["a_cons_s0", "a_cons_s1"]}


def test_claim_table_means_the_seeds_and_states_the_ratios_against_the_default(tmp_path, capsys):
    """bench.results_claim: a row's cell is the mean over its street model's seeds (an ensemble ``_s0+s1`` is not a
    seed), the room rows read the room study's modes, the ratios divide the drift figures; a missing study is one
    line and exit 2."""
    from bench import results_claim as rc

    def rec(err, ate, shares=(0.7,) * 6):
        return {"kitti_t_err_pct": None, "endpoint_drift_pct": err, "ate_m": ate, "rpe_t_m": err / 1000,
                "within_1_sigma": list(shares)}

    cfg = rc.ClaimConfig(street_cases=(("k7", "KITTI 07"), ("laps", "loop street")), room_cases=(("teddy", "teddy"),),
                         rows=(("single", "single frames", "syn", "room_syn"), ("sup", "supervised", "sup", None)),
                         ratios=(("single", "sup"),))
    street = {"config": {"models": "bench/paper_recipe"},
              "models": {"syn_s0": {"k7": rec(2.0, 0.5), "laps": {"slam_ate_m": 3.0}},
                         "syn_s1": {"k7": rec(4.0, 0.7, (0.1,) * 6), "laps": {"slam_ate_m": 5.0}},
                         "syn_s0+s1": {"k7": rec(100.0, 9.0)}, "sup_s0": {"k7": rec(6.0, 1.0)}},
              "default": {"k7": rec(1.0, 0.3, (1.0,) * 6)}}
    room = {"config": {}, "rows": {"room_syn": [{"teddy": rec(30.0, 0.2)}]},
            "beside": {"pnp": {"teddy": rec(3.0, 0.02)}}}
    report = rc.gather(cfg, street, room)
    assert report["models"] == {"syn": ["syn_s0", "syn_s1"], "sup": ["sup_s0"]}
    single = report["cells"]["single"]["k7"]["err"]
    assert (single["mean"], single["n"]) == (pytest.approx(3.0), 2)
    assert report["cells"]["single"]["k7"]["dofs_in_band"] == pytest.approx(3.0)  # median of 6 and 0 DoFs in 0.6-0.75
    assert report["cells"]["single"]["teddy"]["err"]["mean"] == pytest.approx(30.0)  # RPE in mm a frame
    assert "teddy" not in report["cells"]["sup"]  # no room model in that row: an empty cell, not a zero
    md = rc.markdown(report)
    assert "| single frames / supervised | x0.50 |  |" in md
    assert "| single frames / the default | x3.00 |  |" in md
    assert "| `pnp` (SIFT + PnP-RANSAC on the frame's depth) |  | 3.00 |" in md
    assert "| | KITTI 07 | teddy |" in md  # the drift tables leave out the loop street, which has only the SLAM's ATE
    assert "| | KITTI 07 | loop street | teddy |" in md and "| single frames | 0.600 ± 0.141 | 4.000 ± 1.414 | 0.200 |" in md

    assert rc.main(["--out", str(tmp_path / "claim")]) == 2
    assert "lever/results.json: not found" in capsys.readouterr().err
    assert not (tmp_path / "claim" / "results.json").exists()


def test_results_lever_mirror_rule_reads_the_median_ratio_of_each_case():
    """bench.results_lever.mirror_rule: the median over the models read both ways, x0.90 at most on a KITTI case and
    x1.05 on a town case; a case nobody was read on both ways fails it."""
    from bench import results_lever as rl

    def rec(err):
        return {"kitti_t_err_pct": None, "endpoint_drift_pct": err}

    report = {"cases": ["lever_dis", "kitti07_dis"], "models": {
        "a_mirrorframes_s0": {"lever_dis": rec(1.0), "lever_dis_mirrored": rec(1.02),
                              "kitti07_dis": rec(4.0), "kitti07_dis_mirrored": rec(2.0)},
        "a_mirrorframes_s1": {"lever_dis": rec(1.0), "lever_dis_mirrored": rec(1.2),
                              "kitti07_dis": rec(2.0), "kitti07_dis_mirrored": rec(1.9)},
        "a_mirrorframes_s2": {"lever_dis": rec(1.0), "lever_dis_mirrored": rec(0.9),
                              "kitti07_dis": rec(3.0), "kitti07_dis_mirrored": rec(2.4)},
        "plain_s0": {"lever_dis": rec(5.0), "kitti07_dis": rec(5.0)}}}
    rule = rl.mirror_rule(report)
    assert rule["medians"] == {"lever_dis": pytest.approx(1.02), "kitti07_dis": pytest.approx(0.8)}
    assert rule["passes"]
    report["models"]["a_mirrorframes_s2"]["lever_dis_mirrored"] = rec(1.1)  # the town's median now x1.10
    assert not rl.mirror_rule(report)["passes"]
    report["cases"].append("kitti06_dis")
    assert rl.mirror_rule(report)["medians"]["kitti06_dis"] is None and not rl.mirror_rule(report)["passes"]
    report["cases"] = ["lever_dis", "kitti07_dis", "lever_pp_dis"]  # a case added after the rule: not read by it
    report["models"]["a_mirrorframes_s2"]["lever_dis_mirrored"] = rec(0.9)
    for name in ("a_mirrorframes_s0", "a_mirrorframes_s1", "a_mirrorframes_s2"):
        report["models"][name].update(lever_pp_dis=rec(1.0), lever_pp_dis_mirrored=rec(3.0))
    assert "lever_pp_dis" not in rl.mirror_rule(report)["medians"] and rl.mirror_rule(report)["passes"]


def test_results_lever_reads_centred_where_the_principal_point_is_off_the_centre(tmp_path):
    """bench.results_lever.principal_point_off_centre: a render moved by half a pixel or more is off the centre, a
    centred one is not (the KITTI slices, whose camera is, are checked by the report itself)."""
    from bench import results_lever as rl
    from deepslam.cli import main

    for name, pp, off in (("centred", None, False), ("moved", "47.5,21", True)):
        args = ["render", "--scene", "street", "--frames", "2", "--width", "96", "--no-flow", "--quiet",
                "--out", str(tmp_path / name)] + (["--principal-point", pp] if pp else [])
        assert main(args) == 0
        assert rl.principal_point_off_centre(tmp_path / name) is off


@pytest.mark.parametrize("env", [{}, {"SYNTH_FLOW": "dis"}, {"SCENE": "room"}])
def test_recipe_script_skip_synthetic_trains_the_supervised_models_only(tmp_path, env):
    """scripts/train_paper_recipe.sh with SKIP_SYNTHETIC=1 (``echo`` standing in for deepslam): on either flow and
    either scene every ``train`` it runs is a supervised one."""
    out = tmp_path / "recipe"
    script = Path(__file__).resolve().parents[1] / "scripts" / "train_paper_recipe.sh"
    p = subprocess.run(["bash", str(script), str(out), "1000", "0"], capture_output=True, text=True,
                       env={**os.environ, **env, "SKIP_SYNTHETIC": "1", "DS": "echo"})
    assert p.returncode == 0, p.stderr
    trains = [line for line in p.stdout.splitlines() if line.startswith("train ")]
    assert trains and all("--mode supervised" in line for line in trains)


def test_recipe_script_pp_crop_renders_wide_towns_and_trains_the_cropped_model_only(tmp_path):
    """scripts/train_paper_recipe.sh with PP_CROP=1 (``echo`` standing in for deepslam): the towns rendered 428 x 129 at
    the 414 px camera's focal length, one synthetic model cut to 640 x 193 windows with coordinate channels, named
    _ppcrop, and no supervised twin; refused on exact flow."""
    script = Path(__file__).resolve().parents[1] / "scripts" / "train_paper_recipe.sh"
    env = {**os.environ, "PP_CROP": "1", "SYNTH_FLOW": "dis", "DS": "echo"}
    p = subprocess.run(["bash", str(script), str(tmp_path / "r"), "1000", "0"], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    renders = [line for line in p.stdout.splitlines() if line.startswith("render ")]
    assert len(renders) == 2 and all("--width 428 --height 129 --focal-px 238.98138297872342" in r for r in renders)
    assert all("lever_wide_train_s" in r for r in renders)
    trains = [line for line in p.stdout.splitlines() if line.startswith("train ")]
    assert len(trains) == 1 and "--crop-window 640,193 --coord-channels" in trains[0]
    assert "_mirrorframes_ppcrop_cons_s0" in trains[0] and "--mode synthetic" in trains[0]
    p = subprocess.run(["bash", str(script), str(tmp_path / "x"), "1000", "0"], capture_output=True, text=True,
                       env={**env, "SYNTH_FLOW": "exact"})
    assert p.returncode == 2 and "PP_CROP=1 is for SCENE=street with SYNTH_FLOW=dis" in p.stderr
