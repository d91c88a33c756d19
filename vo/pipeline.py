"""``run_vo``: visual odometry over a sequence, the library entry of ``deepslam vo`` (beside
:func:`slam.pipeline.run_slam`).

One odometry (the shipped or a given network, or a plug-in) predicts ``cam_{t+k}_from_cam_t`` for the
consecutive pairs of the chosen frames; the motions are chained into ``world_from_cam`` (the first frame at
the origin) and checked finite. A network's flow is set up as its model file records (DIS preset, texture
threshold), the options given overriding it; its pose mode (``net`` or ``epipolar``) and distance source
(``network``, ``road``, ``road-flow``) are the file's unless given.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from deepslam.core.errors import InputError
from deepslam.core.sequence import (  # noqa: F401 - UpsampledView and check_read_width importable from here too
    UpsampledView, check_read_width, read_for_estimated_flow)
from deepslam.core.se3 import chain_euler6
from deepslam.core.trajectory import check_finite_poses
from deepslam.vo.modelfiles import models, modeltree

POSES = ("net", "epipolar")
"""Pose modes: the network's 6DoF, or rotation and direction from the essential matrix of the flow."""
SCALES = ("network", "road", "road-flow")
"""Where the distance travelled comes from in the epipolar pose mode."""


@dataclasses.dataclass(frozen=True)
class VOConfig:
    """How :func:`run_vo` runs (the options of ``deepslam vo``)."""

    model: str | None = None
    """Model file, or a shipped name (``kitti``, ``euroc:loops``, ...); None: the shipped NN_cons of the
    sequence's camera kind, trained on ``flow``'s flow where such a model is shipped."""
    flow: str = "dis"
    """Flow estimator: ``dis``, ``learned``, ``learned-dis``, ``gt`` (the sequence's own) or a plug-in."""
    flow_options: tuple[tuple[str, object], ...] = ()
    """Estimator options given (name, value) that override the model file's record (DIS preset, ...)."""
    pose: str | None = None
    """``net`` or ``epipolar`` (:data:`POSES`); None: the mode the model file records."""
    scale: str | None = None
    """With the epipolar pose, the distance's source (:data:`SCALES`); None: the model file's."""
    camera_height_m: float = 1.65
    """Camera height above the road for the road scale, metres (KITTI and the simulated street)."""
    stride: int = 1
    """Frame gap k: motions cam_{t+k}_from_cam_t for t = start, start + k, ..."""
    start: int = 0
    """First frame."""
    end: int | None = None
    """One past the last frame (None: all)."""
    batch: int = 64
    """Flows per forward pass."""
    device: str = "auto"
    """``auto`` (CUDA when torch sees one), ``cpu``, ``cuda`` or ``cuda:N``."""
    bf16: bool | None = None
    """bfloat16 inference; None: where the CPU computes bf16 natively."""
    progress: bool = True
    """Show a progress bar."""
    read_width_px: int = 640
    """Frames narrower than this are read upsampled to it (bicubic, the camera scaled likewise; a monocular
    network on estimated flow only); 0: read as recorded. At 320 px DIS and the road scale over-read the
    distance (docs/experiments/2026-12-06_read_width.md)."""
    std_from_geometry: bool = False
    """Widen each pair's std per DoF by the network's disagreement with the geometry that reads the same flow (the
    epipolar fit's rotation and direction of travel, the road's distance: the ``epipolar`` pose with the ``road``
    scale), ``sqrt(std^2 + d^2)`` (:func:`vo.calibration.widened_std`); pairs the geometry cannot read keep the
    network's std. With ``pose`` net the motions stay the network's; with ``pose`` epipolar the scale must be road."""
    centre_principal_point: bool = False
    """Move every flow so that the camera's principal point lies at the image's centre before the network reads it
    (:func:`flow.estimators.centre_principal_point`: the simulator's cameras are centred, KITTI's is not)."""
    mirror_average: str = models.MIRROR_AVERAGE_DEFAULT
    """Read every flow also mirrored left-right and average the two motions: ``on``, ``off``, or ``auto`` (a model
    trained on mirrored frames with the ``net`` pose; :func:`vo.modelfiles.models.mirror_average`)."""

    def frames(self, n_frames: int) -> np.ndarray:
        """(N,) int64 indices of the frames a run over an ``n_frames``-frame sequence reads. InputError for an
        empty range, a stride below 1 or fewer than two frames."""
        if self.stride < 1:
            raise InputError(None, f"--stride must be >= 1, got {self.stride}")
        end = n_frames if self.end is None else min(self.end, n_frames)
        if not 0 <= self.start < end:
            raise InputError(None, f"empty frame range [{self.start}, {end}) of a {n_frames}-frame sequence")
        frames = np.arange(self.start, end, self.stride)
        if len(frames) < 2:
            raise InputError(None, f"needs at least two frames at stride {self.stride} in [{self.start}, {end})")
        return frames


@dataclasses.dataclass
class VOResult:
    """What :func:`run_vo` computed."""

    frames: np.ndarray
    """(N,) int64 frame indices of the trajectory's poses."""
    pairs: np.ndarray
    """(N - 1, 2) int64 frame pairs (i, j) of the motions."""
    mean6: np.ndarray
    """(N - 1, 6) float64 cam_j_from_cam_i: euler x, y, z (rad), t x, y, z (m)."""
    std6: np.ndarray
    """(N - 1, 6) float64 predicted std of ``mean6`` (rad, m)."""
    world_from_cam: np.ndarray
    """(N, 4, 4) float64 chained poses, the first frame at the origin."""
    name: str
    """The odometry's name (the model's, or the plug-in's)."""
    record: dict
    """The run's settings as resolved (model, flow, pose, epipolar and road-scale figures ...) for its record."""


def run_vo(seq, cfg: VOConfig = VOConfig(), odometry=None) -> VOResult:
    """Visual odometry over ``seq`` (a :class:`core.sequence.Sequence`) by ``cfg``; ``odometry``: a plug-in
    (:class:`slam.odometry.Odometry`, e.g. from :func:`slam.plugins.from_options`) instead of the network.

    Raises:
        InputError: bad options (before any flow is computed), a model file that cannot be used, an odometry
            that fails or whose chained trajectory is not finite.
    """
    if not 1 <= cfg.batch <= 4096:
        raise InputError(None, f"--batch must be in 1..4096, got {cfg.batch}")
    check_read_width(cfg.read_width_px)
    frames = cfg.frames(len(seq))
    pairs = np.stack([frames[:-1], frames[1:]], axis=1)
    if odometry is not None:
        if cfg.model is not None:
            raise InputError(None, "--model and --odometry/--odometry-command exclude each other")
        for flag, on in (("--pose epipolar", cfg.pose == "epipolar"),
                         (f"--scale {cfg.scale}", cfg.scale in ("road", "road-flow"))):
            if on:
                raise InputError(None, f"{flag} needs the network odometry (not --odometry/--odometry-command)")
        mean6, std6 = odometry.predict(seq, pairs)
        name, record = odometry.name, {"model_name": odometry.name}
    else:
        mean6, std6, name, record = _network(seq, pairs, cfg)
    world_from_cam = chain_euler6(mean6)
    check_finite_poses(world_from_cam, f"the odometry {name}")
    return VOResult(frames, pairs, mean6, std6, world_from_cam, name, record)


def _reads_depth(model_path) -> bool:
    """Whether the VO model file's network reads the frame's depth (its header only); True when unreadable
    (the loader then says what is wrong)."""
    try:
        return bool(modeltree.net_config(modeltree.read_header_tree(model_path)).get("depth_channel"))
    except Exception:  # noqa: BLE001 - any unreadable file: not upsampled, the loader reports it
        return True


def read_view(seq, read_width_px: int, model_path, flow: str):
    """``seq`` as the network of the VO model file ``model_path`` reads it on flow estimator ``flow``: an
    :class:`UpsampledView` ``read_width_px`` wide where the frames are narrower, the flow is estimated (not ``gt``)
    and the network does not read depth; else ``seq`` itself."""
    return read_for_estimated_flow(seq, read_width_px, flow, lambda: _reads_depth(model_path))


def _network(seq, pairs: np.ndarray, cfg: VOConfig) -> tuple[np.ndarray, np.ndarray, str, dict]:
    """(mean6, std6, name, record) of the network odometry over ``pairs``."""
    # deferred: the flow workers load only when a network runs (a plug-in run stays torch-free)
    from deepslam.vo.data.prefetch import PairInputs, model_input

    model_path, shipped = models.locate(cfg.model, seq, flow=cfg.flow)
    recorded_seq = seq
    seq = read_view(seq, cfg.read_width_px, model_path, cfg.flow)
    estimator = models.flow_for_model(cfg.flow, model_path, **dict(cfg.flow_options))  # DIS set up as trained
    # the flows start before torch and the model load (seconds of start-up they overlap)
    spec = model_input(model_path)
    pose = cfg.pose or models.recorded_pose(model_path)
    if not 0.1 <= cfg.camera_height_m <= 100.0:
        raise InputError(None, f"--camera-height must be in [0.1, 100] m, got {cfg.camera_height_m}")
    epi = models.epipolar_config(model_path, pose, cfg.scale, cfg.camera_height_m)
    if cfg.scale in ("road", "road-flow") and epi is None:
        raise InputError(None, f"--scale {cfg.scale} needs --pose epipolar (the road fit uses its rotation and "
                               "direction)")
    # the reading the std is widened by (VOConfig.std_from_geometry)
    geometry = models.geometry_config(model_path, epi, cfg.camera_height_m) if cfg.std_from_geometry else None
    fit_cfg = models.fit_config(epi, geometry)
    fitter = None
    if fit_cfg is not None:
        from deepslam.vo.geometry.epipolar import EpipolarFitter  # deferred with the flow workers above

        fitter = EpipolarFitter(fit_cfg)
    inputs = None if spec is None else PairInputs(seq, pairs, estimator, spec[1], spec[0], unknown=spec[2],
                                                  full_flow_fn=fitter, centre=cfg.centre_principal_point)
    try:
        # deferred: torch (1.5 s to import) loads while the flow workers above already compute the first flows
        from deepslam.runtime.device import resolve_device
        from deepslam.vo.odometry import load_predictor

        predictor = load_predictor(model_path, shipped, batch_size=cfg.batch, bf16=cfg.bf16,
                                   device=resolve_device(cfg.device),
                                   centre_principal_point=cfg.centre_principal_point,
                                   mirror_average=cfg.mirror_average, net_pose=epi is None)
    except BaseException:
        if inputs is not None:
            inputs.close()
        raise
    fits: list = []
    road: list = []
    mean6, std6 = predictor.predict_pairs(seq, pairs, estimator, progress=cfg.progress, inputs=inputs, epipolar=epi,
                                          geometry=geometry, fits_out=fits, road_out=road)
    record = {"model": str(model_path.resolve()) if cfg.model else f"shipped:{models.kind_for_sequence(seq)}_cons",
              "model_name": predictor.name, "model_net": predictor.model.cfg.to_dict(),
              "flow": getattr(estimator, "name", cfg.flow), "bf16": predictor.bf16, "batch": cfg.batch,
              "device": str(predictor.device), "pose": pose,
              "centre_principal_point": predictor.centre_principal_point, "mirror_average": predictor.mirror_average,
              "std_from_geometry": geometry is not None}
    if seq is not recorded_seq:
        record["read_at_px"] = [seq.camera.width, seq.camera.height]
    if fit_cfg is not None:
        record.update(epipolar=dataclasses.asdict(fit_cfg), epipolar_pairs_used=sum(u for _, u in fits))
        if fit_cfg.road_height_m is not None and road:
            record.update(road_scale_pairs_used=int(sum(math.isfinite(d) for d in road[0].distances_m)),
                          road_scale_sources=road[0].counts(), road_pitch_deg=road[0].pitch_deg)
    return mean6, std6, predictor.name, record
