"""deepslam's pytest plugin: simulated sequences with perfect ground truth, and trajectory assertions.

Load it from a ``conftest.py``::

    pytest_plugins = ["deepslam.testing"]

Fixtures:

- ``sim_sequence``: a factory. ``sim_sequence(scene="street", trajectory="auto", frames=10, width=None,
  height=None, moving_objects=0, deform=0.0, seed=0, backend="mujoco", stereo_baseline=None,
  rate=None)`` (the keywords of ``deepslam render``) renders once per test session per set of
  arguments and returns a :class:`deepslam.core.sequence.Sequence` with ground truth:
  ``len(seq)``, ``seq.camera`` (``fx, fy, cx, cy, width, height``), ``seq.image(i)`` (uint8 HxWx3),
  ``seq.depth(i)`` (float32 HxW depth_z, m, 0 = nothing), ``seq.flow(i)`` (float32 HxWx2, px, to
  frame i+1), ``seq.mask(i)`` (uint16 instance ids, 0 = static), ``seq.timestamps_s`` and
  ``seq.gt.world_from_cam`` ((N, 4, 4), OpenCV camera axes).

Assertions (plain functions, also importable outside pytest):

- :func:`assert_trajectory_close` (ATE within a tolerance after a named alignment),
- :func:`assert_relative_motion_close` (per-step relative pose errors within tolerances).

Both fail with a message that names the frame and the amount.
"""
from __future__ import annotations

import os

import numpy as np
import pytest

from deepslam.core import metrics, se3
from deepslam.core.readers import open_sequence
from deepslam.core.trajectory import Trajectory, associate

__all__ = ["sim_sequence", "assert_trajectory_close", "assert_relative_motion_close"]


def _render(out, scene: str, trajectory: str, frames: int, width, height, moving_objects: int, deform: float,
            seed: int, backend: str, stereo_baseline, rate):
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
    # deferred: the simulator (~0.3 s) loads only when a test renders; the plugin loads in every test session
    from deepslam.scenes import SceneConfig
    from deepslam.sim.config import RenderConfig, SimConfig, TrajectoryConfig
    from deepslam.sim.writers import render_sequence

    cfg = SimConfig(
        SceneConfig(name=scene, seed=seed, moving_objects=moving_objects, deform_amplitude_m=deform),
        TrajectoryConfig(kind=trajectory, frames=frames, rate_hz=rate),
        RenderConfig(backend=backend, width=width, height=height, stereo_baseline_m=stereo_baseline),
    ).validate()
    return render_sequence(cfg, out, progress=False)


@pytest.fixture(scope="session")
def sim_sequence(tmp_path_factory):
    """Factory of rendered sequences with ground truth, cached per pytest run per set of arguments."""
    cache: dict = {}

    def make(scene: str = "street", trajectory: str = "auto", frames: int = 10, width: int | None = None,
             height: int | None = None, moving_objects: int = 0, deform: float = 0.0, seed: int = 0,
             backend: str = "mujoco", stereo_baseline: float | None = None, rate: float | None = None):
        key = (scene, trajectory, int(frames), width, height, int(moving_objects), float(deform), int(seed), backend,
               stereo_baseline, rate)
        if key not in cache:
            out = tmp_path_factory.mktemp(f"deepslam-{scene}-{seed}") / "sequence"
            cache[key] = open_sequence(_render(out, *key))
        return cache[key]

    return make


def _as_poses(x, what: str) -> np.ndarray:
    poses = x.world_from_cam if isinstance(x, Trajectory) else np.asarray(x, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise AssertionError(f"expected (N, 4, 4) world_from_cam poses or a Trajectory, got shape {poses.shape}")
    _check_finite(poses, what)
    return poses


def _check_finite(poses: np.ndarray, what: str) -> None:
    bad = ~np.isfinite(poses.reshape(len(poses), -1)).all(axis=1)
    if bad.any():
        raise AssertionError(f"{what} pose of frame {int(np.flatnonzero(bad)[0])} is not finite "
                             f"({int(bad.sum())} such frames)")


def _check_tolerance(name: str, value, allow_none: bool = False) -> None:
    if value is None and allow_none:
        return
    try:
        ok = np.isfinite(float(value)) and float(value) >= 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")


def _matched(gt, est) -> tuple[np.ndarray, np.ndarray]:
    """Matched (N, 4, 4) arrays covering EVERY ground-truth frame; AssertionError naming the first frame
    the estimate lacks (by index, or by timestamp for two Trajectory objects with times)."""
    if isinstance(gt, Trajectory) and isinstance(est, Trajectory):
        _check_finite(gt.world_from_cam, "ground-truth")
        _check_finite(est.world_from_cam, "estimated")
        if gt.timestamps_s is not None and est.timestamps_s is not None:
            ig, ie = associate(gt, est)
            missing = np.setdiff1d(np.arange(len(gt)), ig)
            if len(missing):
                k = int(missing[0])
                raise AssertionError(f"no estimated pose for ground-truth frame {k} (t = {gt.timestamps_s[k]:.6f} s); "
                                     f"{len(missing)} of {len(gt)} frames have none")
            return gt.world_from_cam[ig], est.world_from_cam[ie]
        gt, est = gt.world_from_cam, est.world_from_cam
    g, e = _as_poses(gt, "ground-truth"), _as_poses(est, "estimated")
    if len(e) < len(g):
        raise AssertionError(f"no estimated pose for ground-truth frame {len(e)}: {len(e)} estimated poses for "
                             f"{len(g)} ground-truth poses")
    if len(e) != len(g):
        raise AssertionError(f"{len(e)} estimated poses for {len(g)} ground-truth poses")
    return g, e


STILL_RATIO = 1e-3
"""A sim3 alignment is refused when the ground truth's positions spread less than this share of the
estimate's: the fitted scale would shrink the estimate onto the ground truth's point."""


def _check_alignable(g: np.ndarray, e: np.ndarray, align: str) -> None:
    """AssertionError when ``align`` cannot be fitted meaningfully to the matched poses ``g``, ``e``
    (N, 4, 4): fewer than 3 poses for se3 / sim3, or (sim3) a ground truth that stands still against the
    estimate's motion, where the scale collapses towards 0 and any estimate would pass."""
    if align == "none":
        return
    if len(g) < 3:
        raise AssertionError(f"a {align} alignment needs at least 3 matched poses, got {len(g)}")
    if align == "sim3":
        def spread(p: np.ndarray) -> float:  # RMS distance of the positions (N, 3) m from their centroid
            return float(np.sqrt(((p - p.mean(axis=0)) ** 2).sum(axis=1).mean()))

        sg, se = spread(g[:, :3, 3]), spread(e[:, :3, 3])
        if sg <= STILL_RATIO * se or sg == 0.0:
            raise AssertionError(f"the ground truth stands still ({sg:.3g} m RMS spread) while the estimate spans "
                                 f"{se:.3g} m: a sim3 alignment would shrink the estimate onto it; use se3 or none")


def assert_trajectory_close(gt, est, ate_m: float, align: str = "se3", max_m: float | None = None) -> dict:
    """Assert the absolute trajectory error of ``est`` against ``gt`` after ``align``, over every frame of ``gt``.

    Args:
        gt, est: (N, 4, 4) world_from_cam arrays matched by index, or two Trajectory objects
            (matched by timestamp when both have times).
        ate_m: largest allowed ATE (RMSE over poses), metres; finite and >= 0 (ValueError otherwise).
        align: ``none``, ``se3`` or ``sim3`` (monocular scale), as in ``deepslam eval``.
        max_m: optionally, the largest allowed error of any single pose, metres.

    Returns:
        The ATE figures (``rmse_m``, ``max_m``, ``worst_frame``, ``align``) when the assertion holds.

    Raises:
        AssertionError: the ATE or a pose error is too large, a ground-truth frame has no estimate, or a
            pose is not finite (each message names the frame).
    """
    _check_tolerance("ate_m", ate_m)
    _check_tolerance("max_m", max_m, allow_none=True)
    g, e = _matched(gt, est)
    _check_alignable(g, e, align)
    res = metrics.ate(g, e, align)
    err = res["errors_m"]
    worst = int(np.argmax(err))
    out = {"rmse_m": res["rmse_m"], "max_m": res["max_m"], "worst_frame": worst, "align": align}
    if not np.isfinite(res["rmse_m"]) or res["rmse_m"] > ate_m:
        raise AssertionError(f"ATE ({align}-aligned) {res['rmse_m']:.4g} m > {ate_m:.4g} m; worst at frame {worst}: "
                             f"{err[worst]:.4g} m off")
    if max_m is not None and res["max_m"] > max_m:
        raise AssertionError(f"frame {worst} is {err[worst]:.4g} m off ({align}-aligned) > {max_m:.4g} m "
                             f"(ATE {res['rmse_m']:.4g} m)")
    return out


def assert_relative_motion_close(gt, est, trans_m: float, rot_deg: float, delta: int = 1) -> dict:
    """Assert every relative motion over ``delta`` frames: translation error <= ``trans_m`` and rotation
    error <= ``rot_deg`` (the RPE of each pair, no alignment needed).

    Args:
        gt, est: (N, 4, 4) world_from_cam arrays matched by index, or two Trajectory objects.
        trans_m: largest allowed translation error of a relative motion, metres.
        rot_deg: largest allowed rotation error of a relative motion, degrees.
        delta: frame gap of the pairs (i, i + delta).

    Returns:
        ``{"t_max_m", "r_max_deg", "worst_t_pair", "worst_r_pair"}`` when the assertion holds.
    """
    _check_tolerance("trans_m", trans_m)
    _check_tolerance("rot_deg", rot_deg)
    g, e = _matched(gt, est)
    if not 1 <= delta < len(g):
        raise AssertionError(f"delta {delta} needs more than {len(g)} poses")
    i = np.arange(len(g) - delta)
    rel_g = se3.inverse(g[i + delta]) @ g[i]
    rel_e = se3.inverse(e[i + delta]) @ e[i]
    d = se3.inverse(rel_g) @ rel_e
    t_err = np.linalg.norm(d[:, :3, 3], axis=1)
    cos = np.clip((np.trace(d[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)
    r_err = np.degrees(np.arccos(cos))
    kt, kr = int(np.nanargmax(t_err)), int(np.nanargmax(r_err))
    if not np.isfinite(t_err).all() or t_err[kt] > trans_m:
        raise AssertionError(f"relative motion {kt} -> {kt + delta}: translation off by {t_err[kt]:.4g} m > {trans_m:.4g} m")
    if not np.isfinite(r_err).all() or r_err[kr] > rot_deg:
        raise AssertionError(f"relative motion {kr} -> {kr + delta}: rotation off by {r_err[kr]:.4g} deg > {rot_deg:.4g} deg")
    return {"t_max_m": float(t_err[kt]), "r_max_deg": float(r_err[kr]), "worst_t_pair": (kt, kt + delta),
            "worst_r_pair": (kr, kr + delta)}
