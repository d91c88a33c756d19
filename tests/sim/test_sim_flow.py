"""Ground-truth flow, depth and stereo against geometry: static, rigidly moving and deforming surfaces."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepslam.core import se3
from deepslam.scenes.testing import looking_along_y, mini_scene
from deepslam.sim import KeyframeMotion, RenderConfig, SimConfig, Simulator, TrajectoryConfig


def _motion():
    """A camera moving forward/sideways while turning and tilting: 10 Hz, C2 keyframes."""
    keys = []
    for k, t in enumerate(np.linspace(0, 1.0, 5)):
        rot = Rotation.from_euler("zxy", [0.25 * t, -0.1 * t, 0.05 * np.sin(3 * t)]).as_matrix()
        pose = looking_along_y((0.3 * t, 0.8 * t, 0.1 * np.sin(2 * t)))
        pose[:3, :3] = rot @ pose[:3, :3]
        keys.append(pose)
    return KeyframeMotion(np.linspace(0, 1.0, 5), np.array(keys), 10.0)


@pytest.fixture(scope="module", params=["mujoco", "pyrender"])
def frames(request):
    cfg = SimConfig(trajectory=TrajectoryConfig(frames=6),
                    render=RenderConfig(backend=request.param, width=160, height=120, stereo_baseline_m=0.2))
    scene = mini_scene(seed=3, deform_amplitude_m=0.15, px_per_m=40)
    with Simulator(cfg, scene=scene, motion=_motion()) as sim:
        out = [sim.frame(i, depth_right=True) for i in (2, 3)]
        yield sim, out


def _predict(sim, f0, f1, pixels):
    """Independent prediction of where pixels (N, 2) of f0 go in f1, from geometry only: the static
    scene by the camera motion, rigid movers by their reported poses."""
    cam = sim.camera
    u, v = pixels[:, 0], pixels[:, 1]
    z = f0.depth_z[v, u].astype(np.float64)
    p0 = cam.unproject(pixels.astype(np.float64), z)
    p_w = se3.transform_points(f0.world_from_cam, p0)
    ids = f0.mask[v, u]
    for inst, pose0 in f0.instance_poses.items():
        m = ids == inst
        p_w[m] = se3.transform_points(f1.instance_poses[inst] @ se3.inverse(pose0), p_w[m])
    p1 = se3.transform_points(se3.inverse(f1.world_from_cam), p_w)
    uv1, z1 = cam.project(p1)
    return uv1, z1


def test_flow_of_static_and_rigid_pixels_is_their_geometric_motion(frames):
    sim, (f0, f1) = frames
    flag_ids = {b.instance_id for b in sim.scene.bodies if b.kind == "deform"}
    rigid_ids = set(f0.instance_poses)
    assert rigid_ids and (np.isin(f0.mask, list(rigid_ids))).sum() > 50, "the mover must be in view"
    sel = (f0.depth_z > 0) & ~np.isin(f0.mask, list(flag_ids))
    vv, uu = np.nonzero(sel)
    pix = np.stack([uu, vv], -1)
    uv1, z1 = _predict(sim, f0, f1, pix)
    assert (z1 > 0).all()
    got = pix + f0.flow[vv, uu].astype(np.float64)
    err = np.abs(got - uv1).max(axis=1)
    assert err.max() < 0.01, err.max()
    assert np.abs(f0.flow[vv, uu]).max() > 2.0  # the motion is not trivial


def test_flow_on_the_waving_flag_lands_on_the_flag_at_t_plus_1(frames):
    """For flag pixels, the flow target's ray at t+1 hits the flag mesh at t+1 (brute-force
    ray-triangle intersection over all its triangles) exactly where the flow's 3D point is."""
    sim, (f0, f1) = frames
    k = next(i for i, b in enumerate(sim.scene.bodies) if b.kind == "deform")
    body = sim.scene.bodies[k]
    vv, uu = np.nonzero(f0.body == k)
    assert len(vv) > 100, "the flag must be in view"
    idx = np.random.default_rng(0).choice(len(vv), size=min(150, len(vv)), replace=False)
    vv, uu = vv[idx], uu[idx]
    cam = sim.camera
    # the flow's claim: target pixel; and the depth there from the deformation model
    target = np.stack([uu, vv], -1) + f0.flow[vv, uu].astype(np.float64)
    # flag mesh at t+1 in camera t+1
    world_from_flag = body.motion.world_from_body(0.0)[0]
    verts = se3.transform_points(se3.inverse(f1.world_from_cam) @ world_from_flag, body.deform.vertices_at(f1.timestamp_s))
    tri = verts[body.mesh.faces]  # (F, 3, 3)
    rays = np.stack([(target[:, 0] - cam.cx) / cam.fx, (target[:, 1] - cam.cy) / cam.fy, np.ones(len(target))], -1)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    h = np.cross(rays[:, None], e2[None])
    a = np.einsum("fk,nfk->nf", e1, h)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -tri[None, :, 0]
        bu = np.einsum("nfk,nfk->nf", s, h) / a
        q = np.cross(s, e1[None])
        bv = np.einsum("nk,nfk->nf", rays, q) / a
        tt = np.einsum("fk,nfk->nf", e2, q) / a
    hit = (bu >= -1e-9) & (bv >= -1e-9) & (bu + bv <= 1 + 1e-9) & (tt > 0)
    assert hit.any(axis=1).all()
    t_hit = np.where(hit, tt, np.inf).min(axis=1)
    # the point the flow follows, in camera t+1
    p0 = cam.unproject(np.stack([uu, vv], -1).astype(np.float64), f0.depth_z[vv, uu].astype(np.float64))
    p_flag0 = se3.transform_points(se3.inverse(world_from_flag) @ f0.world_from_cam, p0)
    p_flag1 = body.deform.advance(p_flag0, f0.timestamp_s, f1.timestamp_s)
    p1 = se3.transform_points(se3.inverse(f1.world_from_cam) @ world_from_flag, p_flag1)
    np.testing.assert_allclose(t_hit, p1[:, 2], atol=1e-6)
    # and the flag really moved non-rigidly between the frames (else the test proves little)
    moved = np.linalg.norm(p_flag1 - p_flag0, axis=1)
    assert moved.max() > 0.01 and moved.std() > 1e-3


def _valid_targets(sim, f0, f1, sel):
    """Pixels of f0 in ``sel`` whose flow target is inside f1 and not occluded there."""
    vv, uu = np.nonzero(sel)
    tgt = np.stack([uu, vv], -1) + f0.flow[vv, uu].astype(np.float64)
    h, w = f0.depth_z.shape
    inside = (tgt[:, 0] > 1) & (tgt[:, 0] < w - 2) & (tgt[:, 1] > 1) & (tgt[:, 1] < h - 2)
    vv, uu, tgt = vv[inside], uu[inside], tgt[inside]
    _, z1 = _predict(sim, f0, f1, np.stack([uu, vv], -1))
    d1 = cv2.remap(f1.depth_z, tgt[:, 0].astype(np.float32)[None], tgt[:, 1].astype(np.float32)[None], cv2.INTER_NEAREST)[0]
    visible = np.abs(d1 - z1) < 0.02 * z1
    return vv[visible], uu[visible], tgt[visible]


def test_photometric_error_of_warping_by_the_flow_is_small(frames):
    sim, (f0, f1) = frames
    grey0 = cv2.cvtColor(f0.rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    grey1 = cv2.cvtColor(f1.rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    gx, gy = cv2.Sobel(grey0, cv2.CV_32F, 1, 0), cv2.Sobel(grey0, cv2.CV_32F, 0, 1)
    textured = np.hypot(gx, gy) > 20
    # interior of static surfaces (no object edges in the 3x3 neighbourhood)
    interior = cv2.erode((f0.body == 0).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    vv, uu, tgt = _valid_targets(sim, f0, f1, textured & interior & (f0.depth_z > 0))
    assert len(vv) > 500

    def err(offset):
        warped = cv2.remap(grey1, (tgt[:, 0] + offset).astype(np.float32)[None], tgt[:, 1].astype(np.float32)[None], cv2.INTER_LINEAR)[0]
        return float(np.median(np.abs(warped - grey0[vv, uu])))

    e = err(0.0)
    assert e < 6.0, e
    assert err(0.5) > 1.3 * e and err(1.0) > 2 * e  # a sub-pixel error in the flow would show


def test_stereo_disparity_is_f_b_over_z(frames):
    """Left pixel (u, v) with depth z sees the same surface point as right pixel (u - f B / z, v):
    the right camera's depth there is z, and the colours match."""
    sim, (f0, _) = frames
    cam, b = sim.camera, f0.baseline_m
    assert b == pytest.approx(0.2)
    # geometry: the right camera is at +B along x
    np.testing.assert_allclose(se3.relative(f0.world_from_cam, f0.world_from_cam_right), se3.from_rt(np.eye(3), [b, 0, 0]), atol=1e-12)
    vv, uu = np.nonzero(f0.depth_z > 0)
    z = f0.depth_z[vv, uu].astype(np.float64)
    ur = uu - cam.fx * b / z
    inside = ur > 1
    vv, uu, z, ur = vv[inside], uu[inside], z[inside], ur[inside]
    zr = cv2.remap(f0.depth_right, ur.astype(np.float32)[None], vv.astype(np.float32)[None], cv2.INTER_NEAREST)[0]
    same = np.abs(zr - z) < 0.02 * z   # not occluded in the right view
    assert same.mean() > 0.85
    # nearest-pixel sampling on a smooth surface: the depth agrees to a fraction of a pixel's extent
    zr_lin = cv2.remap(f0.depth_right, ur.astype(np.float32)[None], vv.astype(np.float32)[None], cv2.INTER_LINEAR)[0]
    interior = cv2.erode((f0.body >= 0).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)[vv, uu] & same
    assert np.median(np.abs(zr_lin[interior] - z[interior]) / z[interior]) < 1e-3
    gl = cv2.cvtColor(f0.rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    gr = cv2.cvtColor(f0.rgb_right, cv2.COLOR_RGB2GRAY).astype(np.float32)
    col = cv2.remap(gr, ur.astype(np.float32)[None], vv.astype(np.float32)[None], cv2.INTER_LINEAR)[0]
    assert np.median(np.abs(col[interior] - gl[vv, uu][interior])) < 6.0


def test_sky_pixels_get_the_rotation_only_flow(frames):
    sim, (f0, f1) = frames
    vv, uu = np.nonzero(f0.depth_z == 0)
    assert len(vv) > 100, "the view must include sky"
    cam = sim.camera
    rays = np.stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones(len(uu))], -1)
    rot = se3.relative(f1.world_from_cam, f0.world_from_cam)[:3, :3]
    uv1, _ = cam.project(rays @ rot.T)
    np.testing.assert_allclose(np.stack([uu, vv], -1) + f0.flow[vv, uu], uv1, atol=1e-3)
    assert (f0.mask[vv, uu] == 0).all() and (f0.body[vv, uu] == -1).all()
