"""Your own meshes in a scene (scenes.custom): placed where the file says, seen with exact depth, movers
with their own instance id and pose."""
import json

import numpy as np
import pytest

from deepslam.core.errors import InputError
from deepslam.scenes import SceneConfig, build_scene
from deepslam.scenes.custom import load_scene_file
from deepslam.sim import RenderConfig, SimConfig, Simulator, TrajectoryConfig


def _box(path, size=(2.0, 2.0, 2.0)):
    import trimesh

    trimesh.creation.box(extents=size).export(path)
    return path


def _start_pose():
    """The street car's camera at frame 0 (the scene file's meshes do not move it)."""
    cfg = SimConfig(SceneConfig(name="street", seed=5), TrajectoryConfig(frames=4), RenderConfig(width=160, stereo_baseline_m=0.0))
    with Simulator(cfg) as sim:
        return sim.trajectory.world_from_cam[0]


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("custom")
    _box(d / "box.obj")
    _box(d / "cart.ply", (1.5, 1.0, 1.2))
    w = _start_pose()
    fwd = w[:3, 2]
    yaw = np.degrees(np.arctan2(fwd[1], fwd[0]))
    at = w[:3, 3] + 9.0 * np.array([fwd[0], fwd[1], 0.0]) / np.hypot(fwd[0], fwd[1])
    spec = {"scene": "street", "seed": 5, "meshes": [
        {"file": "box.obj", "xyz": [float(at[0]), float(at[1]), 1.0], "yaw_deg": float(yaw), "rgb": [220, 40, 40]},
        {"file": "cart.ply", "path": {"waypoints": [[-5, -1.75], [60, -1.75], [60, 1.75], [-5, 1.75]], "speed_mps": 3.0,
                                      "z_m": 0.6}}]}
    f = d / "scene.json"
    f.write_text(json.dumps(spec))
    return f


def test_a_static_mesh_stands_where_the_file_puts_it(scene_file):
    spec = load_scene_file(scene_file)
    cfg = SimConfig(SceneConfig(name="street", seed=5, scene_file=str(spec.path)), TrajectoryConfig(frames=4),
                    RenderConfig(width=160, stereo_baseline_m=0.0))
    with Simulator(cfg) as sim:
        f = sim.frame(0, flow=False)
    h, w = f.depth_z.shape
    # the box's near face, 9 m - 1 m ahead, square to the optical axis: depth_z 8 m at the image centre
    centre = f.depth_z[h // 2 - 1:h // 2 + 2, w // 2 - 1:w // 2 + 2]
    np.testing.assert_allclose(centre, 8.0, atol=0.02)
    assert (f.rgb[h // 2, w // 2, 0] > 1.5 * f.rgb[h // 2, w // 2, 1])  # its red colour
    assert (f.mask[h // 2, w // 2] == 0)  # static: part of the static scene


def test_a_mesh_on_a_path_is_a_mover_with_its_own_id(scene_file):
    base = build_scene(SceneConfig(name="street", seed=5))
    scene = build_scene(SceneConfig(name="street", seed=5, scene_file=str(scene_file)))
    assert len(scene.bodies) == len(base.bodies) + 2
    cart = scene.bodies[-1]
    assert cart.kind == "rigid" and cart.instance_id >= 1
    assert cart.instance_id not in {b.instance_id for b in base.bodies if b.instance_id}
    # the other bodies keep their texels: coordinates rescaled to the taller atlas
    b0, s0 = base.bodies[0].mesh, scene.bodies[0].mesh
    ah0, ah1 = base.atlas.shape[0], scene.atlas.shape[0]
    np.testing.assert_allclose(s0.texcoords[:, 1] * ah1, b0.texcoords[:, 1] * ah0, atol=1e-9)
    assert np.array_equal(scene.atlas[:ah0], base.atlas)
    cfg = SimConfig(SceneConfig(name="street", seed=5, scene_file=str(scene_file)), TrajectoryConfig(frames=30),
                    RenderConfig(width=160, stereo_baseline_m=0.0))
    with Simulator(cfg) as sim:
        seen = [sim.frame(i, flow=False) for i in range(0, 30, 3)]
    assert any((f.mask == cart.instance_id).any() for f in seen), "the cart was placed where the camera sees it"
    assert all(cart.instance_id in f.instance_poses for f in seen)


@pytest.mark.parametrize("doc,what", [({"scene": "moon"}, "scene must be"), ({"meshes": [{"file": "nope.obj"}]}, "does not exist"),
                                      ({"colour": 1}, "unknown key"), ({"meshes": [{"file": "box.obj", "scale": -1}]}, "scale"),
                                      ({"meshes": [{"file": "box.obj", "path": {"waypoints": [[0, 0], [1, 1]]}}]}, "3 points")])
def test_bad_scene_files_name_the_file(tmp_path, doc, what):
    _box(tmp_path / "box.obj")
    f = tmp_path / "s.json"
    f.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=what) as e:
        load_scene_file(f)
    assert str(f) in str(e.value)
