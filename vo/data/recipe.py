"""The paper's training data from single frames: frames with depth + a motion model -> flow -> 6DoF targets,
as :func:`vo.train.train` takes it (a training source and a held-out one), with the record of what it saw.

Used by ``deepslam train --mode synthetic --source ...`` and by ``deepslam adapt`` (:mod:`vo.adapt`). Nothing
here reads a ground-truth pose: the frames' images and depth (rendered, sensor, or from the stereo pair) and
the motion model's samples are all it uses.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

from deepslam.core.errors import InputError
from deepslam.core.integrity import sha256_file
from deepslam.core.readers import open_sequence
from deepslam.gen.motion import MotionModel
from deepslam.vo.data.frames import load_frames, load_image_frames, with_mirrored
from deepslam.vo.data.motion import CameraTilt, FlatSpeed, MotionMixture, SceneScale, motion_sampler
from deepslam.vo.data.synthetic import EstimatedFlowSource, SyntheticSource
from deepslam.vo.net import NetConfig


def load_motion(spec: str):
    """(sampler, weight, description) from ``FILE[:loops][@WEIGHT]`` (a :mod:`gen.motion` JSON; ``:loops``
    samples its loop distribution)."""
    rest, _, w = spec.rpartition("@") if "@" in spec else (spec, "", "")
    try:
        weight = float(w) if w else 1.0
    except ValueError:
        raise InputError(None, f"bad motion weight in {spec!r}") from None
    loops = rest.endswith(":loops")
    path = Path(rest[: -len(":loops")] if loops else rest.removesuffix(":cons"))
    model = MotionModel.load(path)
    try:
        sampler = motion_sampler(model, loops)
    except InputError as e:
        raise InputError(path, e.what) from None
    return sampler, weight, {"file": str(path), "distribution": "loops" if loops else "consecutive",
                             "stride": model.stride, "weight": weight,
                             "sha256": sha256_file(path)}


@dataclasses.dataclass(frozen=True)
class SyntheticData:
    """What the synthetic training samples are made of (the ``deepslam train --mode synthetic`` flags)."""

    frames: tuple[str, ...]
    """Sequence folders whose single frames (with depth) are the training images."""
    motion: tuple[str, ...]
    """Motion model specs ``FILE[:loops][@WEIGHT]``; several make a mixture."""
    depth: str = "auto"
    """Depth of the frames: ``rendered``, ``stereo`` or ``auto``."""
    frame_step: int = 1
    """Every N-th frame."""
    max_frames: int = 0
    """At most this many frames per sequence (0: all)."""
    samples_per_epoch: int = 20000
    """Samples drawn per epoch."""
    holdout: float = 0.1
    """Fraction of the frames held out."""
    holdout_samples: int = 0
    """Held-out samples (0: ``holdout * samples_per_epoch``, at least one batch)."""
    batch_size: int = 128
    """Training batch (the held-out set holds at least one)."""
    synth_factor: int = 1
    """Exact flow synthesized at this multiple of the network's size, then pooled."""
    synthetic_flow: str = "exact"
    """``exact`` (synthesized from depth) or a flow estimator's name run on the frame and its second view
    rendered from depth (what the network sees at test time)."""
    flow_options: tuple[tuple[str, object], ...] = ()
    """That estimator's options (:func:`flow.registry.estimator_options`), as (name, value) pairs."""
    frame_scales: tuple[float, ...] = (1.0,)
    """Each frame also at these scales (estimated flow only)."""
    appearance_noise: float = 0.0
    """Grey levels of noise on the rendered second view (estimated flow only)."""
    crop_window: tuple[int, int] | None = None
    """(width, height) px of a window each sample's views are cut to at a random place, its principal point moved
    with it (estimated flow only; :class:`vo.data.synthetic.EstimatedFlowSource`); None: the whole frame."""
    data_threads: int = 2
    """Threads estimating the flow of the samples."""
    sample_pool: int = 0
    """Draw this many samples once and train on them every epoch (0: fresh samples each epoch)."""
    missing_depth: str | None = None
    """Pixels without depth: ``infinity`` or ``invalid`` (None: invalid for sensor depth, else infinity)."""
    speed_range: str | None = None
    """``MIN:MAX[@FRACTION]`` m/s drawn flat instead of the model's forward speed."""
    rate_hz: float = 10.0
    """Frame rate of the motion model, for ``speed_range``."""
    camera_tilt_deg: str | None = None
    """``PMIN:PMAX[:ROLL]``: each sample's camera rotated by a random pitch and roll."""
    scene_scale: str | None = None
    """``MIN:MAX``: each sample's scene scaled."""
    mirror_frames: bool = False
    """Every training frame also mirrored left-right."""
    device: str = "cpu"
    """Torch device that holds the frames' depth and synthesizes exact flow (``cpu`` or the training GPU)."""


def synthetic_sources(spec: SyntheticData, net: NetConfig, seed: int, progress: bool):
    """(training source, held-out source, meta) for :func:`vo.train.train` from ``spec``.

    ``meta`` holds ``data`` (what the samples were made of, with the motion files' sha256) and, for
    estimated flow, ``flow`` (the estimator and its options, which ``vo`` / ``slam`` set up to match).
    """
    if not spec.frames:
        raise InputError(None, "synthetic mode needs --source DIR... (or --toy N)")
    if not spec.motion:
        raise InputError(None, "synthetic mode needs --motion FILE (a gen.motion JSON; repeat for a mixture)")
    if spec.crop_window is not None and spec.synthetic_flow == "exact":
        raise InputError(None, "--crop-window cuts the views an estimator reads: it needs --synthetic-flow NAME")
    h, w = net.input_height, net.input_width
    tilt = CameraTilt.parse(spec.camera_tilt_deg) if spec.camera_tilt_deg else None
    scene_scale = SceneScale.parse(spec.scene_scale) if spec.scene_scale else None
    motions = [load_motion(m) for m in spec.motion]
    sampler = MotionMixture([m[0] for m in motions], [m[1] for m in motions])
    speed_range, flat_speed = None, None
    if spec.speed_range:
        sampler = flat_speed = FlatSpeed.parse(sampler, spec.speed_range, spec.rate_hz)
        speed_range = [flat_speed.min_mps, flat_speed.max_mps, flat_speed.rate_hz]
    f = max(1, spec.synth_factor)
    seqs = [open_sequence(d) for d in spec.frames]
    missing_depth = spec.missing_depth or ("invalid" if any(sq.kind == "tum" for sq in seqs) else "infinity")
    n_hold = spec.holdout_samples or max(spec.batch_size, int(round(spec.holdout * spec.samples_per_epoch)))
    opts = dict(spec.flow_options)
    if spec.synthetic_flow == "exact":
        frames = load_frames(seqs, w * f, h * f, spec.frame_step, spec.depth, spec.max_frames, progress)
        train_frames, hold_frames = frames.split(spec.holdout, seed)

        def source(fr, n, s):
            return SyntheticSource(fr, sampler, n, s, f, missing_depth, tilt=tilt, inv_depth=net.depth_channel,
                                   scene_scale=scene_scale, unknown=net.unknown_flow, device=spec.device)
    else:
        frames = load_image_frames(seqs, spec.frame_step, spec.depth, spec.max_frames, progress,
                                   scales=spec.frame_scales)
        train_frames, hold_frames = frames.split(spec.holdout, seed)

        def source(fr, n, s):
            return EstimatedFlowSource(fr, sampler, spec.synthetic_flow, w, h, n, s, spec.data_threads, opts,
                                       spec.appearance_noise, tilt=tilt, inv_depth=net.depth_channel,
                                       scene_scale=scene_scale, unknown=net.unknown_flow, crop_window=spec.crop_window)
    if spec.mirror_frames:  # after the split: a frame and its mirror stay on the same side
        train_frames, hold_frames = with_mirrored(train_frames), with_mirrored(hold_frames)
    hold_src = source(hold_frames, n_hold, seed + 1).materialize(n_hold, seed + 1, progress)
    train_src = source(train_frames, spec.samples_per_epoch, seed)
    estimator_name = getattr(train_src, "estimator_name", None)  # None: exact synthetic flow
    if spec.sample_pool:
        train_src = train_src.materialize(spec.sample_pool, seed, progress)
    meta: dict = {}
    meta["data"] = {"frames": [str(s.root) for s in seqs], "depth": spec.depth, "frame_step": spec.frame_step,
                    "n_frames": len(frames), "n_train_frames": len(train_frames), "n_holdout_frames": len(hold_frames),
                    "motion": [m[2] for m in motions], "samples_per_epoch": spec.samples_per_epoch,
                    "holdout_samples": n_hold, "synth_factor": f, "missing_depth": missing_depth,
                    "sample_pool": spec.sample_pool, "speed_range_mps_at_hz": speed_range,
                    **({"speed_range_fraction": flat_speed.fraction}
                       if flat_speed is not None and flat_speed.fraction < 1 else {}),
                    "camera_tilt": tilt.to_dict() if tilt else None,
                    "scene_scale": scene_scale.to_dict() if scene_scale else None,
                    **({"mirror_frames": True} if spec.mirror_frames else {}),
                    **({"synth_device": spec.device} if spec.device != "cpu" else {})}
    if estimator_name is not None:
        meta["flow"] = {"estimator": spec.synthetic_flow, "options": opts}  # what vo/slam set up to match
        meta["data"].update(synth_factor=None, missing_depth=None, frame_scales=list(spec.frame_scales),
                            appearance_noise=spec.appearance_noise, synthetic_flow=estimator_name,
                            **({"crop_window": list(spec.crop_window)} if spec.crop_window is not None else {}))
    return train_src, hold_src, meta
