"""Scenes for the simulator: procedural, textured, deterministic from a seed.

    from deepslam.scenes import SceneConfig, build_scene
    scene = build_scene(SceneConfig(name="street", seed=0, moving_objects=3, deform_amplitude_m=0.2))

A :class:`scenes.spec.Scene` is backend-neutral: one texture atlas (procedural textures with baked
lighting), a static triangle mesh, rigid movers (``world_from_body(t)``) and deforming flags
(``FlagDeform``). ``scenes.mjcf`` turns it into MJCF for MuJoCo; ``sim`` renders it with MuJoCo or
pyrender. Scenes:

- ``street``: a KITTI-like town block (two blocks in a ring road, facades, parked cars, poles,
  signs, trees, flags); default camera KITTI's (1241x376, f = 718.856, baseline 0.54 m), 10 Hz.
- ``room``: a EuRoC-like hall (8.5-10 m, shelves, boxes, posters, a table with flags); default
  camera EuRoC's (752x480, f = 458, baseline 0.11 m), 20 Hz.

Same config, same bytes: all randomness comes from ``numpy.random.default_rng(seed)``. The static
geometry, its textures' content and the flags do not depend on ``moving_objects`` or
``deform_amplitude_m`` (the atlas packing does: movers add texture regions).
"""
from __future__ import annotations

import dataclasses
import functools

import numpy as np

from deepslam.core.errors import InputError
from deepslam.scenes.custom import add_user_meshes, load_scene_file
from deepslam.scenes.lighting import Lighting
from deepslam.scenes.room import build_room
from deepslam.scenes.street import StreetLayout, build_street
from deepslam.scenes.street_kitti import ROUTES, build_kitti_street

SCENE_NAMES = ("street", "room")
STREET_STYLES = ("kitti", "town")
"""Looks of the street: ``kitti`` (:mod:`scenes.street_kitti`: narrow residential streets and a long
avenue, grainy asphalt, cars parked along both kerbs, stop-and-go driving up to 30 m/s, the camera
pitched 1 degree down) and ``town`` (:mod:`scenes.street`: the two-block town of uniform roads)."""
DEFAULT_PX_PER_M = {"street": 20.0, "room": 100.0}


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """What to build."""

    name: str = "street"
    """Scene: "street" (KITTI-like town) or "room" (EuRoC-like hall)."""
    seed: int = 0
    """Seed of the layout, the procedural textures and the moving objects."""
    moving_objects: int = 0
    """Number of moving objects: cars driving on the road (street) or boxes flying (room)."""
    deform_amplitude_m: float = 0.0
    """Amplitude of the waving flags in metres; 0 leaves the flags static (part of the static scene)."""
    texture_px_per_m: float | None = None
    """Texel density of the procedural textures, texels per metre (None: street 20, room 100)."""
    street_style: str | None = None
    """Street only: the street's look, one of :data:`STREET_STYLES`; None: ``town`` when one of the
    town's options below (varied or narrow layout, grainy road) is set, else ``kitti``."""
    varied_layout: bool = False
    """Street only: a narrow, crowded variant of the town from the seed (narrower pavements, so
    facades closer; more parked cars, trees and poles near the kerb), like KITTI's residential
    streets (:meth:`scenes.street.StreetLayout.varied`). False: the original town."""
    narrow_layout: bool = False
    """Street only: a narrow residential street from the seed (8-10 m kerb to kerb, cars parked on the
    road along both kerbs, the ego car near the middle, facades 1-2.5 m behind the kerb:
    :meth:`scenes.street.StreetLayout.narrow`). Not together with ``varied_layout``."""
    grainy_road: bool = False
    """Street only: asphalt with visible grain, its contrast drawn per road stretch
    (:func:`scenes.textures.asphalt_grainy`), instead of the near-uniform surface on which DIS reads
    a third of the road's motion (half on KITTI's real roads). The rest of the scene is unchanged."""
    scene_file: str | None = None
    """A scene file adding your own meshes to this scene (:mod:`scenes.custom`), or None."""
    route: str = "default"
    """Street, KITTI look only: the ego car's route, one of :data:`scenes.street_kitti.ROUTES`: ``default`` (the
    block once, then the avenue and back) or ``laps`` (the block's lap, then every road once each way: loop
    closures in both directions, :func:`scenes.street_kitti.ego_route`). The town is the same for both."""
    random_lighting: bool = False
    """Draw the lighting from the seed (:meth:`scenes.lighting.Lighting.random`: sun direction,
    ambient share, brightness, colour temperature) instead of the scene's fixed one; the geometry and
    everything else stay as without it."""

    def __post_init__(self):
        if self.street_style is None:
            town = self.varied_layout or self.narrow_layout or self.grainy_road
            object.__setattr__(self, "street_style", "town" if town else "kitti")

    def validate(self) -> "SceneConfig":
        if self.name not in SCENE_NAMES:
            raise InputError(None, f"unknown scene {self.name!r} (choose from {', '.join(SCENE_NAMES)})")
        if not isinstance(self.moving_objects, int) or self.moving_objects < 0 or self.moving_objects > 64:
            raise InputError(None, f"moving objects must be an integer in 0..64, got {self.moving_objects}")
        if not (np.isfinite(self.deform_amplitude_m) and 0.0 <= self.deform_amplitude_m <= 0.3):
            raise InputError(None, f"deform amplitude must be in [0, 0.3] m, got {self.deform_amplitude_m}")
        if self.texture_px_per_m is not None and not (1.0 <= self.texture_px_per_m <= 400.0):
            raise InputError(None, f"texture density must be in [1, 400] texels/m, got {self.texture_px_per_m}")
        street_only = [flag for flag, on in (("varied layout", self.varied_layout), ("narrow layout", self.narrow_layout),
                                             ("grainy road", self.grainy_road)) if on]
        if street_only and self.name != "street":
            raise InputError(None, f"{street_only[0]} is a street option; scene {self.name!r} has no road")
        if self.street_style not in STREET_STYLES:
            raise InputError(None, f"unknown street style {self.street_style!r} (choose from {', '.join(STREET_STYLES)})")
        if street_only and self.street_style != "town":
            raise InputError(None, f"{street_only[0]} is an option of the town street: add --street-style town")
        if self.varied_layout and self.narrow_layout:
            raise InputError(None, "choose one street layout: varied or narrow, not both")
        if self.route not in ROUTES:
            raise InputError(None, f"unknown route {self.route!r} (choose from {', '.join(ROUTES)})")
        if self.route != "default" and not (self.name == "street" and self.street_style == "kitti"):
            raise InputError(None, f"route {self.route!r} is a route of the street's KITTI look (scene street, "
                                   "--street-style kitti)")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise InputError(None, f"seed must be a non-negative integer, got {self.seed}")
        return self

    @property
    def px_per_m(self) -> float:
        return float(self.texture_px_per_m or DEFAULT_PX_PER_M[self.name])


@functools.lru_cache(maxsize=4)
def build_scene(config: SceneConfig):
    """Build (and cache: treat the result as read-only) the scene described by ``config``."""
    config.validate()
    rng = np.random.default_rng(config.seed)
    lighting = None
    if config.random_lighting:
        lighting = Lighting.random(config.seed)
    if config.name == "street" and config.street_style == "kitti":
        scene = build_kitti_street(config.seed, config.px_per_m, config.moving_objects, float(config.deform_amplitude_m),
                                   rng, lighting, route_name=config.route)
    elif config.name == "street":
        layout = (StreetLayout.varied(config.seed) if config.varied_layout else
                  StreetLayout.narrow(config.seed) if config.narrow_layout else StreetLayout())
        scene = build_street(config.seed, config.px_per_m, config.moving_objects, float(config.deform_amplitude_m), rng,
                             layout, lighting, grainy_road=config.grainy_road)
    else:
        scene = build_room(config.seed, config.px_per_m, config.moving_objects, float(config.deform_amplitude_m), rng,
                           lighting)
    if lighting is not None:  # the light's brightness and colour on the baked atlas and the sky
        scene.atlas = lighting.apply_gain(scene.atlas)
        scene.sky_rgb = tuple(int(c) for c in lighting.apply_gain(np.array(scene.sky_rgb, np.uint8)))
    if config.scene_file:
        spec = load_scene_file(config.scene_file)
        if spec.base != config.name:
            raise InputError(spec.path, f"the file's base scene is {spec.base!r}, the config's {config.name!r}")
        scene = add_user_meshes(scene, spec)
    scene.config = config
    return scene
