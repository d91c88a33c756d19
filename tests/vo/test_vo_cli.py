"""``deepslam vo`` end to end on a tiny rendered sequence, with a tiny model trained here on toy flows."""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from deepslam import cli
from deepslam.core import se3, trajio
from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.core.se3 import chain, chain_euler6
from deepslam.vo.infer import VOPredictor
from deepslam.vo.modelfiles import models
from deepslam.vo.odometry import load_shipped, resolve_predictor

REPO = Path(__file__).resolve().parents[2]


def _vo(*args):
    from deepslam.cli import main

    return main(["vo", *map(str, args)])


def test_vo_cli_writes_trajectory_motions_and_metrics(plane_sequence, street_model, tmp_path, capsys):
    out = tmp_path / "traj.txt"
    assert _vo("--sequence", plane_sequence, "--model", street_model, "--out", out, "--flow", "gt", "--quiet") == 0
    text = capsys.readouterr().out
    assert "ATE" in text and "RPE" in text
    seq = open_sequence(plane_sequence)
    est = trajio.read_trajectory(out, "tum")
    assert len(est) == len(seq) == 12
    np.testing.assert_allclose(est.timestamps_s, seq.timestamps_s)
    np.testing.assert_allclose(est.world_from_cam[0], np.eye(4), atol=1e-12)
    rows = (tmp_path / "traj.motions.csv").read_text().splitlines()
    assert rows[0].startswith("i,j,t_i_s,t_j_s,ex_rad") and len(rows) == 12
    vals = np.array([[float(x) for x in r.split(",")] for r in rows[1:]])
    np.testing.assert_array_equal(vals[:, :2], np.stack([np.arange(11), np.arange(1, 12)], 1))
    assert (vals[:, 10:] > 0).all()
    # the trajectory is the chain of the CSV's motions
    np.testing.assert_allclose(chain_euler6(vals[:, 4:10])[:, :3, 3], est.positions, atol=1e-6)
    # and it follows the ground truth: 11 x 0.8 m forward
    gt_len = seq.gt.path_length_m()
    assert abs(est.path_length_m() - gt_len) < 0.25 * gt_len
    metrics = json.loads((tmp_path / "traj.metrics.json").read_text())
    assert metrics["ate_m"] < 0.15 * gt_len
    assert (tmp_path / "traj.png").is_file() and (tmp_path / "traj.config.json").is_file()


def test_vo_cli_dis_stride_and_kitti_format(plane_sequence, street_model, tmp_path):
    out = tmp_path / "traj.kitti"
    assert _vo("--sequence", plane_sequence, "--model", street_model, "--out", out, "--flow", "dis",
               "--format", "kitti", "--stride", "2", "--quiet") == 0
    est = trajio.read_trajectory(out, "kitti")
    assert len(est) == 6  # frames 0, 2, ..., 10
    assert len((tmp_path / "traj.motions.csv").read_text().splitlines()) == 6
    cfg = json.loads((tmp_path / "traj.config.json").read_text())
    assert cfg["stride"] == 2 and cfg["flow"] == "dis-medium"


def test_predict_pairs_matches_per_pair_predictions(plane_sequence, street_model):
    from deepslam.flow import registry as flow_registry

    seq = open_sequence(plane_sequence)
    pred = VOPredictor.from_file(street_model, bf16=False)
    pairs = [(0, 1), (3, 5), (2, 3)]
    mean, std = pred.predict_pairs(seq, pairs, flow_registry.make("gt"), progress=False)
    for k, (i, j) in enumerate(pairs):
        f, intr = pred.prepare(flow_registry.make("gt").pair_flow(seq, i, j), seq.camera)
        m1, s1 = pred.predict(f[None], intr[None])
        np.testing.assert_allclose(m1[0], mean[k], rtol=1e-5, atol=1e-7)
    odo = pred.as_odometry(flow_registry.make("gt"), progress=False)
    m2, _ = odo.predict(seq, pairs)
    np.testing.assert_array_equal(m2, mean)


def test_chain_inverts_relative_motions():
    rng = np.random.default_rng(0)
    world_from_cam = se3.from_euler6(np.cumsum(rng.normal(0, 0.1, (6, 6)), axis=0))
    world_from_cam = se3.inverse(world_from_cam[0]) @ world_from_cam
    rel = se3.relative(world_from_cam[1:], world_from_cam[:-1])  # cam_{k+1}_from_cam_k
    np.testing.assert_allclose(chain(rel), world_from_cam, atol=1e-12)


def test_bad_input_is_one_line_and_status_2(tmp_path, plane_sequence):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    r = subprocess.run([sys.executable, "-m", "deepslam", "vo", "--sequence", str(tmp_path / "nope"), "--out",
                        str(tmp_path / "t.txt")], cwd=REPO, env=env, capture_output=True, text=True)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert _vo("--sequence", plane_sequence, "--model", tmp_path / "missing.pt", "--out", tmp_path / "t.txt") == 2
    (tmp_path / "junk.pt").write_bytes(b"not a model")
    assert _vo("--sequence", plane_sequence, "--model", tmp_path / "junk.pt", "--out", tmp_path / "t.txt") == 2
    assert not (tmp_path / "t.txt").exists()


def test_shipped_model_names(monkeypatch, tmp_path, plane_sequence):

    monkeypatch.setattr(models, "models_dir", lambda: tmp_path)  # an empty models folder
    with pytest.raises(InputError, match="missing"):
        load_shipped("euroc", "loops")
    assert _vo("--sequence", plane_sequence, "--out", tmp_path / "t.txt", "--quiet") == 2
    seq = open_sequence(plane_sequence)
    assert models.kind_for_sequence(seq) == "kitti"  # scene "test-street-plane"

    assert models.shipped_path("kitti", "cons").name == "kitti_cons.safetensors"
    assert models.shipped_path("tum", "cons").name == "tum_cons.safetensors"
    with pytest.raises(InputError):
        models.shipped_path("lidar", "cons")
    with pytest.raises(InputError):
        models.shipped_path("kitti", "sometimes")


def test_shipped_models_follow_the_flow_estimator(monkeypatch, tmp_path, street_model):
    """A model trained on an estimator's flow (<kind>_<which>_dis.safetensors) is chosen for that estimator,
    the exact-flow model for ground-truth flow or where no variant is shipped."""
    import shutil

    from deepslam.flow import registry as flow_registry

    monkeypatch.setattr(models, "models_dir", lambda: tmp_path)
    shutil.copy(street_model, tmp_path / "kitti_cons.safetensors")
    shutil.copy(street_model, tmp_path / "kitti_cons_dis.safetensors")
    assert models.shipped_path("kitti", "cons", "dis").name == "kitti_cons_dis.safetensors"
    assert models.shipped_path("kitti", "cons", flow_registry.make("dis", preset="fast")).name == "kitti_cons_dis.safetensors"
    assert models.shipped_path("kitti", "cons", "gt").name == "kitti_cons.safetensors"
    assert models.shipped_path("kitti", "cons").name == "kitti_cons.safetensors"
    assert models.shipped_path("kitti", "loops", "dis").name == "kitti_loops.safetensors"   # no variant: the plain one
    assert models.shipped_path("kitti", "cons", "learned").name == "kitti_cons.safetensors"  # not (yet) shipped here
    shutil.copy(street_model, tmp_path / "kitti_cons_learned.safetensors")
    assert models.shipped_path("kitti", "cons", "learned").name == "kitti_cons_learned.safetensors"
    assert models.shipped_path("kitti", "cons", "dis").name == "kitti_cons_dis.safetensors"
    assert resolve_predictor("kitti", None, "cons", "dis").name == "kitti_cons_dis"
    assert resolve_predictor(str(tmp_path / "kitti_cons.safetensors"), None, "cons", "dis").name != "kitti_cons_dis"
    assert models.shipped_path("kitti", "cons", "learned-dis").name == "kitti_cons_dis.safetensors"
    shutil.copy(street_model, tmp_path / "kitti_cons_gt.safetensors")  # exact flow's own choice where shipped
    assert models.shipped_path("kitti", "cons", "gt").name == "kitti_cons_gt.safetensors"
    assert models.shipped_path("kitti", "loops", "gt").name == "kitti_loops.safetensors"
    assert models.shipped_path("kitti", "cons").name == "kitti_cons.safetensors"


def test_vo_runs_on_the_learned_flow_refined_by_dis(plane_sequence, tmp_path):
    """``--flow learned-dis`` with no model: the shipped DIS model reads it; the flow is recorded."""
    import json

    assert _vo("--sequence", plane_sequence, "--flow", "learned-dis", "--end", "5", "--out", tmp_path / "t.txt",
               "--quiet") == 0
    cfg = json.loads((tmp_path / "t.config.json").read_text())
    assert cfg["flow"] == "learned-dis" and cfg["model_name"] == "kitti_cons_dis"
    assert len([ln for ln in (tmp_path / "t.txt").read_text().splitlines() if not ln.startswith("#")]) == 5


def test_vo_picks_the_rgbd_model_for_a_tum_sequence(shared_data, tmp_path):
    """No flags: a TUM RGB-D folder gets the shipped tum_cons (640x480 hand-held cameras), and the
    metrics are scored on the frames the ground truth covers."""
    import json

    assert _vo("--sequence", shared_data / "tum" / "rgbd_dataset_freiburg3_teddy", "--end", "24",
               "--out", tmp_path / "t.txt", "--quiet") == 0
    cfg = json.loads((tmp_path / "t.config.json").read_text())
    assert cfg["model_name"] == "tum_cons" and cfg["model"] == "shipped:tum_cons"
    metrics = json.loads((tmp_path / "t.metrics.json").read_text())
    assert metrics["frames_scored"] < metrics["frames"] == 24  # the motion capture starts late


def test_vo_takes_an_ensemble_file(plane_sequence, street_model, tmp_path):
    """An ensemble of one network twice answers as that network (the members agree: no spread)."""
    from deepslam.cli import main

    ens = tmp_path / "ens.safetensors"
    assert main(["ensemble-model", str(street_model), str(street_model), "--out", str(ens)]) == 0
    for name, model in (("one", street_model), ("two", ens)):
        assert _vo("--sequence", plane_sequence, "--model", model, "--out", tmp_path / f"{name}.txt", "--flow", "gt",
                   "--bf16", "off", "--quiet") == 0
    one = np.loadtxt(tmp_path / "one.motions.csv", delimiter=",", skiprows=1)
    two = np.loadtxt(tmp_path / "two.motions.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(two[:, 4:], one[:, 4:], rtol=1e-5, atol=1e-7)
    cfg = json.loads((tmp_path / "two.config.json").read_text())
    assert cfg["model_name"] == "ens"


def test_run_vo_is_what_the_command_writes(plane_sequence, tmp_path):
    """The library entry gives the command's trajectory, and its range checks come before any flow."""
    from deepslam.cli import main
    from deepslam.vo.pipeline import VOConfig, run_vo

    seq = open_sequence(plane_sequence)
    res = run_vo(seq, VOConfig(flow="gt", pose="net", progress=False, stride=2))
    assert res.world_from_cam.shape == (len(res.frames), 4, 4) and res.pairs.shape == (len(res.frames) - 1, 2)
    assert main(["vo", "--sequence", str(plane_sequence), "--flow", "gt", "--pose", "net", "--stride", "2", "--quiet",
                 "--out", str(tmp_path / "t.txt")]) == 0
    written = trajio.read_trajectory(tmp_path / "t.txt")
    np.testing.assert_allclose(written.world_from_cam, res.world_from_cam, atol=1e-6)
    with pytest.raises(InputError, match="at least two frames"):
        run_vo(seq, VOConfig(start=len(seq) - 1))


def test_read_width_reads_small_frames_upsampled_with_the_camera_scaled(plane_sequence):
    from deepslam.vo.pipeline import UpsampledView, VOConfig, run_vo

    seq = open_sequence(plane_sequence)
    view = UpsampledView(seq, 2 * seq.camera.width)
    cam, big = seq.camera, view.camera
    assert view.image(0).shape[:2] == (big.height, big.width) == (2 * cam.height, 2 * cam.width)
    # the same ray through the same point of the image: pixel centres kept
    assert (big.fx, big.cx) == pytest.approx((2 * cam.fx, 2 * cam.cx + 0.5))
    assert len(view) == len(seq) and view.gt is seq.gt
    res = run_vo(seq, VOConfig(read_width_px=2 * seq.camera.width, progress=False, stride=3))
    assert res.record["read_at_px"] == [big.width, big.height] and np.isfinite(res.world_from_cam).all()
    exact = run_vo(seq, VOConfig(flow="gt", read_width_px=2 * seq.camera.width, progress=False, stride=3))
    assert "read_at_px" not in exact.record  # the stored flow is at the recorded size


def test_slam_reads_small_frames_as_the_network_does_and_plugins_as_recorded(plane_sequence, tmp_path):
    from deepslam.slam.plugins import OdometryOptions, network_view
    from deepslam.vo.pipeline import UpsampledView

    seq = open_sequence(plane_sequence)
    wide = 2 * seq.camera.width
    view = network_view(OdometryOptions(read_width_px=wide), seq)
    assert isinstance(view, UpsampledView) and view.camera.width == wide
    assert network_view(OdometryOptions(read_width_px=0), seq) is seq                    # 0: as recorded
    assert network_view(OdometryOptions(), seq).camera.width == 640                       # the default: 640 px
    assert network_view(OdometryOptions(read_width_px=wide, odometry="pnp"), seq) is seq  # a plug-in: as recorded
    assert network_view(OdometryOptions(read_width_px=wide, flow="gt"), seq) is seq      # stored flow: its own size
    with pytest.raises(InputError, match="--read-width must be in"):
        network_view(OdometryOptions(read_width_px=10 ** 6), seq)
    out = tmp_path / "slam.txt"
    assert cli.main(["slam", "--sequence", str(plane_sequence), "--out", str(out), "--no-loops", "--quiet",
                     "--read-width", str(wide)]) == 0
    assert json.loads((tmp_path / "slam.json").read_text())["read_at_px"] == [wide, 2 * seq.camera.height]


def test_centring_the_principal_point_is_recorded_and_moves_an_off_centre_cameras_reading(plane_sequence):
    """`vo --centre-principal-point` records that it centred; on this fixture, whose principal point lies 12 px above
    the image's centre, the network reads other flows (a centred camera's are read unchanged:
    tests/flow/test_estimators.py)."""
    from deepslam.vo.pipeline import VOConfig, run_vo

    seq = open_sequence(plane_sequence)
    assert seq.camera.cy != (seq.camera.height - 1) / 2
    plain = run_vo(seq, VOConfig(flow="gt", pose="net", progress=False, end=6))
    centred = run_vo(seq, VOConfig(flow="gt", pose="net", progress=False, end=6, centre_principal_point=True))
    assert centred.record["centre_principal_point"] and not plain.record["centre_principal_point"]
    assert np.isfinite(centred.mean6).all() and not np.array_equal(centred.mean6, plain.mean6)


def test_slam_and_calibrate_take_the_centring_flag_to_both_networks(plane_sequence, tmp_path):
    from deepslam.commands import _odometry_flags
    from deepslam.slam.plugins import OdometryOptions, odometries

    seq = open_sequence(plane_sequence)
    cons, loops = odometries(OdometryOptions(centre_principal_point=True), seq)
    assert cons.predictor.centre_principal_point and loops.predictor.centre_principal_point
    cons, _ = odometries(OdometryOptions(no_loops=True), seq)
    assert not cons.predictor.centre_principal_point
    p = argparse.ArgumentParser()
    _odometry_flags.add_arguments(p)
    for flag in ("--model-cons", "--model-loops", "--flow", "--pose"):
        p.add_argument(flag, default=None)
    args = p.parse_args(["--centre-principal-point", "--flow", "dis"])
    args.quiet = args.json = False
    assert _odometry_flags.options(args).centre_principal_point
    out = tmp_path / "cal.safetensors"
    assert cli.main(["calibrate", "kitti", "--sequence", str(plane_sequence), "--out", str(out), "--flow", "gt",
                     "--pose", "net", "--centre-principal-point", "--quiet"]) == 0 and out.is_file()


def test_slam_widens_the_consecutive_pairs_std_by_the_geometry_as_vo_does(plane_sequence):
    from deepslam.slam.plugins import OdometryOptions, odometries
    from deepslam.vo.pipeline import VOConfig, run_vo

    seq = open_sequence(plane_sequence)
    cons, loops = odometries(OdometryOptions(std_from_geometry=True, pose="net"), seq)
    assert cons.geometry is not None and loops.geometry is None
    pairs = np.array([(i, i + 1) for i in range(5)])
    mean6, std6 = cons.predict(seq, pairs)
    want = run_vo(seq, VOConfig(pose="net", std_from_geometry=True, progress=False, end=6, read_width_px=0))
    np.testing.assert_allclose(mean6, want.mean6, rtol=1e-9)
    np.testing.assert_allclose(std6, want.std6, rtol=1e-9)


def test_the_mirror_average_is_recorded_and_reaches_both_networks_of_the_slam(plane_sequence):
    from deepslam.commands import _odometry_flags
    from deepslam.slam.plugins import OdometryOptions, odometries
    from deepslam.vo.pipeline import VOConfig, run_vo

    seq = open_sequence(plane_sequence)
    plain = run_vo(seq, VOConfig(flow="gt", pose="net", progress=False, end=6))
    both = run_vo(seq, VOConfig(flow="gt", pose="net", progress=False, end=6, mirror_average="on"))
    assert both.record["mirror_average"] and not plain.record["mirror_average"]
    assert np.isfinite(both.mean6).all() and not np.array_equal(both.mean6, plain.mean6)
    cons, loops = odometries(OdometryOptions(mirror_average="on"), seq)
    assert cons.predictor.mirror_average and loops.predictor.mirror_average
    p = argparse.ArgumentParser()
    _odometry_flags.add_arguments(p)
    for flag in ("--model-cons", "--model-loops", "--flow", "--pose"):
        p.add_argument(flag, default=None)
    args = p.parse_args(["--mirror-average", "auto", "--flow", "dis"])
    args.quiet = args.json = False
    assert _odometry_flags.options(args).mirror_average == "auto"
