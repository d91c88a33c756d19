"""The models shipped in ``<repo>/models/`` (see models/README.md for the commands that make them).

Files are named ``<kind>_<which>.safetensors``: kind ``kitti`` (street cameras, 96 x 320-like input),
``euroc`` (indoor MAV cameras) or ``tum`` (640x480 hand-held RGB-D cameras); which ``cons`` (NN_cons: the motion distribution of consecutive
frames, for odometry) or ``loops`` (NN_loops: the wide distribution of loop-closure pairs).

Each is trained on exact synthetic flow (the paper). Where a flow estimator's errors matter, a
variant trained on that estimator's flow is shipped beside it as ``<kind>_<which>_<estimator>.safetensors``
(``deepslam train --synthetic-flow dis``): given the estimator's name (``flow=``), the functions here
pick it, and fall back to the exact-flow model where there is none.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

import deepslam.models
from deepslam.core.errors import InputError
from deepslam.core.kinds import KINDS, kind_for_sequence  # noqa: F401 - part of this module's API
from deepslam.core.textio import short
from deepslam.vo.geometry.epipolar import EpipolarConfig
from deepslam.vo.modelfiles import modeltree

WHICH = ("cons", "loops")
"""NN_cons (consecutive frames) and NN_loops (loop pairs)."""
FLOW_VARIANTS = ("dis", "learned", "gt")
"""Estimators with models chosen for their flow (file suffix ``_<name>``): OpenCV DIS, the learned flow estimator
(``models/flow_learned.safetensors``), and the simulator's exact flow (``gt``: on streets the paper recipe's
single-frame model, chosen by docs/experiments/2026-12-06_exact_flow_model.md; elsewhere the plain model)."""
SHARED_VARIANTS = {"learned-dis": "dis"}
"""Estimators read by the models of another's flow: ``learned-dis`` (DIS refining the learned flow) by DIS's
models (chosen on KITTI 06, 2026-12-03: the DIS model reads it at drift 2.0 %, the learned-flow model 4.2 %)."""


def flow_variant(flow: str | None) -> str | None:
    """The variant suffix for a flow estimator's name or object name (``dis``, ``dis-medium`` -> ``dis``;
    ``learned`` -> ``learned``; ``learned-dis`` -> ``dis`` (:data:`SHARED_VARIANTS`); ``gt`` -> ``gt``; None ->
    None). A kind without a file of the variant uses its plain model (exact flow is what it learned)."""
    if flow is None:
        return None
    name = str(getattr(flow, "name", flow))
    if name in SHARED_VARIANTS:
        return SHARED_VARIANTS[name]
    base = name.split("-")[0]
    return base if base in FLOW_VARIANTS else None


def models_dir() -> Path:
    """The shipped models' folder: the ``deepslam.models`` package (``<repo>/models`` in a checkout,
    ``site-packages/deepslam/models`` installed)."""
    return Path(deepslam.models.__file__).resolve().parent


def shipped_path(kind: str, which: str = "cons", flow=None) -> Path:
    """Path of a shipped model file (it may not exist): ``<kind>_<which>.safetensors``, or the variant trained on
    ``flow``'s estimator (a name or an estimator object) where that file exists."""
    if kind not in KINDS:
        raise InputError(None, f"no shipped model for camera kind {kind!r} (one of {', '.join(KINDS)})")
    if which not in WHICH:
        raise InputError(None, f"unknown model variant {which!r} (one of {', '.join(WHICH)})")
    variant = flow_variant(flow)
    trained_on_flow = models_dir() / f"{kind}_{which}_{variant}.safetensors"
    if variant is not None and trained_on_flow.is_file():
        return trained_on_flow
    return models_dir() / f"{kind}_{which}.safetensors"


RECORDED_OPTIONS = {"dis": ("preset", "min_texture", "fb_max_px", "max_width", "patch_stride")}
"""The options a model file's flow record may set, per estimator (:class:`flow.estimators.DISFlow`'s)."""


def recorded_flow_options(path: str | Path, flow: str) -> dict:
    """The options of flow estimator ``flow`` (a :func:`vo.flow_registry.make` name) that the VO model
    file at ``path`` was trained on: its meta's ``flow`` record (``deepslam train`` writes
    ``{"estimator": name, "options": {...}}`` for a model trained on an estimator's flow;
    ``ensemble-model`` copies its members' shared record). {} when the file records another estimator
    or none (exact synthetic flow; DIS models trained before the record existed used DIS medium on
    every pixel, the estimator's defaults), or cannot be read (the loader reports that). Read from the
    file's header: no torch.

    Raises:
        InputError: naming ``path``, when the record's options are not ones ``flow`` takes
            (:data:`RECORDED_OPTIONS`).
    """
    try:
        record = modeltree.meta(modeltree.read_header_tree(path)).get("flow")
    except Exception:  # noqa: BLE001 - an unreadable file: the loader says what is wrong
        return {}
    if not isinstance(record, dict) or record.get("estimator") != flow:
        return {}
    options = record.get("options")
    allowed = RECORDED_OPTIONS.get(flow, ())
    if not isinstance(options, dict) or set(options) - set(allowed):
        raise InputError(path, f"malformed VO model: its meta.flow options {short(options)} are not options of flow "
                               f"estimator {flow} (it takes {', '.join(allowed) or 'none'})")
    return dict(options)


POSES = ("net", "epipolar")
"""How a VO model's motions are used: ``net``, the network's 6DoF (the paper); ``epipolar``, the rotation and
direction of travel from the essential matrix of the flow and the distance from the network (:mod:`vo.geometry.epipolar`)."""


def _recorded(path: str | Path, key: str, choices: tuple[str, ...], default: str) -> str:
    """The value of meta ``key`` of the VO model file at ``path`` (one of ``choices``), from the header (no
    torch); ``default`` where the file records none or cannot be read (the loader reports that).
    InputError naming ``path`` for a value not in ``choices``."""
    try:
        value = modeltree.meta(modeltree.read_header_tree(path)).get(key, default)
    except Exception:  # noqa: BLE001 - an unreadable file: the loader says what is wrong
        return default
    if value not in choices:
        raise InputError(path, f"malformed VO model: its meta.{key} {short(value)} is not one of {', '.join(choices)}")
    return value


def recorded_pose(path: str | Path) -> str:
    """The pose mode (:data:`POSES`) the VO model file at ``path`` records as its own (meta ``pose``,
    written by ``deepslam set-pose``): what ``vo`` and ``slam`` use when ``--pose`` is not given.
    ``net`` where the file records none or cannot be read."""
    return _recorded(path, "pose", POSES, "net")


SCALES = ("network", "road", "road-flow")
"""Where the epipolar pose's distance comes from: the network's translation, the road (:mod:`vo.geometry.road_flow`:
its motion in the flow, the images where the flow loses it, neighbours' distances across short gaps) or the
road's motion in the flow only."""
ROAD_HEIGHT_M = 1.65
"""Camera height above the road of the KITTI cameras and the simulated street, metres."""


def recorded_scale(path: str | Path) -> str:
    """The distance source (:data:`SCALES`) the VO model file at ``path`` records (meta ``scale``, written by
    ``deepslam set-pose --scale``); ``network`` where it records none or cannot be read."""
    return _recorded(path, "scale", SCALES, "network")


def epipolar_config(path: str | Path, pose: str | None = None, scale: str | None = None,
                    road_height_m: float = ROAD_HEIGHT_M):
    """The :class:`vo.geometry.epipolar.EpipolarConfig` to run the VO model file at ``path`` with in pose mode ``pose``
    and distance source ``scale`` (None: the ones the file records, :func:`recorded_pose`,
    :func:`recorded_scale`; ``road`` / ``road-flow``: read with the camera ``road_height_m`` above the road);
    None in the ``net`` mode."""
    if pose not in (None, *POSES):
        raise ValueError(f"pose must be one of {', '.join(POSES)} or None, got {pose!r}")
    if scale not in (None, *SCALES):
        raise ValueError(f"scale must be one of {', '.join(SCALES)} or None, got {scale!r}")
    if (pose or recorded_pose(path)) != "epipolar":
        return None
    source = scale or recorded_scale(path)
    road = source in ("road", "road-flow")
    return EpipolarConfig(road_height_m=float(road_height_m) if road else None, road_fill=source == "road")


def fit_config(epipolar=None, geometry=None):
    """The :class:`vo.geometry.epipolar.EpipolarConfig` each pair's flow is fitted with: the epipolar pose's
    (``epipolar``), or the one the std is widened by (``geometry``, :func:`geometry_config`), or None when neither is
    asked for. Both given must be the same configuration (ValueError otherwise)."""
    if geometry is not None and epipolar is not None and epipolar != geometry:
        raise ValueError("the std is widened by the geometry the epipolar pose reads: pass one configuration")
    return epipolar if geometry is None else geometry


MIRROR_AVERAGE = ("auto", "on", "off")
"""``vo --mirror-average``: ``on`` reads every flow also mirrored left-right and averages the two motions
(:attr:`vo.infer.VOPredictor.mirror_average`), ``off`` reads it once, ``auto`` mirrors for a model trained on mirrored
frames (:func:`trained_on_mirrored_frames`) read with its own pose (``net``)."""
MIRROR_AVERAGE_DEFAULT = "off"
"""The default of ``--mirror-average`` (docs/experiments/2026-12-07_mirror_average.md)."""


def trained_on_mirrored_frames(meta: dict) -> bool:
    """True for a VO model whose training read every single frame and its left-right mirror image (``train
    --mirror-frames``: its meta ``data.mirror_frames``)."""
    return bool((meta.get("data") or {}).get("mirror_frames"))


def mirror_average(choice: str, meta: dict, net_pose: bool) -> bool:
    """Whether a VO model with ``meta`` reads each flow also mirrored (:data:`MIRROR_AVERAGE`'s ``choice``);
    ``net_pose``: the run uses the network's own pose. ValueError for a choice not in :data:`MIRROR_AVERAGE`."""
    if choice not in MIRROR_AVERAGE:
        raise ValueError(f"mirror_average must be one of {', '.join(MIRROR_AVERAGE)}, got {choice!r}")
    return choice == "on" or (choice == "auto" and net_pose and trained_on_mirrored_frames(meta))


def geometry_config(path: str | Path, epipolar=None, road_height_m: float = ROAD_HEIGHT_M):
    """The :class:`vo.geometry.epipolar.EpipolarConfig` whose reading widens the VO model file ``path``'s std
    (``vo --std-from-geometry``): the epipolar fit with the road's distance, the camera ``road_height_m`` above the
    road. ``epipolar``: the run's own epipolar configuration (None in the ``net`` pose), which must be that same one.
    InputError otherwise."""
    geometry = epipolar_config(path, "epipolar", "road", road_height_m)
    if epipolar is not None and epipolar != geometry:
        raise InputError(None, "--std-from-geometry compares the network with the fit and the road's distance: with "
                               "--pose epipolar it needs --scale road")
    return geometry


def write_with_pose(path: str | Path, out: str | Path, pose: str, scale: str | None = None) -> dict:
    """Write the VO model file ``path`` (single network or ensemble) to ``out`` (atomically) with ``pose``
    (:data:`POSES`) recorded as its pose mode and, when given, ``scale`` (:data:`SCALES`) as its distance
    source: the same weights and meta otherwise. Returns the new meta. InputError naming ``path`` when it is
    not a VO model file."""
    if pose not in POSES:
        raise InputError(None, f"pose must be one of {', '.join(POSES)}, got {pose!r}")
    if scale is not None and scale not in SCALES:
        raise InputError(None, f"scale must be one of {', '.join(SCALES)}, got {scale!r}")
    return write_with_meta(path, out, {"pose": pose, **({"scale": scale} if scale is not None else {})})


def write_with_meta(path: str | Path, out: str | Path, updates: dict) -> dict:
    """Write the VO model file ``path`` to ``out`` (atomically) with the meta entries ``updates`` set (JSON
    values), the same weights and other meta. Returns the new meta. InputError naming ``path`` when it is not a
    VO model file."""
    # deferred: both import torch; the header readers here stay torch-free (deepslam vo starts its flows first)
    from deepslam.models import modelfile
    from deepslam.vo.modelfiles.modelio import MODEL_FORMAT

    kind, tree = modelfile.load(path, (MODEL_FORMAT,))
    meta = {**(tree.get("meta") if isinstance(tree.get("meta"), dict) else {}), **updates}
    modelfile.save(out, kind, {**tree, "meta": meta})
    return meta


def recorded_std_scale(meta: dict, path=None) -> np.ndarray:
    """(6,) float64 the per-DoF factor on the predicted std that the model's meta records (``deepslam calibrate``:
    :mod:`vo.calibration`); ones where it records none. InputError naming ``path`` for a malformed one."""
    value = meta.get("std_scale") if isinstance(meta, dict) else None
    if value is None:
        return np.ones(6)
    try:
        scale = np.asarray(value, np.float64).reshape(6)
    except (TypeError, ValueError):
        scale = None
    if scale is None or not (np.isfinite(scale).all() and (scale > 0).all()):
        raise InputError(path, f"malformed VO model: its meta.std_scale {short(value)} is not 6 positive numbers")
    return scale


def flow_for_model(flow: str, path: str | Path, recorded: dict | None = None, **given):
    """The flow estimator ``flow`` set up as the model file at ``path`` saw it in training
    (:func:`recorded_flow_options`: DIS's preset and texture threshold; ``recorded``: those options
    when the caller has read them already), with the options in ``given`` that are not None taking
    precedence (a command line's explicit flags). InputError naming ``path`` when its recorded
    options are not valid ones."""
    from deepslam.flow import registry as flow_registry  # deferred: it imports torch (the learned estimators)

    if recorded is None:
        recorded = recorded_flow_options(path, flow)
    options = {**recorded, **{k: v for k, v in given.items() if v is not None}}
    try:
        return flow_registry.make(flow, **options)
    except InputError as e:
        bad_record = bool(recorded)
        if recorded and options != recorded:
            try:
                flow_registry.make(flow, **recorded)
                bad_record = False  # the file's own options are fine: the command line's are not
            except InputError:
                pass
        if not bad_record:
            raise
        raise InputError(path, f"malformed VO model: its meta.flow options {recorded!r} do not set up flow "
                               f"estimator {flow} ({e.what})") from None


def resolve_path(spec: str | None, seq=None, which: str = "cons", flow=None) -> Path:
    """The model file :func:`resolve` loads for ``spec`` (it may not exist; no torch needed)."""
    return locate(spec, seq, which, flow)[0]


def locate(spec: str | None, seq=None, which: str = "cons", flow=None) -> tuple[Path, bool]:
    """(model file for ``spec``, whether it is a shipped one), as :func:`resolve` finds it (no torch
    needed). With :func:`flow_for_model` and :func:`load`: set a model's flow up before loading torch."""
    if spec is None:
        if seq is None:
            raise InputError(None, "no model given and no sequence to choose a shipped one")
        return shipped_path(kind_for_sequence(seq), which, flow), True
    kind, _, w = spec.partition(":")
    if kind in KINDS and not Path(spec).exists():
        return shipped_path(kind, w or which, flow), True
    return Path(spec), False
