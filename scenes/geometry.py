"""Geometry helpers for scene builders: a texture atlas, textured box/quad/grid meshes, closed C2 paths.

Texture coordinates: every mesh vertex carries ``texcoord = (s, t)`` in the scene's single texture
atlas, ``s = column / atlas_width`` and ``t = row / atlas_height`` with rows counted from the TOP of
the atlas image (row 0 = first row of the array). Renderers adapt this to their own convention
(MuJoCo takes (s, t) as is; OpenGL/pyrender uses (s, 1 - t)); tests check both against each other.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import cv2
import numpy as np
from scipy.interpolate import CubicSpline

from deepslam.scenes.textures import Painter

# ----------------------------------------------------------------------------------------------
# texture atlas
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass
class _Region:
    w_px: int
    h_px: int
    painter: Painter
    rng: np.random.Generator
    shade: float
    px_per_m: float


class AtlasBuilder:
    """Collects texture regions, packs them into one atlas image and paints them.

    Each region gets its own child generator at registration, so the painted bytes do not depend
    on packing order. Regions are padded by replicating their edges (less mipmap bleeding).

    Args:
        px_per_m: default texel density (texels per metre of surface).
        rng: generator the region generators are spawned from.
        max_texels: if the regions need more texels than this, all are scaled down uniformly.
        pad: padding in texels around each region.
    """

    def __init__(self, px_per_m: float, rng: np.random.Generator, max_texels: int = 24_000_000, pad: int = 4):
        self.px_per_m = float(px_per_m)
        self._rng = rng
        self.max_texels = int(max_texels)
        self.pad = int(pad)
        self._regions: list[_Region] = []
        self.rects: np.ndarray | None = None
        """(N, 5) float64 (x0, y0, w, h, rotated) of each region in the atlas after :meth:`build`:
        top-left pixel corner, the painted size, and 1 where it is stored turned 90 degrees
        counter-clockwise (portrait regions are stored landscape)."""
        self.shape: tuple[int, int] | None = None

    def region(self, w_m: float, h_m: float, painter: Painter, shade: float = 1.0,
               density: float = 1.0, min_px: int = 2, max_px: int = 4096) -> int:
        """Register a surface of ``w_m`` x ``h_m`` metres; returns the region's handle.

        ``density`` multiplies the default texel density (e.g. 0.1 for surfaces never seen close).
        ``shade`` (baked lighting factor) multiplies the painted colours.
        """
        ppm = self.px_per_m * density
        w_px = int(np.clip(np.ceil(w_m * ppm), min_px, max_px))
        h_px = int(np.clip(np.ceil(h_m * ppm), min_px, max_px))
        self._regions.append(_Region(w_px, h_px, painter, self._rng.spawn(1)[0], float(shade), ppm))
        return len(self._regions) - 1

    def build(self) -> np.ndarray:
        """Pack, paint and return the atlas, uint8 (H, W, 3) RGB; fills :attr:`rects`."""
        regs = self._regions
        need = sum((r.w_px + 2 * self.pad) * (r.h_px + 2 * self.pad) for r in regs)
        scale = min(1.0, np.sqrt(self.max_texels / max(need, 1)))
        if scale < 1.0:
            for r in regs:
                r.w_px = max(2, int(r.w_px * scale))
                r.h_px = max(2, int(r.h_px * scale))
                r.px_per_m *= scale
            need = sum((r.w_px + 2 * self.pad) * (r.h_px + 2 * self.pad) for r in regs)
        # store portrait regions rotated (landscape), then first-fit shelves by decreasing height
        rot = np.array([r.h_px > r.w_px for r in regs])
        pw = np.array([(r.h_px if q else r.w_px) + 2 * self.pad for r, q in zip(regs, rot)])
        ph = np.array([(r.w_px if q else r.h_px) + 2 * self.pad for r, q in zip(regs, rot)])
        aw = int(max(pw.max(), 2 ** int(np.ceil(np.log2(max(np.sqrt(need * 1.05), 16))))))
        aw = int(np.ceil(aw / 4) * 4)
        order = sorted(range(len(regs)), key=lambda i: (-ph[i], i))
        shelves: list[list[int]] = []   # [y, height, x_used]
        pos = np.zeros((len(regs), 2), np.int64)
        y_end = 0
        for i in order:
            for sh in shelves:
                if ph[i] <= sh[1] and sh[2] + pw[i] <= aw:
                    pos[i] = (sh[2] + self.pad, sh[0] + self.pad)
                    sh[2] += pw[i]
                    break
            else:
                shelves.append([y_end, int(ph[i]), int(pw[i])])
                pos[i] = (self.pad, y_end + self.pad)
                y_end += int(ph[i])
        ah = int(np.ceil(y_end / 4) * 4)
        atlas = np.zeros((ah, aw, 3), np.uint8)
        rects = np.zeros((len(regs), 5))
        for i, r in enumerate(regs):
            img = r.painter(r.h_px, r.w_px, r.px_per_m, r.rng)
            if img.shape[:2] != (r.h_px, r.w_px):
                raise RuntimeError(f"painter returned {img.shape}, expected {(r.h_px, r.w_px)}")
            if r.shade != 1.0:
                img = np.clip(img.astype(np.float32) * r.shade, 0, 255).astype(np.uint8)
            if rot[i]:
                img = np.rot90(img)  # counter-clockwise: pixel (row, col) -> (w - 1 - col, row)
            padded = cv2.copyMakeBorder(np.ascontiguousarray(img), self.pad, self.pad, self.pad, self.pad, cv2.BORDER_REPLICATE)
            x0, y0 = pos[i]
            atlas[y0 - self.pad:y0 + img.shape[0] + self.pad, x0 - self.pad:x0 + img.shape[1] + self.pad] = padded
            rects[i] = (x0, y0, r.w_px, r.h_px, float(rot[i]))
        self.rects = rects
        self.shape = (ah, aw)
        return atlas


# ----------------------------------------------------------------------------------------------
# meshes
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(eq=False)
class MeshData:
    """A textured triangle mesh in its body's frame.

    Attributes:
        vertices: (V, 3) float64 metres, body frame.
        faces: (F, 3) int32 vertex indices, counter-clockwise seen from the front (normal side).
        normals: (V, 3) float64 unit normals (flat per face: boxes have 4 vertices per face).
        texcoords: (V, 2) float64 atlas coordinates (s, t), t counted from the atlas' top row.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    texcoords: np.ndarray

    @staticmethod
    def concatenate(meshes: list["MeshData"]) -> "MeshData":
        offs = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return MeshData(np.concatenate([m.vertices for m in meshes]),
                        np.concatenate([m.faces + o for m, o in zip(meshes, offs)]).astype(np.int32),
                        np.concatenate([m.normals for m in meshes]),
                        np.concatenate([m.texcoords for m in meshes]))


class MeshBuilder:
    """Accumulates quads (each with its own atlas region) and grids; :meth:`finish` maps the
    per-region texture coordinates into the atlas once it is packed."""

    def __init__(self) -> None:
        self._v: list[np.ndarray] = []
        self._n: list[np.ndarray] = []
        self._ab: list[np.ndarray] = []   # (a, b) in [0,1]^2 inside the region, b from the top
        self._reg: list[np.ndarray] = []
        self._f: list[np.ndarray] = []
        self._count = 0

    def add_quad(self, bl, br, tr, tl, region: int) -> None:
        """A planar quad given by its corners as a viewer sees it from its front side: bottom-left,
        bottom-right, top-right, top-left (metres, body frame)."""
        corners = np.array([bl, br, tr, tl], np.float64)
        n = np.cross(corners[1] - corners[0], corners[3] - corners[0])
        n /= np.linalg.norm(n)
        self._v.append(corners)
        self._n.append(np.tile(n, (4, 1)))
        self._ab.append(np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float64))
        self._reg.append(np.full(4, region, np.int64))
        k = self._count
        self._f.append(np.array([[k, k + 1, k + 2], [k, k + 2, k + 3]], np.int64))
        self._count += 4

    def add_box(self, body_from_box: np.ndarray, half: np.ndarray, regions: dict[str, int]) -> None:
        """A box with half sizes ``half`` (metres) at ``body_from_box`` (4, 4).

        ``regions`` maps face names ("+x", "-x", "+y", "-y", "+z", "-z") to atlas regions. On the
        vertical faces (+-x, +-y) the texture's up is the box's +z and its right is up x normal (as
        seen from outside); on +z the texture's up is +y and its right +x.
        """
        half = np.asarray(half, np.float64)
        rot, t = body_from_box[:3, :3], body_from_box[:3, 3]
        axes = np.eye(3)
        for name, region in regions.items():
            sign = 1.0 if name[0] == "+" else -1.0
            ax = "xyz".index(name[1])
            n = axes[ax] * sign
            if ax == 2:
                up = axes[1] * sign
                right = axes[0]
            else:
                up = axes[2]
                right = np.cross(up, n)
            hu = half[int(np.argmax(np.abs(up)))]
            hr = half[int(np.argmax(np.abs(right)))]
            c = n * half[ax]
            pts = [c - right * hr - up * hu, c + right * hr - up * hu, c + right * hr + up * hu, c - right * hr + up * hu]
            self.add_quad(*[rot @ p + t for p in pts], region=region)

    def add_grid(self, origin, x_axis, z_axis, length_m: float, height_m: float, nx: int, nz: int, region: int) -> None:
        """A flat grid of nx x nz vertices spanning ``length_m`` along ``x_axis`` and ``height_m`` along
        ``z_axis`` from ``origin`` (the bottom-left corner); two triangles per cell, diagonal from
        (i, j) to (i+1, j+1). Vertex (i, j) has index ``i * nz + j``. The texture's top row is at
        the top edge (z = height), column 0 at x = 0."""
        origin, x_axis, z_axis = (np.asarray(a, np.float64) for a in (origin, x_axis, z_axis))
        xs = np.linspace(0.0, length_m, nx)
        zs = np.linspace(0.0, height_m, nz)
        gx, gz = np.meshgrid(xs, zs, indexing="ij")
        v = origin + gx.reshape(-1, 1) * x_axis + gz.reshape(-1, 1) * z_axis
        n = np.cross(x_axis, z_axis)
        n /= np.linalg.norm(n)
        ab = np.stack([gx.ravel() / length_m, 1.0 - gz.ravel() / height_m], axis=-1)
        i, j = np.meshgrid(np.arange(nx - 1), np.arange(nz - 1), indexing="ij")
        v00 = (i * nz + j).ravel()
        v10 = ((i + 1) * nz + j).ravel()
        v11 = ((i + 1) * nz + j + 1).ravel()
        v01 = (i * nz + j + 1).ravel()
        k = self._count
        faces = np.concatenate([np.stack([v00, v10, v11], -1), np.stack([v00, v11, v01], -1)]) + k
        self._v.append(v)
        self._n.append(np.tile(n, (len(v), 1)))
        self._ab.append(ab)
        self._reg.append(np.full(len(v), region, np.int64))
        self._f.append(faces)
        self._count += len(v)

    def finish(self, atlas: AtlasBuilder) -> MeshData:
        if self._count == 0:
            raise ValueError("empty mesh")
        ab = np.concatenate(self._ab)
        reg = np.concatenate(self._reg)
        rects = atlas.rects[reg]
        ah, aw = atlas.shape
        rotated = rects[:, 4] > 0.5
        col = np.where(rotated, ab[:, 1] * rects[:, 3], ab[:, 0] * rects[:, 2])
        row = np.where(rotated, (1.0 - ab[:, 0]) * rects[:, 2], ab[:, 1] * rects[:, 3])
        s = (rects[:, 0] + col) / aw
        t = (rects[:, 1] + row) / ah
        return MeshData(np.concatenate(self._v), np.concatenate(self._f).astype(np.int32),
                        np.concatenate(self._n), np.stack([s, t], axis=-1))


def box_faces(side: int, top: int, bottom: int | None = None) -> dict[str, int]:
    """Face -> region map using one region for all four sides (each side still gets its own
    texture coordinates: they share the painted image, so use this only for small boxes)."""
    faces = {"+x": side, "-x": side, "+y": side, "-y": side, "+z": top}
    if bottom is not None:
        faces["-z"] = bottom
    return faces


# ----------------------------------------------------------------------------------------------
# closed paths
# ----------------------------------------------------------------------------------------------


class PeriodicPath:
    """A closed planar C2 curve (periodic cubic spline) through points sampled about 1 m apart.

    The parameter ``c`` is the chord length of the samples (metres, nearly arc length: the true
    speed along the curve is ``|p'(c)| * dc/dt``); the curve repeats with period :attr:`length`.
    """

    def __init__(self, points_xy: np.ndarray):
        pts = np.asarray(points_xy, np.float64)
        closed = np.vstack([pts, pts[:1]])
        seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
        c = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(c[-1])
        self._spline = CubicSpline(c, closed, bc_type="periodic")

    def position(self, c) -> np.ndarray:
        """(..., 2) metres at parameters ``c`` (...,)."""
        return self._spline(np.mod(c, self.length))

    def derivative(self, c, order: int = 1) -> np.ndarray:
        return self._spline(np.mod(c, self.length), order)

    def heading(self, c) -> np.ndarray:
        d = self.derivative(c)
        return np.arctan2(d[..., 1], d[..., 0])

    def curvature(self, c) -> np.ndarray:
        d1, d2 = self.derivative(c, 1), self.derivative(c, 2)
        cross = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
        return cross / np.linalg.norm(d1, axis=-1) ** 3

    @staticmethod
    def from_polyline(corners_xy: np.ndarray, corner_radius_m: float, step_m: float = 1.0) -> "PeriodicPath":
        """A closed path through the polygon ``corners_xy`` (N, 2) with circular fillets of the
        given radius at every corner (collinear corners pass straight), sampled every ``step_m``."""
        p = np.asarray(corners_xy, np.float64)
        n = len(p)
        pieces = []
        for i in range(n):
            a, b, c = p[i - 1], p[i], p[(i + 1) % n]
            d0 = (b - a) / np.linalg.norm(b - a)
            d1 = (c - b) / np.linalg.norm(c - b)
            turn = np.arctan2(d0[0] * d1[1] - d0[1] * d1[0], d0 @ d1)
            if abs(turn) < 1e-6:
                pieces.append(("pt", b))
                continue
            tlen = corner_radius_m * np.tan(abs(turn) / 2)
            start = b - d0 * tlen
            normal = np.array([-d0[1], d0[0]]) * np.sign(turn)
            centre = start + normal * corner_radius_m
            pieces.append(("arc", centre, start - centre, turn, b + d1 * tlen))
        # walk: from the end of each corner's fillet to the start of the next one
        samples = []
        for i in range(n):
            piece = pieces[i]
            if piece[0] == "arc":
                _, centre, r0, turn, _ = piece
                k = max(2, int(np.ceil(abs(turn) * corner_radius_m / step_m)))
                for ang in np.linspace(0, turn, k, endpoint=False):
                    cs, sn = np.cos(ang), np.sin(ang)
                    samples.append(centre + np.array([cs * r0[0] - sn * r0[1], sn * r0[0] + cs * r0[1]]))
                seg_start = piece[4]
            else:
                seg_start = piece[1]
            nxt = pieces[(i + 1) % n]
            seg_end = nxt[1] + nxt[2] if nxt[0] == "arc" else nxt[1]
            length = np.linalg.norm(seg_end - seg_start)
            k = max(1, int(np.ceil(length / step_m)))
            for f in np.linspace(0, 1, k, endpoint=False):
                samples.append(seg_start + f * (seg_end - seg_start))
        return PeriodicPath(np.array(samples))


def offset_polyline(corners_xy: np.ndarray, offset_m: float) -> np.ndarray:
    """Offset a closed polygon to the right of its direction of travel by ``offset_m`` (lane
    centre of right-hand traffic); corners are the intersections of the offset edges."""
    p = np.asarray(corners_xy, np.float64)
    n = len(p)
    out = []
    for i in range(n):
        a, b, c = p[i - 1], p[i], p[(i + 1) % n]
        d0 = (b - a) / np.linalg.norm(b - a)
        d1 = (c - b) / np.linalg.norm(c - b)
        r0 = np.array([d0[1], -d0[0]])
        r1 = np.array([d1[1], -d1[0]])
        cross = d0[0] * d1[1] - d0[1] * d1[0]
        if abs(cross) < 1e-9:
            out.append(b + r0 * offset_m)
            continue
        # intersection of line (b + r0*o) + s*d0 and (b + r1*o) + u*d1
        rhs = (b + r1 * offset_m) - (b + r0 * offset_m)
        s = (rhs[0] * d1[1] - rhs[1] * d1[0]) / cross
        out.append(b + r0 * offset_m + s * d0)
    return np.array(out)


Motion = Callable[[np.ndarray], np.ndarray]
