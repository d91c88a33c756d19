"""How a flow -> 6DoF model's translation read depends on the true speed (issue: scale from flow, not a prior).

For single frames with depth, the camera is moved straight forward by ``speed / rate`` metres (the
paper's vector ``(0, 0, 0, 0, 0, -d)`` of ``cam1_from_cam0``; forward motion is -z in that frame),
the flow that motion causes is made the way the model will meet it (exact synthesis, or an
estimator on a second view rendered from the frame), and the model's forward read is compared to the
truth. A model that reads metric motion from the flow gives read/true = 1 at every speed; one that
leans on its training motion prior pulls slow speeds up and fast ones down.

Nothing here uses poses of the frames: the same single-frame machinery as training
(:class:`deepslam.vo.data.SyntheticSource`, :class:`deepslam.vo.data.EstimatedFlowSource`).
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


def _forward(distance_m: float):
    vec = np.array([0.0, 0.0, 0.0, 0.0, 0.0, -float(distance_m)])

    def sample(n: int, rng: np.random.Generator) -> np.ndarray:
        return np.tile(vec, (n, 1))

    return sample


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
        batch = make_source(_forward(d)).make_batch(np.random.default_rng(seed), int(n_frames))
        extra = (batch["inv_depth"],) if "inv_depth" in batch else ()  # depth-channel models only
        mean, _ = predictor.predict(batch["flow"], batch["intrinsics"], *extra)
        read = -mean[:, 5]
        q25, q50, q75 = np.percentile(read, [25, 50, 75])
        ratio = float(np.median(read / d)) if d > 0 else None
        out.append(SpeedRead(float(v), d, float(q50), float(q25), float(q75), ratio))
    return out


def flatness(reads: list[SpeedRead], min_speed_mps: float = 2.0) -> dict:
    """Summary of a sweep: the range of read/true over speeds >= ``min_speed_mps`` and the read at rest."""
    ratios = [r.ratio_median for r in reads if r.ratio_median is not None and r.speed_mps >= min_speed_mps]
    still = [r.read_median_m for r in reads if r.speed_mps == 0]
    return {"ratio_min": float(min(ratios)) if ratios else None, "ratio_max": float(max(ratios)) if ratios else None,
            "read_at_rest_m": still[0] if still else None, "min_speed_mps": min_speed_mps}
