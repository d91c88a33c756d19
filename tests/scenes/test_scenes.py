"""Scene builders: determinism, layout facts, geometry helpers, the MJCF they compile to."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core.errors import InputError
from deepslam.scenes import SceneConfig, build_scene
from deepslam.scenes.geometry import PeriodicPath, offset_polyline
from deepslam.scenes.room import build_room
from deepslam.scenes.spec import FlagDeform, PathProgress, speed_profile
from deepslam.scenes.street import build_street


def _build(name, seed, k=0, a=0.0, ppm=3.0):
    fn = build_street if name == "street" else build_room
    return fn(seed, ppm, k, a, np.random.default_rng(seed))


@pytest.mark.parametrize("name", ["street", "room"])
def test_same_seed_same_bytes_other_seed_other_scene(name):
    a, b, c = _build(name, 1), _build(name, 1), _build(name, 2)
    assert np.array_equal(a.atlas, b.atlas)
    assert all(np.array_equal(x.mesh.vertices, y.mesh.vertices) and np.array_equal(x.mesh.texcoords, y.mesh.texcoords)
               for x, y in zip(a.bodies, b.bodies))
    assert a.atlas.shape != c.atlas.shape or not np.array_equal(a.atlas, c.atlas)
    assert a.bodies[0].mesh.vertices.shape != c.bodies[0].mesh.vertices.shape or \
        not np.allclose(a.bodies[0].mesh.vertices, c.bodies[0].mesh.vertices)


@pytest.mark.parametrize("name", ["street", "room"])
def test_moving_objects_and_deformation_leave_the_static_geometry_alone(name):
    plain = _build(name, 3)
    busy = _build(name, 3, k=3, a=0.2)
    assert np.array_equal(plain.bodies[0].mesh.vertices, busy.bodies[0].mesh.vertices)
    kinds = [b.kind for b in busy.bodies]
    assert kinds.count("rigid") == 3 and kinds.count("deform") >= 1 and "deform" not in [b.kind for b in plain.bodies]
    ids = [b.instance_id for b in busy.bodies if b.dynamic]
    assert sorted(ids) == list(range(1, len(ids) + 1))
    flags_plain = [b for b in plain.bodies if b.name.startswith("flag")]
    assert flags_plain and all(b.instance_id == 0 for b in flags_plain)


def test_street_layout_has_a_200m_loop_and_a_revisited_stretch():
    s = _build("street", 0)
    bx, by = s.layout["block_m"]
    assert 2 * (bx + by) >= 200.0            # road loop around block A (centrelines)
    path = s.layout["lane_path"]
    assert path.length > 2 * 200.0            # the ego route: loop A, then around both blocks
    # the stretch of bottom road from x = 5 to x = bx - 5 is driven twice per lap
    c = np.linspace(0, path.length, 20000, endpoint=False)
    p = path.position(c)
    on_stretch = (np.abs(p[:, 1] + 1.75) < 0.05) & (p[:, 0] > 15) & (p[:, 0] < bx - 15)
    passes = np.sum(on_stretch & ~np.roll(on_stretch, 1))   # rising edges on the closed curve
    assert passes == 2
    assert s.znear_m == 1.5 and s.camera.width == 1241 and s.camera.fx == pytest.approx(718.856)
    assert s.stereo_baseline_m == 0.54 and s.rate_hz == 10.0


def test_room_is_a_hall_of_8_to_10_m_with_euroc_camera():
    s = _build("room", 0)
    lx, ly, h = s.layout["size_m"]
    assert 8.5 <= lx <= 10 and 8.5 <= ly <= 10 and 3.4 <= h <= 4
    assert (s.camera.width, s.camera.height, s.camera.fx) == (752, 480, 458.0)
    assert s.stereo_baseline_m == 0.11 and s.rate_hz == 20.0
    # nothing static inside the drone's ring except the central pole/table/flags
    v = s.bodies[0].mesh.vertices
    r = np.linalg.norm(v[:, :2], axis=1)
    inside = (r > 1.0) & (r < 2.3) & (v[:, 2] > 0.5) & (v[:, 2] < 2.5)
    assert not inside.any()


def test_periodic_path_is_c2_and_closed():
    corners = np.array([(0, 0), (60, 0), (60, 45), (0, 45)], float)
    path = PeriodicPath.from_polyline(offset_polyline(corners, 1.75), 9.0)
    assert path.length == pytest.approx(2 * (63.5 + 48.5) - 4 * (2 - np.pi / 2) * 9.0, rel=0.01)
    for order in (0, 1, 2):
        np.testing.assert_allclose(path.derivative(np.array([0.0]), order) if order else path.position(np.array([0.0])),
                                   path.derivative(np.array([path.length]), order) if order else path.position(np.array([path.length])),
                                   atol=1e-9)
    # the right-hand lane of a counter-clockwise loop lies outside the centreline rectangle
    p = path.position(np.linspace(0, path.length, 1000))
    assert p[:, 1].min() == pytest.approx(-1.75, abs=5e-3)   # cubic ringing at the arc ends: millimetres


def test_path_progress_gives_the_requested_speed():
    corners = np.array([(0, 0), (60, 0), (60, 45), (0, 45)], float)
    path = PeriodicPath.from_polyline(corners, 9.0)
    prof = speed_profile(path, 12.0, 3.0, 2.0)
    prog = PathProgress(path, prof, c0=5.0, ramp_s=3.0)
    t = np.arange(0, 60, 0.001)
    c = prog.c(t)
    speed = np.linalg.norm(np.diff(path.position(c), axis=0), axis=1) / 0.001
    np.testing.assert_allclose(speed, prog.speed_at(t[:-1] + 0.0005), rtol=2e-3, atol=2e-3)
    assert c[0] == pytest.approx(5.0) and speed[0] < 1e-3 and speed.max() <= 12.0 + 1e-6


def test_flag_advance_keeps_points_on_the_moving_mesh():
    flag = FlagDeform(nx=9, nz=5, length_m=1.6, height_m=1.0, amplitude_m=0.2, wavelength_m=1.0, freq_hz=1.0,
                      phase=0.3, tilt_rad_per_m=0.5)
    rng = np.random.default_rng(0)
    gx, gz = rng.uniform(0, 1.6, 200), rng.uniform(0, 1.0, 200)
    # points on the mesh at t0 by barycentric interpolation of its vertices
    v0 = flag.vertices_at(0.1)
    i = np.minimum((gx / 0.2).astype(int), 7)
    j = np.minimum((gz / 0.25).astype(int), 3)
    a, b = gx / 0.2 - i, gz / 0.25 - j
    y00, y10, y11, y01 = (v0[(i + di) * 5 + j + dj, 1] for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)))
    y = np.where(a >= b, (1 - a) * y00 + (a - b) * y10 + b * y11, (1 - b) * y00 + a * y11 + (b - a) * y01)
    p0 = np.stack([gx, y, gz], -1)
    p1 = flag.advance(p0, 0.1, 0.35)
    np.testing.assert_array_equal(p1[:, [0, 2]], p0[:, [0, 2]])
    # advancing to the same time is the identity; advancing at the vertices gives the vertices
    np.testing.assert_allclose(flag.advance(p0, 0.1, 0.1), p0, atol=1e-12)
    np.testing.assert_allclose(flag.advance(v0, 0.1, 0.35), flag.vertices_at(0.35), atol=1e-12)
    assert np.abs(p1[:, 1] - p0[:, 1]).max() > 0.02


def test_config_validation():
    for bad in (SceneConfig(name="moon"), SceneConfig(moving_objects=-1), SceneConfig(deform_amplitude_m=1.0),
                SceneConfig(texture_px_per_m=0.0), SceneConfig(seed=-3)):
        with pytest.raises(InputError):
            bad.validate()
    assert build_scene(SceneConfig(name="room", texture_px_per_m=3)) is build_scene(SceneConfig(name="room", texture_px_per_m=3))


def test_mjcf_compiles_and_keeps_the_geometry(tmp_path):
    import mujoco

    from deepslam.core import se3
    from deepslam.scenes import mjcf

    s = _build("street", 4, k=2, a=0.1)
    from deepslam.sim.render_mujoco import compile_model

    model = compile_model(s, 320, 240, 30.0, 0.5)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    assert model.ngeom == len(s.bodies) and model.ncam == 2 and model.nmocap == 3
    for i, b in enumerate(s.bodies):
        if b.kind == "rigid":
            continue
        g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, mjcf.geom_name(i))
        mid = model.geom_dataid[g]
        v = model.mesh_vert[model.mesh_vertadr[mid]:model.mesh_vertadr[mid] + model.mesh_vertnum[mid]]
        world = data.geom_xpos[g] + v @ data.geom_xmat[g].reshape(3, 3).T
        want = se3.transform_points(b.motion.world_from_body(0.0)[0], b.mesh.vertices)
        assert np.abs(world - want).max() < 1e-4
    path = mjcf.write_mjcf(s, tmp_path)
    assert mujoco.MjModel.from_xml_path(str(path)).ngeom == model.ngeom


def test_varied_street_layout_is_deterministic_narrower_and_leaves_the_default_alone():
    from deepslam.scenes.street import StreetLayout

    default = _build("street", 5)
    assert StreetLayout() == StreetLayout(sidewalk_m=3.5, park_probability=0.55)  # the original town's numbers
    varied_cfg = StreetLayout.varied(5)
    assert varied_cfg == StreetLayout.varied(5) and varied_cfg != StreetLayout.varied(6)
    assert 1.5 <= varied_cfg.sidewalk_m <= 3.5 and 3.8 <= varied_cfg.park_offset_m <= 4.75
    assert 0.3 <= varied_cfg.ego_lane_offset_m <= 1.75
    a = build_street(5, 3.0, 0, 0.0, np.random.default_rng(5), varied_cfg)
    b = build_street(5, 3.0, 0, 0.0, np.random.default_rng(5), varied_cfg)
    assert np.array_equal(a.bodies[0].mesh.vertices, b.bodies[0].mesh.vertices)
    assert not np.array_equal(a.bodies[0].mesh.vertices.shape, default.bodies[0].mesh.vertices.shape) or \
        not np.allclose(a.bodies[0].mesh.vertices, default.bodies[0].mesh.vertices)
    via_config = build_scene(SceneConfig(name="street", seed=5, texture_px_per_m=3.0, varied_layout=True))
    assert np.array_equal(via_config.bodies[0].mesh.vertices, a.bodies[0].mesh.vertices)
    plain_again = build_scene(SceneConfig(name="street", seed=5, texture_px_per_m=3.0, street_style="town"))
    assert np.array_equal(plain_again.bodies[0].mesh.vertices, default.bodies[0].mesh.vertices)


def test_narrow_street_is_narrow_with_cars_parked_on_the_road_along_both_kerbs():
    from deepslam.core.errors import InputError
    from deepslam.scenes.street import ROAD_HALF_M, StreetLayout

    lay = StreetLayout.narrow(5)
    assert lay == StreetLayout.narrow(5) and lay != StreetLayout.narrow(6)
    assert 4.0 <= lay.road_half_m <= 5.0 < ROAD_HALF_M
    # parked cars (1.8 m wide) stand on the road by the kerb, clear of the moving cars' lanes (1.8 m wide)
    assert lay.road_half_m - 1.1 <= lay.park_offset_m <= lay.road_half_m - 0.9
    assert lay.park_offset_m - 0.9 > lay.lane_offset_m + 0.9
    from deepslam.scenes.street import KERB_M

    def nearest_kerb_top(scene) -> float:
        """|y| of the pavement's nearest vertex at kerb height along the first street (y = 0)."""
        v = scene.bodies[0].mesh.vertices
        m = (np.abs(v[:, 2] - KERB_M) < 1e-9) & (v[:, 0] > 10) & (v[:, 0] < 40) & (np.abs(v[:, 1]) < 15)
        return float(np.abs(v[m, 1]).min())

    narrow = build_scene(SceneConfig(name="street", seed=5, texture_px_per_m=3.0, narrow_layout=True, moving_objects=2))
    town = build_scene(SceneConfig(name="street", seed=5, texture_px_per_m=3.0, moving_objects=2, street_style="town"))
    # the pavement moved in by exactly the road's lost half-width
    assert nearest_kerb_top(town) - nearest_kerb_top(narrow) == pytest.approx(ROAD_HALF_M - lay.road_half_m, abs=1e-6)
    with pytest.raises(InputError, match="one street layout"):
        SceneConfig(name="street", varied_layout=True, narrow_layout=True).validate()


def test_grainy_road_textures_the_asphalt_and_leaves_the_rest_of_the_street_alone():
    import cv2

    from deepslam.scenes import textures as tx

    def grain(img):  # relative contrast of the texture at 6-20 cm (ppm 25: 1.5-5 texels), what survives mip-mapping
        g = img.mean(axis=2)
        return float((cv2.GaussianBlur(g, (0, 0), 1.5) - cv2.GaussianBlur(g, (0, 0), 5)).std() / g.mean())

    smooth = [grain(tx.asphalt(200, 400, 25.0, np.random.default_rng(s))) for s in range(4)]
    grainy = [grain(tx.asphalt_grainy(200, 400, 25.0, np.random.default_rng(s))) for s in range(4)]
    assert max(smooth) < 0.025 < 0.04 < min(grainy)
    assert np.array_equal(tx.asphalt_grainy(50, 60, 25.0, np.random.default_rng(1)),
                          tx.asphalt_grainy(50, 60, 25.0, np.random.default_rng(1)))
    plain = build_scene(SceneConfig(name="street", seed=5, texture_px_per_m=3.0, street_style="town"))
    rough = build_scene(SceneConfig(name="street", seed=5, texture_px_per_m=3.0, grainy_road=True))
    assert all(np.array_equal(a.mesh.vertices, b.mesh.vertices) and np.array_equal(a.mesh.texcoords, b.mesh.texcoords)
               for a, b in zip(plain.bodies, rough.bodies))
    assert plain.atlas.shape == rough.atlas.shape and not np.array_equal(plain.atlas, rough.atlas)
    # only the road's texels change (each region paints from its own stream)
    assert 0.005 < float((plain.atlas != rough.atlas).any(axis=2).mean()) < 0.5
    with pytest.raises(InputError, match="street option"):
        SceneConfig(name="room", grainy_road=True).validate()
