"""Which flow shows the road's motion? The camera height each flow estimator implies for the road.

For consecutive frame pairs that move at least 0.3 m, :func:`deepslam.vo.geometry.road_height.implied_road_height`
fits the road plane in front of the car to the flow with the TRUE motion: an estimator that moves the
road as far as it really moves gives the camera's height (1.65 m, in the simulated street and on
KITTI); one that under-moves it a larger height. Sets: a held-out simulated street (seed 7, never
trained on; exact flow as the check that the fit is right), the same street with ``--grainy-road``
(asphalt with visible grain), and the real KITTI slices 06 and 07 (no
flow ground truth: the ground-truth poses give the motion). Estimators: DIS (medium, the default of
``deepslam vo``), the shipped learned flow, and the learned flow refined by DIS (``learned-dis``).

Second table, how near the roadside is: on straight driving (yaw < 0.5 deg per frame), the median
learned-flow magnitude per metre of motion in the image's left and right fifths around the horizon
(rows 0.12 fy above to 0.06 fy below the principal point), in pixels at f = 1000 px: larger is a
nearer roadside. Sets: the held-out town and a held-out ``--narrow-layout`` street (seed 7), KITTI
06 and 07. Writes results.json, results.md and road_height.png into ``out/results/road``
(``python -m bench.results_road``, about a minute once the two held-out streets are rendered).
"""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

from bench.results_common import write_report
from deepslam.core import se3
from deepslam.core.plots import new_figure, save_figure
from deepslam.core.readers import open_sequence


@dataclasses.dataclass(frozen=True)
class ResultsRoadConfig:
    """Sizes of the measurement."""

    width: int = 414
    """Rendered width of the held-out street, pixels (the training renders' scale)."""
    heldout_seed: int = 7
    """Town of the held-out street."""
    heldout_frames: int = 120
    """Frames rendered of it."""
    pair_step: int = 2
    """Every pair_step-th consecutive pair is measured."""
    min_motion_m: float = 0.3
    """Pairs that move less are skipped (the road's flow is then too small to read)."""
    estimators: tuple[str, ...] = ("dis", "learned", "learned-dis")
    """Flow estimators measured (registry names)."""


QUICK = ResultsRoadConfig(heldout_frames=16, pair_step=6)


def moving_pairs(seq, cfg: ResultsRoadConfig):
    """``(i, cam1_from_cam0, metres)`` of every ``pair_step``-th consecutive pair (i, i + 1) with ground
    truth at both frames that moves at least ``min_motion_m``."""
    for i in range(0, len(seq) - 1, cfg.pair_step):
        p0, p1 = seq.gt_pose(i), seq.gt_pose(i + 1)
        if p0 is None or p1 is None:
            continue
        motion = se3.inverse(p1) @ p0
        d = float(np.linalg.norm(motion[:3, 3]))
        if d >= cfg.min_motion_m:
            yield i, motion, d


def measure(seq, flows: dict, cfg: ResultsRoadConfig, heights: bool = True, roadside_from: str | None = None):
    """One pass over :func:`moving_pairs`, each flow estimated once per pair: the implied road heights of
    every flow in ``flows`` ({name: i -> (H, W, 2) flow of pair (i, i + 1)}; when ``heights``), and the
    roadside nearness from the flow named ``roadside_from`` on straight pairs (yaw < 0.5 deg): the
    median flow magnitude per metre of motion, px at f = 1000, in the image's left and right fifths
    around the horizon (rows 0.12 fy above to 0.06 fy below the principal point).

    Returns ``(heights per flow, roadside)``: {name: {pairs, median_m, q25_m, q75_m, heights_m}} (empty
    without ``heights``) and {pairs, left_px_per_m, right_px_per_m} (None without ``roadside_from``)."""
    from deepslam.vo.geometry.road_height import implied_road_height

    cam = seq.camera
    v0, v1 = int(cam.cy - 0.12 * cam.fy), int(cam.cy + 0.06 * cam.fy) + 1
    fifth = cam.width // 5
    found: dict[str, list[float]] = {name: [] for name in flows} if heights else {}
    left, right = [], []
    for i, motion, d in moving_pairs(seq, cfg):
        straight = roadside_from is not None and abs(np.degrees(se3.to_euler6(motion[None])[0, 1])) <= 0.5
        for name, flow_of in flows.items():
            side = straight and name == roadside_from
            if not (heights or side):
                continue
            flow = flow_of(i)
            if heights:
                fit = implied_road_height(flow, cam, motion)
                if np.isfinite(fit.height_m):
                    found[name].append(fit.height_m)
            if side:
                mag = np.linalg.norm(flow[v0:v1], axis=-1) * (1000.0 / cam.fx) / d
                left.append(float(np.nanmedian(mag[:, :fifth])))
                right.append(float(np.nanmedian(mag[:, cam.width - fifth:])))
    per_flow = {name: {"pairs": len(h), "median_m": float(np.median(h)) if h else None,
                       "q25_m": float(np.quantile(h, 0.25)) if h else None,
                       "q75_m": float(np.quantile(h, 0.75)) if h else None,
                       "heights_m": [round(float(x), 4) for x in h]} for name, h in found.items()}
    roadside = None if roadside_from is None else {
        "pairs": len(left), "left_px_per_m": float(np.median(left)) if left else None,
        "right_px_per_m": float(np.median(right)) if right else None}
    return per_flow, roadside


def roadside_flow(seq, flow_of, cfg: ResultsRoadConfig) -> dict:
    """The roadside nearness of :func:`measure` from one flow (``flow_of(i)``: the flow of pair (i, i + 1))."""
    return measure(seq, {"flow": flow_of}, cfg, heights=False, roadside_from="flow")[1]


def run(cfg: ResultsRoadConfig, out: Path, data_dir: Path) -> dict:
    from deepslam.flow import registry as flow_registry
    from deepslam.studies.demo import render_once

    out.mkdir(parents=True, exist_ok=True)
    ests = {n: flow_registry.make(n, **({"preset": "medium"} if n == "dis" else {})) for n in cfg.estimators}
    held = open_sequence(render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                                     out / f"street_heldout_s{cfg.heldout_seed}", []))
    grainy = open_sequence(render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                                       out / f"street_grainy_s{cfg.heldout_seed}", [], extra=("--grainy-road",)))
    narrow = open_sequence(render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                                       out / f"street_narrow_s{cfg.heldout_seed}", [], extra=("--narrow-layout", "--no-flow")))
    # (label, sequence, extra flows, whether to fit road heights); the roadside from the learned flow in every set
    sets = [("simulated street, held out (seed 7)", held, {"exact": held.flow}, True),
            ("the same street with --grainy-road", grainy, {"exact": grainy.flow}, True)]
    for name in ("06", "07"):
        root = data_dir / "kitti" / "sequences" / name
        if (root / "calib.txt").is_file():
            sets.append((f"KITTI {name} (real)", open_sequence(root), {}, True))
    sets.append(("simulated narrow street, held out (seed 7)", narrow, {}, False))
    report = {"config": dataclasses.asdict(cfg), "true_height_m": 1.65, "sets": {}, "roadside": {}}
    for label, seq, flows, heights in sets:
        for n, est in ests.items():
            flows[n] = lambda i, seq=seq, est=est: est.pair_flow(seq, i, i + 1)
        side_from = "learned" if "learned" in ests else None
        if not heights:
            flows = {n: f for n, f in flows.items() if n == side_from}
        per_flow, roadside = measure(seq, flows, cfg, heights=heights, roadside_from=side_from)
        if roadside is not None:
            report["roadside"][label] = roadside
        if heights:
            report["sets"][label] = per_flow
            print(f"{label}: " + ", ".join(f"{k} {v['median_m']:.2f} m" for k, v in per_flow.items()
                                           if v["median_m"] is not None), file=sys.stderr)
    write_report(out, report, markdown)
    _plot(report, out / "road_height.png")
    return report


def _plot(report: dict, path: Path) -> None:
    data, labels = [], []
    for label, per in report["sets"].items():
        for name, r in per.items():
            if r["heights_m"]:
                data.append(np.clip(r["heights_m"], 0, 8))
                labels.append(f"{label.split(' (')[0]}\n{name}")
    fig = new_figure((max(6, 1.1 * len(data)), 4))
    ax = fig.subplots()
    ax.boxplot(data, showfliers=False)
    ax.set_xticks(range(1, len(labels) + 1), labels, fontsize=7)
    ax.axhline(report["true_height_m"], color="k", lw=0.8, ls="--")
    ax.set(ylabel="implied camera height above the road [m]", title="road motion shown by each flow (true: 1.65 m)")
    fig.tight_layout()
    save_figure(fig, path, dpi=90)


def markdown(report: dict) -> str:
    lines = ["| frames | flow | pairs | implied road height, median [m] | q25-q75 [m] |", "|---|---|---|---|---|"]
    for label, per in report["sets"].items():
        for name, r in per.items():
            if r["median_m"] is None:
                continue
            lines.append(f"| {label} | {name} | {r['pairs']} | {r['median_m']:.2f} | {r['q25_m']:.2f}-{r['q75_m']:.2f} |")
    text = ("camera height above the road implied by each flow with the true motion (true: "
            f"{report['true_height_m']} m; larger = the flow under-moves the road)\n\n" + "\n".join(lines) + "\n")
    side = report.get("roadside") or {}
    if side:
        rows = ["| frames | straight pairs | left fifth [px per m] | right fifth [px per m] |", "|---|---|---|---|"]
        for label, r in side.items():
            if r["left_px_per_m"] is not None:
                rows.append(f"| {label} | {r['pairs']} | {r['left_px_per_m']:.0f} | {r['right_px_per_m']:.0f} |")
        text += ("\nhow near the roadside is: learned flow per metre of straight motion beside the horizon, "
                 "px at f = 1000 (larger = nearer)\n\n" + "\n".join(rows) + "\n")
    return text


def main(argv: list[str] | None = None) -> int:
    from bench.results_common import results_main

    return results_main("results_road", __doc__, ResultsRoadConfig(), QUICK, "road", run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
