"""Flow estimators by name: the built-in ones (``dis``, ``gt``, ``learned``, ``learned-dis``), plug-ins
(``MODULE:FACTORY`` or an entry point of the group ``deepslam.flow``), and the command line's DIS options.

A learned estimator (RAFT, PWC-Net...) is added with :func:`register` (``@register("raft") def make(**options)``)
or as a plug-in; see :class:`deepslam.flow.estimators.FlowEstimator` for what it must offer.
"""
from __future__ import annotations

from importlib.metadata import entry_points
from pathlib import Path
from typing import Callable

from deepslam.core.errors import InputError
from deepslam.core.plugins import ENTRY_POINT_GROUPS, load_factory
from deepslam.flow.estimators import DISFlow, FlowEstimator, GroundTruthFlow
from deepslam.models import models_dir


_REGISTRY: dict[str, Callable[..., FlowEstimator]] = {}


def register(name: str) -> Callable[[Callable[..., FlowEstimator]], Callable[..., FlowEstimator]]:
    """Decorator: ``@register("raft") def make_raft(**options) -> FlowEstimator``."""

    def deco(factory):
        _REGISTRY[name] = factory
        return factory

    return deco


def _learned_model_path(path=None):
    """The learned flow model file: ``path``, or the shipped one; InputError when it is not there."""
    p = Path(path) if path else models_dir() / "flow_learned.safetensors"
    if not p.is_file():
        raise InputError(p, "no learned flow model here (train one with `deepslam train-flow`; README: Learned flow)")
    return p


def _learned(path=None, threads: int = 0):
    """The shipped learned estimator (:class:`flow.net.LearnedFlow`), or the model file ``path``."""
    from deepslam.flow.net import LearnedFlow  # deferred: torch, only when a learned estimator is made (DIS runs first)

    return LearnedFlow(_learned_model_path(path), threads=threads)


def _learned_dis(path=None, threads: int = 0):
    """The learned flow as DIS's starting point (:class:`flow.net.LearnedDISFlow`), with the shipped learned
    model or the flow model file ``path``."""
    from deepslam.flow.net import LearnedDISFlow  # deferred: torch, as in _learned

    return LearnedDISFlow(_learned_model_path(path), threads=threads)


register("dis")(DISFlow)
register("gt")(GroundTruthFlow)
register("learned")(_learned)
register("learned-dis")(_learned_dis)


def estimator_options(name: str, dis_preset: str | None = "medium", dis_min_texture: float | None = 0.0,
                      dis_fb_check: float | None = None, dis_max_width: int | None = None,
                      dis_patch_stride: int | None = None) -> dict:
    """The options :func:`make` passes to ``name``'s factory from the command line's DIS flags
    (``--dis-preset``, ``--dis-min-texture``, ``--dis-fb-check``, ``--dis-max-width``, ``--dis-patch-stride``;
    None = not given): those of
    :class:`DISFlow` for ``dis``, none otherwise (a check or width limit not given is left out, so a model trained
    without one records what files from before it record). InputError when a texture threshold, a
    forward-backward check or a width limit is given for another estimator (it would be silently ignored)."""
    if name == "dis":
        opts = {"preset": dis_preset, "min_texture": dis_min_texture}
        if dis_fb_check is not None:
            opts["fb_max_px"] = dis_fb_check
        if dis_max_width is not None:
            opts["max_width"] = dis_max_width
        if dis_patch_stride is not None:
            opts["patch_stride"] = dis_patch_stride
        return opts
    for flag, given in (("--dis-min-texture", dis_min_texture), ("--dis-fb-check", dis_fb_check),
                        ("--dis-max-width", dis_max_width), ("--dis-patch-stride", dis_patch_stride)):
        if given:
            raise InputError(None, f"{flag} applies to DIS flow only, not to flow estimator {name!r}")
    return {}


DIS_FLAGS = ("dis_preset", "dis_min_texture", "dis_fb_check", "dis_max_width", "dis_patch_stride")
"""The command line's DIS flags as namespace attributes (``--dis-preset`` -> ``dis_preset``), in
:func:`estimator_options`' order; ``deepslam.commands._dis_flags`` defines them and reads them (:func:`deepslam.commands._dis_flags.given_options`)."""


def names() -> list[str]:
    """Names of the registered estimators."""
    return sorted(_REGISTRY)


def make(name: str, **options) -> FlowEstimator:
    """An estimator by registry name (``options`` go to its factory: ``preset`` for ``dis``), or a
    plug-in: ``MODULE:FACTORY`` or a name registered under the entry-point group ``deepslam.flow``
    (called with no arguments; the object needs ``name``, ``estimate(img0, img1)`` and
    ``pair_flow(seq, i, j)``, see :class:`FlowEstimator`)."""
    if name in _REGISTRY:
        return _REGISTRY[name](**options)

    group = ENTRY_POINT_GROUPS["flow"]
    if ":" not in name and not any(ep.name == name for ep in entry_points(group=group)):
        raise InputError(None, f"unknown flow estimator {name!r} (one of {', '.join(names())}, MODULE:FACTORY, or "
                               f"an entry point of group {group})")
    factory = load_factory(name, group)
    try:
        est = factory()
    except Exception as e:  # noqa: BLE001 - a user's plug-in
        raise InputError(None, f"flow plugin {name}: the factory failed ({type(e).__name__}: {e})") from None
    missing = [m for m in ("estimate", "pair_flow") if not callable(getattr(est, m, None))]
    if missing:
        raise InputError(None, f"flow plugin {name}: the estimator has no {' or '.join(missing)} method")
    if not hasattr(est, "name"):
        est.name = name
    return est
