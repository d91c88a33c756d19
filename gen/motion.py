"""The paper's motion model: an independent Student-t per degree of freedom of the relative camera motion.

Each DoF of the paper's vector ``(euler_x, euler_y, euler_z, t_x, t_y, t_z)`` (radians, metres; R = Rz Ry Rx)
of ``cam_{i+k}_from_cam_i`` (the motion that maps points of frame i into frame i+k, stride k) over
ground-truth trajectories gets a Student-t (``df``, ``loc``, ``scale``) fitted by maximum likelihood
(``scipy.stats.t.fit``, then refined for the truncation below: :func:`fit_student_t`). Sampling
draws the six independently with a ``numpy.random.Generator`` (the draws of
``scipy.stats.t.rvs(random_state=rng)``), truncated to the range the data covered (``lo``, ``hi``)
by redrawing: the fitted tails are heavy (KITTI's yaw gets df < 1) and would otherwise give absurd
rotations now and then.

The *loop* distribution models the motion between frames far apart in time that are close in space
(pairs (i, j) with |i - j| > ``min_gap_frames``, camera centres closer than ``max_distance_m`` and a
relative rotation below ``max_angle_deg`` so that the two views overlap), both orders (i->j and j->i):
what a flow network sees at a loop closure.

The paper's independent draws lose what the DoFs do together: a car's camera that turns also slides
sideways (the chord of the arc, and the camera ahead of the rear axle), and its speed is not one
Student-t around the median (KITTI drives 0-26 m/s). ``fit-motion --consecutive kde`` fits instead a
kernel density estimate (:class:`KdeSix`): the ground-truth motions themselves, each drawn with a small
Gaussian jitter. A network trained on the independent draws reads a turning camera's sideways slide as
more yaw (the shipped KITTI model: +2-5 % yaw on held-out renders and KITTI 06 when the slide of a real
turn is added).

JSON file (``deepslam fit-motion`` writes it, :meth:`MotionModel.load` validates it)::

    {"format": "deepslam-motion", "version": 1,
     "dof_names": ["euler_x", ..., "t_z"], "units": ["rad", "rad", "rad", "m", "m", "m"],
     "stride": 1, "sources": ["00.txt", ...],
     "consecutive": {"num_motions": N, "dofs": {"euler_x": {"df": .., "loc": .., "scale": .., "lo": .., "hi": ..}, ...}},
     "loop": null or {"num_motions": M, "min_gap_frames": .., "max_distance_m": .., "max_angle_deg": .., "dofs": {...},
              "fit": "truncated" or "plain" (optional: how the loop t were fitted, see fit_student_t)}}

with, for a KDE, ``"consecutive": {"kind": "kde", "num_motions": N, "bandwidth": {"euler_x": .., ...},
"lo": {..}, "hi": {..}, "motions": [[euler_x, .., t_z], ...]}`` and optionally ``"speed_scale": [lo, hi]``
(:attr:`KdeSix.speed_scale`) and ``"body": {"sources": [..], "bandwidth": {"euler_x": .., "euler_z": ..}, "motions":
[[euler_x, euler_z], ...]}`` (:attr:`KdeSix.body`); a file without ``kind`` is Student-t.
"""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree

from deepslam.core import atomic, plots, se3
from deepslam.core.errors import InputError
from deepslam.core.textio import JSON_MAX_DEPTH, json_depth
from deepslam.core.trajectory import Trajectory

FORMAT = "deepslam-motion"
VERSION = 1
DOF_NAMES = ("euler_x", "euler_y", "euler_z", "t_x", "t_y", "t_z")
DOF_UNITS = ("rad", "rad", "rad", "m", "m", "m")
MAX_ABS_ROTATION_RAD = math.pi
"""Largest |value| a rotation DoF's parameters may have (a motion between two frames)."""
MAX_ABS_TRANSLATION_M = 1000.0
"""Largest |value| a translation DoF's parameters may have, metres."""
MIN_MOTIONS = 20
"""Fewest motions a Student-t is fitted to."""


@dataclasses.dataclass(frozen=True)
class StudentT:
    """One fitted Student-t and the range samples are truncated to."""

    df: float
    """Degrees of freedom (> 0)."""
    loc: float
    """Location (rad or m)."""
    scale: float
    """Scale (> 0, rad or m)."""
    lo: float
    """Smallest value sampled (the data's minimum)."""
    hi: float
    """Largest value sampled (the data's maximum)."""

    def _mass(self) -> float:
        from scipy import stats  # deferred: scipy.stats (~0.7 s) only where a t distribution is evaluated

        return float(stats.t.cdf(self.hi, self.df, self.loc, self.scale) - stats.t.cdf(self.lo, self.df, self.loc, self.scale))

    def pdf(self, x: np.ndarray) -> np.ndarray:
        """Density of the t truncated to [lo, hi] (what :meth:`sample` draws from)."""
        from scipy import stats  # deferred: scipy.stats (~0.7 s) only where a t distribution is evaluated

        x = np.asarray(x, dtype=np.float64)
        inside = (x >= self.lo) & (x <= self.hi)
        return np.where(inside, stats.t.pdf(x, self.df, self.loc, self.scale) / self._mass(), 0.0)

    def cdf(self, x: np.ndarray) -> np.ndarray:
        """Distribution function of the t truncated to [lo, hi]."""
        from scipy import stats  # deferred: scipy.stats (~0.7 s) only where a t distribution is evaluated

        x = np.clip(np.asarray(x, dtype=np.float64), self.lo, self.hi)
        c0 = stats.t.cdf(self.lo, self.df, self.loc, self.scale)
        return (stats.t.cdf(x, self.df, self.loc, self.scale) - c0) / self._mass()

    def sample(self, n: int, rng: np.random.Generator, max_rounds: int = 64) -> np.ndarray:
        """(n,) float64 draws in [lo, hi] (out-of-range draws are redrawn; clipped after ``max_rounds``).

        Each draw is ``loc + scale * rng.standard_t(df)``: exactly what ``scipy.stats.t.rvs(df, loc, scale,
        random_state=rng)`` returns, without its per-call overhead (this runs once per training sample).
        """
        out = self.loc + self.scale * rng.standard_t(self.df, size=n)
        for _ in range(max_rounds):
            bad = np.flatnonzero((out < self.lo) | (out > self.hi))
            if bad.size == 0:
                break
            out[bad] = self.loc + self.scale * rng.standard_t(self.df, size=bad.size)
        return np.clip(out, self.lo, self.hi)


@dataclasses.dataclass(frozen=True)
class SixDof:
    """Independent Student-t distributions of the six DoF (paper order) and the data they came from."""

    dofs: tuple[StudentT, ...]
    """Six distributions in :data:`DOF_NAMES` order."""
    num_motions: int
    """Number of relative motions fitted."""

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, 6) float64 paper vectors (rad, m); DoFs drawn in order, each with ``rng``."""
        return np.stack([d.sample(n, rng) for d in self.dofs], axis=-1)

    def to_dict(self) -> dict:
        return {"num_motions": self.num_motions,
                "dofs": {name: dataclasses.asdict(d) for name, d in zip(DOF_NAMES, self.dofs)}}


KDE_MAX_MOTIONS = 25_000
"""At most this many motions are kept in a KDE model (a seeded subsample beyond; KITTI 00-05, 08-10 has 20,990)."""
BODY_MAX_MOTIONS = 5_000
"""At most this many pitch-and-roll pairs are kept in a KDE model's :attr:`KdeSix.body` (a seeded subsample beyond)."""
BODY_DOFS = (0, 2)
"""Columns of a paper vector the body's motion adds to: euler_x (pitch, about the camera's x axis) and euler_z (roll,
about its optical axis)."""
KDE_DIGITS = 6
"""Decimal places the KDE model's motions are stored with (1e-6 rad / 1e-6 m: far below any flow's resolution)."""


@dataclasses.dataclass(frozen=True, eq=False)
class KdeSix:
    """The joint distribution of the six DoF as a kernel density estimate: the fitted motions themselves.

    A draw picks one of the ground-truth motions at random and adds independent Gaussian jitter of
    ``bandwidth`` to each DoF, kept inside the data's range. Unlike :class:`SixDof` it keeps what the
    DoFs do together: a car's camera that turns also slides sideways (KITTI 00-05, 08-10: t_x ~ 0.88 x
    yaw x forward metres in turns, correlation 0.51), and the forward speed keeps the data's own
    distribution (standing still, town, highway) instead of one Student-t around the median.
    """

    motions: np.ndarray
    """(N, 6) float64 paper vectors (rad, m) of the fitted motions, :data:`DOF_NAMES` order."""
    bandwidth: np.ndarray
    """(6,) float64 Gaussian jitter per DoF (rad, m): Silverman's rule on the DoF's robust spread (:func:`fit_kde`)."""
    lo: np.ndarray
    """(6,) float64 smallest value sampled per DoF (the data's minimum)."""
    hi: np.ndarray
    """(6,) float64 largest value sampled per DoF (the data's maximum)."""
    speed_scale: tuple[float, float] | None = None
    """(lo, hi) of a factor drawn log-uniform per motion that multiplies its translation, its rotation kept
    (``fit-motion --speed-scale``); None: none. On a circular arc the chord's direction depends on the heading
    change alone, so a scaled motion is the same turn at a radius and speed scaled by the factor: it frees
    the turn radius from the one the fitted routes were driven at (a town's car takes every corner on one arc)."""
    body: np.ndarray | None = None
    """(M, 2) float64 frame-to-frame pitch and roll (euler_x, euler_z; rad) of other trajectories, one pair drawn
    per motion (with Gaussian jitter of :attr:`body_bandwidth`) and added to the drawn motion's pitch and roll
    (``fit-motion --body-from``); None: none. The car body's pitch and roll on its suspension, which the
    simulator's car does not have: KITTI 00-05, 08-10 pitch 0.18 and roll 0.15 degrees RMS a frame, the towns'
    0.001 and 0.03 (docs/experiments/2026-12-06_turn_radius_prior.md, section 8)."""
    body_bandwidth: np.ndarray | None = None
    """(2,) float64 Gaussian jitter of the :attr:`body` draws (rad), Silverman's rule as :func:`fit_kde`."""
    body_sources: tuple[str, ...] = ()
    """Names of the trajectories :attr:`body` was taken from."""
    lever_m: float = 0.0
    """Metres the fitted routes' camera sits ahead of the rear axle (``render --camera-ahead``; KITTI's 0.84): the
    :attr:`speed_scale` factor then multiplies the axle's translation and keeps the camera's sideways slide into a
    turn, which is the lever times the turn and does not grow with the distance travelled. With ``S`` the shift
    (0, 0, L) from the axle to the camera, ``cam_j_from_cam_i = S^-1 axle_j_from_axle_i S``, so t_cam = t_axle +
    (R - I) s: the scaled motion is k (t_cam - (R - I) s) + (R - I) s. 0: the whole translation is scaled."""

    @property
    def num_motions(self) -> int:
        """Number of motions kept."""
        return int(len(self.motions))

    def sample(self, n: int, rng: np.random.Generator, max_rounds: int = 64) -> np.ndarray:
        """(n, 6) float64 paper vectors (rad, m): ``rng.integers`` picks the motions, then ``rng.standard_normal``
        the jitter; a value the jitter took out of [lo, hi] gets its jitter redrawn (clipped after
        ``max_rounds``), so the range's ends get no pile of clipped draws (standing still stays still, not
        0.016 m backwards). With :attr:`speed_scale`, ``rng.uniform`` then draws each motion's factor (the
        translation may then leave [lo, hi]: that is the point). With :attr:`body`, ``rng.integers`` and
        ``rng.standard_normal`` then draw each motion's added pitch and roll."""
        pick = rng.integers(0, len(self.motions), size=n)
        base = self.motions[pick]
        out = base + rng.standard_normal((n, 6)) * self.bandwidth
        for _ in range(max_rounds):
            bad = np.nonzero((out < self.lo) | (out > self.hi))
            if bad[0].size == 0:
                break
            out[bad] = base[bad] + rng.standard_normal(bad[0].size) * self.bandwidth[bad[1]]
        out = np.clip(out, self.lo, self.hi)
        if self.speed_scale is not None:
            lo, hi = self.speed_scale
            factor = np.exp(rng.uniform(math.log(lo), math.log(hi), size=n))[:, None]
            slide = lever_slide(out, self.lever_m)
            out[:, 3:] = (out[:, 3:] - slide) * factor + slide
        if self.body is not None:
            pick = rng.integers(0, len(self.body), size=n)
            out[:, BODY_DOFS] += self.body[pick] + rng.standard_normal((n, 2)) * self.body_bandwidth
        return out

    def marginal_pdf(self, k: int, x: np.ndarray) -> np.ndarray:
        """Density of DoF ``k`` at ``x`` (before clipping): the mean of the motions' Gaussian kernels."""
        x = np.asarray(x, dtype=np.float64)
        h = float(self.bandwidth[k])
        z = (x[:, None] - self.motions[None, :, k]) / h
        return np.exp(-0.5 * z * z).mean(axis=1) / (h * math.sqrt(2 * math.pi))

    def to_dict(self) -> dict:
        d = {"kind": "kde", "num_motions": self.num_motions,
             "bandwidth": {n: float(b) for n, b in zip(DOF_NAMES, self.bandwidth)},
             "lo": {n: float(v) for n, v in zip(DOF_NAMES, self.lo)},
             "hi": {n: float(v) for n, v in zip(DOF_NAMES, self.hi)},
             "motions": np.round(self.motions, KDE_DIGITS).tolist()}
        if self.speed_scale is not None:
            d["speed_scale"] = [float(x) for x in self.speed_scale]
            if self.lever_m:
                d["lever_m"] = float(self.lever_m)
        if self.body is not None:
            d["body"] = {"sources": list(self.body_sources),
                         "bandwidth": {DOF_NAMES[k]: float(b) for k, b in zip(BODY_DOFS, self.body_bandwidth)},
                         "motions": np.round(self.body, KDE_DIGITS).tolist()}
        return d


def lever_slide(vectors: np.ndarray, lever_m: float) -> np.ndarray:
    """(N, 3) float64 part of each motion's translation (m, frame j) that a camera ``lever_m`` metres ahead of the
    rear axle adds to the axle's: (R - I) (0, 0, L), R the rotation of (N, 6) paper vectors of ``cam_j_from_cam_i``
    (:attr:`KdeSix.lever_m`); zeros for ``lever_m`` 0."""
    v = np.asarray(vectors, dtype=np.float64).reshape(-1, 6)
    if not lever_m:
        return np.zeros((len(v), 3))
    rotation = se3.from_euler6(v)[:, :3, :3]
    return (rotation[:, :, 2] - np.array([0.0, 0.0, 1.0])) * lever_m


LEVER_LIMITS_M = (0.0, 5.0)
"""Range of :attr:`KdeSix.lever_m` (the simulator's ``--camera-ahead`` range)."""

SPEED_SCALE_LIMITS = (0.05, 20.0)
"""Smallest and largest factor ``speed_scale`` may give (a motion model, not a teleport)."""


def fit_kde(vectors: np.ndarray, seed: int = 0, speed_scale: tuple[float, float] | None = None,
            lever_m: float = 0.0) -> KdeSix:
    """A :class:`KdeSix` of (N, 6) paper vectors: bandwidth per DoF by Silverman's rule, 0.9 x min(std,
    IQR / 1.349) x N^(-1/5) (each marginal's own; the jitter only has to keep draws from repeating the data,
    and a wider one would blur the straight-driving peak of yaw); motions rounded to :data:`KDE_DIGITS`
    places as stored; more than :data:`KDE_MAX_MOTIONS` are subsampled with ``seed``; ``speed_scale`` as
    :attr:`KdeSix.speed_scale` (ValueError outside :data:`SPEED_SCALE_LIMITS` or with lo > hi); ``lever_m`` as
    :attr:`KdeSix.lever_m` (with a ``speed_scale`` only; ValueError outside :data:`LEVER_LIMITS_M`)."""
    if speed_scale is not None:
        speed_scale = check_speed_scale(speed_scale, ValueError)
    lever_m = check_lever(lever_m, speed_scale, ValueError)
    v = _kept_motions(vectors, KDE_MAX_MOTIONS, seed, "motions to fit")
    return KdeSix(v, silverman_bandwidth(v), v.min(axis=0), v.max(axis=0), speed_scale, lever_m=lever_m)


def check_lever(value, speed_scale, error, names: tuple[str, str] = ("lever_m", "a speed_scale")) -> float:
    """``value`` as a float lever (m), or ``error(message)`` raised when it is not a finite number within
    :data:`LEVER_LIMITS_M`, or is not 0 without a ``speed_scale`` (the lever only changes how that scales);
    ``names``: what the message calls the lever and the speed scale."""
    lo, hi = LEVER_LIMITS_M
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not lo <= value <= hi:
        raise error(f"{names[0]} must be a number of metres within [{lo:g}, {hi:g}], got {value!r}")
    if value and speed_scale is None:
        raise error(f"{names[0]} needs {names[1]} (it says which part of the translation the factor scales)")
    return float(value)


def _kept_motions(vectors: np.ndarray, most: int, seed: int, what: str) -> np.ndarray:
    """The rows of (N, D) ``vectors`` a KDE keeps: the finite ones, a sorted subsample of ``most`` drawn with
    ``seed`` beyond that, rounded to :data:`KDE_DIGITS` places; ValueError ("need at least ... {what}") with
    fewer than :data:`MIN_MOTIONS`."""
    v = np.asarray(vectors, dtype=np.float64)
    v = v[np.all(np.isfinite(v), axis=1)]
    if len(v) < MIN_MOTIONS:
        raise ValueError(f"need at least {MIN_MOTIONS} {what}, got {len(v)}")
    if len(v) > most:
        v = v[np.sort(np.random.default_rng(seed).choice(len(v), most, replace=False))]
    return np.round(v, KDE_DIGITS)


def silverman_bandwidth(v: np.ndarray) -> np.ndarray:
    """(D,) Gaussian kernel width per column of (N, D) samples: 0.9 x min(std, IQR / 1.349) x N^(-1/5) (the
    std where the IQR is 0); ValueError when a column has one value throughout."""
    q25, q75 = np.percentile(v, [25, 75], axis=0)
    spread = np.minimum(v.std(axis=0), (q75 - q25) / 1.349)
    spread = np.where(spread > 0, spread, v.std(axis=0))
    if np.any(spread <= 0):
        raise ValueError("a DoF has the same value in every motion: nothing to fit")
    return 0.9 * spread * len(v) ** (-1.0 / 5.0)


def with_body(kde: KdeSix, vectors: np.ndarray, sources: Sequence[str] = (), seed: int = 0) -> KdeSix:
    """``kde`` with :attr:`KdeSix.body` taken from the pitch and roll (:data:`BODY_DOFS`) of (N, 6) paper vectors
    (rad, m) of other trajectories: the non-finite dropped, more than :data:`BODY_MAX_MOTIONS` subsampled with
    ``seed``, rounded to :data:`KDE_DIGITS` places, the jitter by :func:`silverman_bandwidth`. ValueError with
    fewer than :data:`MIN_MOTIONS`."""
    v = _kept_motions(np.asarray(vectors, dtype=np.float64)[:, BODY_DOFS], BODY_MAX_MOTIONS, seed,
                      "motions for the body's pitch and roll")
    return dataclasses.replace(kde, body=v, body_bandwidth=silverman_bandwidth(v), body_sources=tuple(sources))


def check_speed_scale(value, error) -> tuple[float, float]:
    """``value`` as (lo, hi) floats, or ``error(message)`` raised when it is not two finite numbers with
    lo <= hi inside :data:`SPEED_SCALE_LIMITS`."""
    lo_lim, hi_lim = SPEED_SCALE_LIMITS
    ok = (isinstance(value, (list, tuple)) and len(value) == 2
          and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value))
    if not ok or not lo_lim <= value[0] <= value[1] <= hi_lim:
        raise error(f"speed_scale must be two numbers lo <= hi within [{lo_lim:g}, {hi_lim:g}], got {value!r}")
    return float(value[0]), float(value[1])


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """Which frame pairs count as loops."""

    min_gap_frames: int = 100
    """Pairs must be more than this many frames apart."""
    max_distance_m: float = 5.0
    """... with camera centres closer than this (metres)."""
    max_angle_deg: float = 30.0
    """... and a relative rotation below this (degrees), so that the views overlap."""
    max_pairs: int = 50_000
    """At most this many motions are fitted (a seeded subsample beyond)."""


@dataclasses.dataclass(frozen=True)
class MotionModel:
    """Student-t motion model for consecutive motions at one stride, plus an optional loop model."""

    stride: int
    """Frame stride k of the fitted consecutive motions cam_{i+k}_from_cam_i."""
    consecutive: "SixDof | KdeSix"
    """The consecutive-motion distribution: independent Student-t per DoF (the paper's), or a joint KDE."""
    loop: SixDof | None = None
    """The loop-motion distributions, or None."""
    loop_config: LoopConfig | None = None
    """How loop pairs were chosen (None without a loop model)."""
    sources: tuple[str, ...] = ()
    """File names of the trajectories fitted (for the record)."""
    loop_fit: str | None = None
    """How the loop distribution's Student-t were fitted (:data:`FITS`); None where the file does not
    say (files written before it was recorded)."""

    # -------------------------------------------------------------------------------- sampling
    def sample(self, n: int, rng: np.random.Generator, loop_fraction: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Draw n motions.

        Args:
            n: number of motions.
            rng: the generator (consumed in a fixed order: loop choice, then consecutive, then loop draws).
            loop_fraction: probability that a motion comes from the loop model (needs one).

        Returns:
            (vec6 (n, 6) float64 paper vectors of cam1_from_cam0, is_loop (n,) bool).
        """
        if loop_fraction > 0 and self.loop is None:
            raise ValueError("loop_fraction > 0 but the motion model has no loop distribution (fit with --loops)")
        is_loop = rng.random(n) < loop_fraction if loop_fraction > 0 else np.zeros(n, dtype=bool)
        vec = self.consecutive.sample(n, rng)
        if is_loop.any():
            vec[is_loop] = self.loop.sample(int(is_loop.sum()), rng)
        return vec, is_loop

    def sample_transforms(self, n: int, rng: np.random.Generator, loop_fraction: float = 0.0):
        """(cam1_from_cam0 (n, 4, 4) float64, vec6 (n, 6), is_loop (n,)) from :meth:`sample`."""
        vec, is_loop = self.sample(n, rng, loop_fraction)
        return se3.from_euler6(vec), vec, is_loop

    # ------------------------------------------------------------------------------------- I/O
    def to_dict(self) -> dict:
        loop = None
        if self.loop is not None:
            loop = {**self.loop.to_dict(), **{k: v for k, v in dataclasses.asdict(self.loop_config).items()}}
            if self.loop_fit is not None:
                loop["fit"] = self.loop_fit
        return {"format": FORMAT, "version": VERSION, "dof_names": list(DOF_NAMES), "units": list(DOF_UNITS),
                "stride": self.stride, "sources": list(self.sources),
                "consecutive": self.consecutive.to_dict(), "loop": loop}

    def save(self, path: str | Path) -> Path:
        """Write the JSON atomically (indented; a KDE's motions one per line, which keeps the file small)."""
        d = self.to_dict()
        motions = d["consecutive"].pop("motions", None)
        text = json.dumps(d, indent=2, sort_keys=True)
        if motions is not None:
            rows = ",\n".join("      " + json.dumps(m) for m in motions)
            anchor = '  "consecutive": {\n'
            text = text.replace(anchor, anchor + '    "motions": [\n' + rows + "\n    ],\n", 1)
        atomic.write_text(path, text + "\n")
        return Path(path)

    @classmethod
    def from_dict(cls, d: dict, path: str | Path | None = None) -> "MotionModel":
        """Validate and build; any fault raises InputError naming ``path`` and the field."""
        def bad(what: str):
            return InputError(path, f"malformed motion model: {what}")

        if not isinstance(d, dict):
            raise bad("top level is not a JSON object")
        if d.get("format") != FORMAT:
            raise bad(f"format is {d.get('format')!r}, expected {FORMAT!r}")
        if d.get("version") != VERSION:
            raise bad(f"version is {d.get('version')!r}, expected {VERSION}")
        stride = d.get("stride")
        if not isinstance(stride, int) or isinstance(stride, bool) or stride < 1:
            raise bad(f"stride must be an integer >= 1, got {stride!r}")
        if "consecutive" not in d:
            raise bad("missing key 'consecutive'")
        c = d["consecutive"]
        if isinstance(c, dict) and c.get("kind", "student-t") not in CONSECUTIVE_KINDS:
            raise bad(f"consecutive.kind must be 'student-t' or 'kde', got {c.get('kind')!r}")
        consecutive = (_kde_from_dict(c, "consecutive", bad) if isinstance(c, dict) and c.get("kind") == "kde"
                       else _six_from_dict(c, "consecutive", bad))
        loop, loop_cfg, loop_fit = None, None, None
        if d.get("loop") is not None:
            loop = _six_from_dict(d["loop"], "loop", bad)
            loop_fit = d["loop"].get("fit")
            if loop_fit is not None and loop_fit not in FITS:
                raise bad(f"loop.fit must be one of {', '.join(FITS)}, got {loop_fit!r}")
            try:
                loop_cfg = LoopConfig(**{f.name: d["loop"][f.name] for f in dataclasses.fields(LoopConfig)})
            except KeyError as e:
                raise bad(f"loop: missing key {e.args[0]!r}") from None
        sources = d.get("sources", [])
        if not isinstance(sources, list) or not all(isinstance(s, str) for s in sources):
            raise bad("sources must be a list of strings")
        return cls(stride, consecutive, loop, loop_cfg, tuple(sources), loop_fit)

    @classmethod
    def load(cls, path: str | Path) -> "MotionModel":
        path = Path(path)
        if not path.is_file():
            raise InputError(path, "motion model file is missing")
        try:
            text = path.read_text()
        except (OSError, UnicodeDecodeError) as e:
            raise InputError(path, f"cannot read motion model ({e})") from None
        if json_depth(text) > JSON_MAX_DEPTH:  # bounded (core.textio): json.loads recurses once per level
            raise InputError(path, f"malformed motion model: nested more than {JSON_MAX_DEPTH} levels deep")
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise InputError(path, f"malformed motion model: not JSON ({e.msg})", line=e.lineno) from None
        return cls.from_dict(d, path)


def _dof_limit(name: str) -> tuple[float, str]:
    """(largest |value| a parameter of DoF ``name`` may have, its unit): a motion between two frames."""
    return (MAX_ABS_ROTATION_RAD, "rad") if name.startswith("euler") else (MAX_ABS_TRANSLATION_M, "m")


def _six_from_dict(d, where: str, bad) -> SixDof:
    if not isinstance(d, dict):
        raise bad(f"{where} is not an object")
    if "dofs" not in d or not isinstance(d["dofs"], dict):
        raise bad(f"{where}: missing key 'dofs'")
    n = d.get("num_motions")
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        raise bad(f"{where}.num_motions must be a positive integer, got {n!r}")
    dofs = []
    for name in DOF_NAMES:
        if name not in d["dofs"]:
            raise bad(f"{where}.dofs: missing key {name!r}")
        entry = d["dofs"][name]
        if not isinstance(entry, dict):
            raise bad(f"{where}.dofs.{name} is not an object")
        vals = {}
        for key in ("df", "loc", "scale", "lo", "hi"):
            if key not in entry:
                raise bad(f"{where}.dofs.{name}: missing key {key!r}")
            v = entry[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise bad(f"{where}.dofs.{name}.{key} must be a finite number, got {v!r}")
            vals[key] = float(v)
        if vals["df"] <= 0:
            raise bad(f"{where}.dofs.{name}.df must be > 0, got {vals['df']}")
        if vals["scale"] <= 0:
            raise bad(f"{where}.dofs.{name}.scale must be > 0, got {vals['scale']}")
        if not vals["lo"] < vals["hi"]:
            raise bad(f"{where}.dofs.{name}: lo must be below hi, got {vals['lo']} >= {vals['hi']}")
        limit, unit = _dof_limit(name)
        for key in ("loc", "scale", "lo", "hi"):
            if abs(vals[key]) > limit:
                raise bad(f"{where}.dofs.{name}.{key} = {vals[key]:g} is beyond {limit:g} "
                          f"{unit}: not a camera motion between two frames")
        dofs.append(StudentT(**vals))
    return SixDof(tuple(dofs), n)


def _kde_from_dict(d: dict, where: str, bad) -> KdeSix:
    motions = d.get("motions")
    if not isinstance(motions, list) or not motions:
        raise bad(f"{where}.motions must be a non-empty list of [6 numbers]")
    try:
        arr = np.array(motions, dtype=np.float64)
    except (TypeError, ValueError):
        raise bad(f"{where}.motions must be a list of [6 numbers]") from None
    if arr.ndim != 2 or arr.shape[1] != 6:
        raise bad(f"{where}.motions must be a list of [6 numbers], got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        row = int(np.flatnonzero(~np.all(np.isfinite(arr), axis=1))[0])
        raise bad(f"{where}.motions[{row}] holds a non-finite value")
    n = d.get("num_motions")
    if n != len(arr) or isinstance(n, bool):
        raise bad(f"{where}.num_motions is {n!r} but {len(arr)} motions are stored")
    vals = {}
    for key in ("bandwidth", "lo", "hi"):
        entry = d.get(key)
        if not isinstance(entry, dict):
            raise bad(f"{where}: missing key {key!r}")
        row = []
        for name in DOF_NAMES:
            v = entry.get(name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise bad(f"{where}.{key}.{name} must be a finite number, got {v!r}")
            row.append(float(v))
        vals[key] = np.array(row)
    for k, name in enumerate(DOF_NAMES):
        limit, unit = _dof_limit(name)
        if not vals["bandwidth"][k] > 0:
            raise bad(f"{where}.bandwidth.{name} must be > 0, got {vals['bandwidth'][k]}")
        if not vals["lo"][k] < vals["hi"][k]:
            raise bad(f"{where}: {name}: lo must be below hi, got {vals['lo'][k]} >= {vals['hi'][k]}")
        worst = float(np.abs(arr[:, k]).max())
        if max(worst, abs(vals["lo"][k]), abs(vals["hi"][k]), vals["bandwidth"][k]) > limit:
            raise bad(f"{where}: {name} has a value beyond {limit:g} {unit}: not a camera motion between two frames")
    speed_scale = d.get("speed_scale")
    if speed_scale is not None:
        speed_scale = check_speed_scale(speed_scale, lambda m: bad(f"{where}.{m}"))
    lever_m = check_lever(d.get("lever_m", 0.0), speed_scale, lambda m: bad(f"{where}.{m}"))
    kde = KdeSix(arr, vals["bandwidth"], vals["lo"], vals["hi"], speed_scale, lever_m=lever_m)
    return kde if d.get("body") is None else _body_from_dict(kde, d["body"], f"{where}.body", bad)


def _body_from_dict(kde: KdeSix, d, where: str, bad) -> KdeSix:
    """``kde`` with the :attr:`KdeSix.body` of a motion file's ``body`` entry, validated (``bad(message)`` raised)."""
    if not isinstance(d, dict):
        raise bad(f"{where} must be an object with sources, bandwidth and motions")
    sources = d.get("sources", [])
    if not isinstance(sources, list) or not all(isinstance(x, str) for x in sources):
        raise bad(f"{where}.sources must be a list of names")
    try:
        arr = np.array(d.get("motions"), dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.zeros((0, 0))
    if arr.ndim != 2 or arr.shape[1] != 2 or not len(arr):
        raise bad(f"{where}.motions must be a non-empty list of [euler_x, euler_z] pairs")
    if not np.all(np.isfinite(arr)) or np.abs(arr).max() > MAX_ABS_ROTATION_RAD:
        raise bad(f"{where}.motions must be finite rotations within {MAX_ABS_ROTATION_RAD:g} rad")
    bw = d.get("bandwidth")
    names = [DOF_NAMES[k] for k in BODY_DOFS]
    values = [bw.get(n) if isinstance(bw, dict) else None for n in names]
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
               and 0 < v <= MAX_ABS_ROTATION_RAD for v in values):
        raise bad(f"{where}.bandwidth must give {' and '.join(names)} as numbers in (0, {MAX_ABS_ROTATION_RAD:g}] rad")
    return dataclasses.replace(kde, body=arr, body_bandwidth=np.array(values, dtype=np.float64),
                               body_sources=tuple(sources))


# ------------------------------------------------------------------------------------------- fitting

def relative_vectors(trajectories: Sequence[Trajectory], stride: int = 1) -> np.ndarray:
    """(N, 6) float64 paper vectors of cam_{i+stride}_from_cam_i over all trajectories."""
    out = [se3.to_euler6(t.relative_motions(stride)) for t in trajectories if len(t) > stride]
    return np.concatenate(out, axis=0) if out else np.zeros((0, 6))


MIRROR_SIGNS = np.array([1.0, -1.0, -1.0, -1.0, 1.0, 1.0])
"""Per DoF of a paper vector, its sign in the motion seen in a left-right mirror: with S = diag(-1, 1, 1) the
mirrored motion is (S R S, S t), and S Rz(c) Ry(b) Rx(a) S = Rz(-c) Ry(-b) Rx(a)."""


def mirrored_vectors(vectors: np.ndarray) -> np.ndarray:
    """(N, 6) paper vectors (rad, m) of the same motions seen in a left-right mirror (:data:`MIRROR_SIGNS`): a
    turn to the left becomes the same turn to the right, its sideways slide with it."""
    return np.asarray(vectors, dtype=np.float64) * MIRROR_SIGNS


def loop_motions(trajectory: Trajectory, config: LoopConfig = LoopConfig()) -> np.ndarray:
    """(M, 4, 4) ``cam_j_from_cam_i`` for loop pairs of one trajectory (both orders), see module doc."""
    pos = trajectory.positions
    pairs = cKDTree(pos).query_pairs(config.max_distance_m, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 4, 4))
    pairs = pairs[np.abs(pairs[:, 0] - pairs[:, 1]) > config.min_gap_frames]
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    if len(pairs) == 0:
        return np.zeros((0, 4, 4))
    both = np.concatenate([pairs, pairs[:, ::-1]], axis=0)
    i, j = both[:, 0], both[:, 1]
    # cam_j_from_cam_i = inverse(world_from_cam_j) @ world_from_cam_i
    rel = se3.relative(trajectory.world_from_cam[j], trajectory.world_from_cam[i])
    keep = np.degrees(se3.rotation_angle(rel)) < config.max_angle_deg
    return rel[keep]


CONSECUTIVE_KINDS = ("student-t", "kde")
"""How the consecutive distribution is modelled: :class:`SixDof` or :class:`KdeSix`."""

FITS = ("truncated", "plain")
"""How a Student-t is fitted (:func:`fit_student_t`): refined for the truncation, or scipy's plain fit."""


def fit_student_t(x: np.ndarray, fit: str = "truncated") -> StudentT:
    """Student-t of 1-D data, truncated to the data's range [min, max].

    ``scipy.stats.t.fit`` gives the maximum-likelihood (df, loc, scale) of the plain t; since samples
    are drawn from the t truncated to [lo, hi] (see :meth:`StudentT.sample`), the estimate is then
    refined to maximise the likelihood of the TRUNCATED t (``log pdf - log(cdf(hi) - cdf(lo))``,
    L-BFGS-B from the plain fit). For light tails both agree; for KITTI's yaw (df ~ 0.7 plain) the
    plain fit puts ~10 % of its mass beyond the data and its truncated samples come out too narrow,
    while the refined one reproduces the data's quantiles.

    ``fit="plain"`` keeps scipy's plain fit (no refinement): where the data fill their range (the
    forward offset of KITTI's loop pairs, near-uniform over +-5 m) its samples crowd nearer the
    centre than the data do (t_z scale 2.8 m against the refined fit's 6.3 m). It is what
    ``models/motion/kitti_s1.json``'s loop part was fitted with, and the loop models trained on it
    are the better ones on the simulated street's loops (``models/README.md``).
    """
    from scipy import optimize, stats  # deferred: scipy.optimize and .stats (~1 s), only when fitting

    if fit not in FITS:
        raise ValueError(f"fit must be one of {FITS}, got {fit!r}")

    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    if len(x) < MIN_MOTIONS:
        raise ValueError(f"need at least {MIN_MOTIONS} values to fit, got {len(x)}")
    if np.ptp(x) == 0:
        raise ValueError("all values are equal: nothing to fit")
    lo, hi = float(x.min()), float(x.max())
    df0, loc0, scale0 = (float(v) for v in stats.t.fit(x))
    if fit == "plain":
        return StudentT(df0, loc0, scale0, lo, hi)
    df0 = float(np.clip(df0, 0.05, 1e8))

    def unpack(p):
        return float(np.clip(np.exp(p[0]), 0.05, 1e8)), loc0 + p[1] * scale0, scale0 * float(np.exp(p[2]))

    def nll(p) -> float:
        df, loc, scale = unpack(p)
        mass = stats.t.cdf(hi, df, loc, scale) - stats.t.cdf(lo, df, loc, scale)
        if not mass > 0:
            return 1e300
        return float(-(stats.t.logpdf(x, df, loc, scale).mean() - np.log(mass)))

    start = np.array([np.log(df0), 0.0, 0.0])
    res = optimize.minimize(nll, start, method="L-BFGS-B")
    p = res.x if np.all(np.isfinite(res.x)) and res.fun <= nll(start) else start
    df, loc, scale = unpack(p)
    return StudentT(df, float(loc), float(scale), lo, hi)


def fit_six(vectors: np.ndarray, fit: str = "truncated") -> SixDof:
    """Fit each column of (N, 6) paper vectors (``fit``: see :func:`fit_student_t`)."""
    return SixDof(tuple(fit_student_t(vectors[:, k], fit) for k in range(6)), int(len(vectors)))


def fit_motion(trajectories: Sequence[Trajectory], stride: int = 1, loops: bool = False,
               loop_config: LoopConfig = LoopConfig(), sources: Sequence[str] = (),
               seed: int = 0, loop_fit: str = "truncated",
               consecutive_kind: str = "student-t",
               speed_scale: tuple[float, float] | None = None,
               mirror: bool = False,
               body: Sequence[Trajectory] = (),
               body_sources: Sequence[str] = (),
               lever_m: float = 0.0) -> tuple[MotionModel, np.ndarray, np.ndarray | None]:
    """Fit the consecutive (and optionally loop) model to ground-truth trajectories.

    Args:
        trajectories: world_from_cam trajectories (OpenCV axes, metres).
        stride: frame stride k.
        loops: also fit the loop distribution.
        loop_config: which pairs are loops.
        sources: names recorded in the model.
        seed: seeds the subsample of loop pairs when there are more than ``loop_config.max_pairs``.
        loop_fit: how the loop distribution's Student-t are fitted (:func:`fit_student_t`).
        consecutive_kind: ``"student-t"`` (the paper's independent Student-t per DoF) or ``"kde"`` (the
            joint :class:`KdeSix`; the loop distribution stays Student-t).
        speed_scale: the KDE's :attr:`KdeSix.speed_scale` (a ``"kde"`` fit only).
        mirror: fit the consecutive motions together with their mirror images (:func:`mirrored_vectors`): turns
            both ways as often, whichever way the routes turned (a route that goes round its blocks one way).
        body: trajectories whose frame-to-frame pitch and roll at ``stride`` are added to each drawn motion
            (:func:`with_body`; a ``"kde"`` fit only); ``body_sources`` their names.
        lever_m: the KDE's :attr:`KdeSix.lever_m` (with ``speed_scale`` only).

    Returns:
        (model, consecutive vectors (N, 6), loop vectors (M, 6) or None): the data, for plots and checks.

    Raises:
        ValueError when there are too few motions (or no loop pair when ``loops``).
    """
    vec = relative_vectors(trajectories, stride)
    if mirror:
        vec = np.concatenate([vec, mirrored_vectors(vec)], axis=0)
    if len(vec) < MIN_MOTIONS:
        raise ValueError(f"only {len(vec)} relative motions at stride {stride}; need at least {MIN_MOTIONS}")
    if consecutive_kind not in CONSECUTIVE_KINDS:
        raise ValueError(f"consecutive_kind must be one of {CONSECUTIVE_KINDS}, got {consecutive_kind!r}")
    if speed_scale is not None and consecutive_kind != "kde":
        raise ValueError("speed_scale needs the joint KDE (consecutive_kind 'kde')")
    if body and consecutive_kind != "kde":
        raise ValueError("body needs the joint KDE (consecutive_kind 'kde')")
    consecutive = fit_kde(vec, seed, speed_scale, lever_m) if consecutive_kind == "kde" else fit_six(vec)
    if body:
        consecutive = with_body(consecutive, relative_vectors(body, stride), body_sources, seed)
    loop, loop_vec = None, None
    if loops:
        rel = [loop_motions(t, loop_config) for t in trajectories]
        rel = np.concatenate(rel, axis=0) if rel else np.zeros((0, 4, 4))
        if len(rel) < MIN_MOTIONS:
            raise ValueError(f"only {len(rel)} loop motions (pairs more than {loop_config.min_gap_frames} frames "
                             f"apart within {loop_config.max_distance_m} m and {loop_config.max_angle_deg} deg); "
                             f"need at least {MIN_MOTIONS}")
        if len(rel) > loop_config.max_pairs:
            pick = np.sort(np.random.default_rng(seed).choice(len(rel), loop_config.max_pairs, replace=False))
            rel = rel[pick]
        loop_vec = se3.to_euler6(rel)
        loop = fit_six(loop_vec, loop_fit)
    model = MotionModel(stride, consecutive, loop, loop_config if loops else None, tuple(sources),
                        loop_fit if loops else None)
    return model, vec, loop_vec


def ks_statistics(model: "SixDof | KdeSix", data: np.ndarray, seed: int = 0) -> np.ndarray:
    """(6,) Kolmogorov-Smirnov statistic of each DoF of ``data`` (N, 6) against its fit: one-sample against
    the (truncated) Student-t, or two-sample against 20,000 draws of a KDE (``seed``)."""
    from scipy import stats  # deferred: scipy.stats (~0.7 s) only where a t distribution is evaluated

    if isinstance(model, KdeSix):
        draws = model.sample(20_000, np.random.default_rng(seed))
        return np.array([stats.ks_2samp(data[:, k], draws[:, k]).statistic for k in range(6)])
    return np.array([stats.kstest(data[:, k], model.dofs[k].cdf).statistic for k in range(6)])


# -------------------------------------------------------------------------------------------- plotting

def plot_motion_fit(path_png: str | Path, data: np.ndarray, model: "SixDof | KdeSix", title: str = "",
                    loop_data: np.ndarray | None = None, loop_model: SixDof | None = None) -> Path:
    """The paper's Figure 3: a histogram per DoF with the fitted Student-t density, as a PNG.

    Args:
        path_png: output file (written atomically).
        data: (N, 6) paper vectors the model was fitted to.
        model: the fitted distributions.
        title: figure title.
        loop_data, loop_model: a second row of six panels for the loop distribution.
    """
    rows = [(data, model, "consecutive")]
    if loop_data is not None and loop_model is not None:
        rows.append((loop_data, loop_model, "loop"))
    fig = plots.new_figure((13, 6.5 * len(rows)), dpi=100)
    axes = fig.subplots(2 * len(rows), 3, squeeze=False)
    for r, (vec, six, label) in enumerate(rows):
        for k in range(6):
            ax = axes[2 * r + k // 3, k % 3]
            x = vec[:, k]
            lo, hi = np.quantile(x, [0.005, 0.995])
            pad = 0.1 * (hi - lo) if hi > lo else 1e-3
            lo, hi = lo - pad, hi + pad
            inside = x[(x >= lo) & (x <= hi)]
            bins = 80
            # Density of ALL the data (the tails beyond the plotted range keep their share), so the
            # bars and the fitted density are on the same scale.
            ax.hist(inside, bins=bins, range=(lo, hi), weights=np.full(len(inside), bins / (len(x) * (hi - lo))),
                    color="#8fb3d9", edgecolor="none", label=f"data (N={len(x)})")
            grid = np.linspace(lo, hi, 400)
            if isinstance(six, KdeSix):
                ax.plot(grid, six.marginal_pdf(k, grid), color="#c0392b", lw=1.6,
                        label=f"KDE, bandwidth {six.bandwidth[k]:.3g}")
            else:
                d = six.dofs[k]
                ax.plot(grid, d.pdf(grid), color="#c0392b", lw=1.6,
                        label=f"Student-t df={d.df:.2g}\nloc={d.loc:.3g} scale={d.scale:.3g}")
            ax.set_title(f"{label}: {DOF_NAMES[k]} [{DOF_UNITS[k]}]", fontsize=10)
            ax.legend(fontsize=7, loc="upper right")
            ax.tick_params(labelsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path_png = Path(path_png)
    with atomic.atomic_path(path_png) as tmp:
        fig.savefig(tmp, format="png")
    return path_png
