"""Motion samplers of the synthetic training data: ``(n, rng) -> (n, 6)`` paper vectors of cam1_from_cam0
from a fitted :class:`gen.motion.MotionModel` (:func:`motion_sampler`), mixtures of them
(:class:`MotionMixture`), a flat forward speed (:class:`FlatSpeed`); and the per-sample camera tilt
(:class:`CameraTilt`) and scene scale (:class:`SceneScale`) the sources apply to each frame."""
from __future__ import annotations

import numpy as np

from deepslam.core.errors import InputError
from deepslam.gen.rotate_view import rotate_motion, rotation_from_pitch_roll

def motion_sampler(model, loops: bool = False):
    """``(n, rng) -> (n, 6)`` from a :class:`gen.motion.MotionModel`: its consecutive distribution, or
    with ``loops`` its loop distribution (NN_loops)."""
    if loops and model.loop is None:
        raise InputError(None, "the motion model has no loop distribution (fit it with --loops)")
    frac = 1.0 if loops else 0.0
    return lambda n, rng: model.sample(n, rng, frac)[0]


class MotionMixture:
    """Several motion samplers mixed with weights (strides 1, 2, 3..., or consecutive + loops).

    Args:
        samplers: callables ``(n, rng) -> (n, 6)`` paper vectors of cam1_from_cam0 (e.g. the
            ``sample`` method of a gen.motion model).
        weights: mixing weights (normalised here); equal by default.
        names: labels for the resolved config.
    """

    def __init__(self, samplers, weights=None, names=None):
        self.samplers = list(samplers)
        w = np.ones(len(self.samplers)) if weights is None else np.asarray(weights, dtype=np.float64)
        if len(w) != len(self.samplers) or (w < 0).any() or w.sum() <= 0:
            raise InputError(None, f"bad motion mixture weights {list(w)}")
        self.weights = w / w.sum()
        self.names = list(names) if names else [f"motion{k}" for k in range(len(self.samplers))]

    def __call__(self, n: int, rng: np.random.Generator) -> np.ndarray:
        which = rng.choice(len(self.samplers), size=n, p=self.weights)
        out = np.zeros((n, 6))
        for k, s in enumerate(self.samplers):
            m = which == k
            if m.any():
                out[m] = np.asarray(s(int(m.sum()), rng), dtype=np.float64).reshape(-1, 6)
        return out


class FlatSpeed:
    """A motion sampler whose forward speed is uniform over a range instead of the fitted prior, for
    all of its motions or for a fraction of them.

    The fitted Student-t of t_z (KITTI: about 9 m/s, scale 3 m/s) teaches a network a speed prior:
    it reads slow driving too fast and the highway too slow. This keeps every other DoF of ``base``
    and draws the forward motion per frame uniformly in ``[min_mps, max_mps] / rate_hz``, so the
    flow is the only cue to the speed. Forward is -t_z of cam1_from_cam0 (the paper's vector).
    With ``fraction`` < 1 only that share of the motions (each chosen with probability ``fraction``)
    gets the flat speed and the rest keep ``base``'s: a prior with a flat tail, which shows the
    network the speeds its fitted prior all but never draws (KITTI's: under 2 % above 20 m/s, none
    above 27 m/s) while keeping the prior's help at the speeds it covers.

    Args:
        base: ``(n, rng) -> (n, 6)`` sampler (its t_z is replaced).
        min_mps, max_mps: speed range, m/s (0 <= min < max).
        rate_hz: frame rate of the motions (KITTI 10 Hz; a stride-k model: 10 / k).
        fraction: share of the motions drawn with the flat speed, in (0, 1]. At 1 (the default) no
            choice is drawn, so the draws are those of the sampler before this option existed.
    """

    def __init__(self, base, min_mps: float, max_mps: float, rate_hz: float, fraction: float = 1.0):
        if not (np.isfinite([min_mps, max_mps, rate_hz]).all() and 0 <= min_mps < max_mps and rate_hz > 0):
            raise InputError(None, f"bad speed range {min_mps}:{max_mps} m/s at {rate_hz} Hz (need 0 <= min < max)")
        if not (np.isfinite(fraction) and 0 < fraction <= 1):
            raise InputError(None, f"bad flat-speed fraction {fraction} (need 0 < fraction <= 1)")
        self.base, self.min_mps, self.max_mps, self.rate_hz = base, float(min_mps), float(max_mps), float(rate_hz)
        self.fraction = float(fraction)

    def __call__(self, n: int, rng: np.random.Generator) -> np.ndarray:
        out = np.array(self.base(n, rng), dtype=np.float64).reshape(n, 6)
        flat = -rng.uniform(self.min_mps, self.max_mps, n) / self.rate_hz
        if self.fraction >= 1.0:
            out[:, 5] = flat
        else:
            chosen = rng.random(n) < self.fraction
            out[chosen, 5] = flat[chosen]
        return out

    @classmethod
    def parse(cls, base, text: str, rate_hz: float) -> "FlatSpeed":
        """From ``MIN:MAX[@FRACTION]`` m/s (the ``train --speed-range`` flag); InputError naming the flag."""
        rng_text, _, frac_text = text.partition("@")
        try:
            lo, hi = (float(x) for x in rng_text.split(":"))
            fraction = float(frac_text) if frac_text else 1.0
        except ValueError:
            raise InputError(None, f"--speed-range must be MIN:MAX[@FRACTION] (m/s; a fraction in (0, 1]), "
                                   f"got {text!r}") from None
        return cls(base, lo, hi, rate_hz, fraction)


class CameraTilt:
    """Random rotations of the training frames' cameras about their centres (pitch and roll), exact
    from the single frame (:mod:`gen.rotate_view`): the road then sits at other image rows, as it does
    under another camera mounting, a loaded car or a braking one.

    Why: a network reads metric translation largely from where the road lies in the image. The
    simulated car's camera is level, KITTI's is pitched down by about a degree, and a model trained on
    level renders read KITTI 06's exact flow (stereo depth + ground-truth motion) at 1.175x the motion,
    1.03x once the frames were levelled by 0.95 degrees (14 % per degree).

    The sampled motion is the car's, in the level camera; the sample's motion and target are that motion
    seen from the rotated camera (``R m R^T``), so the car still drives along its road.

    Args:
        pitch_deg: (min, max) pitch, degrees, positive = looking further down; uniform.
        roll_deg: roll drawn uniformly in (-roll_deg, roll_deg), degrees.
    """

    def __init__(self, pitch_deg: tuple[float, float], roll_deg: float = 0.0):
        lo, hi = (float(x) for x in pitch_deg)
        if not (np.isfinite([lo, hi, roll_deg]).all() and -30 <= lo <= hi <= 30 and 0 <= roll_deg <= 30):
            raise InputError(None, f"bad camera tilt: pitch {lo}:{hi} deg, roll {roll_deg} deg "
                                   "(need -30 <= min <= max <= 30, 0 <= roll <= 30)")
        self.pitch_deg, self.roll_deg = (lo, hi), float(roll_deg)

    @classmethod
    def parse(cls, text: str) -> "CameraTilt":
        """From ``PMIN:PMAX[:ROLL]`` degrees (the ``--camera-tilt-deg`` flag)."""
        try:
            parts = [float(x) for x in text.split(":")]
            if len(parts) not in (2, 3):
                raise ValueError
        except ValueError:
            raise InputError(None, f"--camera-tilt-deg must be PMIN:PMAX[:ROLL] in degrees, got {text!r}") from None
        return cls((parts[0], parts[1]), parts[2] if len(parts) == 3 else 0.0)

    def to_dict(self) -> dict:
        return {"pitch_deg": list(self.pitch_deg), "roll_deg": self.roll_deg}

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, 3, 3) float64 cam_new_from_cam rotations."""
        pitch = np.radians(rng.uniform(*self.pitch_deg, n))
        roll = np.radians(rng.uniform(-self.roll_deg, self.roll_deg, n))
        return np.stack([rotation_from_pitch_roll(p, r) for p, r in zip(pitch, roll)]) if n else np.zeros((0, 3, 3))


class SceneScale:
    """A random scale of each training frame's depth (the whole scene, log-uniform in [min, max]): the
    same image then stands for a smaller or larger world, so the same motion makes more or less
    parallax. The flow (exact, or the estimator's on a view rendered from the scaled depth) and the
    depth channel follow the scaled depth; the motion and target stay metric.

    Why: a network reads translation from the parallax of the geometry it was shown. The simulated
    rooms' nearest tenth of the pixels lies 2-2.5 m away, the TUM fr3/teddy slice's 0.8 m (median depth
    3-4.5 m against 2.5 m); at the same hand-held motion the real scene's parallax is two to three times
    any training frame's.

    Args:
        lo, hi: the factor's range (0.05 <= lo <= hi <= 20).
    """

    def __init__(self, lo: float, hi: float):
        lo, hi = float(lo), float(hi)
        if not (np.isfinite([lo, hi]).all() and 0.05 <= lo <= hi <= 20):
            raise InputError(None, f"bad scene scale {lo}:{hi} (need 0.05 <= min <= max <= 20)")
        self.lo, self.hi = lo, hi

    @classmethod
    def parse(cls, text: str) -> "SceneScale":
        """From ``MIN:MAX`` (the ``--scene-scale`` flag)."""
        try:
            lo, hi = (float(x) for x in text.split(":"))
        except ValueError:
            raise InputError(None, f"--scene-scale must be MIN:MAX (factors), got {text!r}") from None
        return cls(lo, hi)

    def to_dict(self) -> dict:
        return {"min": self.lo, "max": self.hi}

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n,) float64 factors, log-uniform."""
        return np.exp(rng.uniform(np.log(self.lo), np.log(self.hi), n))


def tilted(rot: np.ndarray, cam1_from_cam0: np.ndarray) -> np.ndarray:
    """(n, 4, 4) motions seen from cameras rotated by ``rot`` (n, 3, 3): ``R m R^T``."""
    return np.stack([rotate_motion(m, r) for m, r in zip(cam1_from_cam0, rot)])
