"""Rolling shutter and random lighting: the rows are renders at their own times, the flow is the
per-row projection, the per-row poses are written; lighting changes the light and nothing else."""
import dataclasses
import json

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.scenes import SceneConfig, build_scene
from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig
from deepslam.sim.simulator import rolling_shutter_bands
from deepslam.sim.world import world_state

BASE = SimConfig(SceneConfig(name="street", seed=2, moving_objects=3), TrajectoryConfig(frames=20),
                 RenderConfig(width=160, stereo_baseline_m=0.0))
FRAME = 12


def _rs(readout_ms: float, bands: int) -> SimConfig:
    return dataclasses.replace(BASE, render=dataclasses.replace(BASE.render, rolling_shutter_ms=readout_ms,
                                                                rolling_shutter_bands=bands))


@pytest.fixture(scope="module")
def per_row():
    """Frame 12 with a 60 ms readout, every row at its own time (48 rows)."""
    with Simulator(_rs(60.0, 4096)) as sim:
        return sim.frame(FRAME), sim.row_time_offsets_s, sim.scene, sim.motion, sim.camera, sim.time(FRAME + 1)


def test_bands_cover_the_rows_with_their_middle_row_times():
    bands = rolling_shutter_bands(48, 0.047, 5)
    assert [b[0] for b in bands][0] == 0 and bands[-1][1] == 48
    assert all(a[1] == b[0] for a, b in zip(bands[:-1], bands[1:]))
    for r0, r1, dt in bands:
        assert dt == pytest.approx(((r0 + r1 - 1) / 2 / 47 - 0.5) * 0.047)
    assert [dt for *_, dt in rolling_shutter_bands(48, 0.047, 48)] == pytest.approx(list((np.arange(48) / 47 - 0.5) * 0.047))
    assert rolling_shutter_bands(48, 0.03, 1) == [(0, 48, 0.0)]


def test_each_band_of_rows_is_a_render_at_its_time():
    with Simulator(_rs(40.0, 4)) as sim:
        f = sim.frame(FRAME, flow=False)
        bands = sim._bands
        for r0, r1, dt in bands:
            sim.backend.set_state(world_state(sim.scene, sim.motion, sim.time(FRAME) + dt))
            want = sim.backend.render("left", colour=True, depth=True)
            np.testing.assert_array_equal(f.rgb[r0:r1], want["rgb"][r0:r1])
            np.testing.assert_array_equal(f.depth_z[r0:r1], want["depth_z"][r0:r1])
            np.testing.assert_array_equal(f.body[r0:r1], want["body"][r0:r1])
            np.testing.assert_allclose(f.row_poses[r0:r1], np.repeat(sim.motion.world_from_cam(sim.time(FRAME) + dt), r1 - r0, 0))


def test_frames_in_order_equal_frames_rendered_alone():
    """Frame i+1 reuses the depth bands frame i's occlusion test rendered: the same bytes as alone."""
    cfg = _rs(40.0, 4)
    with Simulator(cfg) as sim:
        in_order = [sim.frame(i) for i in (FRAME - 1, FRAME)]
    with Simulator(cfg) as sim:
        alone = sim.frame(FRAME)
    for name in ("rgb", "depth_z", "body", "flow", "occlusion", "flow_backward", "row_poses"):
        np.testing.assert_array_equal(getattr(in_order[1], name), getattr(alone, name), err_msg=name)


def test_one_band_is_the_global_shutter():
    """One band is captured at its middle row's time, the frame time: the same frame as without."""
    with Simulator(BASE) as sim:
        g = sim.frame(FRAME)
    with Simulator(_rs(30.0, 1)) as sim:
        r = sim.frame(FRAME)
    for name in ("rgb", "depth_z", "mask", "flow", "flow_backward", "occlusion"):
        np.testing.assert_array_equal(getattr(r, name), getattr(g, name), err_msg=name)
    np.testing.assert_allclose(r.row_poses, np.repeat(g.world_from_cam[None], g.rgb.shape[0], 0))


def test_rolling_shutter_flow_is_the_per_row_projection(per_row):
    """Independently of the simulator's flow code: each pixel's point at its row's time (static, or on a
    moving car), moved to the capture time of the row it lands in (frame 13), projects exactly there."""
    f, offsets, scene, motion, cam, t1 = per_row
    h, w = f.depth_z.shape
    vv, uu = np.mgrid[0:h, 0:w]
    hit = f.depth_z > 0
    land_u, land_v = uu + f.flow[..., 0], vv + f.flow[..., 1]
    inside = hit & np.isfinite(land_v) & (land_v > -0.5) & (land_v < h - 0.5)
    movers = 0
    errs = []
    for v, u in zip(*np.nonzero(inside)):
        p_cam0 = np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0]) * f.depth_z[v, u]
        x_world = se3.transform_points(f.row_poses[v], p_cam0[None])[0]
        b = f.body[v, u]
        r = int(np.rint(land_v[v, u]))
        t_r = t1 + offsets[r]
        if scene.bodies[b].kind == "rigid":
            movers += 1
            t_v = (f.timestamp_s + offsets[v])
            body_from_world = se3.inverse(scene.bodies[b].motion.world_from_body(t_v)[0])
            x_world = se3.transform_points(scene.bodies[b].motion.world_from_body(t_r)[0] @ body_from_world, x_world[None])[0]
        p1 = se3.transform_points(se3.inverse(motion.world_from_cam(t_r)[0]), x_world[None])[0]
        errs.append(np.hypot(cam.fx * p1[0] / p1[2] + cam.cx - land_u[v, u], cam.fy * p1[1] / p1[2] + cam.cy - land_v[v, u]))
    errs = np.array(errs)
    assert len(errs) > 0.5 * h * w and movers > 20
    assert np.quantile(errs, 0.995) < 2e-3, np.quantile(errs, [0.5, 0.99, 1.0])


def test_rolling_shutter_flow_differs_from_the_global_shutter_flow(per_row):
    f = per_row[0]
    with Simulator(BASE) as sim:
        g = sim.frame(FRAME)
    both = np.isfinite(f.flow).all(-1) & np.isfinite(g.flow).all(-1)
    diff = np.abs(f.flow[both] - g.flow[both])
    # the car moves ~1 m per frame; rows read 60 ms apart see the near road and facades skewed
    assert diff.mean() > 0.02 and diff.max() > 0.2


def test_row_poses_and_times_are_written(tmp_path):
    from deepslam.sim.writers import render_sequence

    cfg = dataclasses.replace(_rs(30.0, 6), trajectory=TrajectoryConfig(frames=3))
    root = render_sequence(cfg, tmp_path / "ours", fmt="ours", progress=False)
    head = json.loads((root / "sequence.json").read_text())
    offs = np.array(head["rolling_shutter"]["row_time_offsets_s"])
    h = head["camera"]["height"]
    assert head["has"]["row_poses"] and len(offs) == h and len(np.unique(offs)) == 6
    poses = np.load(root / "row_poses" / "000001.npy")
    assert poses.shape == (h, 4, 4) and poses.dtype == np.float64
    with Simulator(cfg) as sim:
        np.testing.assert_allclose(poses, sim.motion.world_from_cam(sim.time(1) + offs))
    kitti = render_sequence(cfg, tmp_path / "kitti", fmt="kitti", progress=False)
    assert "rolling_shutter" in json.loads((kitti / "deepslam.json").read_text())
    from deepslam.core.readers import open_sequence

    for path in (root, kitti):
        seq = open_sequence(path)
        np.testing.assert_array_equal(seq.row_poses(2), np.load(path / "row_poses" / "000002.npy"))
    np.save(root / "row_poses" / "000000.npy", np.zeros((3, 4, 4)))
    with pytest.raises(InputError, match="row poses"):
        open_sequence(root).row_poses(0)
    with Simulator(BASE) as sim:
        assert sim.row_time_offsets_s is None


@pytest.mark.parametrize("field,value", [("rolling_shutter_ms", -1.0), ("rolling_shutter_ms", float("inf")),
                                         ("rolling_shutter_bands", 0), ("rolling_shutter_bands", 2.5)])
def test_bad_rolling_shutter_settings_are_refused(field, value):
    with pytest.raises(InputError):
        RenderConfig(**{field: value}).validate()
    with pytest.raises(InputError, match="motion blur"):
        RenderConfig(rolling_shutter_ms=20.0, exposure_ms=10.0).validate()


@pytest.mark.parametrize("name", ["street", "room"])
def test_random_lighting_changes_the_light_and_nothing_else(name):
    plain = build_scene(SceneConfig(name=name, seed=4))
    lit = build_scene(SceneConfig(name=name, seed=4, random_lighting=True))
    other = build_scene(SceneConfig(name=name, seed=5, random_lighting=True))
    assert lit.atlas.shape == plain.atlas.shape and not np.array_equal(lit.atlas, plain.atlas)
    for a, b in zip(plain.bodies, lit.bodies):
        np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
        np.testing.assert_array_equal(a.mesh.texcoords, b.mesh.texcoords)
    again = build_scene(SceneConfig(name=name, seed=4, random_lighting=True, texture_px_per_m=plain.config.px_per_m))
    np.testing.assert_array_equal(again.atlas, lit.atlas)            # same seed, same light
    assert np.abs(lit.atlas.astype(int).mean((0, 1)) - other.atlas.astype(int).mean((0, 1))).max() > 1.0
