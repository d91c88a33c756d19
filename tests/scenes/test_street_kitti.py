"""The KITTI-look street: its geometry (narrow streets and a wide avenue, parked cars on the road),
the ego car's stop-and-go drive (0 to about 30 m/s in one sequence, C2), the camera's height and
pitch, cars driving ahead in view, and same seed -> same bytes."""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from deepslam.core.errors import InputError
from deepslam.scenes import SceneConfig, build_scene
from deepslam.scenes.geometry import PeriodicPath
from deepslam.scenes.spec import LeadProgress, StopGoProgress
from deepslam.scenes.street_kitti import KittiTown, build_kitti_street
from deepslam.sim.config import RenderConfig, SimConfig, TrajectoryConfig
from deepslam.sim.simulator import Simulator
from deepslam.sim.trajectories import CarMotion, make_motion
from deepslam.sim.writers import render_sequence


def _scene(seed=0, k=0, a=0.0):
    return build_kitti_street(seed, 3.0, k, a, np.random.default_rng(seed))


def test_same_seed_same_scene_and_movers_leave_the_static_geometry_alone():
    a, b, busy = _scene(1), _scene(1), _scene(1, k=4, a=0.2)
    assert np.array_equal(a.atlas, b.atlas)
    assert np.array_equal(a.bodies[0].mesh.vertices, b.bodies[0].mesh.vertices)
    assert np.array_equal(a.bodies[0].mesh.vertices, busy.bodies[0].mesh.vertices)
    assert [x.kind for x in busy.bodies].count("rigid") == 4
    assert not np.array_equal(a.bodies[0].mesh.vertices[:50], _scene(2).bodies[0].mesh.vertices[:50])


def test_roads_are_narrow_in_the_residential_block_and_wide_on_the_avenue():
    scene = _scene(3)
    v = scene.bodies[0].mesh.vertices
    road = v[np.abs(v[:, 2]) < 1e-6]             # road surface vertices (z = 0)
    a, _ = scene.layout["block_m"]
    town = KittiTown()
    segments = scene.layout["road_segments"]
    assert len(segments) == 7
    for (x0, y0), (x1, y1), half in segments:
        along_x = abs(y1 - y0) < 1e-9
        wide = along_x and min(x0, x1) > a - 1.0 or not along_x and x0 > a + 1.0
        lo, hi = town.wide_half_m if wide else town.narrow_half_m
        assert lo <= half <= hi
        # the road's surface reaches exactly half its width either side of the centreline
        edge = np.array([x0, y0 - half]) if along_x else np.array([x0 - half, y0])
        assert np.min(np.linalg.norm(road[:, :2] - edge, axis=1)) < 1e-6


def test_the_ego_car_drives_stop_and_go_from_standstill_to_about_30_mps():
    scene = _scene(0)
    motion = make_motion(scene, "car", np.random.default_rng([0, 1]))
    assert isinstance(motion, CarMotion) and isinstance(motion.progress, StopGoProgress)
    t = np.arange(0.0, 60.0, 0.05)
    v = motion.progress.speed_at(t)
    assert v[0] < 1.0                               # starts from standstill
    assert 27.0 <= v.max() <= 30.5                  # the avenue
    assert v.min() >= 0.0
    # it stops again within a lap (speed under 0.3 m/s somewhere after driving)
    lap = np.arange(5.0, motion.progress.period_s, 0.05)
    assert motion.progress.speed_at(lap).min() < 0.3
    # C2: acceleration (finite differences of the pose) stays physical and continuous
    pos = motion.world_from_cam(t)[:, :3, 3]
    acc = np.diff(pos, 2, axis=0) / 0.05 ** 2
    assert np.abs(acc[:, :2]).max() < 8.0
    assert np.abs(np.diff(acc, axis=0)).max() < 1.0
    # laps repeat: c(t + T) = c(t) + L
    p = motion.progress
    assert np.allclose(p.c(np.array([3.0])) + p.path.length, p.c(np.array([3.0 + p.period_s])), atol=1e-6)


def test_camera_is_1_65_m_up_and_pitched_one_degree_down():
    scene = _scene(0)
    motion = make_motion(scene, "car", np.random.default_rng([0, 1]))
    pose = motion.world_from_cam(np.array([4.0]))[0]
    assert np.isclose(pose[2, 3], 1.65)
    forward = pose[:3, 2]
    assert np.isclose(np.degrees(np.arcsin(-forward[2])), KittiTown().camera_pitch_deg, atol=1e-6)
    assert abs(pose[:3, 0][2]) < 1e-9               # no roll: the x axis stays level


def test_stop_go_progress_dwells_at_its_stops():
    path = PeriodicPath.from_polyline(np.array([(0, 0), (200, 0), (200, 40), (0, 40)], float), 10.0)
    prog = StopGoProgress(path, lambda c: np.full(np.shape(c), 12.0), [0.0, 250.0], [2.0, 3.0])
    t = np.arange(0.0, prog.period_s, 0.02)
    c = prog.c(t)
    assert np.all(np.diff(c) >= -1e-9)              # never backwards
    slow = prog.speed_at(t) < 0.3
    assert slow.sum() * 0.02 > 3.0                  # 5 s of dwell, its edges rounded by the smoothing


@pytest.mark.parametrize("seed", [1, 2])
def test_a_car_drives_ahead_in_view_in_every_short_render(seed):
    cfg = SimConfig(SceneConfig(name="street", seed=seed, moving_objects=1, street_style="kitti", texture_px_per_m=4.0),
                    TrajectoryConfig(frames=12), RenderConfig(width=160, flow=False, stereo_baseline_m=0.0))
    with Simulator(cfg) as sim:
        lead = [b for b in sim.scene.bodies if b.kind == "rigid"]
        assert isinstance(lead[0].motion.progress, LeadProgress) and lead[0].motion.progress.leader is sim.motion.progress
        share = np.array([(sim.frame(i, right=False).mask > 0).mean() for i in range(12)])
    assert np.mean(share > 0) >= 0.5
    # the car ahead keeps its distance: never closer than the standstill gap minus a car length
    t = np.arange(0.0, 40.0, 0.1)
    ego = sim.motion.world_from_cam(t)[:, :2, 3]
    car = lead[0].motion.world_from_body(t)[:, :2, 3]
    assert np.linalg.norm(car - ego, axis=1).min() > KittiTown().standstill_gap_m[0] - 2.5


@pytest.mark.parametrize("route", ["default", "laps"])
def test_same_seed_same_bytes_on_disk(tmp_path: Path, route):
    def render(out):
        cfg = SimConfig(SceneConfig(name="street", seed=5, moving_objects=2, street_style="kitti", texture_px_per_m=4.0,
                                    route=route), TrajectoryConfig(frames=2), RenderConfig(width=96)).validate()
        render_sequence(cfg, out, progress=False)
        return {p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(out.rglob("*")) if p.is_file() and p.name != "sequence.json"}

    a, b = render(tmp_path / "a"), render(tmp_path / "b")
    assert a == b and any(k.startswith("mask") for k in a)


def test_town_options_belong_to_the_town():
    with pytest.raises(InputError, match="town"):
        SceneConfig(name="street", street_style="kitti", grainy_road=True).validate()
    with pytest.raises(InputError, match="street style"):
        SceneConfig(name="street", street_style="paris").validate()
    assert build_scene(SceneConfig(name="street", street_style="town", texture_px_per_m=3.0)).layout.get("stop_and_go") is None


def test_a_record_without_a_street_style_reads_as_the_town():
    d = SimConfig().to_dict()
    del d["scene"]["street_style"]
    assert SimConfig.from_dict(d).scene.street_style == "town"


def _laps_drive(seed):
    scene = build_kitti_street(seed, 3.0, 0, 0.0, np.random.default_rng(seed), route_name="laps")
    motion = make_motion(scene, "car", np.random.default_rng([seed, 1]))
    t = np.arange(0.0, motion.progress.period_s, 0.1)          # one round at 10 Hz
    return scene, motion, motion.world_from_cam(t)


def _revisits(poses, min_gap_frames=100, radius_m=4.5):
    """(frame, earlier frame, cos of the angle between their optical axes) of the frames whose camera comes
    within ``radius_m`` of a camera at least ``min_gap_frames`` earlier (the nearest such)."""
    pos, axis = poses[:, :3, 3], poses[:, :3, 2]
    out = []
    for i in range(min_gap_frames, len(poses)):
        d = np.linalg.norm(pos[:i - min_gap_frames + 1] - pos[i], axis=1)
        j = int(np.argmin(d))
        if d[j] < radius_m:
            out.append((i, j, float(axis[i] @ axis[j])))
    return out


@pytest.mark.parametrize("seed", [0, 7])
def test_the_laps_route_revisits_the_same_way_and_the_opposite_way(seed):
    scene, motion, poses = _laps_drive(seed)
    a, d = scene.layout["block_m"]
    pos = poses[:, :3, 3]
    length = float(np.linalg.norm(np.diff(pos, axis=0), axis=1).sum())
    b = float(pos[:, 0].max()) - a - 1.75                     # the avenue's length, from the drive's east end
    assert length == pytest.approx(6 * a + 4 * b + 8 * d, rel=0.05)   # the block's lap + every road each way
    hits = _revisits(poses)
    same = [(i, j) for i, j, c in hits if c > 0.9]
    opposite = [(i, j) for i, j, c in hits if c < -0.9]
    # the block's lap is driven again the same way within the first ~200 m; its first frames seen again
    assert same and pos[same[0][0], 0] < a + 5 and np.linalg.norm(np.diff(pos[:same[0][0]], axis=0), axis=1).sum() < 230
    # every road is driven both ways: opposite revisits on the avenue (y = 0 and y = d) and on the three cross roads
    opp = pos[[i for i, _ in opposite]]
    assert (opp[:, 0] > a + 50).any()                                          # the avenue
    for x in (0.0, a):                                                           # the block's cross roads
        assert (np.abs(opp[:, 0] - x) < 3.0).sum() >= 10
    # the T-junctions are entered from three sides: headings at (a, 0) take three of the four directions
    near = np.linalg.norm(pos[:, :2] - [a, 0.0], axis=1) < 12.0
    heading = np.round(np.degrees(np.arctan2(poses[near, 1, 2], poses[near, 0, 2])) / 90.0) % 4
    assert len(set(heading.astype(int))) >= 3
    # the route closes: after one round the car is back where it started, heading the same way
    end = motion.world_from_cam(np.array([motion.progress.period_s]))[0]
    assert np.linalg.norm(end[:3, 3] - poses[0, :3, 3]) < 0.5 and end[:3, 2] @ poses[0, :3, 2] > 0.99


def test_the_laps_route_keeps_the_default_town_and_its_speeds():
    default, laps = _scene(4), build_kitti_street(4, 3.0, 0, 0.0, np.random.default_rng(4), route_name="laps")
    assert np.array_equal(default.bodies[0].mesh.vertices, laps.bodies[0].mesh.vertices)   # the same town
    _, motion, poses = _laps_drive(4)
    v = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) / 0.1
    assert v[0] < 1.0 and 27.0 <= v.max() <= 30.5 and (v[20:] < 0.3).any()             # stop-and-go, the avenue
    with pytest.raises(InputError, match="route 'laps' is a route of the street's KITTI look"):
        SceneConfig(name="street", street_style="town", route="laps").validate()
    with pytest.raises(InputError, match="unknown route"):
        SceneConfig(route="spiral").validate()
