"""Shared machinery of the scene builders: one atlas, one static mesh, movers and flags."""
from __future__ import annotations

import cv2
import numpy as np

from deepslam.core import se3
from deepslam.scenes import textures as tx
from deepslam.scenes.geometry import AtlasBuilder, MeshBuilder
from deepslam.scenes.spec import DEFORM, STATIC, Body, FlagDeform, StaticPose


class Assembler:
    """Collects boxes and flags, then packs the atlas and returns the scene's bodies.

    Args:
        px_per_m: default texel density.
        rng: the scene's generator (regions spawn their own children from it).
        sun_dir: unit vector towards the light, used to bake Lambert shading into each face's texels.
        ambient: shading of faces turned away from the light (0..1).
    """

    def __init__(self, px_per_m: float, rng: np.random.Generator, sun_dir, ambient: float = 0.55,
                 max_texels: int = 24_000_000):
        self.atlas = AtlasBuilder(px_per_m, rng, max_texels=max_texels)
        self.rng = rng
        self.sun = np.asarray(sun_dir, np.float64) / np.linalg.norm(sun_dir)
        self.ambient = float(ambient)
        self.static = MeshBuilder()
        self._dynamic: list[tuple[str, MeshBuilder, str, object, FlagDeform | None, bool]] = []

    def shade(self, normal_world) -> float:
        return self.ambient + (1.0 - self.ambient) * max(0.0, float(np.dot(normal_world, self.sun)))

    def box(self, centre, half, painters: dict, yaw: float = 0.0, densities: dict | None = None,
            builder: MeshBuilder | None = None) -> None:
        """A box at ``centre`` (body frame) with half sizes ``half``, rotated by ``yaw`` about z.

        ``painters`` maps face names ("+x", "-x", "+y", "-y", "+z", "-z") to painters; a missing
        face is not built (faces on the ground or against another box). ``densities`` optionally
        scales the texel density per face.
        """
        builder = builder or self.static
        cs, sn = np.cos(yaw), np.sin(yaw)
        rot = np.array([[cs, -sn, 0], [sn, cs, 0], [0, 0, 1.0]])
        half = np.asarray(half, np.float64)
        regions = {}
        for name, painter in painters.items():
            ax = "xyz".index(name[1])
            n_box = np.eye(3)[ax] * (1 if name[0] == "+" else -1)
            n_world = rot @ n_box  # movers: shaded as in their body frame
            others = [i for i in range(3) if i != ax]
            if ax == 2:
                w_m, h_m = 2 * half[0], 2 * half[1]
            else:
                w_m, h_m = 2 * half[others[0] if others[0] != 2 else others[1]], 2 * half[2]
            dens = (densities or {}).get(name, 1.0)
            regions[name] = self.atlas.region(w_m, h_m, painter, shade=self.shade(n_world), density=dens)
        builder.add_box(se3.from_rt(rot, np.asarray(centre, np.float64)), half, regions)

    def dynamic_builder(self, name: str, kind: str, motion, deform: FlagDeform | None = None,
                        double_sided: bool = False) -> MeshBuilder:
        b = MeshBuilder()
        self._dynamic.append((name, b, kind, motion, deform, double_sided))
        return b

    def flag(self, name: str, world_from_flag: np.ndarray, deform: FlagDeform, painter, dynamic: bool) -> None:
        """A flag grid in its own body (x along the flag, z up, displaced along y)."""
        region = self.atlas.region(deform.length_m, deform.height_m, painter, shade=1.0)
        kind = DEFORM if dynamic else STATIC
        b = self.dynamic_builder(name, kind, StaticPose(world_from_flag), deform if dynamic else None, double_sided=True)
        b.add_grid([0, 0, 0], [1, 0, 0], [0, 0, 1], deform.length_m, deform.height_m, deform.nx, deform.nz, region)

    def finish(self) -> tuple[np.ndarray, list[Body]]:
        atlas = self.atlas.build()
        bodies = [Body("static", self.static.finish(self.atlas), STATIC, 0, StaticPose(np.eye(4)))]
        next_id = 1
        for name, b, kind, motion, deform, double in self._dynamic:
            inst = 0
            if kind != STATIC:
                inst = next_id
                next_id += 1
            bodies.append(Body(name, b.finish(self.atlas), kind, inst, motion, deform, double_sided=double))
        return atlas, bodies


def flag_painter(rng_style: np.random.Generator):
    """A flag: bold stripes/bands, an emblem and some text, plus cloth noise."""
    kind = int(rng_style.integers(0, 3))
    cols = rng_style.uniform(0, 255, (3, 3))

    def paint(h, w, ppm, rng):
        img = np.empty((h, w, 3), np.float32)
        if kind == 0:
            for i in range(3):
                img[:, i * w // 3:(i + 1) * w // 3] = cols[i]
        elif kind == 1:
            for i in range(3):
                img[i * h // 3:(i + 1) * h // 3] = cols[i]
        else:
            img[:] = cols[0]
            yy, xx = np.mgrid[0:h, 0:w]
            img[((xx + yy) // max(2, h // 6)) % 2 == 0] = cols[1]
        cv2.circle(img, (int(w * rng.uniform(0.3, 0.7)), h // 2), max(2, h // 4), tuple(float(c) for c in cols[2]), -1, cv2.LINE_AA)
        tx.put_text_box(img, w // 8, int(0.72 * h), 7 * w // 8, int(0.95 * h), tx._rand_text(rng, 4),
                        (250, 250, 250), tuple(float(c) for c in cols[1] * 0.5))
        img = img * (0.8 + 0.4 * tx.fbm(h, w, max(2.0, 0.2 * ppm), rng, 4))[..., None]
        return np.clip(img, 0, 255).astype(np.uint8)
    return paint
