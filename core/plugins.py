"""Plug-ins by name: ``MODULE:FACTORY`` or an installed package's entry point.

Two entry-point groups: ``deepslam.odometry`` (odometries for vo, slam, tune-slam, stress; see
:mod:`deepslam.slam.plugins`) and ``deepslam.flow`` (flow estimators for ``--flow``; see
:func:`deepslam.vo.flow_registry.make`). A package registers ``NAME = "module:factory"`` under one
of them in its ``pyproject.toml`` (``[project.entry-points."deepslam.flow"]``).
"""
from __future__ import annotations

import importlib
from importlib.metadata import entry_points

from deepslam.core.errors import InputError

ENTRY_POINT_GROUPS = {"odometry": "deepslam.odometry", "flow": "deepslam.flow"}
"""The entry-point group of each plug-in kind."""


def _entry_point(name: str, group: str):
    found = [ep for ep in entry_points(group=group) if ep.name == name]
    return found[0] if found else None


def load_factory(spec: str, group: str):
    """The callable named by ``MODULE:FACTORY`` or by an entry point NAME of ``group``."""
    if ":" in spec:
        mod_name, _, attr = spec.partition(":")
        try:
            mod = importlib.import_module(mod_name)
        except Exception as e:  # noqa: BLE001 - ImportError, or the module's own error at import
            raise InputError(None, f"plugin {spec}: cannot import {mod_name} ({type(e).__name__}: {e})") from None
        obj = mod
        for part in attr.split("."):
            if not hasattr(obj, part):
                raise InputError(None, f"plugin {spec}: {mod_name} has no attribute {attr!r}")
            obj = getattr(obj, part)
    else:
        ep = _entry_point(spec, group)
        if ep is None:
            raise InputError(None, f"unknown plugin {spec!r}: neither MODULE:FACTORY nor an installed entry point "
                                   f"of group {group}")
        try:
            obj = ep.load()
        except Exception as e:  # noqa: BLE001
            raise InputError(None, f"plugin {spec} ({ep.value}): cannot load ({type(e).__name__}: {e})") from None
    if not callable(obj):
        raise InputError(None, f"plugin {spec}: {type(obj).__name__} is not callable")
    return obj
