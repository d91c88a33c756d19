"""The stress study: where the method's rigid-scene assumption breaks, and by how much.

``deepslam stress`` sweeps, in simulation, the number of moving objects, their size and the
deformation amplitude of the waving flags, one factor at a time from the static scene. For every
setting it renders a short sequence at small resolution (our format, :func:`sim.writers.render_sequence`,
mono) and measures

(a) the synthesized-vs-true flow error (:func:`gen.validate.validate_sequence`, the library behind
    ``deepslam validate-flow``): flow synthesized from frame t's depth and the ground-truth camera
    motion, i.e. under the rigid-scene assumption, against the simulator's exact flow, on dynamic
    (moving or deforming) pixels and, as the control, on static visible pixels; and the fraction of
    dynamic pixels (instance mask > 0, over all pixels of the frames that have flow);
(b) the visual-odometry error (ATE and RPE per frame, and KITTI t_err / r_err where the ground truth
    is longer than 100 m; :func:`core.metrics.evaluate`, SE3-aligned) of the learned odometry
    (dead reckoning of NN_cons) run on the simulator's ground-truth flow AND on DIS flow;
(c) the SLAM error on the same sequence for both flows: the stages of :func:`slam.pipeline.run_slam`
    (odometry, BoVW loop closure, gtsam pose graph), with NN_loops on DIS flow for the loop pairs.

Odometry: the shipped NN_cons / NN_loops (:func:`vo.models.load_shipped`) or the given model files.
When no learned model is available (or with ``odometry="rigid-fit"``) the study falls back, with a
note in every table, to :class:`RigidFitOdometry`: a least-squares rigid-motion fit (reprojection
error, :func:`cv2.solvePnP`) of the flow + frame-i depth over ALL pixels with depth. That estimator
is exact on a rigid scene with exact flow, so whatever error it makes on ground-truth flow is the
rigid assumption failing, directly.

Size of the moving objects: :class:`scenes.SceneConfig` has no size knob, so a scale factor is
applied here to the meshes of the rigid movers (cars in ``street``, flying boxes in ``room``) about
their body origins (:func:`scaled_movers`), after the movers were placed as for the unscaled scene
(:func:`setting_scene`); the flags are not scaled. The simulator computes exact flow for any mesh,
so the scaled scene is as exact as the built one.

Outputs (all written atomically) in ``out``: ``stress.json`` (rows, config, conclusion, timings),
``stress.md`` (the table and the conclusion line), ``config.json`` (the resolved configuration),
``stress_flow_epe.png``, ``stress_vo_ate.png``, ``stress_vo_rpe.png``, ``stress_slam_ate.png``
(error against the fraction of dynamic pixels), ``settings/<name>.json`` (one result per setting,
reused by ``resume``) and, with ``keep_sequences``, the rendered sequences under ``sequences/``.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import shutil
import time
from pathlib import Path

import numpy as np

from deepslam.core import atomic, se3
from deepslam.core.errors import InputError
from deepslam.core.kinds import kind_for_scene

SCENES = ("street", "room")
ODOMETRIES = ("model", "rigid-fit")
MAX_OBJECTS = 64
"""Most moving objects the scenes accept (:class:`scenes.SceneConfig`)."""
MAX_DEFORM_M = 0.3
"""Largest deformation amplitude the scenes accept, metres."""
MAX_OBJECT_SCALE = 3.0
"""Largest mover scale factor accepted (3: a car becomes 12.6 m long and 5.4 m wide, as wide as its lane)."""
RESULT_FORMAT = "deepslam-stress-v1"


# --------------------------------------------------------------------------------------------------
# configuration


@dataclasses.dataclass(frozen=True)
class Setting:
    """One point of the sweep."""

    name: str
    """Unique short name, e.g. ``k16_s2_a0`` (objects, scale, amplitude)."""
    axis: str
    """Which sweep it belongs to: "objects", "size", "deform" or "combined" (the baseline is in "objects")."""
    moving_objects: int
    """Number of moving objects (cars / flying boxes)."""
    object_scale: float
    """Scale factor of the moving objects' meshes (1 = as built)."""
    deform_amplitude_m: float
    """Amplitude of the waving flags, metres (0: static flags)."""


def setting_name(objects: int, scale: float, amplitude_m: float) -> str:
    return f"k{objects}_s{scale:g}_a{amplitude_m:g}"


@dataclasses.dataclass(frozen=True)
class StressConfig:
    """What the stress study sweeps and measures."""

    scene: str = "street"
    """Scene: "street" (car trajectory, KITTI-like camera) or "room" (drone, EuRoC-like camera)."""
    frames: int = 300
    """Frames rendered per setting (street at 10 Hz: its loop around block A closes after about 27 s)."""
    width: int = 320
    """Image width in pixels (the height follows the scene camera's aspect ratio)."""
    objects: tuple[int, ...] = (0, 2, 8, 32)
    """Numbers of moving objects swept (size 1, no deformation)."""
    object_sizes: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0)
    """Scale factors of the moving objects swept (at ``size_objects`` objects, no deformation; 3: bus-sized)."""
    size_objects: int = 8
    """Number of moving objects of the size sweep (0: no size sweep)."""
    deform_amplitudes_m: tuple[float, ...] = (0.0, 0.15, 0.3)
    """Flag deformation amplitudes swept, metres (no moving objects)."""
    combined: bool = True
    """Add one setting with the most of everything (largest count, size and amplitude): the heaviest,
    KITTI-like (32 cars at 3x: 34 % of the pixels on average, p90 52 %, 100 frames at 160 px)."""
    seed: int = 0
    """Seed of the scene (layout, textures, movers) and the trajectory; the same for every setting."""
    backend: str = "mujoco"
    """Renderer: "mujoco" or "pyrender"."""
    odometry: str = "model"
    """"model": learned NN_cons / NN_loops (falls back to "rigid-fit", noted, when none is available);
    "rigid-fit": :class:`RigidFitOdometry` (least-squares rigid motion from flow + depth, all pixels)."""
    plugins: tuple[str, ...] = ()
    """Further odometries measured side by side with the first, each on the images alone: plug-in specs
    (``MODULE:FACTORY`` or an entry-point name of group ``deepslam.odometry``, e.g. ``pnp``, the shipped
    classical baseline; see :mod:`deepslam.slam.plugins`). Their rows are keyed by the plug-in's name."""
    model_cons: str | None = None
    """NN_cons model file or shipped name (None: the shipped model for the scene's camera kind)."""
    model_loops: str | None = None
    """NN_loops model file or shipped name (None: the shipped loops model)."""
    dis_preset: str = "medium"
    """Preset of the DIS optical flow (ultrafast, fast, medium)."""
    slam_params: str | None = None
    """JSON of C_s, C_r, T_loop from ``deepslam tune-slam`` (None: the defaults of SlamParams)."""
    loops: bool = True
    """Run loop closure in the SLAM stage (False: the pose graph equals dead reckoning)."""
    validation_frames: int = 60
    """Frames whose synthesized flow is compared with the true flow (evenly spread; all when fewer)."""
    keyframe_stride: int = 2
    """Every k-th frame is a relocalization keyframe in the SLAM stage."""
    sift_image_scale: float = 1.0
    """Resize factor of the images before SIFT (the study's images are already small)."""
    vocabulary_size: int = 200
    """Visual words of the BoW vocabulary trained on the first setting's keyframes (shared by all)."""
    device: str = "auto"
    """Torch device of the learned odometry: ``auto`` (CUDA when torch sees one), ``cpu``, ``cuda[:N]``."""
    threads: int = 1
    """CPU threads of torch and OpenCV during the study (restored after). The study's arrays are small, and
    on a busy 2-core machine one thread was 2-4x faster than two (thread contention)."""
    keep_sequences: bool = False
    """Keep the rendered sequences under ``out/sequences`` (about 0.4 MB per frame at 320 px)."""

    def validate(self) -> "StressConfig":
        if self.scene not in SCENES:
            raise InputError(None, f"unknown scene {self.scene!r} (choose from {', '.join(SCENES)})")
        if not isinstance(self.frames, int) or not 3 <= self.frames <= 100_000:
            raise InputError(None, f"frames must be an integer in 3..100000, got {self.frames}")
        if not isinstance(self.width, int) or not 16 <= self.width <= 4096:
            raise InputError(None, f"width must be an integer in 16..4096 px, got {self.width}")
        for name, values in (("objects", self.objects), ("object sizes", self.object_sizes),
                             ("deformation amplitudes", self.deform_amplitudes_m)):
            if len(values) == 0:
                raise InputError(None, f"the list of {name} is empty")
        for k in self.objects:
            if not isinstance(k, int) or not 0 <= k <= MAX_OBJECTS:
                raise InputError(None, f"number of moving objects must be an integer in 0..{MAX_OBJECTS}, got {k}")
        for s in self.object_sizes:
            if not (math.isfinite(s) and 0.0 < s <= MAX_OBJECT_SCALE):
                raise InputError(None, f"object size (scale factor) must be in (0, {MAX_OBJECT_SCALE:g}], got {s:g}")
        for a in self.deform_amplitudes_m:
            if not math.isfinite(a) or a < 0:
                raise InputError(None, f"deformation amplitude must be a non-negative number of metres, got {a:g}")
            if a > MAX_DEFORM_M:
                raise InputError(None, f"deformation amplitude must be at most {MAX_DEFORM_M:g} m, got {a:g}")
        if not isinstance(self.size_objects, int) or not 0 <= self.size_objects <= MAX_OBJECTS:
            raise InputError(None, f"size-sweep object count must be an integer in 0..{MAX_OBJECTS}, "
                             f"got {self.size_objects}")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise InputError(None, f"seed must be a non-negative integer, got {self.seed}")
        if self.backend not in ("mujoco", "pyrender"):
            raise InputError(None, f"unknown backend {self.backend!r} (choose from mujoco, pyrender)")
        if self.odometry not in ODOMETRIES:
            raise InputError(None, f"unknown odometry {self.odometry!r} (choose from {', '.join(ODOMETRIES)})")
        if len(set(self.plugins)) != len(self.plugins):
            raise InputError(None, f"an odometry is listed twice: {list(self.plugins)}")
        if self.odometry == "rigid-fit" and (self.model_cons or self.model_loops):
            raise InputError(None, "model files are for --odometry model; rigid-fit uses no model")
        if self.dis_preset not in ("ultrafast", "fast", "medium"):
            raise InputError(None, f"unknown DIS preset {self.dis_preset!r} (choose from ultrafast, fast, medium)")
        if not isinstance(self.threads, int) or not 1 <= self.threads <= 256:
            raise InputError(None, f"threads must be an integer in 1..256, got {self.threads}")
        if not isinstance(self.validation_frames, int) or self.validation_frames < 1:
            raise InputError(None, f"validation frames must be a positive integer, got {self.validation_frames}")
        if not isinstance(self.keyframe_stride, int) or self.keyframe_stride < 1:
            raise InputError(None, f"keyframe stride must be a positive integer, got {self.keyframe_stride}")
        if not (math.isfinite(self.sift_image_scale) and 0.1 <= self.sift_image_scale <= 2.0):
            raise InputError(None, f"SIFT image scale must be in [0.1, 2], got {self.sift_image_scale:g}")
        if not isinstance(self.vocabulary_size, int) or not 2 <= self.vocabulary_size <= 100_000:
            raise InputError(None, f"vocabulary size must be an integer in 2..100000, got {self.vocabulary_size}")
        return self

    def settings(self) -> list[Setting]:
        """The sweep, one factor at a time from the static scene: the object counts (size 1, no
        deformation), the sizes (at ``size_objects`` objects), the deformation amplitudes (no objects)
        and, with ``combined``, the most of everything. Duplicates are listed once (first axis wins);
        a size sweep without objects is skipped (there is nothing to scale)."""
        out: dict[str, Setting] = {}

        def add(axis: str, k: int, s: float, a: float) -> None:
            name = setting_name(k, s, a)
            out.setdefault(name, Setting(name, axis, int(k), float(s), float(a)))

        for k in self.objects:
            add("objects", k, 1.0, 0.0)
        if self.size_objects > 0:
            for s in self.object_sizes:
                add("size", self.size_objects, s, 0.0)
        for a in self.deform_amplitudes_m:
            add("deform", 0, 1.0, a)
        if self.combined:
            k = max(max(self.objects), self.size_objects)
            s = max(self.object_sizes) if k > 0 else 1.0
            a = max(self.deform_amplitudes_m)
            if sum([k > 0, s != 1.0, a > 0]) >= 2:
                add("combined", k, s, a)
        return list(out.values())

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["plugins"] = list(self.plugins)
        return d


# --------------------------------------------------------------------------------------------------
# scene with scaled movers


def scaled_movers(scene, scale: float):
    """A copy of ``scene`` (a :class:`scenes.spec.Scene`, left unchanged) whose rigid movers' meshes
    are scaled by ``scale`` about their body origins (street cars: the origin is on the road under the
    car's centre, so a scaled car still stands on the road; room boxes: the box centre). Flags and the
    static scene are unchanged; texture coordinates are kept (the texture stretches with the mesh)."""
    from deepslam.scenes.geometry import MeshData
    from deepslam.scenes.spec import RIGID

    if scale == 1.0:
        return scene
    bodies = []
    for b in scene.bodies:
        if b.kind == RIGID:
            m = b.mesh
            b = dataclasses.replace(b, mesh=MeshData(m.vertices * float(scale), m.faces, m.normals, m.texcoords))
        bodies.append(b)
    return dataclasses.replace(scene, bodies=bodies)


def sim_config(config: StressConfig, setting: Setting):
    """The simulator's :class:`sim.SimConfig` of one setting (mono, scene default trajectory)."""
    from deepslam.sim import RenderConfig, SceneConfig, SimConfig, TrajectoryConfig

    return SimConfig(SceneConfig(name=config.scene, seed=config.seed, moving_objects=setting.moving_objects,
                                 deform_amplitude_m=setting.deform_amplitude_m),
                     TrajectoryConfig(kind="auto", frames=config.frames),
                     RenderConfig(backend=config.backend, width=config.width, stereo_baseline_m=0.0, flow=True))


def setting_scene(config: StressConfig, setting: Setting):
    """(SimConfig, Scene) of one setting.

    With a scale other than 1 the movers are first placed exactly as the simulator places them for
    the unscaled scene (:func:`sim.world.separate_movers` with the simulator's own generator
    ``[trajectory seed, 2]``), then scaled; the placed scene says ``movers_placed`` so that the
    simulator keeps that placement: a size setting differs from its unscaled twin in the size of the
    movers only, not in where they drive (bigger cars would otherwise be pushed away from the camera
    by the clearance rule and the sweep would measure fewer dynamic pixels for bigger objects).
    """
    from deepslam.scenes import build_scene
    from deepslam.sim.trajectories import make_motion
    from deepslam.sim.world import separate_movers

    cfg = sim_config(config, setting).validate()
    base = build_scene(cfg.scene)
    if setting.object_scale == 1.0:
        return cfg, base
    tcfg = cfg.trajectory
    tseed = tcfg.seed if tcfg.seed is not None else cfg.scene.seed
    motion = make_motion(base, tcfg.resolved_kind(base.name), np.random.default_rng([tseed, 1]), tcfg.rate_hz)
    placed = separate_movers(base, motion, (tcfg.frames + 1) / float(motion.rate_hz), np.random.default_rng([tseed, 2]))
    scaled = scaled_movers(placed, setting.object_scale)
    return cfg, scaled


def render_setting(config: StressConfig, setting: Setting, out_dir: Path, progress: bool = False) -> Path:
    """Render one setting into ``out_dir`` (our format; resumes an interrupted render). Returns the folder."""
    from deepslam.sim import Simulator
    from deepslam.sim.writers import render_sequence

    cfg, scene = setting_scene(config, setting)
    with Simulator(cfg, scene=scene) as simulator:
        return render_sequence(cfg, out_dir, fmt="ours", resume=True, progress=progress, simulator=simulator)


# --------------------------------------------------------------------------------------------------
# the rigid-fit odometry (fallback, and the direct view of the rigid assumption)


class RigidFitOdometry:
    """Relative motion by a least-squares rigid fit of flow + depth over all pixels (slam Odometry protocol).

    For a pair (i, j): every pixel of frame i with a positive finite depth and a finite flow (at most
    ``max_points`` of them, evenly spread in raster order) is unprojected with its depth to ``p_cam_i``
    and its flow target ``uv_j = uv_i + flow[v, u]`` is taken as its observation in frame j; then
    ``cam_j_from_cam_i`` minimises the sum of squared reprojection errors (OpenCV ``solvePnP``,
    Levenberg-Marquardt from the identity and, for pairs more than one frame apart, also from the
    DLT solution; the lower cost wins). No robust loss, no outlier rejection: every moving and deforming
    pixel pulls on the fit as a static one would, which is the rigid-scene assumption of a flow->motion
    network in its plainest form.

    The reported std is the Gauss-Newton one, ``sigma^2 (J^T J)^-1`` with ``sigma`` the residual RMS,
    rotation-vector std taken as the Euler-angle std (equal to first order), floored at ``min_std``.

    Args:
        flow_estimator: anything with ``name`` and ``pair_flow(seq, i, j) -> (H, W, 2)`` (flow.estimators).
        max_points: most pixels used per pair.
        min_std: floor of the std (rad for rotations, m for translations).
    """

    def __init__(self, flow_estimator, max_points: int = 2000, min_std: tuple[float, float] = (1e-4, 1e-3)):
        self.flow_estimator = flow_estimator
        self.max_points = int(max_points)
        self.min_std = min_std
        self.name = f"rigid-fit+{getattr(flow_estimator, 'name', 'flow')}"

    def fit(self, depth_z: np.ndarray, flow: np.ndarray, camera, dlt_start: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(mean6, std6) of cam_j_from_cam_i from depth (H, W) float32 m and flow (H, W, 2) float32 px;
        ``dlt_start``: also start from the DLT solution (for wide motions), not only from the identity."""
        import cv2

        depth = np.asarray(depth_z, np.float64)
        flow = np.asarray(flow, np.float64)
        ok = np.isfinite(depth) & (depth > 0) & np.isfinite(flow).all(axis=-1)
        vv, uu = np.nonzero(ok)
        big = np.array([1.0, 1.0, 1.0, 100.0, 100.0, 100.0])
        if len(vv) < 12:
            return np.zeros(6), big
        step = max(1, int(math.ceil(len(vv) / self.max_points)))
        vv, uu = vv[::step], uu[::step]
        uv = np.stack([uu, vv], axis=1).astype(np.float64)
        p_cam_i = camera.unproject(uv, depth[vv, uu])
        uv_j = uv + flow[vv, uu]
        k = camera.k.astype(np.float64)
        obj = np.ascontiguousarray(p_cam_i.reshape(-1, 1, 3))
        img = np.ascontiguousarray(uv_j.reshape(-1, 1, 2))
        best = None
        for guess in ((True, False) if dlt_start else (True,)):
            r0, t0 = np.zeros((3, 1)), np.zeros((3, 1))
            try:
                ok_, rvec, tvec = cv2.solvePnP(obj, img, k, None, r0, t0, useExtrinsicGuess=guess,
                                               flags=cv2.SOLVEPNP_ITERATIVE)
            except cv2.error:
                continue
            if not ok_ or not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
                continue
            proj, jac = cv2.projectPoints(obj, rvec, tvec, k, None)
            res = (proj.reshape(-1, 2) - uv_j).ravel()
            cost = float(res @ res)
            if best is None or cost < best[0]:
                best = (cost, rvec, tvec, res, jac[:, :6])
        if best is None:
            return np.zeros(6), big
        cost, rvec, tvec, res, jac = best
        rot, _ = cv2.Rodrigues(rvec)
        mean6 = se3.to_euler6(se3.from_rt(rot, tvec.ravel()))
        dof = max(1, len(res) - 6)
        sigma2 = cost / dof
        try:
            cov = sigma2 * np.linalg.inv(jac.T @ jac)
            std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        except np.linalg.LinAlgError:
            std = big.copy()
        floor = np.array([self.min_std[0]] * 3 + [self.min_std[1]] * 3)
        return mean6, np.maximum(std, floor)

    def predict(self, seq, pairs) -> tuple[np.ndarray, np.ndarray]:
        means, stds = [], []
        for i, j in pairs:
            depth = seq.depth(int(i))
            if depth is None:
                raise InputError(getattr(seq, "root", None), "the rigid-fit odometry needs a sequence with depth")
            m, s = self.fit(depth, self.flow_estimator.pair_flow(seq, int(i), int(j)), seq.camera,
                            dlt_start=abs(int(j) - int(i)) > 1)
            means.append(m)
            stds.append(s)
        if not means:
            return np.zeros((0, 6)), np.zeros((0, 6))
        return np.array(means), np.array(stds)


# --------------------------------------------------------------------------------------------------
# odometry selection


def camera_kind(scene: str) -> str:
    """Shipped-model kind of a scene (:func:`core.kinds.kind_for_scene`; the study's scenes are street and room)."""
    return kind_for_scene(scene) or "euroc"


@dataclasses.dataclass
class OdometrySet:
    """The odometries of the study.

    Consecutive frames (VO, and the SLAM graph's consecutive edges) are measured on each flow source;
    loop pairs always use DIS flow between the two images: the only "ground-truth flow" between frames
    hundreds apart would be the chain of the simulator's consecutive flows, which runs through every
    occlusion in between and is not the flow between the two images.
    """

    kind: str
    """"model" (learned) or "rigid-fit"."""
    cons: dict
    """{"gt": odometry on the simulator's flow, "dis": odometry on DIS flow} (slam Odometry protocol)."""
    loops: object
    """Loop-pair odometry (NN_loops, or the rigid fit) on DIS flow."""
    description: str
    """What it is, for the table."""
    note: str | None = None
    """Why the study fell back to the rigid fit, or None."""
    plugins: dict = dataclasses.field(default_factory=dict)
    """{key: plug-in odometry} measured side by side (consecutive and loop pairs on the images alone)."""


def make_odometries(config: StressConfig) -> OdometrySet:
    """Learned odometry when available (shipped or given models), else the rigid fit, noted; plus the
    plug-ins of ``config.plugins``."""
    odo = _main_odometries(config)
    odo.plugins = load_plugins(config.plugins)
    return odo


def plugin_key(name: str) -> str:
    """A plug-in's name as a column key: lower case letters, digits and ``-``."""
    import re

    return re.sub(r"[^a-z0-9-]+", "-", str(name).lower()).strip("-") or "plugin"


def load_plugins(specs) -> dict:
    """{key: checked plug-in odometry} of the specs, keys unique and distinct from gt/dis."""
    from deepslam.slam.plugins import load_odometry

    out: dict = {}
    for spec in specs:
        odo = load_odometry(spec)
        key = plugin_key(odo.name)
        while key in out or key in ("gt", "dis"):
            key += "-2"
        out[key] = odo
    return out


def _main_odometries(config: StressConfig) -> OdometrySet:
    from deepslam.flow.estimators import DISFlow, GroundTruthFlow

    flows = {"gt": GroundTruthFlow(), "dis": DISFlow(config.dis_preset)}
    note = None
    if config.odometry == "model":
        kind = camera_kind(config.scene)
        try:
            from deepslam.vo import models

            # shipped models follow the flow they are given (a DIS-trained variant where one is shipped)
            from deepslam.gen.device import resolve_device

            dev = resolve_device(config.device)
            cons, cons_flows = {}, dict(flows)
            for f, est in flows.items():
                path, shipped = models.locate(config.model_cons or kind, None, "cons", est)
                if f == "dis":  # DIS set up as this model was trained (its texture threshold), at the study's preset
                    cons_flows[f] = models.flow_for_model("dis", path, preset=config.dis_preset)
                cons[f] = models.load(path, shipped, device=dev)
            path, shipped = models.locate(config.model_loops or f"{kind}:loops", None, "loops", flows["dis"])
            loops_flow = models.flow_for_model("dis", path, preset=config.dis_preset)
            loops = models.load(path, shipped, device=dev)
        except InputError as e:
            if config.model_cons or config.model_loops:
                raise  # a model the user named is missing or broken: bad input
            note = (f"learned odometry unavailable ({e.message()}); fell back to the rigid least-squares "
                    "fit of flow + depth over all pixels")
        except ImportError as e:
            if config.model_cons or config.model_loops:
                raise InputError(None, f"the learned odometry (package vo) cannot be imported: {e}") from None
            note = (f"learned odometry unavailable (vo cannot be imported: {e}); fell back to the rigid "
                    "least-squares fit of flow + depth over all pixels")
        else:
            names = ", ".join(f"{cons[f].name} on {f} flow" for f in flows)
            return OdometrySet("model", {f: cons[f].as_odometry(est, progress=False) for f, est in cons_flows.items()},
                               loops.as_odometry(loops_flow, progress=False),
                               f"learned, NN_cons {names}, and NN_loops {loops.name} (on DIS flow)")
    return OdometrySet("rigid-fit", {f: RigidFitOdometry(est) for f, est in flows.items()}, RigidFitOdometry(flows["dis"]),
                       "rigid least-squares fit of flow + depth over all pixels (solvePnP, no outlier rejection); "
                       "loop pairs on DIS flow", note)


# --------------------------------------------------------------------------------------------------
# measuring one setting


def dynamic_fraction(seq, frames) -> float:
    """Fraction of all pixels of ``frames`` whose instance mask is > 0 (moving or deforming surface)."""
    dyn = total = 0
    for t in frames:
        m = seq.mask(t)
        if m is None:
            return 0.0
        dyn += int((m > 0).sum())
        total += m.size
    return dyn / total if total else 0.0


def _metrics(gt, est) -> dict:
    from deepslam.core import metrics

    ev = metrics.evaluate(gt, est, align="se3")
    out = {"ate_m": ev["ate_m"], "rpe_t_m": ev["rpe_t_m"], "rpe_r_deg": ev["rpe_r_deg"], "gt_length_m": ev["gt_length_m"]}
    out["kitti_t_err_pct"] = ev.get("kitti_t_err_pct")
    out["kitti_r_err_deg_per_100m"] = ev.get("kitti_r_err_deg_per_100m")
    return out


def validation_frames(n: int, count: int) -> range | list[int]:
    """At most ``count`` frames t (flow t -> t+1) evenly spread over the n - 1 frames with flow."""
    if count >= n - 1:
        return range(n - 1)
    return sorted({int(round(x)) for x in np.linspace(0, n - 2, count)})


def measure_sequence(seq, odometries: OdometrySet, config: StressConfig, vocabulary=None) -> dict:
    """Flow validation, VO and SLAM on one rendered sequence (our format, with depth, flow, mask, poses).

    The SLAM stage is what :func:`slam.pipeline.run_slam` does (its stages :func:`slam.pipeline.prepare`
    and :func:`slam.pipeline.solve`, and dead reckoning of the consecutive edges for VO), called stage
    by stage so that the relocalization (features, retrieval, verification: they depend on the images
    only) runs once and is shared by the flow sources; each flow source brings its own consecutive
    and loop odometry. VO is that dead reckoning (the trajectory ``deepslam vo`` would chain).
    """
    from deepslam.gen.validate import validate_sequence
    from deepslam.slam.odometry import check_prediction
    from deepslam.slam.pipeline import PipelineConfig, SlamParams, consecutive_pairs, prepare, solve
    from deepslam.slam.posegraph import Edges, PoseGraphConfig, chain
    from deepslam.slam.reloc import RelocConfig
    from deepslam.core.trajectory import Trajectory

    timings = {}
    t0 = time.perf_counter()
    n = len(seq)
    rep = validate_sequence(seq, validation_frames(n, config.validation_frames), progress=False)
    flow = {"dynamic_fraction": dynamic_fraction(seq, range(n - 1)),
            "static_visible": rep["static_visible"], "static_occluded": rep["static_occluded"],
            "moving": rep["moving"], "frames_compared": rep["frames_compared"]}
    timings["flow_validation_s"] = time.perf_counter() - t0

    params = SlamParams.load(config.slam_params) if config.slam_params else SlamParams()
    reloc = dataclasses.replace(RelocConfig.for_kind(camera_kind(config.scene)), image_scale=config.sift_image_scale,
                                vocabulary_size=config.vocabulary_size)
    pipe = PipelineConfig(reloc=reloc, graph=PoseGraphConfig(robust="cauchy"), keyframe_stride=config.keyframe_stride,
                          loops=config.loops, seed=config.seed)
    first_pose = seq.gt.world_from_cam[0]
    times = np.asarray(seq.timestamps_s, np.float64)
    vo, slam, loops = {}, {}, {}

    def score(key: str, prep_k, t1: float) -> None:
        """Solve the graph of ``prep_k``; VO (dead reckoning) and SLAM errors under ``key``."""
        res, loop_edges = solve(prep_k, params, pipe.graph, first_pose)
        vo[key] = _metrics(seq.gt, Trajectory(chain(n, prep_k.cons, first_pose), times))
        slam[key] = _metrics(seq.gt, Trajectory(res.world_from_cam, times))
        kept = int(np.sum(res.loop_inliers)) if res.loop_inliers is not None else len(loop_edges)
        loops[key] = {"loop_edges": len(loop_edges), "loop_edges_kept": kept}
        timings[f"vo_slam_{key}_s"] = time.perf_counter() - t1

    prep = None
    loop_odo = odometries.loops if config.loops else None
    for f, cons in odometries.cons.items():
        t1 = time.perf_counter()
        if prep is None:
            prep = base = prepare(seq, cons, loop_odo, pipe, vocabulary, show_progress=False)
        else:  # same relocalization and loop odometry (its cache too), this flow's consecutive edges
            pairs = consecutive_pairs(n)
            mean6, std6 = check_prediction(cons.name, pairs, *cons.predict(seq, pairs))
            prep = dataclasses.replace(base, cons=Edges(np.array(pairs), mean6, std6))
        score(f, prep, t1)
    for key, odo in odometries.plugins.items():  # side by side: the same stages with the plug-in's motions
        t1 = time.perf_counter()
        score(key, prepare(seq, odo, odo if config.loops else None, pipe, vocabulary, show_progress=False), t1)
    return {"flow": flow, "vo": vo, "slam": slam, "loops": loops, "timings": timings}


# --------------------------------------------------------------------------------------------------
# the study


@contextlib.contextmanager
def cpu_threads(n: int):
    """Set torch's and OpenCV's thread counts to ``n`` inside the block, restore them after."""
    import cv2
    import torch

    old_torch, old_cv = torch.get_num_threads(), cv2.getNumThreads()
    torch.set_num_threads(n)
    cv2.setNumThreads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old_torch)
        cv2.setNumThreads(old_cv)


def run_stress(config: StressConfig, out: str | Path, resume: bool = False, progress: bool | None = None) -> dict:
    """Run the whole sweep; write the table, plots and JSON into ``out``. Returns the result dict.

    Args:
        config: the sweep (validated here; bad values raise InputError before anything is written).
        out: output folder (created; files in it are replaced atomically).
        resume: reuse ``out/settings/<name>.json`` results computed with the same configuration.
        progress: progress bar over the settings (None: the project's default policy).
    """
    from deepslam.core.lock import output_lock

    config = config.validate()
    with cpu_threads(config.threads), output_lock(out):  # one writer per output folder
        return _run(config, Path(out), resume, progress)


def _run(config: StressConfig, out: Path, resume: bool, progress: bool | None) -> dict:
    from deepslam.core.progress import progress as progress_bar
    from deepslam.core.readers import open_sequence
    from deepslam.slam.pipeline import SlamParams

    if out.exists() and not out.is_dir():
        raise InputError(out, "output exists and is not a folder")
    if not resume and out.is_dir() and any(out.iterdir()):
        raise InputError(out, "output folder is not empty; choose another --out, or pass --resume to reuse the "
                              "per-setting results of a stress run there")
    settings = config.settings()
    params = SlamParams.load(config.slam_params) if config.slam_params else SlamParams()  # fail early on a bad file
    notes = []
    if config.loops and config.frames <= params.t_loop + 1:
        notes.append(f"no loop closure: {config.frames} frames per setting, loops need more than T_loop + 1 = "
                     f"{params.t_loop + 1} (SLAM equals VO)")
        config = dataclasses.replace(config, loops=False)
    odometries = make_odometries(config)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(out, f"cannot create the output folder ({e.strerror or e})") from None
    atomic.write_json(out / "config.json", {"format": RESULT_FORMAT, "config": config.to_dict(),
                                            "settings": [dataclasses.asdict(s) for s in settings],
                                            "odometry": odometries.kind, "odometry_description": odometries.description,
                                            "odometry_note": odometries.note})
    work = out / "sequences" if config.keep_sequences else _scratch_folder(out)
    t_start = time.perf_counter()
    rows = []
    vocabulary = None
    cfg_key = _config_key(config, odometries)
    opts = {} if progress is None else {"disable": not progress}
    try:
        bar = progress_bar(settings, desc="stress", unit="setting", **opts)
        for s in bar:
            bar.set_postfix_str(s.name)
            row_path = out / "settings" / f"{s.name}.json"
            old = _load_row(row_path) if resume else None
            if old is not None and old.get("key") == cfg_key and old.get("setting") == dataclasses.asdict(s):
                rows.append(old)
                continue
            seq_dir = work / s.name
            t0 = time.perf_counter()
            if seq_dir.exists() and not resume:
                shutil.rmtree(seq_dir)
            render_setting(config, s, seq_dir)
            t_render = time.perf_counter() - t0
            seq = open_sequence(seq_dir)
            if config.loops and vocabulary is None:
                vocabulary = _shared_vocabulary(out, config, seq)
                if vocabulary is None:
                    notes.append("no loop closure: no SIFT keypoints in the rendered images to build a vocabulary")
                    config = dataclasses.replace(config, loops=False)
            result = measure_sequence(seq, odometries, config, vocabulary)
            result["timings"]["render_s"] = t_render
            row = _clean({"key": cfg_key, "setting": dataclasses.asdict(s), **result})
            atomic.write_json(row_path, row)
            rows.append(row)
            if not config.keep_sequences:
                shutil.rmtree(seq_dir, ignore_errors=True)
    finally:
        if not config.keep_sequences:
            shutil.rmtree(work, ignore_errors=True)
    elapsed = time.perf_counter() - t_start
    report = build_report(config, settings, rows, odometries, elapsed, notes)
    write_outputs(out, report)
    return report


def _load_row(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _scratch_folder(out: Path) -> Path:
    """Where sequences that are deleted after measuring are rendered: a fresh folder in /dev/shm
    (memory: the per-file fsync of the atomic writers costs nothing there) when it exists with at least
    2 GB free, else ``out/sequences``."""
    import tempfile

    shm = Path("/dev/shm")
    try:
        if shm.is_dir() and shutil.disk_usage(shm).free > 2 << 30:
            return Path(tempfile.mkdtemp(prefix="deepslam-stress-", dir=shm))
    except OSError:
        pass
    return out / "sequences"


def _config_key(config: StressConfig, odometries: OdometrySet) -> dict:
    """What a setting's result depends on besides the setting (for resume)."""
    d = config.to_dict()
    for k in ("objects", "object_sizes", "size_objects", "deform_amplitudes_m", "combined",
              "keep_sequences"):
        d.pop(k, None)
    d["odometry_used"] = odometries.kind
    d["odometry_description"] = odometries.description
    d["plugin_names"] = {k: o.name for k, o in odometries.plugins.items()}
    return _clean(d)


def _shared_vocabulary(out: Path, config: StressConfig, seq):
    """One BoW vocabulary for the whole study, trained on the first rendered setting's frames and saved
    as ``out/vocabulary.npz`` (so every setting's SLAM sees the same words); None without keypoints."""
    from deepslam.slam.reloc import FeatureExtractor, RelocConfig, Vocabulary, train_vocabulary

    path = out / "vocabulary.npz"
    reloc = dataclasses.replace(RelocConfig.for_kind(camera_kind(config.scene)), image_scale=config.sift_image_scale,
                                vocabulary_size=config.vocabulary_size)
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                key = json.loads(str(z["meta"])).get("stress_key")
            if key == _vocab_key(config):
                return Vocabulary.load(path)
        except (InputError, OSError, ValueError, KeyError):
            pass
    extract = FeatureExtractor(reloc)
    descs = [d for d in (extract(seq.image(i)).descriptors for i in range(0, len(seq), config.keyframe_stride)) if len(d)]
    if not descs:
        return None
    v = train_vocabulary(descs, reloc.vocabulary_size, np.random.default_rng(config.seed))
    v.save(path, meta={"stress_key": _vocab_key(config)})
    return v


def _vocab_key(config: StressConfig) -> str:
    return f"{config.scene}/{config.seed}/{config.width}/{config.frames}/{config.sift_image_scale}/{config.vocabulary_size}"


# --------------------------------------------------------------------------------------------------
# report


def _clean(v):
    """JSON-safe copy (see core.atomic.json_safe)."""
    from deepslam.core.atomic import json_safe

    return json_safe(v)


def table_rows(rows: list[dict]) -> list[dict]:
    """Flat rows for the table: one per setting, sorted by the fraction of dynamic pixels."""
    flat = []
    for r in rows:
        s, f = r["setting"], r["flow"]
        row = {"setting": s["name"], "axis": s["axis"], "objects": s["moving_objects"], "size": s["object_scale"],
               "deform_m": s["deform_amplitude_m"], "dynamic_pct": 100.0 * f["dynamic_fraction"],
               "epe_static_px": f["static_visible"]["epe_mean_px"], "epe_dynamic_px": f["moving"]["epe_mean_px"],
               "epe_dynamic_p95_px": f["moving"]["epe_p95_px"], "dynamic_pixels_compared": f["moving"]["pixels"]}
        for flow in r["vo"]:
            vo, sl = r["vo"].get(flow), r["slam"].get(flow)
            if vo is None:
                continue
            row[f"vo_ate_{flow}_m"] = vo["ate_m"]
            row[f"vo_rpe_t_{flow}_m"] = vo["rpe_t_m"]
            row[f"vo_rpe_r_{flow}_deg"] = vo["rpe_r_deg"]
            row[f"vo_t_err_{flow}_pct"] = vo.get("kitti_t_err_pct")
            row[f"vo_r_err_{flow}_deg_per_100m"] = vo.get("kitti_r_err_deg_per_100m")
            row[f"slam_ate_{flow}_m"] = sl["ate_m"]
            row[f"slam_loops_{flow}"] = r["loops"][flow]["loop_edges_kept"]
        flat.append(row)
    flat.sort(key=lambda x: (x["dynamic_pct"], x["setting"]))
    return flat


def conclusion(flat: list[dict]) -> dict:
    """Numbers of the conclusion: the static baseline against the setting with the most dynamic pixels."""
    if not flat:
        return {"text": "no settings were measured"}
    static = [r for r in flat if r["objects"] == 0 and r["deform_m"] == 0]
    base = static[0] if static else flat[0]
    worst = max(flat, key=lambda r: r["dynamic_pct"])
    c = {"baseline": base["setting"], "worst": worst["setting"], "baseline_dynamic_pct": base["dynamic_pct"],
         "worst_dynamic_pct": worst["dynamic_pct"]}
    for k in ("epe_static_px", "epe_dynamic_px", "vo_ate_gt_m", "vo_ate_dis_m", "vo_rpe_t_gt_m", "vo_rpe_t_dis_m",
              "slam_ate_gt_m", "slam_ate_dis_m"):
        c[f"baseline_{k}"] = base.get(k)
        c[f"worst_{k}"] = worst.get(k)
    # least-squares slope of each error against the dynamic percentage (over all settings)
    x = np.array([r["dynamic_pct"] for r in flat])
    for k in ("vo_ate_gt_m", "vo_ate_dis_m", "slam_ate_gt_m", "slam_ate_dis_m", "epe_dynamic_px"):
        y = np.array([np.nan if r.get(k) is None else r[k] for r in flat], dtype=np.float64)
        ok = np.isfinite(y)
        if ok.sum() >= 2 and np.ptp(x[ok]) > 0:
            c[f"slope_{k}_per_pct"] = float(np.polyfit(x[ok], y[ok], 1)[0])
    # where it breaks: the fewest dynamic pixels at which the VO error on exact flow doubles
    for k in ("vo_ate_gt_m", "vo_ate_dis_m"):
        b = base.get(k)
        if b is None:
            continue
        over = [r for r in flat if r.get(k) is not None and r[k] > 2.0 * b and r is not base]
        if over:
            first = min(over, key=lambda r: r["dynamic_pct"])
            c[f"break_{k}"] = {"setting": first["setting"], "dynamic_pct": first["dynamic_pct"], "value": first[k]}
    c["text"] = _conclusion_text(c)
    return c


def _fmt(v, f=".3g", unit="") -> str:
    return "n/a" if v is None else f"{format(v, f)}{unit}"


def _ratio(a, b) -> str:
    if a is None or b is None or b <= 0 or a / b > 1e4:
        return ""
    return f" (x{a / b:.3g})"


def _conclusion_text(c: dict) -> str:
    parts = [f"Rigid-scene assumption: from the static scene ({c['baseline']}, {c['baseline_dynamic_pct']:.2f} % "
             f"dynamic pixels) to {c['worst']} ({c['worst_dynamic_pct']:.2f} % dynamic pixels), the flow synthesized "
             f"from depth + true camera motion is off by {_fmt(c['worst_epe_dynamic_px'])} px (mean EPE) on dynamic "
             f"pixels while static pixels stay at {_fmt(c['worst_epe_static_px'])} px"]
    for label, k in (("VO ATE on ground-truth flow", "vo_ate_gt_m"), ("VO ATE on DIS flow", "vo_ate_dis_m"),
                     ("SLAM ATE on ground-truth flow", "slam_ate_gt_m"), ("SLAM ATE on DIS flow", "slam_ate_dis_m")):
        a, b = c.get(f"baseline_{k}"), c.get(f"worst_{k}")
        if a is None and b is None:
            continue
        slope = c.get(f"slope_{k}_per_pct")
        extra = "" if slope is None else f", {slope:+.3g} m per % of dynamic pixels over the sweep"
        parts.append(f"{label} goes from {_fmt(a)} m to {_fmt(b)} m{_ratio(b, a)}{extra}")
    text = "; ".join(parts) + "."
    brk = c.get("break_vo_ate_gt_m")
    if brk is not None:
        text += (f" The VO error on exact flow already doubles at {brk['dynamic_pct']:.2f} % dynamic pixels "
                 f"({brk['setting']}: ATE {brk['value']:.3g} m vs {c['baseline_vo_ate_gt_m']:.3g} m).")
    elif c.get("baseline_vo_ate_gt_m") is not None:
        text += " The VO error on exact flow never doubled over the sweep."
    return text


def odometry_columns(odometries: OdometrySet) -> dict:
    """{column key: label} of every odometry the study measured: the main one on each flow source and
    each plug-in."""
    main = "learned" if odometries.kind == "model" else odometries.kind
    cols = {f: f"{main} on {'ground-truth' if f == 'gt' else 'DIS'} flow" for f in odometries.cons}
    cols.update({k: f"{o.name} (plug-in)" for k, o in odometries.plugins.items()})
    return cols


def side_by_side(flat: list[dict], odometries: OdometrySet) -> list[dict]:
    """One entry per setting and odometry (the ``--json`` settings list): ``name``, ``odometry``,
    ``dynamic_fraction``, ``flow_epe_dynamic_px``, ``vo_ate_m``, ``vo_rpe_t_m``, ``vo_rpe_r_deg``,
    ``slam_ate_m``, ``loop_edges_kept``."""
    out = []
    for r in flat:
        for key, label in odometry_columns(odometries).items():
            if r.get(f"vo_ate_{key}_m") is None:
                continue
            out.append({"name": r["setting"], "odometry": label, "odometry_key": key,
                        "dynamic_fraction": r["dynamic_pct"] / 100.0, "flow_epe_dynamic_px": r["epe_dynamic_px"],
                        "vo_ate_m": r[f"vo_ate_{key}_m"], "vo_rpe_t_m": r.get(f"vo_rpe_t_{key}_m"),
                        "vo_rpe_r_deg": r.get(f"vo_rpe_r_{key}_deg"), "slam_ate_m": r.get(f"slam_ate_{key}_m"),
                        "loop_edges_kept": r.get(f"slam_loops_{key}")})
    return out


def build_report(config: StressConfig, settings, rows: list[dict], odometries: OdometrySet, elapsed_s: float,
                 notes: list[str] | None = None) -> dict:
    flat = table_rows(rows)
    return _clean({"format": RESULT_FORMAT, "config": config.to_dict(), "odometry": odometries.kind,
                   "odometry_description": odometries.description, "odometry_note": odometries.note,
                   "plugins": {k: o.name for k, o in odometries.plugins.items()},
                   "side_by_side": side_by_side(flat, odometries),
                   "notes": list(notes or []),
                   "settings": [dataclasses.asdict(s) for s in settings], "rows": flat, "results": rows,
                   "conclusion": conclusion(flat), "elapsed_s": elapsed_s})


def markdown(report: dict) -> str:
    cfg = report["config"]
    lines = [f"# Stress study: moving and deforming objects ({cfg['scene']})", "",
             f"{cfg['frames']} frames per setting at {cfg['width']} px wide, seed {cfg['seed']}, "
             f"{len(report['rows'])} settings, {report['elapsed_s']:.0f} s in all.", "",
             f"Odometry: {report['odometry_description']}."]
    if report.get("odometry_note"):
        lines += ["", f"**Note: {report['odometry_note']}.**"]
    for note in report.get("notes", []):
        lines += ["", f"Note: {note}."]
    lines += ["", "**Conclusion.** " + report["conclusion"]["text"], "",
              "Flow EPE: flow synthesized from frame t's depth and the true camera motion (the rigid-scene "
              "assumption) against the simulator's exact flow; static = static visible pixels (control), dyn = "
              "moving/deforming pixels. VO and SLAM: SE3-aligned ATE (m) and RPE per frame (m, deg) on the "
              "ground-truth flow (gt) and on DIS flow (dis); t_err (%) where the path is longer than 100 m; "
              "loops = loop edges kept by the pose graph.", ""]
    has_terr = any(r.get("vo_t_err_gt_pct") is not None or r.get("vo_t_err_dis_pct") is not None for r in report["rows"])
    head = ["setting", "axis", "dyn %", "EPE static px", "EPE dyn px", "VO ATE gt m", "VO ATE dis m",
            "RPE gt m / deg", "RPE dis m / deg"]
    if has_terr:
        head += ["t_err gt %", "t_err dis %"]
    head += ["SLAM ATE gt m", "SLAM ATE dis m", "loops gt/dis"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in report["rows"]:
        cells = [r["setting"], r["axis"], f"{r['dynamic_pct']:.2f}", _fmt(r["epe_static_px"], ".2g"),
                 _fmt(r["epe_dynamic_px"]), _fmt(r.get("vo_ate_gt_m")), _fmt(r.get("vo_ate_dis_m")),
                 f"{_fmt(r.get('vo_rpe_t_gt_m'))} / {_fmt(r.get('vo_rpe_r_gt_deg'))}",
                 f"{_fmt(r.get('vo_rpe_t_dis_m'))} / {_fmt(r.get('vo_rpe_r_dis_deg'))}"]
        if has_terr:
            cells += [_fmt(r.get("vo_t_err_gt_pct")), _fmt(r.get("vo_t_err_dis_pct"))]
        cells += [_fmt(r.get("slam_ate_gt_m")), _fmt(r.get("slam_ate_dis_m")),
                  f"{r.get('slam_loops_gt', 'n/a')}/{r.get('slam_loops_dis', 'n/a')}"]
        lines.append("| " + " | ".join(cells) + " |")
    if report.get("plugins"):
        keys = sorted({e["odometry_key"] for e in report["side_by_side"]}, key=lambda k: (k not in ("gt", "dis"), k))
        labels = {e["odometry_key"]: e["odometry"] for e in report["side_by_side"]}
        lines += ["", "**Side by side** (VO ATE / SLAM ATE, m, SE3-aligned; plug-ins read the images themselves):", "",
                  "| setting | dyn % | " + " | ".join(labels[k] for k in keys) + " |", "|---|---|" + "---|" * len(keys)]
        by = {(e["name"], e["odometry_key"]): e for e in report["side_by_side"]}
        for r in report["rows"]:
            cells = [f"{_fmt(by[(r['setting'], k)]['vo_ate_m'])} / {_fmt(by[(r['setting'], k)]['slam_ate_m'])}"
                     if (r["setting"], k) in by else "n/a" for k in keys]
            lines.append(f"| {r['setting']} | {r['dynamic_pct']:.2f} | " + " | ".join(cells) + " |")
    lines += ["", "Settings: `kK_sS_aA` = K moving objects scaled by S, flags waving with amplitude A m.", "",
              "![flow EPE](stress_flow_epe.png)", "![VO ATE](stress_vo_ate.png)", "![VO RPE](stress_vo_rpe.png)",
              "![SLAM ATE](stress_slam_ate.png)", ""]
    return "\n".join(lines)


PLOTS = {
    "stress_flow_epe.png": ("synthesized-vs-true flow EPE (mean, px)",
                            [("epe_dynamic_px", "dynamic pixels"), ("epe_static_px", "static pixels (control)")], True),
    "stress_vo_ate.png": ("VO ATE (m, SE3-aligned)",
                          [("vo_ate_gt_m", "ground-truth flow"), ("vo_ate_dis_m", "DIS flow")], False),
    "stress_vo_rpe.png": ("VO RPE per frame (m)",
                          [("vo_rpe_t_gt_m", "ground-truth flow"), ("vo_rpe_t_dis_m", "DIS flow")], False),
    "stress_slam_ate.png": ("SLAM ATE (m, SE3-aligned)",
                            [("slam_ate_gt_m", "ground-truth flow"), ("slam_ate_dis_m", "DIS flow")], False),
}
AXIS_MARKERS = {"objects": "o", "size": "s", "deform": "^", "combined": "*"}


def plot_error(path: Path, rows: list[dict], ylabel: str, series: list[tuple[str, str]], log_y: bool, title: str) -> None:
    """One PNG: each error series against the percentage of dynamic pixels; marker = sweep axis."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(7.0, 4.6), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    colours = ["tab:red", "tab:blue", "tab:green", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:olive"]
    handles = []
    x_all = np.array([r["dynamic_pct"] for r in rows])
    order = np.argsort(x_all, kind="stable")
    for (key, label), colour in zip(series, colours):
        x = np.array([rows[i]["dynamic_pct"] for i in order])
        y = np.array([np.nan if rows[i].get(key) is None else rows[i][key] for i in order], dtype=np.float64)
        if log_y:
            y = np.where(y > 0, y, np.nan)
        if not np.isfinite(y).any():
            continue
        ax.plot(x[np.isfinite(y)], y[np.isfinite(y)], "-", color=colour, alpha=0.35, lw=1)
        for i, xi, yi in zip(order, x, y):
            if np.isfinite(yi):
                ax.plot([xi], [yi], AXIS_MARKERS.get(rows[i]["axis"], "o"), color=colour, ms=7)
        handles.append(Line2D([], [], color=colour, marker="o", ls="-", label=label))
    for axis, m in AXIS_MARKERS.items():
        if any(r["axis"] == axis for r in rows):
            handles.append(Line2D([], [], color="grey", marker=m, ls="", label=f"sweep: {axis}"))
    if log_y:
        ax.set_yscale("log")
    ax.set_xlabel("dynamic pixels (% of all pixels)")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    if handles:
        ax.legend(handles=handles, fontsize=8, loc="best")
    fig.tight_layout()
    with atomic.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")


def write_outputs(out: Path, report: dict) -> None:
    """stress.json, stress.md and the four plots, each atomically."""
    cfg = report["config"]
    title = f"stress study ({cfg['scene']}, {report['odometry']})"
    plugins = report.get("plugins", {})
    for name, (ylabel, series, log_y) in PLOTS.items():
        key = series[0][0]
        if key.startswith(("vo_", "slam_")) and plugins:
            series = series + [(key.replace("_gt_", f"_{k}_"), f"{n} (plug-in)") for k, n in plugins.items()]
        plot_error(out / name, report["rows"], ylabel, series, log_y, title)
    atomic.write_json(out / "stress.json", report)
    atomic.write_text(out / "stress.md", markdown(report))


__all__ = ["StressConfig", "Setting", "RigidFitOdometry", "run_stress", "scaled_movers", "render_setting",
           "measure_sequence", "make_odometries", "conclusion", "markdown"]
