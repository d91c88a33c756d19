"""Motion models (the paper's Student-t per DoF, the joint KDE): fit on KITTI ground truth, samples vs data, JSON, loops, the CLI."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.trajectory import Trajectory
from deepslam.cli import main
from deepslam.gen.motion import (DOF_NAMES, KdeSix, LoopConfig, MotionModel, StudentT, fit_motion, fit_six,
                                 fit_student_t, ks_statistics, loop_motions, relative_vectors)


@pytest.fixture(scope="module")
def kitti_fit(shared_data):
    """Consecutive motions of all of KITTI 00-10; loops of 00 and 05 (the sequences that revisit)."""
    from deepslam.core.trajio import read_trajectory

    trajs = [read_trajectory(shared_data / "kitti" / "poses" / f"{k:02d}.txt") for k in range(11)]
    model, vec, _ = fit_motion(trajs, 1)
    loop_model, _, loop_vec = fit_motion([trajs[0], trajs[5]], 1, loops=True)
    model = MotionModel(1, model.consecutive, loop_model.loop, loop_model.loop_config, ("kitti",))
    return model, vec, loop_vec, trajs


def test_fit_on_kitti_samples_match_the_data(kitti_fit):
    model, vec, _, _ = kitti_fit
    assert vec.shape == (23190, 6)  # 4541 + 1101 + ... + 1201 poses, minus one per sequence
    # Forward motion: points move backwards in the camera (t_z of cam1_from_cam0 < 0), about 1 m/frame.
    assert -1.2 < model.consecutive.dofs[5].loc < -0.7
    samples = model.consecutive.sample(20_000, np.random.default_rng(0))
    for k, name in enumerate(DOF_NAMES):
        ks = stats.ks_2samp(vec[:, k], samples[:, k]).statistic
        assert ks < 0.06, (name, ks)
        q_data = np.quantile(vec[:, k], [0.05, 0.25, 0.5, 0.75, 0.95])
        q_samp = np.quantile(samples[:, k], [0.05, 0.25, 0.5, 0.75, 0.95])
        spread = q_data[-1] - q_data[0]
        # Worst case: t_z's 5 % quantile (-1.71 m sampled vs -1.50 m in the data): KITTI 01's highway
        # speeds make a second mode that one Student-t cannot follow.
        assert np.all(np.abs(q_samp - q_data) < 0.2 * spread), (name, q_data, q_samp)
        assert samples[:, k].min() >= model.consecutive.dofs[k].lo and samples[:, k].max() <= model.consecutive.dofs[k].hi
    # One-sample KS of the data against the fitted densities is small too.
    assert np.all(ks_statistics(model.consecutive, vec) < 0.05)


def test_a_wrong_model_fails_the_same_check(kitti_fit):
    """The check above can fail: samples of a model fitted to stride 5 do not match stride-1 data."""
    model, vec, _, trajs = kitti_fit
    model5, _, _ = fit_motion(trajs[3:5], 5)
    samples = model5.consecutive.sample(20_000, np.random.default_rng(0))
    assert stats.ks_2samp(vec[:, 5], samples[:, 5]).statistic > 0.3


def test_loop_distribution_on_kitti(kitti_fit):
    model, _, loop_vec, trajs = kitti_fit
    assert model.loop is not None and loop_vec is not None and len(loop_vec) > 10_000
    cfg = model.loop_config
    assert np.all(np.linalg.norm(loop_vec[:, 3:], axis=1) < cfg.max_distance_m)
    rel = se3.from_euler6(loop_vec)
    assert np.all(np.degrees(se3.rotation_angle(rel)) < cfg.max_angle_deg)
    # Both orders are present: translations are symmetric about zero.
    assert abs(np.median(loop_vec[:, 5])) < 0.5
    vec, is_loop = model.sample(2000, np.random.default_rng(1), loop_fraction=0.25)
    assert 0.2 < is_loop.mean() < 0.3
    assert np.abs(vec[is_loop, 5]).mean() > 3 * np.abs(vec[~is_loop, 5] - vec[~is_loop, 5].mean()).mean()


def test_loop_motions_known_answer():
    """A square path driven twice: frame i and i + 40 are the same pose -> identity loop motions."""
    n = 80
    t = np.arange(n) % 40
    pos = np.stack([np.cos(2 * np.pi * t / 40) * 20, np.zeros(n), np.sin(2 * np.pi * t / 40) * 20], axis=1)
    yaw = -2 * np.pi * t / 40
    rot = np.stack([se3.from_euler6([0, y, 0, 0, 0, 0])[:3, :3] for y in yaw])
    traj = Trajectory(se3.from_rt(rot, pos))
    rel = loop_motions(traj, LoopConfig(min_gap_frames=30, max_distance_m=1.0, max_angle_deg=10))
    assert len(rel) == 2 * 40
    np.testing.assert_allclose(rel, np.broadcast_to(np.eye(4), rel.shape), atol=1e-9)
    assert len(loop_motions(traj, LoopConfig(min_gap_frames=50, max_distance_m=1.0))) == 0


def test_relative_vectors_and_fit_student_t_known_answer():
    rng = np.random.default_rng(2)
    x = stats.t.rvs(4.0, 0.5, 0.2, size=20_000, random_state=rng)
    d = fit_student_t(x)
    assert d.df == pytest.approx(4.0, rel=0.15) and d.loc == pytest.approx(0.5, abs=0.01)
    assert d.scale == pytest.approx(0.2, rel=0.05) and d.lo == x.min() and d.hi == x.max()
    poses = se3.from_euler6(np.cumsum(np.tile([0, 0.01, 0, 0, 0, 1.0], (5, 1)), axis=0))
    vec = relative_vectors([Trajectory(poses)], 2)
    assert vec.shape == (3, 6)
    np.testing.assert_allclose(se3.from_euler6(vec), se3.relative(poses[2:], poses[:-2]), atol=1e-12)
    with pytest.raises(ValueError):
        fit_student_t(np.ones(100))


def test_plain_loop_fit_is_scipys_and_is_recorded(kitti_fit, tmp_path):
    """``loop_fit="plain"`` keeps scipy's plain t (narrower than the data where they fill their range:
    the loop pairs' forward offset); the file says which fit it holds, and an unknown one is refused."""
    _, _, loop_vec, trajs = kitti_fit
    plain, _, vec = fit_motion([trajs[0], trajs[5]], 1, loops=True, loop_fit="plain")
    np.testing.assert_array_equal(vec, loop_vec)
    df, loc, scale = stats.t.fit(loop_vec[:, 5])
    assert plain.loop.dofs[5] == StudentT(df, loc, scale, loop_vec[:, 5].min(), loop_vec[:, 5].max())
    assert plain.loop.dofs[5].scale < fit_student_t(loop_vec[:, 5]).scale
    assert plain.loop_fit == "plain" and plain.to_dict()["loop"]["fit"] == "plain"
    back = MotionModel.load(plain.save(tmp_path / "plain.json"))
    assert back == plain
    d = plain.to_dict()
    d["loop"]["fit"] = "guess"
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match="loop.fit must be one of"):
        MotionModel.load(tmp_path / "bad.json")
    with pytest.raises(ValueError, match="fit must be one of"):
        fit_student_t(loop_vec[:, 5], "guess")


def test_sampling_is_scipy_rvs_and_deterministic():
    d = StudentT(2.5, 0.1, 0.3, -1e9, 1e9)
    a = d.sample(500, np.random.default_rng(5))
    b = stats.t.rvs(2.5, 0.1, 0.3, size=500, random_state=np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    narrow = StudentT(1.0, 0.0, 1.0, -0.5, 0.5)
    s = narrow.sample(5000, np.random.default_rng(6))
    assert s.min() >= -0.5 and s.max() <= 0.5


def test_json_round_trip(kitti_fit, tmp_path):
    model = kitti_fit[0]
    path = model.save(tmp_path / "m.json")
    back = MotionModel.load(path)
    assert back == model
    v1, l1 = model.sample(10, np.random.default_rng(3), 0.5)
    v2, l2 = back.sample(10, np.random.default_rng(3), 0.5)
    np.testing.assert_array_equal(v1, v2)
    np.testing.assert_array_equal(l1, l2)


@pytest.mark.parametrize("edit,what", [
    (lambda d: d.pop("consecutive"), "missing key 'consecutive'"),
    (lambda d: d["consecutive"]["dofs"].pop("t_z"), "missing key 't_z'"),
    (lambda d: d["consecutive"]["dofs"]["t_x"].pop("scale"), "missing key 'scale'"),
    (lambda d: d["consecutive"]["dofs"]["t_x"].__setitem__("scale", -0.1), "scale must be > 0"),
    (lambda d: d["consecutive"]["dofs"]["t_x"].__setitem__("df", 0), "df must be > 0"),
    (lambda d: d["consecutive"]["dofs"]["euler_y"].__setitem__("loc", math.nan), "finite number"),
    (lambda d: d["consecutive"]["dofs"]["euler_y"].__setitem__("loc", "0.1"), "finite number"),
    (lambda d: d["consecutive"]["dofs"]["euler_y"].__setitem__("lo", 5.0), "lo must be below hi"),
    (lambda d: d.__setitem__("stride", 0), "stride"),
    (lambda d: d.__setitem__("format", "something"), "format"),
    (lambda d: d["loop"].pop("max_distance_m"), "missing key 'max_distance_m'"),
    (lambda d: d["consecutive"]["dofs"]["t_z"].update(lo=-1e300, hi=1e300), "beyond 1000 m"),
    (lambda d: d["consecutive"]["dofs"]["euler_x"].__setitem__("scale", 7.0), "beyond 3.14159 rad"),
])
def test_malformed_json_names_the_file(kitti_fit, tmp_path, edit, what):
    d = kitti_fit[0].to_dict()
    edit(d)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))  # json writes NaN as a bare NaN literal, which json.loads accepts
    with pytest.raises(InputError) as e:
        MotionModel.load(path)
    assert str(path) in str(e.value) and what in str(e.value)


def test_not_json_and_missing_file(tmp_path):
    bad = tmp_path / "x.json"
    bad.write_text('{"format": "deepslam-motion",\n  oops}')
    with pytest.raises(InputError, match=r"x.json:2: malformed motion model: not JSON"):
        MotionModel.load(bad)
    with pytest.raises(InputError, match="missing"):
        MotionModel.load(tmp_path / "absent.json")


def test_cli_fit_motion(shared_data, tmp_path, capsys):
    poses = [str(shared_data / "kitti" / "poses" / f"{k:02d}.txt") for k in (4, 6)]
    out = tmp_path / "motion.json"
    png = tmp_path / "fig3.png"
    assert main(["fit-motion", "--poses", *poses, "--stride", "2", "--out", str(out), "--loops",
                 "--plot", str(png), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    model = MotionModel.load(out)
    assert model.stride == 2 and model.loop is not None and model.sources == ("04.txt", "06.txt")
    assert summary["num_motions"] == (271 - 2) + (1101 - 2)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    # Bad input: one line, exit 2.
    bad = tmp_path / "bad.txt"
    bad.write_text("1 0 0 0 0 1 0 0 0 0 1\n")
    assert main(["fit-motion", "--poses", str(bad), "--out", str(tmp_path / "m2.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.txt" in err[0]
    assert main(["fit-motion", "--poses", poses[0], "--loops", "--loop-gap", "5000", "--out", str(tmp_path / "m3.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "loop motions" in err[0]


# ------------------------------------------------------------------------------------ the joint KDE model

@pytest.fixture(scope="module")
def kitti_kde(shared_data):
    """KDE of KITTI 00-05 and 08-10 (what models/motion/kitti_no0607_kde.json holds) and its data."""
    from deepslam.core.trajio import read_trajectory

    trajs = [read_trajectory(shared_data / "kitti" / "poses" / f"{k:02d}.txt") for k in (0, 1, 2, 3, 4, 5, 8, 9, 10)]
    model, vec, _ = fit_motion(trajs, 1, consecutive_kind="kde")
    return model, vec


def test_kde_keeps_what_the_dofs_do_together(kitti_kde):
    """The KDE draws the marginals as the data has them AND the turning camera's sideways slide
    (t_x with yaw); the paper's independent Student-t reproduce the marginals but lose the slide."""
    model, vec = kitti_kde
    assert isinstance(model.consecutive, KdeSix) and model.consecutive.num_motions == len(vec) == 20990
    draws = model.consecutive.sample(20_000, np.random.default_rng(0))
    for k, name in enumerate(DOF_NAMES):
        assert stats.ks_2samp(vec[:, k], draws[:, k]).statistic < 0.03, name
        assert model.consecutive.lo[k] <= draws[:, k].min() and draws[:, k].max() <= model.consecutive.hi[k]
    assert np.all(ks_statistics(model.consecutive, vec) < 0.03)
    r_data = np.corrcoef(vec[:, 1], vec[:, 3])[0, 1]
    r_kde = np.corrcoef(draws[:, 1], draws[:, 3])[0, 1]
    t_draws = fit_six(vec).sample(20_000, np.random.default_rng(0))
    r_t = np.corrcoef(t_draws[:, 1], t_draws[:, 3])[0, 1]
    assert r_data > 0.45 and abs(r_kde - r_data) < 0.03 and abs(r_t) < 0.05, (r_data, r_kde, r_t)
    # In turns (|yaw| > 0.02 rad a frame) the slide per radian of yaw is the data's.
    turn = np.abs(draws[:, 1]) > 0.02
    turn_data = np.abs(vec[:, 1]) > 0.02
    assert abs(np.median(draws[turn, 3] / draws[turn, 1]) - np.median(vec[turn_data, 3] / vec[turn_data, 1])) < 0.05
    # The jitter is small against each DoF's spread: draws do not repeat the data, nor blur it.
    assert np.all(model.consecutive.bandwidth < 0.2 * vec.std(axis=0))
    assert len(np.unique(draws[:, 5])) == len(draws)


def test_kde_json_round_trip_and_same_draws(kitti_kde, tmp_path):
    model = kitti_kde[0]
    path = model.save(tmp_path / "m.json")
    text = path.read_text()
    assert len(text) < 120 * model.consecutive.num_motions  # one motion a line, not one number a line
    back = MotionModel.load(path)
    np.testing.assert_array_equal(back.consecutive.motions, model.consecutive.motions)
    np.testing.assert_array_equal(back.consecutive.bandwidth, model.consecutive.bandwidth)
    v1, _ = model.sample(50, np.random.default_rng(3))
    v2, _ = back.sample(50, np.random.default_rng(3))
    np.testing.assert_array_equal(v1, v2)
    v3, _ = back.sample(50, np.random.default_rng(4))
    assert not np.array_equal(v1, v3)


@pytest.mark.parametrize("edit,what", [
    (lambda c: c.__setitem__("kind", "gmm"), "consecutive.kind must be"),
    (lambda c: c.__setitem__("motions", []), "non-empty list"),
    (lambda c: c.__setitem__("motions", [[0.0] * 5] * 3), "shape"),
    (lambda c: c.__setitem__("motions", [[0.0] * 6, ["a"] * 6]), "list of [6 numbers]"),
    (lambda c: c["motions"][2].__setitem__(4, math.inf), "motions[2] holds a non-finite value"),
    (lambda c: c.__setitem__("num_motions", 7), "but 30 motions are stored"),
    (lambda c: c["bandwidth"].__setitem__("t_z", 0.0), "bandwidth.t_z must be > 0"),
    (lambda c: c["bandwidth"].pop("t_x"), "bandwidth.t_x must be a finite number"),
    (lambda c: c.pop("lo"), "missing key 'lo'"),
    (lambda c: c["hi"].__setitem__("euler_y", -1.0), "lo must be below hi"),
    (lambda c: c["motions"][0].__setitem__(0, 9.0), "beyond 3.14159 rad"),
])
def test_malformed_kde_names_the_file(tmp_path, edit, what):
    from deepslam.gen.motion import fit_kde

    rng = np.random.default_rng(0)
    vec = rng.normal(0, 0.01, (30, 6)) + np.array([0, 0, 0, 0, 0, -1.0])
    d = MotionModel(1, fit_kde(vec)).to_dict()
    edit(d["consecutive"])
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(d))
    with pytest.raises(InputError) as e:
        MotionModel.load(path)
    assert str(path) in str(e.value) and what in str(e.value)


def test_cli_fit_motion_kde(shared_data, tmp_path, capsys):
    poses = [str(shared_data / "kitti" / "poses" / f"{k:02d}.txt") for k in (4, 6)]
    out, png = tmp_path / "kde.json", tmp_path / "kde.png"
    assert main(["fit-motion", "--poses", *poses, "--consecutive", "kde", "--out", str(out), "--plot", str(png),
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["consecutive_kind"] == "kde" and set(summary["consecutive"]["t_z"]) == {"bandwidth", "ks"}
    model = MotionModel.load(out)
    assert isinstance(model.consecutive, KdeSix) and model.consecutive.num_motions == 270 + 1100
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_kde_speed_scale_frees_the_turn_radius(tmp_path):
    """A route that takes every corner on one arc: the plain KDE's draws keep its one yaw-per-metre; with a speed
    scale the translation (forward and the sideways slide alike) is scaled by a log-uniform factor in [lo, hi],
    the rotation untouched, so a turn keeps its chord direction (slide / forward) at another radius; the scale
    survives the JSON and the draws are the same for the same seed."""
    from deepslam.gen.motion import fit_kde

    rng = np.random.default_rng(0)
    yaw = np.concatenate([np.zeros(200), np.full(100, 0.05)]) + rng.normal(0, 1e-4, 300)
    forward = 0.6 + rng.normal(0, 0.01, 300)
    vec = np.zeros((300, 6))
    vec[:, 1], vec[:, 5], vec[:, 3] = yaw, forward, -0.5 * yaw * forward  # the chord: half the heading change
    vec[:, [0, 2, 4]] = rng.normal(0, 1e-4, (300, 3))
    plain = fit_kde(vec).sample(5000, np.random.default_rng(1))
    scaled_model = fit_kde(vec, speed_scale=(0.4, 1.5))
    scaled = scaled_model.sample(5000, np.random.default_rng(1))
    turn_p, turn_s = plain[:, 1] > 0.04, scaled[:, 1] > 0.04
    ratio_p, ratio_s = plain[turn_p, 1] / plain[turn_p, 5], scaled[turn_s, 1] / scaled[turn_s, 5]
    assert np.ptp(np.percentile(ratio_p, [5, 95])) < 0.02  # one radius (0.083 rad/m), up to the KDE's jitter
    assert np.percentile(ratio_s, 5) < 0.06 and np.percentile(ratio_s, 95) > 0.15  # 0.055-0.21 rad/m
    # the factor: log-uniform in [0.4, 1.5] (forward / the KDE's forward, up to its small jitter)
    f = scaled[:, 5] / 0.6
    assert 0.38 < f.min() < 0.45 and 1.4 < f.max() < 1.58 and abs(np.median(np.log(f)) - np.log(np.sqrt(0.6))) < 0.05
    # the chord direction is kept: slide / forward against yaw as in the data
    chord_s = np.median(scaled[turn_s, 3] / scaled[turn_s, 5])
    assert abs(chord_s - np.median(plain[turn_p, 3] / plain[turn_p, 5])) < 1e-3 and abs(chord_s + 0.025) < 2e-3
    np.testing.assert_array_equal(np.sort(scaled[:, 1]), np.sort(plain[:, 1]))  # rotations as without the scale
    back = MotionModel.load(MotionModel(1, scaled_model).save(tmp_path / "s.json"))
    assert back.consecutive.speed_scale == (0.4, 1.5)
    np.testing.assert_array_equal(back.sample(40, np.random.default_rng(2))[0], scaled_model.sample(40, np.random.default_rng(2)))
    for bad in ([0.4], [1.5, 0.4], [0.0, 1.0], [0.4, math.inf], ["a", 1.0]):
        d = MotionModel(1, scaled_model).to_dict()
        d["consecutive"]["speed_scale"] = bad
        (tmp_path / "bad.json").write_text(json.dumps(d))
        with pytest.raises(InputError, match="speed_scale must be"):
            MotionModel.load(tmp_path / "bad.json")


def _arc_camera_motion(radius_m: float, yaw_rad: float, lever_m: float) -> np.ndarray:
    """Paper vector of ``cam_j_from_cam_i`` for a camera ``lever_m`` ahead of a rear axle that drives an arc of
    ``radius_m`` turning by ``yaw_rad`` (camera axes: x right, y down, z forward)."""
    world_from_axle_j = se3.from_rt(se3.from_euler6([0, yaw_rad, 0, 0, 0, 0])[:3, :3],
                                    [radius_m * (1 - math.cos(yaw_rad)), 0, radius_m * math.sin(yaw_rad)])
    axle_from_cam = se3.from_rt(np.eye(3), [0, 0, lever_m])
    return se3.to_euler6(se3.relative(world_from_axle_j @ axle_from_cam, axle_from_cam))


def test_kde_speed_scale_with_a_lever_scales_the_axle_and_keeps_the_slide(tmp_path):
    """A camera 0.84 m ahead of the rear axle slides sideways into a turn by the lever times the turn, at any
    speed. Scaling the whole translation (``lever_m`` 0) draws that slide scaled too; with ``lever_m`` the factor
    scales the axle's arc only: the motion scaled by k is the camera's on the arc k times as wide (known answer),
    and every draw's translation less the lever's slide points along the axle's chord; the lever survives the JSON,
    and a lever without a speed scale, or out of range, is refused."""
    from deepslam.gen.motion import fit_kde, lever_slide

    lever = 0.84
    v = _arc_camera_motion(12.0, 0.05, lever)
    for k in (0.4, 1.5):
        slide = lever_slide(v[None], lever)[0]
        np.testing.assert_allclose((v[3:] - slide) * k + slide, _arc_camera_motion(12.0 * k, 0.05, lever)[3:],
                                   atol=1e-12)
    assert not np.allclose(v[3:] * 0.4, _arc_camera_motion(4.8, 0.05, lever)[3:], atol=1e-3)  # plain scaling is not
    rng = np.random.default_rng(0)
    vec = np.array([_arc_camera_motion(r, y, lever) for r, y in zip(rng.uniform(10, 14, 300),
                                                                     rng.choice([0.0, 0.05], 300))])
    vec[:, [0, 2, 4]] = rng.normal(0, 1e-4, (300, 3))
    model = fit_kde(vec, speed_scale=(0.4, 1.5), lever_m=lever)
    draws = model.sample(3000, np.random.default_rng(1))
    turn = np.abs(draws[:, 1]) > 0.04
    assert turn.sum() > 1000
    axle = draws[turn, 3:] - lever_slide(draws[turn], lever)  # where camera i is seen from camera j: behind
    chord = np.arctan2(-axle[:, 0], -axle[:, 2])  # the axle's chord turns by half the heading change
    assert abs(np.mean(chord - draws[turn, 1] / 2)) < 0.003  # on average: each draw has the KDE's jitter
    plain = fit_kde(vec, speed_scale=(0.4, 1.5)).sample(3000, np.random.default_rng(1))
    axle_plain = plain[turn, 3:] - lever_slide(plain[turn], lever)
    assert np.mean(np.arctan2(-axle_plain[:, 0], -axle_plain[:, 2]) - plain[turn, 1] / 2) < -0.015
    back = MotionModel.load(MotionModel(1, model).save(tmp_path / "lever.json"))
    assert back.consecutive.lever_m == lever
    np.testing.assert_array_equal(back.sample(40, np.random.default_rng(2))[0], model.sample(40, np.random.default_rng(2)))
    with pytest.raises(ValueError, match="needs a speed_scale"):
        fit_kde(vec, lever_m=lever)
    for bad in (-0.1, 6.0, math.nan, "a"):
        d = MotionModel(1, model).to_dict()
        d["consecutive"]["lever_m"] = bad
        (tmp_path / "bad.json").write_text(json.dumps(d))
        with pytest.raises(InputError, match="lever_m must be"):
            MotionModel.load(tmp_path / "bad.json")


@pytest.mark.parametrize("flags,what", [(["--speed-scale", "0.4,1.5"], "needs --consecutive kde"),
                                        (["--consecutive", "kde", "--speed-scale", "1.5,0.4"], "LO <= HI"),
                                        (["--consecutive", "kde", "--speed-scale", "x"], "two numbers"),
                                        (["--consecutive", "kde", "--speed-scale-lever", "0.84"],
                                         "--speed-scale-lever needs --speed-scale"),
                                        (["--consecutive", "kde", "--speed-scale", "0.4,1.5", "--speed-scale-lever",
                                          "9"], "--speed-scale-lever must be")])
def test_cli_fit_motion_speed_scale_bad_input(shared_data, tmp_path, capsys, flags, what):
    out = tmp_path / "m.json"
    assert main(["fit-motion", "--poses", str(shared_data / "kitti" / "poses" / "04.txt"), "--out", str(out),
                 *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and what in err[0] and not out.exists()


def test_mirrored_vectors_are_the_motion_seen_in_a_mirror():
    """mirrored_vectors(v) is the paper vector of (S R S, S t), S = diag(-1, 1, 1), for any motion; fitting with
    mirror=True draws turns both ways as often from a route that turned one way."""
    from deepslam.core import se3
    from deepslam.gen.motion import mirrored_vectors

    rng = np.random.default_rng(0)
    vec = rng.normal(0, [0.05, 0.2, 0.05, 0.3, 0.1, 1.0], (50, 6))
    T = se3.from_euler6(vec)
    S = np.diag([-1.0, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(mirrored_vectors(vec), se3.to_euler6(S @ T @ S), atol=1e-12)
    np.testing.assert_array_equal(mirrored_vectors(mirrored_vectors(vec)), vec)
    # a route that turns one way (yaw >= 0): the mirrored fit has both signs, half each
    from deepslam.core.trajectory import Trajectory

    steps = rng.normal(0, 1e-4, (200, 6))
    steps[:, 5] += 0.6
    steps[100:, 1] += 0.05
    world_from_cam = [np.eye(4)]
    for m in se3.from_euler6(steps):
        world_from_cam.append(world_from_cam[-1] @ np.linalg.inv(m))
    traj = Trajectory(np.stack(world_from_cam), np.arange(201) * 0.1)
    plain, _, _ = fit_motion([traj], 1, consecutive_kind="kde")
    both, vec2, _ = fit_motion([traj], 1, consecutive_kind="kde", mirror=True)
    assert len(vec2) == 400
    y_plain = plain.consecutive.sample(4000, np.random.default_rng(1))[:, 1]
    y_both = both.consecutive.sample(4000, np.random.default_rng(1))[:, 1]
    assert (y_plain < -0.03).mean() == 0 and 0.4 < (y_plain > 0.03).mean() < 0.6
    assert 0.2 < (y_both < -0.03).mean() < 0.3 and 0.2 < (y_both > 0.03).mean() < 0.3


def test_kde_body_adds_the_pitch_and_roll_of_other_trajectories(shared_data, tmp_path, capsys):
    """A route driven without body motion (a simulated car: pitch and roll ~0) and KITTI's pitch and roll added
    (``--body-from``): the draws' pitch and roll are the KITTI data's (KS), every other DoF is drawn as without
    the body, the body survives the JSON with the same draws, and a malformed body names the file."""
    from deepslam.core.trajio import read_trajectory
    from deepslam.gen.motion import BODY_MAX_MOTIONS, fit_kde, relative_vectors, with_body

    rng = np.random.default_rng(0)
    vec = np.zeros((300, 6))
    vec[:, 1], vec[:, 5] = np.where(np.arange(300) < 200, 0.0, 0.05), 0.6 + rng.normal(0, 0.01, 300)
    vec[:, [0, 2, 3, 4]] = rng.normal(0, 1e-5, (300, 4))
    kitti = [read_trajectory(shared_data / "kitti" / "poses" / f"{k:02d}.txt") for k in (0, 8)]
    body_vec = relative_vectors(kitti, 1)
    plain = fit_kde(vec)
    model = with_body(plain, body_vec, ["00.txt", "08.txt"])
    assert len(model.body) == BODY_MAX_MOTIONS < len(body_vec) and model.body_sources == ("00.txt", "08.txt")
    draws, without = model.sample(20_000, np.random.default_rng(1)), plain.sample(20_000, np.random.default_rng(1))
    for k in (0, 2):
        assert stats.ks_2samp(draws[:, k], body_vec[:, k]).statistic < 0.03
        assert np.sqrt(np.mean(without[:, k] ** 2)) < 1e-4 < 1e-3 < np.sqrt(np.mean(draws[:, k] ** 2))
    np.testing.assert_array_equal(draws[:, [1, 3, 4, 5]], without[:, [1, 3, 4, 5]])
    back = MotionModel.load(MotionModel(1, model).save(tmp_path / "b.json"))
    np.testing.assert_array_equal(back.sample(40, np.random.default_rng(2))[0], model.sample(40, np.random.default_rng(2)))
    for edit, what in ((lambda b: b.__setitem__("motions", [[0.0, 0.0, 0.0]]), "pairs"),
                       (lambda b: b["motions"][3].__setitem__(0, 9.0), "within 3.14159 rad"),
                       (lambda b: b["bandwidth"].pop("euler_z"), "bandwidth must give")):
        d = MotionModel(1, model).to_dict()
        edit(d["consecutive"]["body"])
        (tmp_path / "bad.json").write_text(json.dumps(d))
        with pytest.raises(InputError, match=what) as e:
            MotionModel.load(tmp_path / "bad.json")
        assert str(tmp_path / "bad.json") in str(e.value)
    # the CLI: a student-t fit refuses it in one line, writing nothing
    out = tmp_path / "m.json"
    poses = str(shared_data / "kitti" / "poses" / "04.txt")
    assert main(["fit-motion", "--poses", poses, "--body-from", poses, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--body-from needs --consecutive kde" in err[0] and not out.exists()
    assert main(["fit-motion", "--poses", poses, "--consecutive", "kde", "--body-from", poses, "--out", str(out)]) == 0
    assert MotionModel.load(out).consecutive.body_sources == ("04.txt",)
