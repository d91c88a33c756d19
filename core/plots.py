"""PNG plots of trajectories and errors (matplotlib, Agg canvas, no pyplot state), written atomically."""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from deepslam.core import atomic

_AXIS_NAMES = "xyz"


def topdown_axes(positions: Sequence[np.ndarray]) -> tuple[int, int]:
    """The two world axes (indices, ascending) with the largest extent over all ``positions`` (N, 3).

    For a KITTI trajectory (OpenCV camera axes, y down) this picks x and z: the ground plane.
    """
    pts = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in positions], axis=0)
    extent = pts.max(axis=0) - pts.min(axis=0) if len(pts) else np.ones(3)
    a, b = sorted(np.argsort(-extent, kind="stable")[:2])
    return int(a), int(b)


def new_figure(size: tuple[float, float] = (7.0, 6.0), dpi: int = 110):
    """A matplotlib Figure of ``size`` inches on its own Agg canvas: no pyplot, so no global figure state to close,
    no backend to switch, and safe beside other threads that draw."""
    # deferred: matplotlib (~0.35 s) is imported only when a figure is drawn, not by every importer of plots
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path_png: str | Path, dpi: int | None = None) -> Path:
    """Write ``fig`` as a PNG at ``path_png`` atomically (a reader never sees half a file); ``dpi``: the figure's
    own where None."""
    path_png = Path(path_png)
    with atomic.atomic_path(path_png) as tmp:
        fig.savefig(tmp, format="png", **({} if dpi is None else {"dpi": dpi}))
    return path_png


def plot_trajectories_topdown(path_png: str | Path, trajectories: Mapping[str, np.ndarray], title: str = "",
                              axes: tuple[int, int] | None = None) -> Path:
    """Draw trajectories from above and write a PNG atomically.

    Args:
        path_png: output file.
        trajectories: label -> positions (N, 3) float, metres, all in one world frame; the first is
            drawn as the reference (black, dashed) and marks the start with a circle.
        title: figure title.
        axes: the two world axes (0 = x, 1 = y, 2 = z) to draw; by default the two with the largest
            extent (x and z for KITTI's camera-frame poses).

    Returns:
        The written path.
    """
    if not trajectories:
        raise ValueError("nothing to plot")
    pos = {k: np.asarray(v, dtype=np.float64).reshape(-1, 3) for k, v in trajectories.items()}
    a, b = axes if axes is not None else topdown_axes(list(pos.values()))
    fig = new_figure()
    ax = fig.add_subplot(1, 1, 1)
    for n, (label, p) in enumerate(pos.items()):
        style = dict(color="black", linestyle="--", linewidth=1.2) if n == 0 else dict(linewidth=1.2)
        ax.plot(p[:, a], p[:, b], label=label, **style)
        if n == 0 and len(p):
            ax.plot(p[:1, a], p[:1, b], "o", color="black", markersize=5)
    ax.set_xlabel(f"{_AXIS_NAMES[a]} [m]")
    ax.set_ylabel(f"{_AXIS_NAMES[b]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return save_figure(fig, path_png)


def plot_kitti_per_length(path_png: str | Path, per_length: Mapping[str, Sequence[Mapping]], title: str = "") -> Path:
    """Bar plots of KITTI t_err (%) and r_err (deg/100 m) per segment length, one bar group per label.

    Args:
        per_length: label -> the ``per_length`` list of :func:`core.metrics.kitti_errors`
            (dicts with length_m, t_err_pct, r_err_deg_per_100m).
    """
    if not per_length:
        raise ValueError("nothing to plot")
    lengths = sorted({float(r["length_m"]) for rows in per_length.values() for r in rows})
    fig = new_figure(size=(10.0, 4.0))
    width = 0.8 / len(per_length)
    x = np.arange(len(lengths))
    for col, (key, unit) in enumerate((("t_err_pct", "translation error [%]"),
                                       ("r_err_deg_per_100m", "rotation error [deg/100 m]"))):
        ax = fig.add_subplot(1, 2, col + 1)
        for n, (label, rows) in enumerate(per_length.items()):
            by_len = {float(r["length_m"]): r[key] for r in rows}
            ax.bar(x + (n - (len(per_length) - 1) / 2) * width, [by_len.get(L, np.nan) for L in lengths],
                   width=width, label=label)
        ax.set_xticks(x, [f"{L:g}" for L in lengths])
        ax.set_xlabel("segment length [m]")
        ax.set_ylabel(unit)
        ax.grid(True, axis="y", alpha=0.3)
        if col == 0:
            ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, path_png)
