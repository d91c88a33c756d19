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

Odometry: the shipped NN_cons / NN_loops (:func:`vo.odometry.load_shipped`) or the given model files.
When no learned model is available (or with ``odometry="rigid-fit"``) the study falls back, with a
note in every table, to :class:`slam.rigid_fit.RigidFitOdometry`: a least-squares rigid-motion fit
(reprojection error, :func:`cv2.solvePnP`) of the flow + frame-i depth over ALL pixels with depth. That
estimator is exact on a rigid scene with exact flow, so whatever error it makes on ground-truth flow is the
rigid assumption failing, directly. Plug-in odometries (``plugins``) and external programs (``commands``,
:class:`slam.plugins.CommandOdometry`) are measured side by side with it (:func:`slam.compare.load_plugins`).

Size of the moving objects: :class:`scenes.SceneConfig` has no size knob, so the meshes of the rigid
movers are scaled after the movers were placed as for the unscaled scene (:mod:`sim.scaled_movers`).

This module runs the sweep; :mod:`deepslam.studies.stress_report` makes its table, conclusion and files.
Outputs (all written atomically) in ``out``: ``stress.json`` (rows, config, conclusion, timings),
``stress.md`` (the table and the conclusion line), ``report.html`` (the same with the plots on one page),
``config.json`` (the resolved configuration),
``stress_flow_epe.png``, ``stress_vo_ate.png``, ``stress_vo_rpe.png``, ``stress_slam_ate.png``
(error against the fraction of dynamic pixels), ``settings/<name>.json`` (one result per setting,
reused by ``resume``), ``vocabulary.npz`` (the BoW vocabulary shared by the settings) and, with
``keep_sequences``, the rendered sequences under ``sequences/``.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from deepslam.core import atomic, metrics
from deepslam.core.atomic import json_safe
from deepslam.core.dynamic import dynamic_fraction
from deepslam.core.errors import InputError
from deepslam.core.kinds import kind_for_scene
from deepslam.core.lock import output_lock
from deepslam.core.progress import progress as progress_bar
from deepslam.core.readers import open_sequence
from deepslam.core.trajectory import Trajectory
from deepslam.flow.estimators import DISFlow, GroundTruthFlow
from deepslam.gen.validate import validate_sequence
from deepslam.runtime.device import resolve_device
from deepslam.sim import RenderConfig, SceneConfig, SimConfig, Simulator, TrajectoryConfig
from deepslam.sim.scaled_movers import scaled_movers, scene_with_scaled_movers
from deepslam.sim.writers import render_sequence
from deepslam.slam.compare import load_plugins
from deepslam.slam.odometry import check_prediction
from deepslam.slam.pipeline import PipelineConfig, SlamParams, consecutive_pairs, prepare, solve
from deepslam.slam.plugins import DEFAULT_COMMAND_TIMEOUT_S, UpsampledReading, command_argv
from deepslam.slam.posegraph import Edges, PoseGraphConfig, chain
from deepslam.slam.reloc import RelocConfig
from deepslam.slam.rigid_fit import RigidFitOdometry
from deepslam.slam.vocab_cache import cached_vocabulary
from deepslam.studies.stress_report import RESULT_FORMAT, build_report, conclusion, markdown, write_outputs

SCENES = ("street", "room")
ODOMETRIES = ("model", "rigid-fit")
MAX_OBJECTS = 64
"""Most moving objects the scenes accept (:class:`scenes.SceneConfig`)."""
MAX_DEFORM_M = 0.3
"""Largest deformation amplitude the scenes accept, metres."""
MAX_OBJECT_SCALE = 3.0
"""Largest mover scale factor accepted (3: a car becomes 12.6 m long and 5.4 m wide, as wide as its lane)."""


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
    "rigid-fit": :class:`slam.rigid_fit.RigidFitOdometry` (least-squares rigid motion from flow + depth, all pixels)."""
    plugins: tuple[str, ...] = ()
    """Further odometries measured side by side with the first, each on the images alone: plug-in specs
    (``MODULE:FACTORY`` or an entry-point name of group ``deepslam.odometry``, e.g. ``pnp``, the shipped
    classical baseline; see :mod:`deepslam.slam.plugins`). Their rows are keyed by the plug-in's name."""
    commands: tuple[str, ...] = ()
    """External odometry programs measured side by side like the plug-ins, after them: command templates
    ``'CMD {sequence} {out}'`` (:class:`slam.plugins.CommandOdometry`: run without a shell on each rendered
    sequence, writing a KITTI or TUM trajectory to ``{out}``). Their rows are keyed by the program's name."""
    command_timeout_s: float = DEFAULT_COMMAND_TIMEOUT_S
    """Seconds an external odometry program may run on one rendered sequence."""
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
    read_width_px: int = 640
    """The networks on DIS flow read frames narrower than this upsampled to it, as ``deepslam vo --read-width``
    (:class:`slam.plugins.UpsampledReading`); 0: as rendered."""
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
        if not isinstance(self.read_width_px, int) or not 0 <= self.read_width_px <= 8192:
            raise InputError(None, f"--read-width must be an integer in 0..8192 px, got {self.read_width_px}")
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
        if len(set(self.commands)) != len(self.commands):
            raise InputError(None, f"an odometry command is listed twice: {list(self.commands)}")
        for template in self.commands:
            command_argv(template, sequence="", out="")  # refused before anything runs
        if not (isinstance(self.command_timeout_s, (int, float)) and math.isfinite(self.command_timeout_s)
                and self.command_timeout_s > 0):
            raise InputError(None, f"the odometry command's timeout must be a positive number of seconds, "
                                   f"got {self.command_timeout_s}")
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
        d["commands"] = list(self.commands)
        return d


# --------------------------------------------------------------------------------------------------
# the scene of a setting


def sim_config(config: StressConfig, setting: Setting) -> SimConfig:
    """The simulator's :class:`sim.SimConfig` of one setting (mono, scene default trajectory)."""
    return SimConfig(SceneConfig(name=config.scene, seed=config.seed, moving_objects=setting.moving_objects,
                                 deform_amplitude_m=setting.deform_amplitude_m),
                     TrajectoryConfig(kind="auto", frames=config.frames),
                     RenderConfig(backend=config.backend, width=config.width, stereo_baseline_m=0.0, flow=True))


def setting_scene(config: StressConfig, setting: Setting):
    """(SimConfig, Scene) of one setting: the movers placed as for the unscaled scene, then scaled by
    ``setting.object_scale`` (:func:`sim.scaled_movers.scene_with_scaled_movers`), so that a size setting
    differs from its unscaled twin in the size of the movers only."""
    cfg = sim_config(config, setting).validate()
    return cfg, scene_with_scaled_movers(cfg, setting.object_scale)


def render_setting(config: StressConfig, setting: Setting, out_dir: Path, progress: bool = False) -> Path:
    """Render one setting into ``out_dir`` (our format; resumes an interrupted render). Returns the folder."""
    cfg, scene = setting_scene(config, setting)
    with Simulator(cfg, scene=scene) as simulator:
        return render_sequence(cfg, out_dir, fmt="ours", resume=True, progress=progress, simulator=simulator)


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
    """{key: plug-in or command odometry} measured side by side (consecutive and loop pairs on the images alone)."""


def make_odometries(config: StressConfig) -> OdometrySet:
    """Learned odometry when available (shipped or given models), else the rigid fit, noted; plus the
    plug-ins of ``config.plugins`` and the external programs of ``config.commands``."""
    odo = _main_odometries(config)
    odo.plugins = load_plugins(config.plugins, config.commands, config.command_timeout_s)
    return odo


def _pose_label(epipolar) -> str:
    """How a model's pose is read, for the report: the network's own, or the essential matrix's (with the
    road scale where its :class:`vo.geometry.epipolar.EpipolarConfig` reads one)."""
    if epipolar is None:
        return "its own pose"
    return "epipolar pose, road scale" if epipolar.road_height_m is not None else "epipolar pose"


def _main_odometries(config: StressConfig) -> OdometrySet:
    flows = {"gt": GroundTruthFlow(), "dis": DISFlow(config.dis_preset)}
    note = None
    if config.odometry == "model":
        kind = camera_kind(config.scene)
        try:
            # deferred: a missing or broken learned stack (ImportError) falls back to the rigid fit
            from deepslam.vo.modelfiles import models
            from deepslam.vo.odometry import model_odometry

            # shipped models follow the flow they are given (a DIS-trained variant where one is shipped), each in the
            # pose mode and with the distance source its file records, as `deepslam vo` runs it (the epipolar pose
            # and the road scale for the street default; the network's own pose where it records none)
            dev = resolve_device(config.device)
            cons, cons_epi = {}, {}
            for f, est in flows.items():
                path, shipped = models.locate(config.model_cons or kind, None, "cons", est)
                if f == "dis":  # DIS set up as this model was trained (its texture threshold), at the study's preset
                    est = models.flow_for_model("dis", path, preset=config.dis_preset)
                cons[f] = model_odometry(path, f, shipped, estimator=est, device=dev)
                cons_epi[f] = models.epipolar_config(path)
                if config.read_width_px and f == "dis":  # as `deepslam vo --read-width` reads the frames
                    cons[f] = UpsampledReading(cons[f], config.read_width_px, path, f)
            path, shipped = models.locate(config.model_loops or f"{kind}:loops", None, "loops", flows["dis"])
            loops = model_odometry(path, "dis", shipped, pose="net",
                                   estimator=models.flow_for_model("dis", path, preset=config.dis_preset), device=dev)
            if config.read_width_px:
                loops = UpsampledReading(loops, config.read_width_px, path, "dis")
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
            names = ", ".join(f"{cons[f].predictor.name} on {f} flow ({_pose_label(cons_epi[f])})" for f in flows)
            read = f"; DIS frames read at {config.read_width_px} px" if config.read_width_px > config.width else ""
            return OdometrySet("model", cons, loops, f"deepslam vo's default: NN_cons {names}, and NN_loops "
                                                     f"{loops.predictor.name} (on DIS flow){read}")
    return OdometrySet("rigid-fit", {f: RigidFitOdometry(est) for f, est in flows.items()}, RigidFitOdometry(flows["dis"]),
                       "rigid least-squares fit of flow + depth over all pixels (solvePnP, no outlier rejection); "
                       "loop pairs on DIS flow", note)


# --------------------------------------------------------------------------------------------------
# measuring one setting


def _metrics(gt, est) -> dict:
    """The figures the study records of one trajectory (:func:`core.metrics.evaluate`, SE3-aligned)."""
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
    timings = {}
    t0 = time.perf_counter()
    n = len(seq)
    rep = validate_sequence(seq, validation_frames(n, config.validation_frames), progress=False)
    flow = {"dynamic_fraction": dynamic_fraction(*(seq.mask(t) for t in range(n - 1))),
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
    config = config.validate()
    with cpu_threads(config.threads), output_lock(out):  # one writer per output folder
        return _run(config, Path(out), resume, progress)


def _run(config: StressConfig, out: Path, resume: bool, progress: bool | None) -> dict:
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
            row = json_safe({"key": cfg_key, "setting": dataclasses.asdict(s), **result})
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
    if not d.get("commands"):  # keys of runs without commands stay those of runs before the option existed
        d.pop("commands", None)
    d.pop("command_timeout_s", None)  # a time limit does not change a result
    return json_safe(d)


def _shared_vocabulary(out: Path, config: StressConfig, seq):
    """One BoW vocabulary for the whole study, trained on the first rendered setting's keyframes and saved
    as ``out/vocabulary.npz`` (so every setting's SLAM sees the same words;
    :func:`slam.vocab_cache.cached_vocabulary`); None without keypoints."""
    reloc = dataclasses.replace(RelocConfig.for_kind(camera_kind(config.scene)), image_scale=config.sift_image_scale,
                                vocabulary_size=config.vocabulary_size)
    images = (seq.image(i) for i in range(0, len(seq), config.keyframe_stride))
    return cached_vocabulary(out / "vocabulary.npz", {"stress_key": _vocab_key(config)}, images, reloc,
                             np.random.default_rng(config.seed))


def _vocab_key(config: StressConfig) -> str:
    return f"{config.scene}/{config.seed}/{config.width}/{config.frames}/{config.sift_image_scale}/{config.vocabulary_size}"


__all__ = ["StressConfig", "Setting", "OdometrySet", "RigidFitOdometry", "run_stress", "scaled_movers",
           "setting_scene", "render_setting", "measure_sequence", "make_odometries", "conclusion", "markdown"]
