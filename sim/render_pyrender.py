"""pyrender (pyrender2) render backend: ``pyrender.OffscreenRenderer``, two or three passes per view.

Pass 1 (colour): ``RenderFlags.FLAT`` (unlit: the atlas carries baked lighting), 4x multisampled.
Passes 2 (and 3) (segmentation): ``RenderFlags.SEG`` with one colour per scene body (index + 1 in 24 bits);
pyrender renders it without multisampling and returns its depth buffer with it, so depth and ids
are sampled at pixel centres. pyrender's depth buffer is 24-bit fixed point, linearised by pyrender
in float32: the error grows like z^2 / znear (below 1 mm up to about 150 m with the street's
znear of 1.5 m; tests compare it with MuJoCo's).

Camera: ``IntrinsicsCamera`` with the PinholeCamera's fx, fy and the principal point shifted by half
a pixel, ``(cx + 0.5, cy + 0.5)``: OpenGL puts pixel centres at half-integers, the project at
integers (a test renders known geometry to check the convention).
"""
from __future__ import annotations

import numpy as np

from deepslam.core.camera import PinholeCamera, world_from_cam_gl_from_cv
from deepslam.core import se3
from deepslam.scenes.spec import DEFORM, RIGID, STATIC, Scene
from deepslam.sim.world import WorldState


SLAB_STEP_M = 2.5e-4
"""Largest depth quantisation step (metres, at zfar) accepted from a single depth pass."""


class PyrenderBackend:
    """Renders a :class:`Scene` with pyrender; same interface as :class:`sim.render_mujoco.MujocoBackend`."""

    name = "pyrender"

    def __init__(self, scene: Scene, camera: PinholeCamera, baseline_m: float | None = None):
        import pyrender  # deferred: the [sim] extra; read after PYOPENGL_PLATFORM is set, only when rendering

        self.scene = scene
        self.camera = camera
        self.baseline_m = float(baseline_m or 0.0)
        self._pr = pyrender
        self.pscene = pyrender.Scene(bg_color=[c / 255.0 for c in scene.sky_rgb] + [1.0], ambient_light=[1.0, 1.0, 1.0])
        sampler = pyrender.Sampler(magFilter=pyrender.constants.GLTF.LINEAR,
                                   minFilter=pyrender.constants.GLTF.LINEAR_MIPMAP_LINEAR,
                                   wrapS=pyrender.constants.GLTF.CLAMP_TO_EDGE, wrapT=pyrender.constants.GLTF.CLAMP_TO_EDGE)
        tex = pyrender.Texture(source=scene.atlas, source_channels="RGB", sampler=sampler)
        self._mat = pyrender.MetallicRoughnessMaterial(baseColorTexture=tex, metallicFactor=0.0, roughnessFactor=1.0)
        self._mat2 = pyrender.MetallicRoughnessMaterial(baseColorTexture=tex, metallicFactor=0.0, roughnessFactor=1.0,
                                                        doubleSided=True)
        self._nodes = []
        self._seg_map = {}
        for i, b in enumerate(scene.bodies):
            node = pyrender.Node(name=b.name, mesh=self._mesh(b.mesh.vertices, b), matrix=b.motion.world_from_body(0.0)[0])
            self.pscene.add_node(node)
            self._nodes.append(node)
            self._seg_map[node] = _id_colour(i + 1)
        self._cam = pyrender.IntrinsicsCamera(camera.fx, camera.fy, camera.cx + 0.5, camera.cy + 0.5,
                                              znear=scene.znear_m, zfar=scene.zfar_m)
        self._cam_node = self.pscene.add(self._cam, pose=np.eye(4))
        self._renderer = pyrender.OffscreenRenderer(camera.width, camera.height)
        # pyrender's own read-back converts every depth buffer to metres in float32 with boolean
        # indexing (about 10 ms at 640x480); ours reads what each pass needs, raw
        self._renderer._renderer._read_main_framebuffer = self._read_main_framebuffer
        # segmentation passes need no multisampling (pyrender disables it but still fills and
        # resolves a 4x buffer): draw them into the single-sample buffer directly
        self._renderer._renderer._configure_forward_pass_viewport = self._configure_forward_pass_viewport
        self._want_depth = False
        self._world_from_cam = np.eye(4)

    def _mesh(self, vertices: np.ndarray, body):
        m = body.mesh
        prim = self._pr.Primitive(positions=vertices.astype(np.float32), normals=m.normals.astype(np.float32),
                                  texcoord_0=np.stack([m.texcoords[:, 0], 1.0 - m.texcoords[:, 1]], -1).astype(np.float32),
                                  indices=m.faces.astype(np.uint32), material=self._mat2 if body.double_sided else self._mat)
        return self._pr.Mesh([prim])

    def set_state(self, state: WorldState) -> None:
        self._world_from_cam = state.world_from_cam
        for i, b in enumerate(self.scene.bodies):
            if b.kind == RIGID:
                self.pscene.set_pose(self._nodes[i], state.world_from_body[i])
            elif b.kind == DEFORM:
                prim = self._nodes[i].mesh.primitives[0]
                if prim._in_context():  # already uploaded: replace its buffers
                    self._renderer._platform.make_current()
                    prim._remove_from_context()
                    prim.positions = state.flag_vertices[i].astype(np.float32)
                    prim._add_to_context()
                else:
                    prim.positions = state.flag_vertices[i].astype(np.float32)
            elif b.kind != STATIC:
                raise ValueError(b.kind)

    def render(self, side: str = "left", colour: bool = True, depth: bool = True) -> dict:
        """Same as :meth:`sim.render_mujoco.MujocoBackend.render`."""
        pr = self._pr
        world_from_cam = self._world_from_cam
        if side == "right":
            if not self.baseline_m:
                raise ValueError("no right camera (baseline 0?)")
            world_from_cam = world_from_cam @ se3.from_rt(np.eye(3), [self.baseline_m, 0.0, 0.0])
        self.pscene.set_pose(self._cam_node, world_from_cam_gl_from_cv(world_from_cam))
        self._cam.znear, self._cam.zfar = self.scene.znear_m, self.scene.zfar_m
        out = {}
        if colour:
            rgb, _ = self._renderer.render(self.pscene, flags=pr.RenderFlags.FLAT)
            out["rgb"] = np.ascontiguousarray(rgb)
        if depth:
            n, f = self.scene.znear_m, self.scene.zfar_m
            if f * f / (n * 2.0 ** 24) < SLAB_STEP_M:   # one pass is precise enough (the room)
                body, d = self._seg_pass(n, f)
                out["body"], out["depth_z"] = body, d.astype(np.float32)
            else:
                # two depth slabs, [znear, split] and [split, zfar], split at their geometric mean: a
                # 24-bit standard-Z buffer over the street's range would be off by ~1 mm at 100 m
                split = float(np.sqrt(n * f))
                body1, d1 = self._seg_pass(n, split * 1.01)   # the slabs overlap: no gap at the seam
                body2, d2 = self._seg_pass(split * 0.99, f)
                near = body1 >= 0
                out["body"] = np.where(near, body1, body2)
                out["depth_z"] = np.where(near, d1, d2).astype(np.float32)
        return out

    def _configure_forward_pass_viewport(self, flags):
        """Stands in for ``pyrender.Renderer._configure_forward_pass_viewport``."""
        from OpenGL import GL  # deferred: the [sim] extra, after PYOPENGL_PLATFORM is set

        r = self._renderer._renderer
        r._configure_main_framebuffer()
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, r._main_fb if self._want_depth else r._main_fb_ms)
        GL.glViewport(0, 0, r.viewport_width, r.viewport_height)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthMask(GL.GL_TRUE)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDepthRange(0.0, 1.0)

    def _read_main_framebuffer(self, scene, flags):
        """Stands in for ``pyrender.Renderer._read_main_framebuffer``: for the colour pass resolve
        the multisampled buffer like pyrender and read the colour; for segmentation passes (drawn
        single-sampled) read the colour and the raw depth buffer (values in [0, 1]); flipped to
        image rows."""
        from OpenGL import GL  # deferred: the [sim] extra, after PYOPENGL_PLATFORM is set

        r = self._renderer._renderer
        w, h = r._main_fb_dims
        if not self._want_depth:  # colour pass: resolve the multisampled buffer, as pyrender does
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, r._main_fb_ms)
            GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, r._main_fb)
            GL.glBlitFramebuffer(0, 0, w, h, 0, 0, w, h, GL.GL_COLOR_BUFFER_BIT, GL.GL_LINEAR)
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, r._main_fb)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        colour = np.frombuffer(GL.glReadPixels(0, 0, w, h, GL.GL_RGB, GL.GL_UNSIGNED_BYTE), np.uint8).reshape(h, w, 3)[::-1]
        depth = None
        if self._want_depth:
            depth = np.frombuffer(GL.glReadPixels(0, 0, w, h, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT), np.float32).reshape(h, w)[::-1]
        return colour, depth

    def _seg_pass(self, znear: float, zfar: float) -> tuple[np.ndarray, np.ndarray]:
        """Body ids and depth_z (float64 metres, 0 = nothing) of a segmentation pass clipped to
        [znear, zfar]; the 24-bit depth buffer is linearised in float64 (pyrender uses float32)."""
        self._cam.znear, self._cam.zfar = znear, zfar
        self._want_depth = True
        try:
            seg, d = self._renderer.render(self.pscene, flags=self._pr.RenderFlags.SEG, seg_node_map=self._seg_map)
        finally:
            self._want_depth = False
        if len(self.scene.bodies) < 255:
            body = seg[..., 0].astype(np.int32) - 1
        else:
            s = seg.astype(np.int32)
            body = (s[..., 0] | (s[..., 1] << 8) | (s[..., 2] << 16)) - 1
        d = d.astype(np.float64)
        n, f = float(znear), float(zfar)
        with np.errstate(divide="ignore"):
            z = 2.0 * n * f / (f + n - (2.0 * d - 1.0) * (f - n))
        return body, np.where((body >= 0) & (d < 1.0), z, 0.0)

    def close(self) -> None:
        """Free the GL resources. pyrender's own ``OffscreenRenderer.delete()`` calls
        ``eglTerminate`` on the EGL display, which is shared process-wide with MuJoCo's EGL
        contexts and would break every live (and every later) MuJoCo renderer; so with EGL the
        context is destroyed here without terminating the display."""
        r = getattr(self, "_renderer", None)
        if r is None:
            return
        self._renderer = None
        plat = r._platform
        if plat is None:
            return
        if hasattr(plat, "_egl_display") and plat._egl_display is not None:
            from OpenGL import EGL  # deferred: the [sim] extra, after PYOPENGL_PLATFORM is set

            plat.make_current()
            r._renderer.delete()
            EGL.eglMakeCurrent(plat._egl_display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
            if plat._egl_context is not None:
                EGL.eglDestroyContext(plat._egl_display, plat._egl_context)
            plat._egl_context = None
            plat._egl_display = None
            r._renderer = None
            r._platform = None
        else:
            r.delete()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


def _id_colour(k: int) -> np.ndarray:
    return np.array([k & 255, (k >> 8) & 255, (k >> 16) & 255], np.float64)
