"""``deepslam dataset`` throughput (local vs Ray with 2 workers), a worker's peak memory against the
sequence length, and how much of the image the movers cover.

Rows:
- sequences/hour of the same dataset rendered locally and by Ray with 2 workers (same bytes: the
  manifests' sha256 are compared), ratio Ray / local;
- peak resident memory of a fresh worker process rendering a 100- and a 1,000-frame sequence (target:
  flat, ratio <= 1.2: frames are streamed to disk, nothing grows with the length);
- the dynamic fraction (share of the image on movers, per frame) of the street and the room with 8
  movers: share of frames with a mover and the mean, against KITTI-like targets (movers in most
  frames, 5-30 % of the image), with a histogram ``out/bench_dynamic_fraction.png``.
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _peak_rss_mib(frames: int, out: Path) -> float:
    """Peak RSS of a fresh process rendering one street sequence of ``frames`` frames (sim.dataset's record)."""
    code = ("import json, sys; from deepslam.sim.dataset import DatasetConfig, plan, render_planned; "
            "import dataclasses; "
            f"e = plan(DatasetConfig(scenes=('street',), sequences=1, frames={frames}, width=96, moving_objects=(2, 2)))[0]; "
            f"print(json.dumps(render_planned(dataclasses.asdict(e), {str(out)!r}, 'ours')))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(json.loads(r.stdout.strip().splitlines()[-1])["peak_rss_mib"])


def _dynamic(scene: str, frames: int, width: int, out: Path) -> np.ndarray:
    from deepslam.scenes import SceneConfig
    from deepslam.sim import RenderConfig, SimConfig, TrajectoryConfig
    from deepslam.sim.writers import DYNAMIC_FRACTION_FILE, render_sequence

    cfg = SimConfig(SceneConfig(name=scene, seed=3, moving_objects=8), TrajectoryConfig(frames=frames),
                    RenderConfig(width=width, stereo_baseline_m=0.0, flow=False))
    root = render_sequence(cfg, out, progress=False)
    return np.loadtxt(Path(root) / DYNAMIC_FRACTION_FILE)


def run(quick: bool = False) -> list[dict]:
    from deepslam.sim.dataset import DatasetConfig, build

    rows = []
    n_seq, frames = (2, 10) if quick else (4, 40)
    cfg = DatasetConfig(sequences=n_seq, frames=frames, width=160, moving_objects=(1, 4))
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        local = build(cfg, Path(tmp) / "local", backend="local", progress=False)
        t_local = time.perf_counter() - t0
        t0 = time.perf_counter()
        ray = build(cfg, Path(tmp) / "ray", backend="ray", workers=2, progress=False)
        t_ray = time.perf_counter() - t0
        rows.append({"name": f"dataset, {n_seq} sequences x {frames} frames at 160 px, local", "value": round(3600 * n_seq / t_local, 1),
                     "unit": "sequences/hour", "baseline": None, "baseline_value": None, "ratio": None, "target": None, "met": None})
        rows.append({"name": f"dataset, {n_seq} sequences x {frames} frames at 160 px, Ray 2 workers (Ray start-up included)",
                     "value": round(3600 * n_seq / t_ray, 1), "unit": "sequences/hour", "baseline": "local",
                     "baseline_value": round(3600 * n_seq / t_local, 1), "ratio": t_local / t_ray,
                     "target": "same bytes", "met": ray["sha256"] == local["sha256"]})
        short, long_ = (20, 200) if quick else (100, 1000)
        m_short = _peak_rss_mib(short, Path(tmp) / "rss_short")
        m_long = _peak_rss_mib(long_, Path(tmp) / "rss_long")
        rows.append({"name": f"worker peak resident memory, {long_}- vs {short}-frame sequence (96 px)",
                     "value": m_long, "unit": "MiB", "baseline": f"{short} frames", "baseline_value": m_short,
                     "ratio": m_long / m_short, "target": "<= 1.2x", "met": m_long / m_short <= 1.2})
        fr = {}
        n_dyn = 30 if quick else 100
        for scene in ("street", "room"):
            f = _dynamic(scene, n_dyn, 160, Path(tmp) / f"dyn_{scene}")
            fr[scene] = f
            rows.append({"name": f"{scene}, 8 movers, {n_dyn} frames: frames with a mover in view", "value": round(float(np.mean(f > 0)), 3),
                         "unit": "share", "baseline": None, "baseline_value": None, "ratio": None,
                         "target": ">= 0.5 (KITTI city: most frames)", "met": bool(np.mean(f > 0) >= 0.5)})
            rows.append({"name": f"{scene}, 8 movers, {n_dyn} frames: mean dynamic fraction", "value": round(float(f.mean()), 4),
                         "unit": "share of pixels", "baseline": None, "baseline_value": None, "ratio": None,
                         "target": ">= 0.05 (KITTI city: often 5-30 %)", "met": bool(f.mean() >= 0.05),
                         "p90": round(float(np.percentile(f, 90)), 4), "max": round(float(f.max()), 4)})
    try:
        from deepslam.core.plots import new_figure, save_figure

        fig = new_figure((6, 3.5))
        ax = fig.subplots()
        bins = np.linspace(0, max(0.3, max(float(v.max()) for v in fr.values())), 31)
        for scene, f in fr.items():
            ax.hist(f, bins=bins, alpha=0.6, label=f"{scene} (8 movers)")
        ax.axvspan(0.05, 0.30, color="grey", alpha=0.15, label="KITTI city, typical")
        ax.set_xlabel("dynamic fraction (share of the image on movers)")
        ax.set_ylabel("frames")
        ax.legend()
        fig.tight_layout()
        Path("out").mkdir(exist_ok=True)
        save_figure(fig, "out/bench_dynamic_fraction.png")
    except Exception:  # noqa: BLE001 - the plot is a convenience
        pass
    return rows
