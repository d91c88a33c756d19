"""Random lighting for domain randomisation: where the sun stands, how much light the shadowed faces
get, how bright and how warm or cool the light is, drawn from a seed.

The scenes bake Lambert shading into their texture atlas (``scenes.assemble.Assembler``), so a
:class:`Lighting` acts when a scene is built: ``sun_dir`` and ``ambient`` go to the assembler, and
``gain_rgb`` multiplies the finished atlas and the sky colour (the light's brightness and colour
temperature). Geometry, textures' content, movers and trajectories do not change with it: the draw
has its own random stream (``numpy.random.default_rng([seed, LIGHTING_STREAM])``).
"""
from __future__ import annotations

import dataclasses

import numpy as np

LIGHTING_STREAM = 0x11647
"""Second word of the lighting's random stream (the first is the scene seed)."""


@dataclasses.dataclass(frozen=True)
class Lighting:
    """One lighting of a scene."""

    sun_dir: tuple[float, float, float]
    """Unit vector towards the light, world frame (z up)."""
    ambient: float
    """Shading of faces turned away from the light, 0..1 (1: no shading)."""
    gain_rgb: tuple[float, float, float]
    """Per-channel gain on the baked atlas and the sky: brightness times colour temperature."""

    @classmethod
    def random(cls, seed: int) -> "Lighting":
        """Sun azimuth uniform, elevation 10-75 degrees; ambient 0.35-0.8; brightness 0.6-1.25;
        colour temperature from warm (evening) to cool (overcast): red and blue gains 1 +- 0.15."""
        rng = np.random.default_rng([int(seed), LIGHTING_STREAM])
        az = rng.uniform(0.0, 2.0 * np.pi)
        el = np.deg2rad(rng.uniform(10.0, 75.0))
        sun = (float(np.cos(el) * np.cos(az)), float(np.cos(el) * np.sin(az)), float(np.sin(el)))
        ambient = float(rng.uniform(0.35, 0.8))
        brightness = float(rng.uniform(0.6, 1.25))
        warmth = float(rng.uniform(-1.0, 1.0))
        gain = tuple(float(brightness * g) for g in (1.0 + 0.15 * warmth, 1.0, 1.0 - 0.15 * warmth))
        return cls(sun, ambient, gain)

    def apply_gain(self, rgb: np.ndarray) -> np.ndarray:
        """(..., 3) uint8 colours times ``gain_rgb``, rounded and clipped to uint8."""
        x = np.asarray(rgb, np.float32) * np.asarray(self.gain_rgb, np.float32)
        return np.clip(np.rint(x), 0, 255).astype(np.uint8)
