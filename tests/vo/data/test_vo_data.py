"""Training data: synthetic flow (gen's algebra, points leaving the image kept, sky at infinity),
deterministic batches, supervised pairs, and both training modes through the command line."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.flow.images import to_grey
from deepslam.gen import flow as gen_flow
from deepslam.vo.data.frames import (Frames, fill_depth_holes, frame_inverse_depth, load_frames, load_image_frames,
                                with_mirrored)
from deepslam.vo.data.motion import MotionMixture, SceneScale
from deepslam.vo.data.samples import concat_samples, epoch_seed
from deepslam.vo.data.supervised import PairSpec, frame_pairs, supervised_samples
from deepslam.vo.data.synthetic import EstimatedFlowSource, SyntheticSource
from deepslam.vo.data.toy import flow_from_depth_np, plane_depth, toy_motion_sampler

CAM = PinholeCamera(160, 48, 120.0, 120.0, 79.5, 20.0)


def _ground_depth(cam: PinholeCamera, height_m: float = 1.6) -> np.ndarray:
    d = plane_depth(cam, np.array([0.0, 1.0, 0.0]), height_m)
    d[d > 100] = 0.0
    return d


def _k(cam, n):
    return np.tile(cam.intrinsics(), (n, 1))


def test_synthesize_flow_matches_gen_and_the_numpy_reference():
    from deepslam.gen.flow import synthesize

    rng = np.random.default_rng(0)
    vec = np.column_stack([rng.normal(0, 0.01, (4, 3)), rng.normal(0, 0.1, (4, 2)), -rng.uniform(0.2, 1.0, 4)])
    motions = se3.from_euler6(vec)
    depth = np.stack([_ground_depth(CAM, h) for h in (1.4, 1.6, 1.8, 2.0)])
    ours, ours_valid = gen_flow.synthesize_flow(torch.from_numpy(depth), _k(CAM, 4), motions, "invalid")
    gflow, gvalid = synthesize(torch.from_numpy(depth), CAM, motions)
    gvalid = gvalid.numpy()
    assert gvalid.sum() > 1000
    np.testing.assert_allclose(ours.permute(0, 2, 3, 1).numpy()[gvalid], gflow.numpy()[gvalid], atol=2e-3)
    # gen drops points that leave the image; we keep them, and they agree with the NumPy reference
    left = ours_valid.numpy() & ~gvalid
    assert left.sum() > 100
    for b in range(4):
        ref, ref_valid = flow_from_depth_np(CAM, depth[b], motions[b])
        g = CAM.pixel_grid()
        p1 = (CAM.unproject(g, depth[b]) @ motions[b][:3, :3].T) + motions[b][:3, 3]
        uv1, _ = CAM.project(p1)
        expect = uv1 - g
        m = left[b]
        np.testing.assert_allclose(ours[b].permute(1, 2, 0).numpy()[m], expect[m], rtol=1e-4, atol=2e-3)


def test_missing_depth_is_a_point_at_infinity():
    depth = torch.zeros(2, 48, 160)  # all sky
    rot_only = se3.from_euler6(np.array([[0.0, 0.02, 0.0, 0.0, 0.0, 0.0]] * 2))
    rot_only[1, :3, 3] = [0.3, 0.1, -2.0]  # translation does not move points at infinity
    flow, valid = gen_flow.synthesize_flow(depth, _k(CAM, 2), rot_only, "infinity")
    assert valid.all()
    torch.testing.assert_close(flow[0], flow[1])
    # rotation about y by 0.02 rad: about fx * 0.02 = 2.4 px at the centre, u shrinking (R maps cam0 to cam1)
    assert abs(abs(float(flow[0, 0, 20, 80])) - 120 * np.tan(0.02)) < 0.05
    _, valid = gen_flow.synthesize_flow(depth, _k(CAM, 2), rot_only, "invalid")
    assert not valid.any()


def _frames(f: int = 2) -> Frames:
    cam = CAM.scaled(80 * f, 24 * f)
    depth = np.stack([_ground_depth(cam, h) for h in (1.5, 1.6, 1.7, 1.8, 1.9)])
    return Frames(depth, np.zeros(5, dtype=np.int64), [cam], [f"f{i}" for i in range(5)])


def test_synthetic_source_is_deterministic_per_epoch_and_pools_correctly():
    src = SyntheticSource(_frames(2), toy_motion_sampler(), samples_per_epoch=20, seed=4, synth_factor=2)
    a = list(src.batches(3, 8))
    b = list(src.batches(3, 8))
    assert [len(x["target"]) for x in a] == [8, 8, 4]
    for x, y in zip(a, b):
        for k in x:
            assert torch.equal(x[k], y[k])
    c = next(src.batches(4, 8))
    assert not torch.equal(a[0]["target"], c["target"])
    assert a[0]["flow"].shape == (8, 2, 24, 80)
    np.testing.assert_allclose(a[0]["intrinsics"][0].numpy(), [CAM.scaled(80, 24).fx, CAM.scaled(80, 24).fy,
                                                               CAM.scaled(80, 24).cx, CAM.scaled(80, 24).cy], rtol=1e-6)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
def test_synthetic_source_on_the_gpu_draws_the_cpu_samples():
    """Made on the GPU (``device``), a batch holds the same frames and motions as on the CPU, its flow on
    the GPU and equal to the CPU's to float rounding; the held-out set comes back to the CPU."""
    kw = dict(samples_per_epoch=20, seed=4, synth_factor=2)
    cpu = next(SyntheticSource(_frames(2), toy_motion_sampler(), **kw).batches(3, 8))
    gpu_src = SyntheticSource(_frames(2), toy_motion_sampler(), device="cuda", **kw)
    gpu = next(gpu_src.batches(3, 8))
    assert gpu["flow"].is_cuda and not gpu["target"].is_cuda
    assert torch.equal(cpu["target"], gpu["target"]) and torch.equal(cpu["intrinsics"], gpu["intrinsics"])
    torch.testing.assert_close(gpu["flow"].cpu(), cpu["flow"], atol=2e-4, rtol=1e-5)
    assert float(cpu["flow"].abs().mean()) > 0.1
    assert gpu_src.materialize(12, 7).flow.device.type == "cpu"


def test_flow_synthesized_at_twice_the_size_and_pooled_matches_the_direct_one():
    motion = se3.from_euler6(np.array([[0.002, 0.01, -0.003, 0.05, 0.02, -0.8]]))
    small, big = CAM.scaled(80, 24), CAM.scaled(160, 48)
    direct, _ = gen_flow.synthesize_flow(torch.from_numpy(_ground_depth(small)[None]), _k(small, 1), motion)
    fine, valid = gen_flow.synthesize_flow(torch.from_numpy(_ground_depth(big)[None]), _k(big, 1), motion)
    pooled, _ = gen_flow.pool_flow(fine, valid, 2)
    # the ground near the camera (smooth), away from the horizon
    np.testing.assert_allclose(pooled[0, :, 14:, 2:-2].numpy(), direct[0, :, 14:, 2:-2].numpy(), atol=0.05)
    assert float(direct[0, 1, 14:].abs().mean()) > 0.5  # a real flow, not zeros


def test_materialized_holdout_is_fixed():
    src = SyntheticSource(_frames(1), toy_motion_sampler(), 10, seed=1)
    a, b = src.materialize(12, 7), src.materialize(12, 7)
    assert len(a) == 12 and torch.equal(a.flow, b.flow) and torch.equal(a.target, b.target)


def test_motion_mixture_draws_from_each_model_by_weight():
    const = [lambda n, rng, v=v: np.full((n, 6), v) for v in (1.0, 2.0)]
    mix = MotionMixture(const, [3, 1])
    out = mix(4000, np.random.default_rng(0))
    assert set(np.unique(out)) == {1.0, 2.0}
    assert abs((out[:, 0] == 1.0).mean() - 0.75) < 0.03


def test_frame_pairs_consecutive_strides_and_loops():
    poses = np.tile(np.eye(4), (60, 1, 1))
    poses[:, 0, 3] = np.r_[np.arange(30), np.arange(30)[::-1]] * 1.0  # out and back along x
    pairs = frame_pairs(poses, PairSpec(strides=(1, 3)))
    assert len(pairs) == 59 + 57 and {tuple(p) for p in pairs[:2]} == {(0, 1), (1, 2)}
    loops = frame_pairs(poses, PairSpec(kind="loops", loop_min_gap_frames=20, loop_max_distance_m=1.0))
    assert len(loops) > 0
    assert (np.abs(poses[loops[:, 0], 0, 3] - poses[loops[:, 1], 0, 3]) <= 1.0).all()
    assert (loops[:, 1] - loops[:, 0] >= 20).all()


def test_supervised_samples_targets_are_ground_truth(plane_sequence):
    from deepslam.flow import registry as flow_registry

    seq = open_sequence(plane_sequence)
    pairs = frame_pairs(seq.gt.world_from_cam, PairSpec(strides=(1, 2)))[:5]
    s = supervised_samples(seq, pairs, flow_registry.make("gt"), 80, 24, progress=False)
    assert s["flow"].shape == (5, 2, 24, 80)
    for k, (i, j) in enumerate(pairs):
        expect = se3.to_euler6(se3.inverse(seq.gt.world_from_cam[j]) @ seq.gt.world_from_cam[i])
        np.testing.assert_allclose(s["target"][k], expect, atol=1e-6)
    # forward motion: t_z of cam_j_from_cam_i is minus the distance driven
    assert (s["target"][:, 5] < -0.5).all()


def test_train_cli_synthetic_from_single_frames(plane_sequence, motion_json, tmp_path):
    from deepslam.cli import main

    out = tmp_path / "syn"
    rc = main(["train", "--mode", "synthetic", "--source", str(plane_sequence), "--motion", str(motion_json),
               "--motion", f"{motion_json}@0.5", "--net", "tiny", "--batch", "16", "--samples-per-epoch", "64",
               "--max-epochs", "2", "--nll-epochs", "1", "--bf16", "off", "--threads", "1", "--quiet", "--out", str(out)])
    assert rc == 0
    cfg = json.loads((out / "config.json").read_text())
    d = cfg["data"]["data"]
    assert d["n_frames"] == 12 and d["n_holdout_frames"] == 1 and len(d["motion"]) == 2
    assert d["motion"][1]["weight"] == 0.5 and d["missing_depth"] == "infinity"
    assert (out / "model.safetensors").is_file()
    assert "mirror_frames" not in d  # only recorded when asked, so older commands keep their bytes


def test_train_cli_with_mirrored_frames_doubles_both_sides_of_the_split(plane_sequence, motion_json, tmp_path):
    from deepslam.cli import main

    out = tmp_path / "mir"
    rc = main(["train", "--mode", "synthetic", "--source", str(plane_sequence), "--motion", str(motion_json),
               "--mirror-frames", "--net", "tiny", "--batch", "16", "--samples-per-epoch", "64", "--max-epochs", "1",
               "--nll-epochs", "1", "--bf16", "off", "--threads", "1", "--quiet", "--out", str(out)])
    assert rc == 0
    d = json.loads((out / "config.json").read_text())["data"]["data"]
    assert d["mirror_frames"] is True and d["n_train_frames"] == 2 * 11 and d["n_holdout_frames"] == 2 * 1
    r = main(["train", "--mode", "synthetic", "--toy", "50", "--mirror-frames", "--out", str(tmp_path / "toy")])
    assert r == 2 and not (tmp_path / "toy").exists()


def test_estimated_flow_source_gives_dis_flow_of_a_rendered_second_view(plane_sequence):
    """Single frames -> second view rendered from depth -> DIS: on the textured ground plane DIS is
    close to the exact flow of the sampled motion; batches are deterministic; targets are the motions."""
    from deepslam.flow.estimators import to_network_input

    seq = open_sequence(plane_sequence)
    frames = load_image_frames([seq], frame_step=3, progress=False)
    assert len(frames) == 4 and frames.grey[0].shape == (80, 256) and frames.grey[0].dtype == np.uint8
    fixed = np.array([0.0, 0.01, 0.0, 0.05, 0.0, -0.5])          # half a metre forward, a slight turn

    def motion(n, rng):
        return np.tile(fixed, (n, 1)) + rng.normal(0, [0.001, 0.002, 0.001, 0.02, 0.01, 0.1], (n, 6))

    src = EstimatedFlowSource(frames, motion, "dis", 80, 24, 6, seed=3, threads=2)
    b1, b2 = list(src.batches(0, 6)), list(src.batches(0, 6))
    assert b1[0]["flow"].shape == (6, 2, 24, 80) and b1[0]["flow"].dtype == torch.float32
    assert torch.equal(b1[0]["flow"], b2[0]["flow"])
    assert not torch.equal(b1[0]["flow"], next(iter(src.batches(1, 6)))["flow"])
    # against the exact flow of the same frames and motions (same rng draws)
    rng = np.random.default_rng(epoch_seed(3, 0, 0))
    idx = rng.integers(0, len(frames), 6)
    vec6 = motion(6, rng)
    np.testing.assert_allclose(b1[0]["target"].numpy(), vec6.astype(np.float32))
    for k in range(6):
        exact, _ = flow_from_depth_np(seq.camera, frames.depth_z[idx[k]], se3.from_euler6(vec6[k]))
        want, intr = to_network_input(exact, seq.camera, 80, 24)
        np.testing.assert_allclose(b1[0]["intrinsics"][k].numpy(), intr)
        got = b1[0]["flow"][k].numpy()
        road = np.abs(want).sum(0) > 0                          # below the horizon
        epe = np.linalg.norm(got - want, axis=0)[road]
        assert np.median(epe) < 0.3 * np.median(np.linalg.norm(want, axis=0)[road])


def test_train_cli_synthetic_with_dis_flow_and_a_sample_pool(plane_sequence, motion_json, tmp_path):
    from deepslam.cli import main

    out = tmp_path / "syn_dis"
    rc = main(["train", "--mode", "synthetic", "--synthetic-flow", "dis", "--dis-preset", "fast", "--sample-pool", "48",
               "--dis-min-texture", "0.5", "--dis-fb-check", "1", "--dis-max-width", "200",
               "--dis-patch-stride", "4", "--source", str(plane_sequence), "--motion", str(motion_json), "--net", "tiny", "--batch", "16",
               "--samples-per-epoch", "64", "--max-epochs", "2", "--nll-epochs", "1", "--bf16", "off", "--threads", "1",
               "--quiet", "--out", str(out)])
    assert rc == 0
    meta = json.loads((out / "config.json").read_text())["data"]
    d = meta["data"]
    assert d["synthetic_flow"] == "dis-fast-tex0.5-fb1-w200-s4" and d["sample_pool"] == 48 and d["synth_factor"] is None
    recorded = {"preset": "fast", "min_texture": 0.5, "fb_max_px": 1.0, "max_width": 200, "patch_stride": 4}
    assert meta["flow"] == {"estimator": "dis", "options": recorded}
    # the model file records the flow it learned, and vo sets DIS up the same unless told otherwise
    from deepslam.vo.modelfiles import models
    from deepslam.vo.odometry import model_odometry

    model = out / "model.safetensors"
    assert models.recorded_flow_options(model, "dis") == recorded
    assert models.recorded_flow_options(model, "learned") == {}
    assert models.flow_for_model("dis", model).name == "dis-fast-tex0.5-fb1-w200-s4"
    assert models.flow_for_model("dis", model, min_texture=0.0, preset=None).name == "dis-fast-fb1-w200-s4"
    with pytest.raises(InputError, match="--dis-fb-check") as bad:  # a bad flag is the flag's fault, not the file's
        models.flow_for_model("dis", model, fb_max_px=-1.0)
    assert "malformed" not in str(bad.value)
    odometry = model_odometry(model)  # as bench and SLAM take a model file: on the flow it records
    assert odometry.flow_estimator.name == "dis-fast-tex0.5-fb1-w200-s4" and not odometry.progress
    for flags, name in (([], "dis-fast-tex0.5-fb1-w200-s4"), (["--dis-min-texture", "0", "--dis-preset", "medium",
                                                            "--dis-fb-check", "0", "--dis-max-width", "0",
                                                            "--dis-patch-stride", "0"], "dis-medium")):
        traj = tmp_path / f"vo{len(flags)}.txt"
        assert main(["vo", "--sequence", str(plane_sequence), "--model", str(model), "--out", str(traj), "--quiet",
                     *flags]) == 0
        assert json.loads(traj.with_suffix(".config.json").read_text())["flow"] == name
    # a texture threshold for a flow it does not apply to is refused, not ignored
    for argv in (["vo", "--sequence", str(plane_sequence), "--model", str(model), "--flow", "gt"],
                 ["train", "--mode", "synthetic", "--source", str(plane_sequence), "--motion", str(motion_json)]):
        for flag in ("--dis-min-texture", "--dis-fb-check"):
            assert main([*argv, flag, "0.5", "--out", str(tmp_path / "refused"), "--quiet"]) == 2
    assert main(["train", "--mode", "synthetic", "--synthetic-flow", "nope", "--source", str(plane_sequence),
                 "--motion", str(motion_json), "--net", "tiny", "--quiet", "--out", str(tmp_path / "o")]) == 2


@pytest.mark.parametrize("options", [{"min_texture": "abc"}, {"foo": 1}, {"preset": "bogus"}, ["medium"]])
def test_a_malformed_flow_record_is_one_line_naming_the_model_file(options, plane_sequence, tmp_path, capsys):
    """A model file whose meta.flow options DIS cannot take: vo exits 2 with one line naming the file."""
    from deepslam.cli import main
    from deepslam.vo.modelfiles.modelio import save_model
    from deepslam.vo.net import FlowPoseNet, NetConfig

    model = tmp_path / "bad_record.safetensors"
    save_model(model, FlowPoseNet(NetConfig(input_height=24, input_width=80, filters=8, hidden_units=16)),
               {"flow": {"estimator": "dis", "options": options}})
    rc = main(["vo", "--sequence", str(plane_sequence), "--model", str(model), "--out", str(tmp_path / "t.txt"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and str(model) in err and "meta.flow" in err, err
    assert not (tmp_path / "t.txt").exists()


def test_train_cli_supervised_with_ground_truth_flow(plane_sequence, tmp_path):
    from deepslam.cli import main

    out = tmp_path / "sup"
    rc = main(["train", "--mode", "supervised", "--sequence", str(plane_sequence), "--strides", "1,2", "--flow", "gt",
               "--net", "tiny", "--batch", "8", "--max-epochs", "2", "--nll-epochs", "1", "--bf16", "off",
               "--threads", "1", "--quiet", "--out", str(out)])
    assert rc == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["data"]["data"]["n_pairs"] == 11 + 10 and cfg["data"]["data"]["flow"] == "gt"


def test_supervised_pairs_read_narrow_frames_upsampled_for_estimated_flow_as_vo_does(plane_sequence):
    from deepslam.vo.data.sources import SupervisedData, supervised_sources
    from deepslam.vo.net import NetConfig

    net = NetConfig(input_height=24, input_width=80)
    spec = SupervisedData(sequences=(str(plane_sequence),), pairs=PairSpec(max_pairs=3), flow="dis", holdout=0.34)

    def flows(read_width: int, flow: str = "dis"):
        train, hold, meta = supervised_sources(dataclasses.replace(spec, read_width_px=read_width, flow=flow), net, 0,
                                               progress=False)
        return np.concatenate([train.flow.numpy(), hold.flow.numpy()]), meta["data"]

    recorded, meta0 = flows(0)
    upsampled, meta = flows(512)  # the plane's frames are 256 px wide
    assert meta0["read_at_px"] == {} and meta["read_at_px"] == {str(plane_sequence): 512} and meta["n_pairs"] == 3
    assert recorded.shape == upsampled.shape and not np.array_equal(recorded, upsampled)
    assert np.nanmean(np.abs(upsampled - recorded)) < 0.3 * np.nanmean(np.abs(recorded))  # the same motion
    np.testing.assert_array_equal(flows(512, "gt")[0], flows(0, "gt")[0])  # exact flow: as recorded
    with pytest.raises(InputError, match="--read-width"):
        flows(-1)


def test_train_cli_bad_input(tmp_path, plane_sequence):
    from deepslam.cli import main

    base = ["train", "--net", "tiny", "--quiet", "--out", str(tmp_path / "o")]
    assert main([*base, "--mode", "synthetic", "--source", str(plane_sequence)]) == 2  # no motion model
    assert main([*base, "--mode", "synthetic", "--source", str(plane_sequence), "--motion", str(tmp_path / "nope.json")]) == 2
    (tmp_path / "bad.json").write_text("{\"format\": 3}")
    assert main([*base, "--mode", "synthetic", "--source", str(plane_sequence), "--motion", str(tmp_path / "bad.json")]) == 2
    assert main([*base, "--mode", "supervised"]) == 2
    assert main([*base, "--mode", "supervised", "--sequence", str(plane_sequence), "--read-width", "-5"]) == 2
    assert main([*base, "--mode", "synthetic", "--toy", "64", "--scene-scale", "0.5:1"]) == 2  # no single frames
    assert main([*base, "--mode", "synthetic", "--source", str(plane_sequence), "--motion", str(tmp_path / "bad.json"),
                 "--scene-scale", "1:0.5"]) == 2


def test_synthetic_flow_equals_the_simulators_true_flow_everywhere():
    """On a rendered street (static scene), flow synthesized from frame t's depth and the true motion
    equals the simulator's flow at EVERY pixel: those leaving the image and the sky included."""
    pytest.importorskip("mujoco")
    from deepslam.scenes import SceneConfig
    from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig

    cfg = SimConfig(SceneConfig(name="street", seed=3), TrajectoryConfig(kind="car", frames=40),
                    RenderConfig(backend="mujoco", width=160, stereo_baseline_m=0.0))
    with Simulator(cfg) as sim:
        f = sim.frame(30)
        nxt = sim.frame(31)
    c = f.camera
    motion = se3.relative(nxt.world_from_cam, f.world_from_cam)
    assert np.linalg.norm(motion[:3, 3]) > 0.3  # the car is moving
    flow, valid = gen_flow.synthesize_flow(torch.from_numpy(f.depth_z[None]), c.intrinsics()[None], motion[None])
    flow = flow[0].permute(1, 2, 0).numpy()
    ok = np.isfinite(f.flow).all(-1) & (f.mask == 0)
    assert ok.mean() > 0.95 and (f.depth_z[ok] == 0).any()  # sky is in the comparison
    np.testing.assert_allclose(flow[ok], f.flow[ok], atol=2e-3)


def test_image_frames_at_several_scales_split_by_source_frame(plane_sequence):
    seq = open_sequence(plane_sequence)
    frames = load_image_frames([seq], frame_step=2, scales=(1.0, 0.5), progress=False)
    assert len(frames) == 12 and len(frames.cameras) == 2
    small = [k for k, n in enumerate(frames.names) if "@" in n]
    assert frames.grey[small[0]].shape == (40, 128) and frames.depth_z[small[0]].shape == (40, 128)
    assert frames.cameras[frames.camera_index[small[0]]].fx == pytest.approx(seq.camera.fx / 2)
    train, hold = frames.split(0.34, seed=0)
    assert len(hold) == 4 and len(train) == 8                 # 2 of 6 source frames, each at both scales
    assert not {n.split("@")[0] for n in train.names} & {n.split("@")[0] for n in hold.names}
    with pytest.raises(Exception, match="scales"):
        load_image_frames([seq], scales=(5.0,), progress=False)


def test_image_frames_above_scale_one_are_what_vo_reads_at_its_read_width(plane_sequence):
    from deepslam.vo.pipeline import UpsampledView

    seq = open_sequence(plane_sequence)
    width = round(seq.camera.width * 1.5)
    frames = load_image_frames([seq], frame_step=2, scales=(1.5,), progress=False)
    view = UpsampledView(seq, width)
    assert frames.cameras == [view.camera]
    np.testing.assert_array_equal(frames.grey[0], to_grey(view.image(0)))
    assert frames.depth_z[0].shape == (view.camera.height, view.camera.width)


def test_appearance_noise_on_the_rendered_view_is_seeded_and_changes_only_the_flow(plane_sequence):
    from deepslam.core.errors import InputError

    frames = load_image_frames([open_sequence(plane_sequence)], frame_step=4, progress=False)

    def motion(n, rng):
        return np.tile([0.0, 0.01, 0.0, 0.05, 0.0, -0.5], (n, 1)) + rng.normal(0, 0.01, (n, 6))

    clean = EstimatedFlowSource(frames, motion, "dis", 80, 24, 4, seed=5, threads=1)
    noisy = EstimatedFlowSource(frames, motion, "dis", 80, 24, 4, seed=5, threads=2, appearance_noise=6.0)
    a, b, b2 = (next(iter(s.batches(0, 4))) for s in (clean, noisy, noisy))
    assert torch.equal(a["target"], b["target"])                # the same frames and motions ...
    assert torch.equal(b["flow"], b2["flow"])                   # ... the noise is seeded ...
    diff = (a["flow"] - b["flow"]).abs()
    assert 0 < diff.mean() < 0.5 * a["flow"].abs().mean()       # ... and perturbs the flow, not replaces it
    with pytest.raises(InputError, match="appearance noise"):
        EstimatedFlowSource(frames, motion, "dis", 80, 24, 4, appearance_noise=-1.0)


def test_flat_speed_replaces_only_the_forward_motion_and_covers_the_range():
    from deepslam.vo.data.motion import FlatSpeed

    base = lambda n, rng: np.tile(np.array([0.01, 0.02, 0.03, 0.1, 0.2, -0.9]), (n, 1))  # noqa: E731
    s = FlatSpeed(base, 0.0, 30.0, 10.0)
    out = s(20000, np.random.default_rng(0))
    np.testing.assert_array_equal(out[:, :5], np.tile([0.01, 0.02, 0.03, 0.1, 0.2], (20000, 1)))
    fwd = -out[:, 5] * 10.0  # m/s
    assert fwd.min() >= 0 and fwd.max() <= 30
    hist, _ = np.histogram(fwd, bins=6, range=(0, 30))
    assert hist.min() > 0.9 * hist.mean()  # flat, not a prior around 9 m/s
    np.testing.assert_array_equal(out, FlatSpeed(base, 0.0, 30.0, 10.0)(20000, np.random.default_rng(0)))
    for bad in ((5.0, 5.0), (-1.0, 3.0), (0.0, float("nan"))):
        with pytest.raises(InputError):
            FlatSpeed(base, *bad, 10.0)


@pytest.mark.parametrize("fraction", [0.2, 0.5])
def test_flat_speed_fraction_gives_a_flat_tail_beside_the_prior(fraction):
    from deepslam.vo.data.motion import FlatSpeed

    base = lambda n, rng: np.tile(np.array([0.01, 0.02, 0.03, 0.1, 0.2, -0.9]), (n, 1))  # noqa: E731
    out = FlatSpeed(base, 0.0, 30.0, 10.0, fraction)(40000, np.random.default_rng(1))
    kept = out[:, 5] == -0.9  # the prior's draw (a flat draw hits -0.9 exactly with probability 0)
    assert abs(1 - kept.mean() - fraction) < 0.01
    fwd = -out[~kept, 5] * 10.0
    assert fwd.min() >= 0 and fwd.max() <= 30
    hist, _ = np.histogram(fwd, bins=6, range=(0, 30))
    assert hist.min() > 0.85 * hist.mean()
    np.testing.assert_array_equal(out[:, :5], np.tile([0.01, 0.02, 0.03, 0.1, 0.2], (40000, 1)))
    np.testing.assert_array_equal(out, FlatSpeed(base, 0.0, 30.0, 10.0, fraction)(40000, np.random.default_rng(1)))


@pytest.mark.parametrize("text, expect", [("0:30", (0.0, 30.0, 1.0)), ("0:30@0.2", (0.0, 30.0, 0.2)),
                                          ("5:25@1", (5.0, 25.0, 1.0))])
def test_flat_speed_parses_the_flag(text, expect):
    from deepslam.vo.data.motion import FlatSpeed

    s = FlatSpeed.parse(lambda n, rng: np.zeros((n, 6)), text, 10.0)
    assert (s.min_mps, s.max_mps, s.fraction) == expect


@pytest.mark.parametrize("text", ["0:30@0", "0:30@1.5", "0:30@x", "30", "0:30:5", "0:30@nan", "10:5@0.2"])
def test_flat_speed_rejects_a_bad_flag_with_one_line(text):
    from deepslam.vo.data.motion import FlatSpeed

    with pytest.raises(InputError):
        FlatSpeed.parse(lambda n, rng: np.zeros((n, 6)), text, 10.0)


def test_train_refuses_a_bad_speed_range_fraction_before_writing(tmp_path):
    """`train --speed-range 0:30@2`: one line naming the flag, exit 2, no output folder."""
    import subprocess
    import sys

    from deepslam.core.paths import base_dir

    motion = base_dir() / "models" / "motion" / "kitti_no0607_s1.json"
    (tmp_path / "frames").mkdir()
    r = subprocess.run([sys.executable, "-m", "deepslam", "train", "--mode", "synthetic", "--source",
                        str(tmp_path / "frames"), "--motion", str(motion), "--speed-range", "0:30@2",
                        "--out", str(tmp_path / "o")],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "fraction" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_speed_sweep_of_a_perfect_reader_is_flat(plane_sequence):
    """A 'model' that reads forward motion exactly from the synthesized flow's intrinsics-free target
    gives read/true = 1 at every speed; the sweep plumbing (frames, motions, signs) is what is tested."""
    from deepslam.studies import scale_sweep

    seq = open_sequence(plane_sequence)
    frames = load_frames([seq], 80, 24, progress=False)
    seen = {}

    class Oracle:
        def predict(self, flow, intrinsics):
            return np.tile(seen["target"], (len(flow), 1)), np.ones((len(flow), 6))

    def make(sample):
        src = SyntheticSource(frames, sample, 4)
        seen["target"] = sample(1, np.random.default_rng(0))[0]
        return src

    reads = scale_sweep.speed_sweep(Oracle(), make, 4, 10.0, speeds_mps=(0.0, 5.0, 20.0))
    assert [r.speed_mps for r in reads] == [0.0, 5.0, 20.0]
    assert reads[0].ratio_median is None and reads[0].read_median_m == 0.0
    assert [r.ratio_median for r in reads[1:]] == pytest.approx([1.0, 1.0])
    assert [r.ratio_spread for r in reads[1:]] == pytest.approx([0.0, 0.0])  # the same read on every frame
    assert [r.std_ratio_median for r in reads[1:]] == pytest.approx([1 / 0.5, 1 / 2.0])  # std 1 m over the motion
    assert reads[0].ratio_spread is None and reads[0].std_ratio_median is None
    assert reads[2].true_m == pytest.approx(2.0)
    assert scale_sweep.flatness(reads) == {"ratio_min": 1.0, "ratio_max": 1.0, "max_abs_dev": 0.0,
                                             "read_at_rest_m": 0.0, "min_speed_mps": 2.0}


@pytest.mark.parametrize("keep_sky", [True, False])
def test_fill_depth_holes_fills_inner_holes_and_leaves_the_sky_at_infinity(keep_sky):
    """Stereo holes inside the scene (a textureless patch, an occlusion shadow) take the nearest known
    depth; the hole touching the top border is the sky and stays 0 (at infinity) unless told otherwise."""
    d = np.full((8, 10), 5.0, np.float32)
    d[:2, :] = 0.0            # sky: the top rows
    d[5, 4:6] = 0.0           # an inner hole
    d[4, 0] = np.nan          # a bad value inside the scene (not connected to the sky)
    out = fill_depth_holes(d, keep_sky=keep_sky)
    assert (out[5, 4:6] == 5.0).all() and out[4, 0] == 5.0
    assert np.array_equal(fill_depth_holes(d), fill_depth_holes(d, keep_sky=False))  # the default
    if keep_sky:
        assert (out[:2] == 0).all()
    else:
        assert (out[:2] == 5.0).all()
    assert np.array_equal(out[out > 0] > 0, np.ones((out > 0).sum(), bool))


def test_sources_give_the_inverse_depth_of_each_samples_frame(plane_sequence):
    """With ``inv_depth=True`` every batch (exact and estimated flow, pooled too) carries the first
    frame's inverse depth at the network resolution: the same frame's depth as the flow's."""
    from deepslam.vo.net import inverse_depth_input

    src = SyntheticSource(_frames(2), toy_motion_sampler(), samples_per_epoch=8, seed=4, synth_factor=2,
                          inv_depth=True)
    b = next(src.batches(0, 8))
    rng = np.random.default_rng(epoch_seed(4, 0, 0))
    idx = rng.integers(0, 5, 8)
    assert b["inv_depth"].shape == (8, 1, 24, 80)
    for k in range(8):
        np.testing.assert_allclose(b["inv_depth"][k].numpy(), inverse_depth_input(src.frames.depth_z[idx[k]], 80, 24))
    pool = src.materialize(8, 1)
    assert pool.inv_depth.shape == (8, 1, 24, 80) and "inv_depth" in next(pool.batches(0, 4))
    assert "inv_depth" not in next(SyntheticSource(_frames(2), toy_motion_sampler(), 8, synth_factor=2).batches(0, 8))
    seq = open_sequence(plane_sequence)
    frames = load_image_frames([seq], frame_step=3, progress=False)
    est = EstimatedFlowSource(frames, toy_motion_sampler(), "dis", 80, 24, 4, seed=3, threads=1, inv_depth=True)
    b = next(est.batches(0, 4))
    idx = np.random.default_rng(epoch_seed(3, 0, 0)).integers(0, len(frames), 4)
    for k in range(4):
        np.testing.assert_allclose(b["inv_depth"][k].numpy(), inverse_depth_input(frames.depth_z[idx[k]], 80, 24))
    np.testing.assert_allclose(frame_inverse_depth(seq, 3, 80, 24), inverse_depth_input(seq.depth(3), 80, 24))


def test_train_and_vo_with_a_depth_channel(plane_sequence, motion_json, tmp_path):
    """`train --depth-channel` makes a network that vo feeds with each pair's first-frame depth, from single
    frames or supervised pairs; the options that have no frames to read depth from are refused with one line."""
    from deepslam.cli import main
    from deepslam.vo.infer import VOPredictor

    out = tmp_path / "depth"
    base = ["train", "--mode", "synthetic", "--source", str(plane_sequence), "--motion", str(motion_json), "--net", "tiny",
            "--batch", "16", "--samples-per-epoch", "64", "--max-epochs", "2", "--nll-epochs", "1", "--bf16", "off",
            "--threads", "1", "--quiet", "--depth-channel"]
    assert main([*base, "--out", str(out)]) == 0
    pred = VOPredictor.from_file(out / "model.safetensors")
    assert pred.needs_depth and pred.model.cfg.depth_channel
    traj = tmp_path / "vo.txt"
    assert main(["vo", "--sequence", str(plane_sequence), "--model", str(out / "model.safetensors"), "--flow", "gt",
                 "--out", str(traj), "--quiet"]) == 0
    assert len([ln for ln in traj.read_text().splitlines() if not ln.startswith("#")]) == 12
    assert main(["train", "--mode", "synthetic", "--toy", "64", "--net", "tiny", "--depth-channel", "--quiet",
                 "--out", str(tmp_path / "toy")]) == 2
    sup = tmp_path / "sup"
    assert main(["train", "--mode", "supervised", "--sequence", str(plane_sequence), "--flow", "gt", "--net", "tiny",
                 "--batch", "8", "--max-epochs", "2", "--nll-epochs", "1", "--bf16", "off", "--threads", "1",
                 "--depth-channel", "--quiet", "--out", str(sup)]) == 0
    assert VOPredictor.from_file(sup / "model.safetensors").needs_depth


def test_supervised_pairs_carry_their_first_frames_depth(plane_sequence):
    from deepslam.flow import registry as flow_registry

    seq = open_sequence(plane_sequence)
    pairs = frame_pairs(seq.gt.world_from_cam, PairSpec(strides=(1, 2)))[:5]
    s = supervised_samples(seq, pairs, flow_registry.make("gt"), 80, 24, progress=False, inv_depth=True)
    assert s["inv_depth"].shape == (5, 1, 24, 80)
    for k, (i, _) in enumerate(pairs):
        np.testing.assert_allclose(s["inv_depth"][k], frame_inverse_depth(seq, int(i), 80, 24))
    both = concat_samples([s, s])
    assert both["inv_depth"].shape == (10, 1, 24, 80)
    with pytest.raises(ValueError, match="inverse depth"):
        concat_samples([s, supervised_samples(seq, pairs, flow_registry.make("gt"), 80, 24, progress=False)])


def test_scene_scale_scales_each_samples_depth_and_keeps_the_motion_metric():
    """A sample's flow with --scene-scale is the flow of its frame's depth times the drawn factor (the
    same motion: nearer geometry, more parallax); the factors are log-uniform in the range."""
    frames = _frames(1)
    scale = SceneScale(0.3, 1.0)
    src = SyntheticSource(frames, toy_motion_sampler(), 6, seed=2, scene_scale=scale, inv_depth=True)
    b = next(src.batches(0, 6))
    rng = np.random.default_rng(epoch_seed(2, 0, 0))
    idx = rng.integers(0, 5, 6)
    vec6 = toy_motion_sampler()(6, rng)
    factors = scale.sample(6, rng)
    assert ((factors >= 0.3) & (factors <= 1.0)).all() and factors.std() > 0
    np.testing.assert_allclose(b["target"].numpy(), vec6.astype(np.float32))
    depth = torch.from_numpy(frames.depth_z[idx] * factors[:, None, None].astype(np.float32))
    want, _ = gen_flow.synthesize_flow(depth, _k(frames.cameras[0], 6), se3.from_euler6(vec6))
    torch.testing.assert_close(b["flow"], want)
    plain = next(SyntheticSource(frames, toy_motion_sampler(), 6, seed=2).batches(0, 6))
    assert float((b["flow"] - plain["flow"]).abs().max()) > 0.1     # the scale changed the parallax
    big = np.random.default_rng(0)
    f = SceneScale(0.5, 2.0).sample(20000, big)
    assert abs(np.median(np.log(f))) < 0.02                            # log-uniform: median at the geometric mean
    for bad in ("1", "a:b", "0.01:1", "2:1"):
        with pytest.raises(InputError):
            SceneScale.parse(bad)


def test_sources_leave_unknown_flow_nan_for_a_validity_channel(plane_sequence):
    """unknown="nan" (a network with a validity channel): the exact source marks pixels without depth
    NaN where the zero reading has 0, with the same flow elsewhere; the DIS source marks network pixels
    with no textured pixel NaN where the zero reading has 0."""
    frames = _frames(2)
    depth = frames.depth_z.copy()
    depth[:, 30:, :40] = 0.0                                     # a hole: no depth (missing_depth="invalid")
    holed = Frames(depth, frames.camera_index, frames.cameras, frames.names)
    zero = next(SyntheticSource(holed, toy_motion_sampler(), 6, seed=2, synth_factor=2,
                                missing_depth="invalid").batches(0, 6))["flow"]
    nan = next(SyntheticSource(holed, toy_motion_sampler(), 6, seed=2, synth_factor=2,
                               missing_depth="invalid", unknown="nan").batches(0, 6))["flow"]
    unknown = torch.isnan(nan)
    assert unknown[:, :, 15:, :20].all() and unknown[:, 0].eq(unknown[:, 1]).all()
    assert torch.equal(zero[unknown], torch.zeros(int(unknown.sum()))) and torch.equal(zero[~unknown], nan[~unknown])
    with pytest.raises(ValueError, match="unknown must be"):
        SyntheticSource(holed, toy_motion_sampler(), 6, unknown="keep")

    seq = open_sequence(plane_sequence)
    image_frames = load_image_frames([seq], frame_step=3, progress=False)
    opts = {"preset": "fast", "min_texture": 1e9}                  # nothing is textured enough: all unknown
    zero = next(EstimatedFlowSource(image_frames, toy_motion_sampler(), "dis", 80, 24, 4, seed=3, threads=1,
                                    estimator_options=opts).batches(0, 4))["flow"]
    nan = next(EstimatedFlowSource(image_frames, toy_motion_sampler(), "dis", 80, 24, 4, seed=3, threads=1,
                                   estimator_options=opts, unknown="nan").batches(0, 4))["flow"]
    assert torch.isnan(nan).all() and torch.equal(zero, torch.zeros_like(zero))
    opts["min_texture"] = 0.0                                      # every pixel known: the two readings agree
    a, b = (next(EstimatedFlowSource(image_frames, toy_motion_sampler(), "dis", 80, 24, 4, seed=3, threads=1,
                                     estimator_options=opts, unknown=u).batches(0, 4))["flow"] for u in ("zero", "nan"))
    assert torch.equal(a, b) and torch.isfinite(a).all()


def test_train_and_vo_with_a_validity_channel(plane_sequence, motion_json, tmp_path, capsys):
    """`train --valid-channel` on DIS with a texture threshold: the model file says its input keeps
    unknown flow apart (read from the header), vo runs it; shards (flows resized with unknown = 0) are refused."""
    from deepslam.cli import main
    from deepslam.vo.data.prefetch import model_input

    out = tmp_path / "valid"
    assert main(["train", "--mode", "synthetic", "--synthetic-flow", "dis", "--dis-preset", "fast", "--dis-min-texture",
                 "0.5", "--valid-channel", "--sample-pool", "32", "--source", str(plane_sequence), "--motion",
                 str(motion_json), "--net", "tiny", "--batch", "16", "--samples-per-epoch", "32", "--max-epochs", "1",
                 "--nll-epochs", "1", "--bf16", "off", "--threads", "1", "--quiet", "--out", str(out)]) == 0
    model = out / "model.safetensors"
    assert model_input(model) == (24, 80, "nan")
    traj = tmp_path / "vo.txt"
    assert main(["vo", "--sequence", str(plane_sequence), "--model", str(model), "--out", str(traj), "--quiet"]) == 0
    rows = [ln.split() for ln in traj.read_text().splitlines() if not ln.startswith("#")]
    assert len(rows) == 12 and np.isfinite(np.array(rows, dtype=float)).all()
    capsys.readouterr()
    (tmp_path / "some_shards").mkdir()
    assert main(["train", "--mode", "synthetic", "--shards", str(tmp_path / "some_shards"), "--net", "tiny",
                 "--valid-channel", "--quiet", "--out", str(tmp_path / "shards")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--valid-channel" in err and not (tmp_path / "shards").exists()


@pytest.mark.parametrize("reads_slide", [True, False])
def test_turn_reads_tell_a_slide_reader_from_a_yaw_reader(plane_sequence, reads_slide):
    """Two 'models' on the sweep's plumbing: one returns the true motion (yaw gain 0, slide read 1); one
    ignores t_x and reads a tenth of the slide as extra yaw (what a network trained on the paper's
    independent prior does on KITTI's turns): yaw gain > 0, slide read 0."""
    from deepslam.studies import scale_sweep

    seq = open_sequence(plane_sequence)
    frames = load_frames([seq], 80, 24, progress=False)
    seen = {}

    class Model:
        def predict(self, flow, intrinsics):
            t = seen["target"].copy()
            if not reads_slide:
                t[1] += 0.1 * t[3]
                t[3] = 0.0
            return np.tile(t, (len(flow), 1)), np.ones((len(flow), 6))

    def make(sample):
        seen["target"] = sample(1, np.random.default_rng(0))[0]
        return SyntheticSource(frames, sample, 4)

    reads = scale_sweep.turn_reads(Model(), make, 4, yaws_rad=(-0.04, 0.04), forwards_m=(1.0,))
    np.testing.assert_allclose([(r.yaw_rad, r.slide_m) for r in reads],
                               [(-0.04, 0.0), (-0.04, -0.0352), (0.04, 0.0), (0.04, 0.0352)], atol=1e-12)
    eff = scale_sweep.slide_effect(reads)
    if reads_slide:
        assert eff["yaw_gain"] == pytest.approx(0.0, abs=1e-12) and eff["slide_read_fraction"] == pytest.approx(1.0)
    else:
        assert eff["yaw_gain"] == pytest.approx(0.088) and eff["slide_read_fraction"] == pytest.approx(0.0)
    assert all(r.forward_ratio_median == pytest.approx(1.0) for r in reads)
    assert scale_sweep.straight_yaw_read(Model(), make, 4, 1.0) == {"forward_m": 1.0, "yaw_median_rad": 0.0,
                                                                     "yaw_mean_rad": 0.0}


def test_mirrored_frame_flow_is_the_mirror_of_the_mirrored_motion():
    """A frame flipped left-right with its camera mirrored is the world seen in a mirror (x -> -x): the flow
    a motion causes on it is, flipped back, the flow of the mirrored motion (yaw, roll and t_x negated) on
    the original frame. This is what makes a mirrored single frame a valid training frame."""
    from deepslam.core import se3
    from deepslam.core.camera import PinholeCamera
    from deepslam.gen.flow import synthesize

    rng = np.random.default_rng(0)
    cam = PinholeCamera(64, 24, 50.0, 52.0, 30.3, 11.7)  # principal point off-centre on purpose
    depth = rng.uniform(2.0, 30.0, (24, 64)).astype(np.float32)
    frames = Frames(depth[None], np.zeros(1, np.int64), [cam], ["f:0"])
    both = with_mirrored(frames)
    assert both.names == ["f:0", "f:0:mirror"] and len(both.cameras) == 2
    mcam = both.cameras[both.camera_index[1]]
    assert mcam.cx == pytest.approx(64 - 1 - 30.3) and mcam.mirrored().cx == pytest.approx(cam.cx)
    np.testing.assert_array_equal(both.depth_z[1], depth[:, ::-1])
    vec = np.array([0.01, 0.03, -0.02, 0.2, -0.05, -0.8])
    mirror_vec = vec * np.array([1, -1, -1, -1, 1, 1])
    flow_m, valid_m = synthesize(both.depth_z[1], mcam, se3.from_euler6(vec[None])[0])
    flow_o, valid_o = synthesize(depth, cam, se3.from_euler6(mirror_vec[None])[0])
    flow_m, valid_m = np.asarray(flow_m), np.asarray(valid_m)  # (H, W, 2) pixels, (H, W)
    flow_o, valid_o = np.asarray(flow_o), np.asarray(valid_o)
    back = flow_m[:, ::-1] * np.array([-1.0, 1.0], np.float32)  # flipped back: columns reversed, du negated
    both_valid = valid_o & valid_m[:, ::-1]
    assert both_valid.mean() > 0.5
    np.testing.assert_allclose(back[both_valid], flow_o[both_valid], atol=2e-3)
    # and it is not the unmirrored motion's flow (the check can fail)
    flow_u, _ = synthesize(depth, cam, se3.from_euler6(vec[None])[0])
    assert np.abs(np.asarray(flow_u) - flow_o).max() > 1.0


def test_mirrored_image_frames_keep_the_sensor_depth_and_refuse_nothing(plane_sequence):
    seq = open_sequence(plane_sequence)
    fr = load_image_frames([seq], progress=False)
    both = with_mirrored(fr)
    n = len(fr)
    assert len(both) == 2 * n and both.names[n:] == [f"{x}:mirror" for x in fr.names]
    np.testing.assert_array_equal(both.grey[n], fr.grey[0][:, ::-1])
    np.testing.assert_array_equal(both.depth_z[n + 1], fr.depth_z[1][:, ::-1])
    assert all(both.cameras[both.camera_index[n + i]] == fr.cameras[fr.camera_index[i]].mirrored() for i in range(n))
    only = with_mirrored(fr, keep_original=False)
    assert len(only) == n and only.names == both.names[n:] and only.cameras == [fr.cameras[0].mirrored()]
    np.testing.assert_array_equal(only.grey[2], both.grey[n + 2])


def test_supervised_pairs_on_tum_read_the_frames_the_ground_truth_covers(shared_data):
    """TUM's ground truth starts a few frames after its first image: a supervised pair's flow and depth are
    those of the frames whose poses make its target."""
    from deepslam.flow import registry as flow_registry

    seq = open_sequence(shared_data / "tum" / "rgbd_dataset_freiburg3_teddy")
    assert seq.gt_frames is not None and seq.gt_frames[0] > 0
    rows = frame_pairs(seq.gt.world_from_cam, PairSpec(strides=(1,)))[:3]
    pairs = np.asarray(seq.gt_frames)[rows]
    dis = flow_registry.make("dis")
    s = supervised_samples(seq, pairs, dis, 32, 24, progress=False, inv_depth=True)
    for k, (i, j) in enumerate(pairs):
        expect = se3.to_euler6(se3.inverse(seq.gt_pose(int(j))) @ seq.gt_pose(int(i)))
        np.testing.assert_allclose(s["target"][k], expect, atol=1e-6)
        np.testing.assert_allclose(s["inv_depth"][k], frame_inverse_depth(seq, int(i), 32, 24))
    with pytest.raises(InputError):
        supervised_samples(seq, np.array([[0, 1]]), dis, 32, 24, progress=False)  # frame 0 has no pose



def test_crop_views_cuts_a_window_and_moves_the_principal_point():
    """vo.data.synthetic.crop_views: the window's pixel (u, v) is the frame's (u + left, v + top), seen along the same
    ray by the window's camera; the places 0 and ~1 give the two extreme windows."""
    from deepslam.vo.data.synthetic import crop_views

    cam = PinholeCamera(20, 10, 15.0, 15.0, 9.5, 4.5)
    img = np.arange(200, dtype=np.float32).reshape(10, 20)
    for place, (top, left) in (((0.0, 0.0), (0, 0)), ((0.9999, 0.9999), (2, 6)), ((0.5, 0.5), (1, 3))):
        (cut, none), wcam = crop_views((img, None), cam, (14, 8), place)
        assert none is None and cut.shape == (8, 14) and cut.flags["C_CONTIGUOUS"]
        np.testing.assert_array_equal(cut, img[top:top + 8, left:left + 14])
        assert (wcam.width, wcam.height, wcam.fx, wcam.cx, wcam.cy) == (14, 8, 15.0, 9.5 - left, 4.5 - top)
        uv = np.array([[0.0, 0.0], [13.0, 7.0]])
        np.testing.assert_allclose(wcam.unproject(uv, np.ones(2)), cam.unproject(uv + [left, top], np.ones(2)))


def test_estimated_flow_source_crop_window_spreads_the_principal_point(plane_sequence, motion_json, tmp_path):
    """EstimatedFlowSource(crop_window=...): every sample's intrinsics (at the network's size) carry its window's
    principal point, spread over the frame's margin; batches stay a function of (seed, epoch, batch); a window larger
    than a frame, or one given to exact flow, is one clear error. The train CLI records the window."""
    from deepslam.cli import main

    seq = open_sequence(plane_sequence)
    frames = load_image_frames([seq], frame_step=3, progress=False)  # 256 x 80 frames

    def motion(n, rng):
        return np.tile([0.0, 0.01, 0.0, 0.05, 0.0, -0.5], (n, 1)) + rng.normal(0, 0.01, (n, 6))

    src = EstimatedFlowSource(frames, motion, "dis", 80, 24, 16, seed=3, threads=2, crop_window=(224, 72))
    b1, b2 = next(iter(src.batches(0, 16))), next(iter(src.batches(0, 16)))
    assert torch.equal(b1["flow"], b2["flow"]) and torch.equal(b1["intrinsics"], b2["intrinsics"])
    k = b1["intrinsics"].numpy().astype(np.float64)  # fx, fy, cx, cy at 80 x 24
    cx_px = k[:, 2] * 224 / 80 + 0.5 * (224 / 80 - 1)  # back to the window's pixels
    offsets = seq.camera.cx - cx_px  # the window's first column in the frame
    assert offsets.min() >= -1e-4 and offsets.max() <= 32 + 1e-4 and offsets.std() > 5
    np.testing.assert_allclose(offsets, np.round(offsets), atol=1e-4)
    with pytest.raises(InputError, match="fit every frame"):
        EstimatedFlowSource(frames, motion, "dis", 80, 24, 16, crop_window=(300, 72))
    out = tmp_path / "crop"
    rc = main(["train", "--mode", "synthetic", "--synthetic-flow", "dis", "--dis-preset", "fast", "--crop-window", "224,72",
               "--coord-channels", "--source", str(plane_sequence), "--motion", str(motion_json), "--net", "tiny",
               "--batch", "16", "--samples-per-epoch", "32", "--max-epochs", "1", "--nll-epochs", "1", "--bf16", "off",
               "--threads", "1", "--quiet", "--out", str(out)])
    assert rc == 0 and json.loads((out / "config.json").read_text())["data"]["data"]["crop_window"] == [224, 72]
    rc = main(["train", "--mode", "synthetic", "--crop-window", "224,72", "--source", str(plane_sequence), "--motion",
               str(motion_json), "--net", "tiny", "--quiet", "--out", str(tmp_path / "exact")])
    assert rc == 2 and not (tmp_path / "exact").exists()
    rc = main(["train", "--mode", "synthetic", "--toy", "50", "--crop-window", "224,72", "--out", str(tmp_path / "toy")])
    assert rc == 2 and not (tmp_path / "toy").exists()
