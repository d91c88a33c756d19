"""Several plug-in odometries measured side by side: each loaded and checked (:mod:`slam.plugins`) and keyed
by a unique column key made from its name, for tables and plots that hold them together."""
from __future__ import annotations

import re
from typing import Sequence as SequenceT

from deepslam.slam.plugins import DEFAULT_COMMAND_TIMEOUT_S, CheckedOdometry, command_odometry, load_odometry

RESERVED_KEYS = ("gt", "dis")
"""Column keys the harness's own odometries use (on ground-truth and on DIS flow)."""


def plugin_key(name: str) -> str:
    """A plug-in's name as a column key: lower case letters, digits and ``-``."""
    return re.sub(r"[^a-z0-9-]+", "-", str(name).lower()).strip("-") or "plugin"


def load_plugins(specs: SequenceT[str] = (), commands: SequenceT[str] = (),
                 command_timeout_s: float = DEFAULT_COMMAND_TIMEOUT_S,
                 reserved: SequenceT[str] = RESERVED_KEYS) -> dict[str, CheckedOdometry]:
    """{key: checked odometry} of the plug-in ``specs`` (``MODULE:FACTORY`` or an entry-point name,
    :func:`slam.plugins.load_odometry`) and then the external ``commands`` (``'CMD {sequence} {out}'``
    templates, :func:`slam.plugins.command_odometry`, each run with ``command_timeout_s``), in that
    order; keys are unique and none is in ``reserved`` (``-2`` is appended until so)."""
    odometries = [load_odometry(spec) for spec in specs]
    odometries += [command_odometry(c, timeout_s=command_timeout_s) for c in commands]
    out: dict[str, CheckedOdometry] = {}
    for odo in odometries:
        key = plugin_key(odo.name)
        while key in out or key in reserved:
            key += "-2"
        out[key] = odo
    return out
