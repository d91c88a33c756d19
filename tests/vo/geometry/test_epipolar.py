"""vo.geometry.epipolar: rotation and direction of travel from the essential matrix of an exact flow, the distance
from the network; ``deepslam vo --pose epipolar`` end to end."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.vo.data.toy import flow_from_depth_np
from deepslam.vo.geometry import epipolar

KITTI_LIKE = PinholeCamera(1242, 375, 718.9, 718.9, 607.2, 185.2)
SLIDE_PER_YAW_PER_M = 0.88  # a turning car's sideways slide, as fitted on KITTI (studies.scale_sweep)


def street_depth(camera: PinholeCamera, half_width_m: tuple[float, float] = (4.0, 6.5), height_m: float = 1.65,
                 far_m: float = 60.0) -> np.ndarray:
    """(H, W) float32 depth_z of a street: a road ``height_m`` below the camera, facades ``half_width_m``
    to the left and right, a wall ``far_m`` ahead (OpenCV axes)."""
    g = camera.pixel_grid()
    dx, dy = (g[..., 0] - camera.cx) / camera.fx, (g[..., 1] - camera.cy) / camera.fy
    z = np.full(dx.shape, far_m)
    with np.errstate(divide="ignore"):
        for cand in (np.where(dy > 0, height_m / dy, np.inf), np.where(dx < 0, -half_width_m[0] / dx, np.inf),
                     np.where(dx > 0, half_width_m[1] / dx, np.inf)):
            z = np.minimum(z, cand)
    return z.astype(np.float32)


def car_motion(yaw_rad: float, forward_m: float, slide: bool = True, pitch_rad: float = 0.0) -> np.ndarray:
    """cam1_from_cam0 (4, 4) of a camera that moves ``forward_m`` and turns by ``yaw_rad``, sliding sideways
    as a car's camera does (t_x = 0.88 x yaw x forward, in camera 0's frame) when ``slide``."""
    t_x = SLIDE_PER_YAW_PER_M * yaw_rad * forward_m if slide else 0.0
    cam0_from_cam1 = se3.from_euler6(np.array([pitch_rad, yaw_rad, 0.0, t_x, 0.0, forward_m]))
    return se3.inverse(cam0_from_cam1)


def exact_flow(motion: np.ndarray, camera: PinholeCamera = KITTI_LIKE) -> np.ndarray:
    flow, valid = flow_from_depth_np(camera, street_depth(camera), motion)
    flow = flow.astype(np.float32)
    flow[~valid] = np.nan
    return flow


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


@pytest.mark.parametrize("yaw, forward, pitch", [
    (0.0, 1.0, 0.0),        # straight
    (0.04, 1.0, 0.0),       # left turn with the slide
    (-0.04, 0.5, 0.0),      # right turn, slow
    (0.01, 2.6, 0.0),       # highway
    (0.02, 0.8, 0.005),     # turning over a crest
])
def test_exact_flow_gives_the_rotation_and_the_direction_with_the_slide(yaw, forward, pitch):
    motion = car_motion(yaw, forward, pitch_rad=pitch)
    fit = epipolar.fit_essential(exact_flow(motion), KITTI_LIKE)
    assert fit.ok, fit.reason
    assert np.degrees(se3.rotation_angle(fit.cam1_from_cam0_rotation @ motion[:3, :3].T)) < 0.01
    assert angle_deg(fit.direction_cam1, motion[:3, 3]) < 0.1
    assert fit.inliers > 0.9 * fit.sampled


def test_the_slide_is_read_where_the_network_reads_yaw():
    """The slide is a shift of the direction of travel: with it and without it the fitted yaw is the same."""
    with_slide = epipolar.fit_essential(exact_flow(car_motion(0.04, 1.0, slide=True)), KITTI_LIKE)
    without = epipolar.fit_essential(exact_flow(car_motion(0.04, 1.0, slide=False)), KITTI_LIKE)
    yaw = [se3.to_euler6(se3.from_rt(f.cam1_from_cam0_rotation, np.zeros(3)))[1] for f in (with_slide, without)]
    assert abs(yaw[0] - yaw[1]) < 2e-5  # rad; the network's read differs by ~0.03 x 0.04 = 1.2e-3 here
    # cam1_from_cam0's t is -R t_slide: the direction's x moves by about the slide over the forward distance
    x_shift = with_slide.direction_cam1[0] / -with_slide.direction_cam1[2] - without.direction_cam1[0] / -without.direction_cam1[2]
    assert abs(abs(x_shift) - SLIDE_PER_YAW_PER_M * 0.04) < 2e-3


@pytest.mark.parametrize("motion, reason", [
    (np.eye(4), "parallax"),                                            # standing still
    (se3.inverse(se3.from_euler6(np.array([0.0, 0.03, 0.0, 0.0, 0.0, 0.0]))), "parallax"),  # turning on the spot
])
def test_no_parallax_leaves_the_pair_to_the_network(motion, reason):
    fit = epipolar.fit_essential(exact_flow(motion), KITTI_LIKE)
    assert not fit.ok and reason in fit.reason
    net = np.array([0.001, 0.03, 0.0, 0.0, 0.0, -0.01])
    fused, used = epipolar.fuse(net, fit)
    assert not used and np.array_equal(fused, net)


def _broken_flow() -> np.ndarray:
    """A flow no rigid motion explains: every vector drawn independently (DIS lost the motion)."""
    return np.random.default_rng(3).normal(0.0, 20.0, (KITTI_LIKE.height, KITTI_LIKE.width, 2)).astype(np.float32)


@pytest.mark.parametrize("flow, ok, rigid", [
    (lambda: exact_flow(car_motion(0.03, 1.0)), True, True),         # driving: fitted and used
    (lambda: exact_flow(np.eye(4)), False, True),                    # standing still: rigid, no direction to read
    (lambda: np.full((KITTI_LIKE.height, KITTI_LIKE.width, 2), np.nan, np.float32), False, False),  # no vectors
    (_broken_flow, False, False),                                    # vectors that fit no motion
])
def test_rigid_tells_a_flow_without_parallax_from_a_broken_one(flow, ok, rigid):
    fit = epipolar.fit_essential(flow(), KITTI_LIKE)
    assert (fit.ok, fit.rigid) == (ok, rigid)


def test_unknown_flow_leaves_the_pair_to_the_network():
    flow = np.full((KITTI_LIKE.height, KITTI_LIKE.width, 2), np.nan, np.float32)
    fit = epipolar.fit_essential(flow, KITTI_LIKE)
    assert not fit.ok and fit.sampled == 0 and "fewer than" in fit.reason


def test_flow_of_another_size_is_an_error():
    with pytest.raises(ValueError, match="flow must be"):
        epipolar.fit_essential(np.zeros((10, 20, 2), np.float32), KITTI_LIKE)


def test_fuse_keeps_the_network_distance_and_takes_the_fitted_rotation_and_direction():
    motion = car_motion(0.04, 1.0)
    fit = epipolar.fit_essential(exact_flow(motion), KITTI_LIKE)
    net = np.array([0.002, -0.05, -0.001, 0.0, 0.01, -1.3])  # rotation 0.6 deg off, direction off, distance 1.30004 m
    fused, used = epipolar.fuse(net, fit)
    assert used
    t = se3.from_euler6(fused)
    assert np.linalg.norm(t[:3, 3]) == pytest.approx(np.linalg.norm(net[3:]), rel=1e-12)
    np.testing.assert_allclose(t[:3, :3], fit.cam1_from_cam0_rotation, atol=1e-12)
    assert angle_deg(t[:3, 3], motion[:3, 3]) < 0.1
    # a network that reads the opposite direction of travel: the fit's sign is not trusted, the network's motion kept
    backward = np.r_[net[:3], -net[3:]]
    back, used = epipolar.fuse(backward, fit)
    assert not used and np.array_equal(back, backward)
    both, used_all = epipolar.fuse_all(np.stack([net, backward]), [fit, fit])
    assert used_all.tolist() == [True, False]
    with pytest.raises(ValueError, match="2 motions but 1"):
        epipolar.fuse_all(np.stack([net, backward]), [fit])


def test_same_flow_same_fit():
    flow = exact_flow(car_motion(0.02, 1.2))
    flow += np.random.default_rng(0).normal(0, 0.3, flow.shape).astype(np.float32)  # noise: RANSAC has work to do
    a, b = (epipolar.fit_essential(flow, KITTI_LIKE) for _ in range(2))
    assert a.ok and a.inliers == b.inliers
    assert np.array_equal(a.cam1_from_cam0_rotation, b.cam1_from_cam0_rotation)


def test_outliers_are_rejected():
    """A quarter of the vectors wrong (a moving car, a bad match): the fit holds."""
    motion = car_motion(-0.03, 1.0)
    flow = exact_flow(motion)
    flow[:, : KITTI_LIKE.width // 4] += np.float32(7.0)
    fit = epipolar.fit_essential(flow, KITTI_LIKE)
    assert fit.ok and fit.inliers < 0.85 * fit.sampled
    assert np.degrees(se3.rotation_angle(fit.cam1_from_cam0_rotation @ motion[:3, :3].T)) < 0.02


@pytest.mark.parametrize("bad", [dict(method="lmeds"), dict(grid_step_px=0), dict(threshold_px=0.0),
                                 dict(min_inliers=4), dict(confidence=1.0), dict(min_parallax_px=-1.0),
                                 dict(max_rotation_disagreement_deg=0.0)])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError):
        epipolar.EpipolarConfig(**bad)


# ------------------------------------------------------------------------------------- end to end (deepslam vo)

@pytest.fixture(scope="module")
def street_sequence(tmp_path_factory):
    """A 6-frame sequence (480 x 160) of the analytic street, turning and sliding, with its exact flow."""
    from deepslam.core.ours import OursWriter

    cam = PinholeCamera(480, 160, 280.0, 280.0, 239.5, 79.5)
    world_from_cam = [np.eye(4)]
    for k in range(5):
        world_from_cam.append(world_from_cam[-1] @ se3.inverse(car_motion(0.03 * (-1) ** k, 1.0)))
    root = tmp_path_factory.mktemp("street") / "seq"
    header = {"num_frames": 6, "rate_hz": 10.0, "camera": cam.to_dict(), "stereo_baseline_m": None,
              "scene": "test-street-analytic", "trajectory": "turns", "seed": 0, "backend": "numpy", "config": {},
              "has": {"rgb_right": False, "depth": True, "flow": True, "mask": False}}
    w = OursWriter(root, header)
    rng = np.random.default_rng(0)
    depth = street_depth(cam)  # the street moves with the camera: the same depth in every frame is enough here
    for i in range(6):
        flow = None
        if i < 5:
            flow, _ = flow_from_depth_np(cam, depth, se3.relative(world_from_cam[i + 1], world_from_cam[i]))
        w.write_frame(i, i / 10.0, world_from_cam[i], rng.integers(0, 255, (160, 480, 3), dtype=np.uint8),
                      depth=depth, flow=flow)
    w.finish()
    return root, world_from_cam


def test_vo_pose_epipolar_takes_the_rotation_from_the_flow(street_sequence, street_model, tmp_path):
    from tests.vo.test_vo_cli import _vo

    root, world_from_cam = street_sequence
    for pose in ("net", "epipolar"):
        assert _vo("--sequence", root, "--model", street_model, "--out", tmp_path / f"{pose}.txt",
                   "--flow", "gt", "--pose", pose, "--quiet") == 0
    cfg = json.loads((tmp_path / "epipolar.config.json").read_text())
    assert cfg["pose"] == "epipolar" and cfg["epipolar_pairs_used"] == 5 and cfg["epipolar"]["method"] == "usac_default"
    rows = {p: np.loadtxt(tmp_path / f"{p}.motions.csv", delimiter=",", skiprows=1) for p in ("net", "epipolar")}
    for k in range(5):
        true = se3.relative(world_from_cam[k + 1], world_from_cam[k])
        got = se3.from_euler6(rows["epipolar"][k, 4:10])
        assert np.degrees(se3.rotation_angle(got[:3, :3] @ true[:3, :3].T)) < 0.02
        assert angle_deg(got[:3, 3], true[:3, 3]) < 0.2
        # the distance and the std are the network's
        assert np.linalg.norm(rows["epipolar"][k, 7:10]) == pytest.approx(np.linalg.norm(rows["net"][k, 7:10]), rel=1e-9)
        np.testing.assert_array_equal(rows["epipolar"][k, 10:], rows["net"][k, 10:])


def test_vo_pose_epipolar_refuses_a_plugin(street_sequence, tmp_path, capsys):
    from tests.vo.test_vo_cli import _vo

    root, _ = street_sequence
    assert _vo("--sequence", root, "--odometry", "pnp", "--pose", "epipolar",
               "--out", tmp_path / "t.txt") == 2
    assert "--pose epipolar needs the network" in capsys.readouterr().err
    assert not (tmp_path / "t.txt").exists()


def test_slam_pose_epipolar_chains_the_same_motions_as_vo(street_sequence, street_model, tmp_path, capsys):
    from deepslam.cli import main
    from deepslam.core import trajio
    from tests.vo.test_vo_cli import _vo

    root, _ = street_sequence
    assert _vo("--sequence", root, "--model", street_model, "--out", tmp_path / "vo.txt", "--flow", "gt",
               "--pose", "epipolar", "--quiet") == 0
    capsys.readouterr()
    assert main(["slam", "--sequence", str(root), "--model-cons", str(street_model), "--flow", "gt", "--pose",
                 "epipolar", "--no-loops", "--out", str(tmp_path / "slam.txt"), "--json"]) == 0
    assert "pair/s" not in capsys.readouterr().err  # --json (and --quiet): no progress bar, the odometry's included
    vo = trajio.read_trajectory(tmp_path / "vo.txt", "tum")
    slam_vo = trajio.read_trajectory(tmp_path / "slam_vo.txt", "tum")  # our format: TUM rows by default
    np.testing.assert_allclose(slam_vo.positions, vo.positions, atol=1e-6)
    assert json.loads((tmp_path / "slam.json").read_text())["odometry_cons"].endswith("+epipolar")


def test_slam_pose_epipolar_refuses_a_plugin(street_sequence, tmp_path, capsys):
    from deepslam.cli import main

    root, _ = street_sequence
    assert main(["slam", "--sequence", str(root), "--odometry", "gt-noisy", "--pose", "epipolar",
                 "--out", str(tmp_path / "t.txt")]) == 2
    assert "--pose epipolar needs the network" in capsys.readouterr().err
    assert not (tmp_path / "t.txt").exists()


def test_a_fit_far_from_the_network_rotation_is_not_used():
    """Near standing still the essential matrix can decompose into a 180-degree twist: left to the network."""
    twisted = epipolar.EpipolarFit(True, se3.from_euler6(np.array([0.0, 0.0, np.pi, 0, 0, 0]))[:3, :3],
                                   np.array([0.0, 0.0, -1.0]), 900, 1000, 600.0)
    net = np.array([0.001, 0.006, 0.001, -0.001, 0.017, -0.08])
    fused, used = epipolar.fuse(net, twisted)
    assert not used and np.array_equal(fused, net)
    near = dataclasses.replace(twisted, cam1_from_cam0_rotation=se3.from_euler6(np.array([0.0, 0.03, 0, 0, 0, 0]))[:3, :3])
    assert epipolar.fuse(net, near)[1]  # 1.4 degrees from the network's: used
    assert not epipolar.fuse(net, near, epipolar.EpipolarConfig(max_rotation_disagreement_deg=1.0))[1]


@pytest.mark.parametrize("fit_yaw_deg,net_yaw_deg,used", [
    (9.0, 6.0, True),     # a corner taken fast: the network reads the turn 3 degrees short, the fit is kept
    (3.0, 2.7, True),
    (12.0, 1.0, False),   # more than the bound apart: the network's
    (180.0, 0.0, False),  # the twisted decomposition
])
def test_the_fits_rotation_is_kept_where_the_network_reads_a_turn_short(fit_yaw_deg, net_yaw_deg, used):
    fit = epipolar.EpipolarFit(True, se3.from_euler6(np.array([0.0, np.radians(fit_yaw_deg), 0, 0, 0, 0]))[:3, :3],
                               np.array([0.0, 0.0, -1.0]), 400, 700, 10.0)
    net = np.array([0.0, np.radians(net_yaw_deg), 0.0, 0.0, 0.0, -2.0])
    assert epipolar.fuse(net, fit)[1] is used


def test_set_pose_records_the_mode_vo_uses_without_a_flag(street_sequence, street_model, tmp_path, capsys):
    from deepslam.cli import main
    from deepslam.models import modelfile
    from deepslam.vo.modelfiles import models
    from deepslam.vo.modelfiles.modelio import MODEL_FORMAT
    from tests.vo.test_vo_cli import _vo

    root, _ = street_sequence
    marked = tmp_path / "marked.safetensors"
    assert main(["set-pose", str(street_model), "--pose", "epipolar", "--out", str(marked)]) == 0
    assert models.recorded_pose(street_model) == "net" and models.recorded_pose(marked) == "epipolar"
    # the same weights: only the meta changed
    w0, w1 = (modelfile.load(p, (MODEL_FORMAT,))[1] for p in (street_model, marked))
    assert {k: v for k, v in w1["meta"].items() if k != "pose"} == w0["meta"]
    from deepslam.vo.infer import VOPredictor

    s0, s1 = (VOPredictor.from_file(p).model.state_dict() for p in (street_model, marked))
    assert s0.keys() == s1.keys() and all(torch_equal(s0[k], s1[k]) for k in s0)
    for pose_flag, want in (([], "epipolar"), (["--pose", "net"], "net")):
        out = tmp_path / f"vo_{want}.txt"
        assert _vo("--sequence", root, "--model", marked, "--out", out, "--flow", "gt", "--quiet", *pose_flag) == 0
        assert json.loads(out.with_suffix(".config.json").read_text())["pose"] == want
    # a meta.pose that is not a mode: one line naming the file, exit 2, nothing written
    kind, tree = modelfile.load(marked, (MODEL_FORMAT,))
    bad = tmp_path / "bad.safetensors"
    modelfile.save(bad, kind, {**tree, "meta": {**tree["meta"], "pose": "sideways"}})
    capsys.readouterr()
    assert _vo("--sequence", root, "--model", bad, "--out", tmp_path / "b.txt", "--flow", "gt", "--quiet") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.safetensors" in err[0] and "meta.pose" in err[0]
    assert not (tmp_path / "b.txt").exists()
    (tmp_path / "junk.safetensors").write_bytes(b"junk")
    assert main(["set-pose", str(tmp_path / "junk.safetensors"), "--pose", "net", "--out", str(tmp_path / "j2")]) == 2
    assert not (tmp_path / "j2").exists()


def torch_equal(a, b) -> bool:
    import torch

    return bool(torch.equal(a, b))


def test_slam_takes_the_recorded_mode_for_consecutive_pairs_only(street_sequence, street_model, tmp_path):
    """A marked file as NN_cons: epipolar with the recorded distance; as NN_loops: epipolar with the network's
    distance whatever the file records (a loop pair is no step along a road), and without a mark too."""
    from deepslam.core.readers import open_sequence
    from deepslam.slam.plugins import OdometryOptions, odometries
    from deepslam.vo.modelfiles import models

    root, _ = street_sequence
    marked = tmp_path / "marked.safetensors"
    models.write_with_pose(street_model, marked, "epipolar")
    models.write_with_pose(street_model, tmp_path / "road.safetensors", "epipolar", "road")
    opts = OdometryOptions(model_cons=str(marked), model_loops=str(tmp_path / "road.safetensors"), flow="gt")
    cons, loops = odometries(opts, open_sequence(root))
    assert cons.epipolar is not None and loops.epipolar is not None and loops.epipolar.road_height_m is None
    cons, loops = odometries(dataclasses.replace(opts, pose="net", model_loops=str(street_model)), open_sequence(root))
    assert cons.epipolar is None and loops.epipolar is not None and loops.epipolar.road_height_m is None
    with pytest.raises(ValueError, match="pose must be"):
        models.epipolar_config(marked, "epi")


def test_a_point_set_opencv_refuses_is_a_failed_fit(monkeypatch):
    """fit_essential turns OpenCV's refusal into a failed fit (the pair is left to the network), for vo's
    fitter and for a plug-in calling it alike."""
    import cv2

    def refuse(*a, **k):
        raise cv2.error("OpenCV(4.x) five-point.cpp: error: (-215:Assertion failed) npoints >= 0")

    monkeypatch.setattr(cv2, "findEssentialMat", refuse)
    flow = exact_flow(car_motion(0.02, 1.0))
    for fit in (epipolar.fit_essential(flow, KITTI_LIKE), epipolar.EpipolarFitter()(flow, KITTI_LIKE)):
        assert not fit.ok and "OpenCV could not fit it" in fit.reason and fit.sampled > 0
