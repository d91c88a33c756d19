"""How a flow -> 6DoF model's translation read depends on the true speed (issue: scale from flow, not a prior).

For single frames with depth, the camera is moved straight forward by ``speed / rate`` metres (the
paper's vector ``(0, 0, 0, 0, 0, -d)`` of ``cam1_from_cam0``; forward motion is -z in that frame),
the flow that motion causes is made the way the model will meet it (exact synthesis, or an
estimator on a second view rendered from the frame), and the model's forward read is compared to the
truth. A model that reads metric motion from the flow gives read/true = 1 at every speed; one that
leans on its training motion prior pulls slow speeds up and fast ones down.

:func:`turn_reads` does the same for turns: yaw and forward motion, without and with the sideways slide a
car's camera makes in a turn, to see whether the model reads the slide or turns it into yaw.

Nothing here uses poses of the frames: the same single-frame machinery as training
(:class:`deepslam.vo.data.synthetic.SyntheticSource`, :class:`deepslam.vo.data.synthetic.EstimatedFlowSource`).
"""
from __future__ import annotations

import dataclasses

import numpy as np

DEFAULT_SPEEDS_MPS = (0.0, 1.0, 2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 20.0, 25.0, 30.0)
"""Speeds of the sweep, m/s: standing still through stop-and-go to highway."""


@dataclasses.dataclass(frozen=True)
class SpeedRead:
    """The model's forward read at one true speed, over the sweep's frames."""

    speed_mps: float
    """True speed, m/s."""
    true_m: float
    """True forward motion per frame, metres."""
    read_median_m: float
    """Median forward read, metres per frame."""
    read_q25_m: float
    """25th percentile of the forward read, metres."""
    read_q75_m: float
    """75th percentile of the forward read, metres."""
    ratio_median: float | None
    """Median of read/true over the frames (None at speed 0)."""
    ratio_spread: float | None = None
    """Standard deviation of read/true over the frames: how much the read varies from frame to frame (None at
    speed 0)."""
    std_ratio_median: float | None = None
    """Median over the frames of the model's own predicted std of the forward motion, over the true motion: the
    spread the model expects (None at speed 0)."""


def _read(predictor, make_source, vec6: np.ndarray, n_frames: int, seed: int, with_std: bool = False):
    """(n_frames, 6) the model's mean read of the one motion ``vec6`` (paper vector of cam1_from_cam0) on
    ``n_frames`` frames drawn by ``seed`` (the same frames for every motion); with ``with_std`` the pair
    (mean, predicted std), both (n_frames, 6)."""
    vec6 = np.asarray(vec6, dtype=np.float64)

    def sample(n: int, rng: np.random.Generator) -> np.ndarray:
        return np.tile(vec6, (n, 1))

    batch = make_source(sample).make_batch(np.random.default_rng(seed), int(n_frames))
    extra = (batch["inv_depth"],) if "inv_depth" in batch else ()  # depth-channel models only
    mean, std = predictor.predict(batch["flow"], batch["intrinsics"], *extra)
    return (mean, std) if with_std else mean


def speed_sweep(predictor, make_source, n_frames: int, rate_hz: float, speeds_mps=DEFAULT_SPEEDS_MPS,
                seed: int = 0) -> list[SpeedRead]:
    """The model's forward read at each speed on the same ``n_frames`` frames.

    Args:
        predictor: a :class:`deepslam.vo.infer.VOPredictor` (``predict(flow, intrinsics)``, and the
            inverse depth too where the source gives it).
        make_source: ``sample_motion -> source`` with ``make_batch(rng, n)`` (a SyntheticSource or an
            EstimatedFlowSource over the sweep's frames, at the predictor's input size).
        n_frames: samples per speed (the frames are drawn by the same seed at every speed).
        rate_hz: frame rate that turns speed into metres per frame.
        speeds_mps: the speeds, m/s.
        seed: which frames are drawn.
    """
    out = []
    for v in speeds_mps:
        d = float(v) / float(rate_hz)
        mean, std = _read(predictor, make_source, [0.0, 0.0, 0.0, 0.0, 0.0, -d], n_frames, seed, with_std=True)
        read = -np.asarray(mean, dtype=np.float64)[:, 5]
        q25, q50, q75 = np.percentile(read, [25, 50, 75])
        ratio = spread = std_ratio = None
        if d > 0:
            ratio, spread = float(np.median(read / d)), float(np.std(read / d))
            std_ratio = float(np.median(np.asarray(std, dtype=np.float64)[:, 5] / d))
        out.append(SpeedRead(float(v), d, float(q50), float(q25), float(q75), ratio, spread, std_ratio))
    return out


def flatness(reads: list[SpeedRead], min_speed_mps: float = 2.0) -> dict:
    """Summary of a sweep: the range of read/true over speeds >= ``min_speed_mps``, the largest |read/true - 1|
    there (``max_abs_dev``: 0 for a model that reads speed from the flow at every speed) and the read at rest."""
    ratios = [r.ratio_median for r in reads if r.ratio_median is not None and r.speed_mps >= min_speed_mps]
    still = [r.read_median_m for r in reads if r.speed_mps == 0]
    return {"ratio_min": float(min(ratios)) if ratios else None, "ratio_max": float(max(ratios)) if ratios else None,
            "max_abs_dev": float(max(abs(x - 1.0) for x in ratios)) if ratios else None,
            "read_at_rest_m": still[0] if still else None, "min_speed_mps": min_speed_mps}


# --------------------------------------------------------------------------------------- turns

SLIDE_PER_YAW_PER_M = 0.88
"""How far KITTI's camera slides sideways in a turn: metres of t_x (of cam1_from_cam0) per radian of yaw
per metre forward, the median over the frames of KITTI 00-05, 08-10 turning by more than 0.02 rad (the
arc's chord plus the camera ahead of the rear axle; t_x takes yaw's sign)."""


@dataclasses.dataclass(frozen=True)
class TurnRead:
    """The model's read of one turn (yaw + forward, with or without the sideways slide) over the frames."""

    yaw_rad: float
    """True yaw (euler_y of cam1_from_cam0), rad."""
    forward_m: float
    """True forward motion, metres (t_z = -forward_m)."""
    slide_m: float
    """True sideways slide t_x, metres (0, or :data:`SLIDE_PER_YAW_PER_M` x yaw x forward)."""
    yaw_ratio_median: float
    """Median of read yaw / true yaw."""
    slide_read_median_m: float
    """Median t_x read, metres."""
    forward_ratio_median: float
    """Median of read forward / true forward."""


def turn_reads(predictor, make_source, n_frames: int, yaws_rad=(-0.04, 0.04), forwards_m=(0.5, 1.0),
               slide_per_yaw_per_m: float = SLIDE_PER_YAW_PER_M, seed: int = 0) -> list[TurnRead]:
    """The model's read of turns without and with the sideways slide a car's camera makes, same frames.

    A model that reads the flow gives the same yaw either way and reads the slide in t_x; one trained on
    motions whose yaw and t_x are independent (the paper's per-DoF prior) may read the slide as more yaw.

    Args:
        predictor, make_source, n_frames, seed: as :func:`speed_sweep`.
        yaws_rad: yaws per frame, rad (both signs: left and right turns).
        forwards_m: forward motions per frame, metres.
        slide_per_yaw_per_m: t_x per rad of yaw per m forward of the "with slide" motions.

    Returns:
        For every yaw and forward motion, the read without the slide, then with it.
    """
    out = []
    for yaw in yaws_rad:
        for fwd in forwards_m:
            for slide in (0.0, slide_per_yaw_per_m * yaw * fwd):
                mean = _read(predictor, make_source, [0.0, yaw, 0.0, slide, 0.0, -fwd], n_frames, seed)
                out.append(TurnRead(float(yaw), float(fwd), float(slide), float(np.median(mean[:, 1] / yaw)),
                                    float(np.median(mean[:, 3])), float(np.median(-mean[:, 5] / fwd))))
    return out


def slide_effect(reads: list[TurnRead]) -> dict:
    """Summary of :func:`turn_reads`: ``yaw_gain`` (mean over the turns of the yaw ratio with the slide minus
    without: 0 for a model that reads the flow, > 0 where the slide is read as yaw) and
    ``slide_read_fraction`` (mean of (t_x read with - without) / true slide: 1 reads the slide, 0 ignores it)."""
    plain = {(r.yaw_rad, r.forward_m): r for r in reads if r.slide_m == 0}
    slid = [r for r in reads if r.slide_m != 0]
    gain = [r.yaw_ratio_median - plain[(r.yaw_rad, r.forward_m)].yaw_ratio_median for r in slid]
    frac = [(r.slide_read_median_m - plain[(r.yaw_rad, r.forward_m)].slide_read_median_m) / r.slide_m for r in slid]
    return {"yaw_gain": float(np.mean(gain)), "slide_read_fraction": float(np.mean(frac)),
            "yaw_ratio_range": [float(min(r.yaw_ratio_median for r in reads)),
                                float(max(r.yaw_ratio_median for r in reads))]}


def straight_yaw_read(predictor, make_source, n_frames: int, forward_m: float, seed: int = 0) -> dict:
    """The yaw a model reads on a straight drive of ``forward_m`` metres a frame (true yaw 0): a read that is
    not 0 is a turn the model sees in the scene's layout (a near kerb on one hand), a heading drift on every
    straight frame. Returns ``{"forward_m", "yaw_median_rad", "yaw_mean_rad"}`` over the frames."""
    mean = _read(predictor, make_source, [0.0, 0.0, 0.0, 0.0, 0.0, -float(forward_m)], n_frames, seed)
    return {"forward_m": float(forward_m), "yaw_median_rad": float(np.median(mean[:, 1])),
            "yaw_mean_rad": float(np.mean(mean[:, 1]))}
