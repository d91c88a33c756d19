"""A principal point off the image centre (``RenderConfig.principal_point_px``, ``render --principal-point``):
the window of a larger centred render, exact to the pixel in every output."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.scenes.testing import looking_along_y, marker_scene
from deepslam.sim import KeyframeMotion, RenderConfig, SceneConfig, SimConfig, Simulator, TrajectoryConfig
from deepslam.sim.config import off_centre
from tests.test_reliability import _cli, _one_line_exit_2

CAM = PinholeCamera(96, 64, 70.0, 70.0, 47.5, 31.5)


@pytest.mark.parametrize("pp, canvas_size, window", [((44.0, 32.5), (103, 66), (0, 7)),
                                                     ((51.0, 31.5), (103, 64), (0, 0)),
                                                     ((47.5, 29.0), (96, 69), (5, 0)),
                                                     ((47.5, 31.5), (96, 64), (0, 0))])
def test_off_centre_canvas_and_window(pp, canvas_size, window):
    out, canvas, (top, left) = off_centre(CAM, pp)
    assert (out.width, out.height, out.fx, out.fy, out.cx, out.cy) == (96, 64, 70.0, 70.0, *pp)
    assert (canvas.width, canvas.height) == canvas_size and (top, left) == window
    assert (canvas.cx, canvas.cy) == ((canvas.width - 1) / 2, (canvas.height - 1) / 2) and canvas.fx == CAM.fx
    # pixel (u, v) of the output is pixel (u + left, v + top) of the canvas: the same ray
    uv = np.array([[0.0, 0.0], [95.0, 63.0], [30.0, 12.0]])
    np.testing.assert_allclose(out.unproject(uv, np.ones(3)), canvas.unproject(uv + [left, top], np.ones(3)))
    assert top + out.height <= canvas.height and left + out.width <= canvas.width


@pytest.mark.parametrize("pp, words", [((44.2, 31.5), "multiple of 0.5 px"), ((-1.0, 31.5), "outside"),
                                       ((47.5, 64.0), "outside")])
def test_off_centre_refuses_what_it_cannot_cut(pp, words):
    with pytest.raises(InputError, match=words):
        off_centre(CAM, pp)


@pytest.mark.parametrize("backend", ["mujoco", "pyrender"])
def test_marker_lands_on_the_pixels_the_off_centre_camera_predicts(backend):
    """A quad whose corners project, through the off-centre camera, to (20.3, 10.3) .. (60.7, 40.7) covers
    exactly the pixel centres inside: a render centred on the image (or a window off by a pixel) would
    cover columns 3.5 px and rows 1 px away."""
    out = PinholeCamera(96, 64, 70.0, 70.0, 44.0, 32.5)
    scene = marker_scene(out, (20.3, 10.3, 60.7, 40.7), marker_depth_m=2.0, plane_depth_m=4.0)
    scene.camera = CAM  # the scene's own (centred) camera; the render config moves the principal point
    cfg = SimConfig(trajectory=TrajectoryConfig(frames=1),
                    render=RenderConfig(backend=backend, width=96, height=64, stereo_baseline_m=0.0, flow=False,
                                        principal_point_px=(44.0, 32.5)))
    motion = KeyframeMotion(np.array([0.0]), looking_along_y()[None], 10.0)
    with Simulator(cfg, scene=scene, motion=motion) as sim:
        assert sim.camera == out
        f = sim.frame(0)
    assert f.rgb.shape == (64, 96, 3) and f.depth_z.shape == (64, 96)
    expected = np.zeros((64, 96), bool)
    expected[11:41, 21:61] = True
    assert ((f.body == 1) == expected).all(), np.argwhere((f.body == 1) != expected)[:5]
    np.testing.assert_allclose(f.depth_z[expected], 2.0, atol=1e-4)


def test_street_outputs_are_the_window_of_the_canvas_render():
    """Every output of a street frame (images, depth, flow both ways, occlusion, masks) with the principal
    point moved equals the window of the same frame rendered on the centred canvas, whose flow was computed
    with the canvas camera: the off-centre camera's geometry is the canvas's, cut."""
    def frames(render: RenderConfig):
        cfg = SimConfig(SceneConfig(name="street", seed=3), TrajectoryConfig(kind="car", frames=3, seed=3), render)
        with Simulator(cfg.validate()) as sim:
            return sim.camera, [sim.frame(i) for i in (0, 1)]

    cam, moved = frames(RenderConfig(width=96, height=29, stereo_baseline_m=0.3, principal_point_px=(44.0, 14.5)))
    canvas_cam, canvas = frames(RenderConfig(width=103, height=30, focal_px=cam.fx, stereo_baseline_m=0.3))
    assert (cam.cx, cam.cy, canvas_cam.cx, canvas_cam.cy) == (44.0, 14.5, 51.0, 14.5)
    for a, b in zip(moved, canvas):
        for key in ("rgb", "rgb_right", "depth_z", "flow", "flow_backward", "occlusion", "mask", "body"):
            x, y = getattr(a, key), getattr(b, key)
            if x is None and y is None:
                continue
            y = y[:29, 7:7 + 96]
            if key == "occlusion":  # a pixel whose motion leaves the output image is occluded there, not on the canvas
                u, v = np.meshgrid(np.arange(96), np.arange(29))
                tu, tv = u + a.flow[..., 0], v + a.flow[..., 1]
                inside = (tu > -0.5) & (tu < 95.5) & (tv > -0.5) & (tv < 28.5)
                assert x[~inside & np.isfinite(tu)].all() and (~inside).any()
                x, y = x[inside], y[inside]
            np.testing.assert_array_equal(x, y, err_msg=key)


def test_render_principal_point_flag_bad_input_is_one_line(tmp_path, capsys):
    for value, words in (("1,2,3", "two numbers"), ("a,b", "CX,CY"), ("200.2,61.5", "multiple of 0.5 px")):
        rc, err = _cli(["render", "--scene", "street", "--frames", "2", "--width", "414", "--principal-point", value,
                        "--out", tmp_path / "seq"], capsys)
        _one_line_exit_2(rc, err, words)
        assert not (tmp_path / "seq").exists()
