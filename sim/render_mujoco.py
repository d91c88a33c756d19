"""MuJoCo render backend: the GL pipeline of ``mujoco.Renderer`` driven directly, two passes per view.

Pass 1 (colour): ``mjr_render`` of the scene as lit by the pure-ambient headlight (textures carry
baked lighting), 4x multisampled, read as RGB. Pass 2 (segmentation, as ``mujoco.Renderer`` does for
depth and segmentation): flat ID colours, no multisampling, read as ID colours and the depth buffer
in one go. MuJoCo draws it with multisampling off but into the 4-sample buffer, then resolves; here
it is drawn straight into MuJoCo's single-sample resolve buffer and read with PyOpenGL's
``glReadPixels`` (the same bytes, about half the pass's time: no 4-sample clear, no resolve).
MuJoCo renders depth with reversed Z into a float buffer; it is linearised here in float64 (the same
formula as ``mujoco.Renderer``, without its cast of the intermediate to float32), so depth_z is exact
to about 1e-6 relative. Pixels where nothing is hit get depth 0 and body -1.

Camera: a fixed camera on a mocap rig body, ``fovy`` from the PinholeCamera's ``fy``; MuJoCo's
cameras have square pixels and the principal point at the image centre, i.e. ((W-1)/2, (H-1)/2) in
the project's convention (pixel centres at integers); tests check this against projected geometry.
"""
from __future__ import annotations

import numpy as np

from deepslam.core import se3
from deepslam.core.camera import PinholeCamera, world_from_cam_gl_from_cv
from deepslam.scenes import mjcf
from deepslam.scenes.spec import DEFORM, RIGID, Scene
from deepslam.sim.world import WorldState


def compile_model(scene: Scene, width: int, height: int, fov_y_deg: float, baseline_m: float | None):
    """Compile the scene's MJCF and fill in its atlas; returns the ``mujoco.MjModel``."""
    import mujoco  # deferred: the [sim] extra; read after MUJOCO_GL is set, only when rendering

    model = mujoco.MjModel.from_xml_string(mjcf.scene_xml(scene, width, height, fov_y_deg, baseline_m))
    tid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXTURE, "atlas")
    adr = int(model.tex_adr[tid])
    n = scene.atlas.size
    if int(model.tex_width[tid]) * int(model.tex_height[tid]) * int(model.tex_nchannel[tid]) != n:
        raise RuntimeError("atlas texture size mismatch")
    model.tex_data[adr:adr + n] = scene.atlas.reshape(-1)
    return model



class MujocoBackend:
    """Renders a :class:`Scene` with MuJoCo.

    Args:
        scene: the scene.
        camera: the left (and right) camera; must have fx == fy and a centred principal point.
        baseline_m: right camera at +baseline along the camera x axis (None or 0: mono).
    """

    name = "mujoco"
    segmentation_in_resolve_buffer = True
    """Draw the segmentation pass into the single-sample resolve buffer (see the module docstring);
    False: MuJoCo's own path (the multisampled buffer, then a resolve), the same bytes, kept as the
    reference that tests and the speed bench compare with."""

    def __init__(self, scene: Scene, camera: PinholeCamera, baseline_m: float | None = None):
        import mujoco  # deferred: the [sim] extra; read after MUJOCO_GL is set, only when rendering

        _check_camera(camera)
        self.scene = scene
        self.camera = camera
        self.baseline_m = float(baseline_m or 0.0)
        self.model = compile_model(scene, camera.width, camera.height, camera.fov_y_deg, self.baseline_m or None)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._gl = mujoco.GLContext(camera.width, camera.height)
        self._gl.make_current()
        from OpenGL import GL  # deferred like MuJoCo: PyOpenGL reads PYOPENGL_PLATFORM on import

        self._gl_api = GL
        self._con = mujoco.MjrContext(m, mujoco.mjtFontScale.mjFONTSCALE_100)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._con)
        self._con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scn = mujoco.MjvScene(m, maxgeom=len(scene.bodies) + 16)
        self._opt = mujoco.MjvOption()
        self._rect = mujoco.MjrRect(0, 0, camera.width, camera.height)
        self._cams = {}
        for side, name in (("left", mjcf.LEFT_CAMERA), ("right", mjcf.RIGHT_CAMERA)):
            cid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, name)
            if cid >= 0:
                cam = mujoco.MjvCamera()
                cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
                cam.fixedcamid = cid
                self._cams[side] = cam
        self._rig_mocap = int(m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, mjcf.RIG_BODY)])
        self._mover_mocap = {}
        for i, b in enumerate(scene.bodies):
            if b.kind == RIGID:
                self._mover_mocap[i] = int(m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b.name)])
        # geom id -> scene body index (geom i is body i's only geom)
        self._geom_body = np.full(m.ngeom + 1, -1, np.int32)
        for i in range(len(scene.bodies)):
            self._geom_body[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, mjcf.geom_name(i))] = i
        # flags: where their vertices live in the model, and the compiler's mesh frame
        self._flags = {}
        for i, b in enumerate(scene.bodies):
            if b.kind == DEFORM:
                mid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_MESH, mjcf.mesh_name(i))
                adr, num = int(m.mesh_vertadr[mid]), int(m.mesh_vertnum[mid])
                if num != len(b.mesh.vertices):
                    raise RuntimeError(f"MuJoCo changed the vertex count of {b.name} ({num} != {len(b.mesh.vertices)})")
                orig_from_mesh = se3.from_quat_wxyz(m.mesh_quat[mid], m.mesh_pos[mid])
                check = se3.transform_points(orig_from_mesh, m.mesh_vert[adr:adr + num].astype(np.float64))
                if np.abs(check - b.mesh.vertices).max() > 1e-4:
                    raise RuntimeError(f"MuJoCo reordered the vertices of {b.name}")
                self._flags[i] = (mid, adr, num, se3.inverse(orig_from_mesh))
        self._seg_rgb = np.empty((camera.height, camera.width, 3), np.uint8)
        self._depth_raw = np.empty((camera.height, camera.width), np.float32)
        extent = float(m.stat.extent)
        self._near = float(np.float32(m.vis.map.znear * extent))
        self._far = float(np.float32(m.vis.map.zfar * extent))

    # ------------------------------------------------------------------------------------------

    def set_state(self, state: WorldState) -> None:
        """Move the camera rig and the movers, reshape the flags, and run MuJoCo's kinematics."""
        import mujoco  # deferred: the [sim] extra; read after MUJOCO_GL is set, only when rendering

        m, d = self.model, self.data
        world_from_rig = world_from_cam_gl_from_cv(state.world_from_cam)
        d.mocap_pos[self._rig_mocap] = world_from_rig[:3, 3]
        d.mocap_quat[self._rig_mocap] = se3.to_quat_wxyz(world_from_rig)
        for i, k in self._mover_mocap.items():
            d.mocap_pos[k] = state.world_from_body[i, :3, 3]
            d.mocap_quat[k] = se3.to_quat_wxyz(state.world_from_body[i])
        if self._flags:
            self._gl.make_current()
            for i, (mid, adr, num, mesh_from_orig) in self._flags.items():
                m.mesh_vert[adr:adr + num] = se3.transform_points(mesh_from_orig, state.flag_vertices[i]).astype(np.float32)
                mujoco.mjr_uploadMesh(m, self._con, mid)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_camlight(m, d)

    def render(self, side: str = "left", colour: bool = True, depth: bool = True) -> dict:
        """Render the current state from the ``side`` camera.

        Returns a dict with ``rgb`` (H, W, 3) uint8 (if colour), ``depth_z`` (H, W) float32 metres
        (0 = nothing hit) and ``body`` (H, W) int32 scene-body index, -1 = nothing (if depth).
        """
        import mujoco  # deferred: the [sim] extra; read after MUJOCO_GL is set, only when rendering

        if side not in self._cams:
            raise ValueError(f"no {side} camera (baseline 0?)")
        self._gl.make_current()
        mujoco.mjv_updateScene(self.model, self.data, self._opt, None, self._cams[side], mujoco.mjtCatBit.mjCAT_ALL, self._scn)
        out = {}
        if colour:
            rgb = np.empty((self.camera.height, self.camera.width, 3), np.uint8)
            mujoco.mjr_render(self._rect, self._scn, self._con)
            mujoco.mjr_readPixels(rgb, None, self._rect, self._con)
            out["rgb"] = np.ascontiguousarray(rgb[::-1])
        if depth:
            flags = self._scn.flags
            old = flags.copy()
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
            try:
                self._segmentation_pass()
            finally:
                np.copyto(flags, old)
            seg = self._seg_rgb[::-1].astype(np.int32)
            segid = seg[..., 0] | (seg[..., 1] << 8) | (seg[..., 2] << 16)
            ngeom = self._scn.ngeom
            seg_to_body = np.full(ngeom + 1, -1, np.int32)
            for k in range(ngeom):
                g = self._scn.geoms[k]
                if g.segid >= 0 and g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                    seg_to_body[g.segid + 1] = self._geom_body[g.objid]
            body = seg_to_body[np.minimum(segid, ngeom)]
            raw = self._depth_raw[::-1].astype(np.float64)
            out["depth_z"] = np.where(body >= 0, _linearise_reversed_z(raw, self._near, self._far), 0.0).astype(np.float32)
            out["body"] = body
        return out

    def _segmentation_pass(self) -> None:
        """Draw the scene (its flags set for segmentation) and read ID colours and raw depth into
        ``_seg_rgb`` / ``_depth_raw`` (OpenGL's bottom-up rows).

        With a multisampled offscreen buffer the pass goes into MuJoCo's single-sample resolve buffer
        (``offFBO_r``): segmentation draws with multisampling off, so every sample of a pixel holds
        the same value and the resolve would copy it; drawing there directly skips the 4-sample
        clear and the resolve. Without multisampling (or with ``segmentation_in_resolve_buffer`` off)
        MuJoCo's own render and read do it."""
        import mujoco  # deferred: the [sim] extra; read after MUJOCO_GL is set, only when rendering

        resolve = int(self._con.offFBO_r) if self.segmentation_in_resolve_buffer else 0
        if not resolve:
            mujoco.mjr_render(self._rect, self._scn, self._con)
            mujoco.mjr_readPixels(self._seg_rgb, self._depth_raw, self._rect, self._con)
            return
        GL = self._gl_api
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, resolve)
        try:
            mujoco.mjr_render(self._rect, self._scn, self._con)   # ends by re-binding MuJoCo's buffer
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, resolve)
            GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0)
            GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
            w, h = self.camera.width, self.camera.height
            GL.glReadPixels(0, 0, w, h, GL.GL_RGB, GL.GL_UNSIGNED_BYTE, self._seg_rgb)
            GL.glReadPixels(0, 0, w, h, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT, self._depth_raw)
        finally:
            mujoco.mjr_restoreBuffer(self._con)

    def close(self) -> None:
        if getattr(self, "_con", None) is not None:
            self._gl.make_current()
            self._con.free()
            self._con = None
        if getattr(self, "_gl", None) is not None:
            self._gl.free()
            self._gl = None

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


def _linearise_reversed_z(raw: np.ndarray, near: float, far: float) -> np.ndarray:
    """Metric depth from MuJoCo's reversed-Z depth buffer values (float64), as mujoco.Renderer."""
    zfar, znear = np.float32(far), np.float32(near)
    c = -(zfar + znear) / (zfar - znear)
    dd = -(np.float32(2) * zfar * znear) / (zfar - znear)
    c = np.float32(-0.5) * c - np.float32(0.5)
    dd = np.float32(-0.5) * dd
    with np.errstate(divide="ignore"):
        return float(dd) / (raw + float(c))


def _check_camera(camera: PinholeCamera) -> None:
    if abs(camera.fx - camera.fy) > 1e-9 * camera.fy:
        raise ValueError(f"renderers need square pixels (fx == fy), got fx={camera.fx}, fy={camera.fy}")
    if max(abs(d) for d in camera.principal_point_offset) > 1e-9:
        raise ValueError(f"renderers need the principal point at the image centre, got ({camera.cx}, {camera.cy})")
