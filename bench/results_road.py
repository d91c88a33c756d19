"""Which flow shows the road's motion? The camera height each flow estimator implies for the road.

For consecutive frame pairs that move at least 0.3 m, :func:`deepslam.vo.road_scale.implied_road_height`
fits the road plane in front of the car to the flow with the TRUE motion: an estimator that moves the
road as far as it really moves gives the camera's height (1.65 m, in the simulated street and on
KITTI); one that under-moves it a larger height. Sets: a held-out simulated street (seed 7, never
trained on; exact flow as the check that the fit is right), and the real KITTI slices 06 and 07 (no
flow ground truth: the ground-truth poses give the motion). Estimators: DIS (medium, the default of
``deepslam vo``) and the shipped learned flow.

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
    estimators: tuple[str, ...] = ("dis", "learned")
    """Flow estimators measured (registry names)."""


QUICK = ResultsRoadConfig(heldout_frames=16, pair_step=6)


def _heights(seq, flows: dict, cfg: ResultsRoadConfig) -> dict:
    from deepslam.core import se3
    from deepslam.vo.road_scale import implied_road_height

    out = {name: [] for name in flows}
    for i in range(0, len(seq) - 1, cfg.pair_step):
        p0, p1 = seq.gt_pose(i), seq.gt_pose(i + 1)
        if p0 is None or p1 is None:
            continue
        motion = se3.inverse(p1) @ p0
        if np.linalg.norm(motion[:3, 3]) < cfg.min_motion_m:
            continue
        for name, flow_of in flows.items():
            fit = implied_road_height(flow_of(i), seq.camera, motion)
            if np.isfinite(fit.height_m):
                out[name].append(fit.height_m)
    return {name: {"pairs": len(h), "median_m": float(np.median(h)) if h else None,
                   "q25_m": float(np.quantile(h, 0.25)) if h else None, "q75_m": float(np.quantile(h, 0.75)) if h else None,
                   "heights_m": [round(float(x), 4) for x in h]} for name, h in out.items()}


def roadside_flow(seq, flow_of, cfg: ResultsRoadConfig) -> dict:
    """Median flow per metre of straight motion in the left and right fifths around the horizon."""
    from deepslam.core import se3

    cam = seq.camera
    v0, v1 = int(cam.cy - 0.12 * cam.fy), int(cam.cy + 0.06 * cam.fy) + 1
    w = cam.width
    left, right = [], []
    for i in range(0, len(seq) - 1, cfg.pair_step):
        p0, p1 = seq.gt_pose(i), seq.gt_pose(i + 1)
        if p0 is None or p1 is None:
            continue
        motion = se3.inverse(p1) @ p0
        d = float(np.linalg.norm(motion[:3, 3]))
        if d < cfg.min_motion_m or abs(np.degrees(se3.to_euler6(motion[None])[0, 1])) > 0.5:
            continue
        mag = np.linalg.norm(flow_of(i)[v0:v1], axis=-1) * (1000.0 / cam.fx) / d
        left.append(float(np.nanmedian(mag[:, : w // 5])))
        right.append(float(np.nanmedian(mag[:, w - w // 5:])))
    return {"pairs": len(left), "left_px_per_m": float(np.median(left)) if left else None,
            "right_px_per_m": float(np.median(right)) if right else None}


def run(cfg: ResultsRoadConfig, out: Path, data_dir: Path) -> dict:
    from deepslam.core import atomic
    from deepslam.core.readers import open_sequence
    from deepslam.studies.demo import render_once
    from deepslam.vo import flow_estimators

    out.mkdir(parents=True, exist_ok=True)
    ests = {n: flow_estimators.make(n, **({"preset": "medium"} if n == "dis" else {})) for n in cfg.estimators}
    held = open_sequence(render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                                     out / f"street_heldout_s{cfg.heldout_seed}", []))
    sets = {"simulated street, held out (seed 7)": (held, {"exact": held.flow})}
    for name in ("06", "07"):
        root = data_dir / "kitti" / "sequences" / name
        if (root / "calib.txt").is_file():
            sets[f"KITTI {name} (real)"] = (open_sequence(root), {})
    narrow = open_sequence(render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                                       out / f"street_narrow_s{cfg.heldout_seed}", [], extra=("--narrow-layout", "--no-flow")))
    report = {"config": dataclasses.asdict(cfg), "true_height_m": 1.65, "sets": {}, "roadside": {}}
    for label, (seq, flows) in [*sets.items(), ("simulated narrow street, held out (seed 7)", (narrow, None))]:
        cache: dict = {}

        def flow_of(i, seq=seq, cache=cache, est=ests.get("learned")):
            if i not in cache:
                cache[i] = est.pair_flow(seq, i, i + 1)
            return cache[i]

        if "learned" in ests:
            report["roadside"][label] = roadside_flow(seq, flow_of, cfg)
        if flows is None:
            continue
        for n, est in ests.items():
            flows[n] = flow_of if n == "learned" else (lambda i, seq=seq, est=est: est.pair_flow(seq, i, i + 1))
        report["sets"][label] = _heights(seq, flows, cfg)
        print(f"{label}: " + ", ".join(f"{k} {v['median_m']:.2f} m" for k, v in report["sets"][label].items()
                                       if v["median_m"] is not None), file=sys.stderr)
    atomic.write_json(out / "results.json", report)
    atomic.write_text(out / "results.md", markdown(report))
    _plot(report, out / "road_height.png")
    return report


def _plot(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from deepslam.core import atomic

    data, labels = [], []
    for label, per in report["sets"].items():
        for name, r in per.items():
            if r["heights_m"]:
                data.append(np.clip(r["heights_m"], 0, 8))
                labels.append(f"{label.split(' (')[0]}\n{name}")
    fig, ax = plt.subplots(figsize=(max(6, 1.1 * len(data)), 4))
    ax.boxplot(data, showfliers=False)
    ax.set_xticks(range(1, len(labels) + 1), labels, fontsize=7)
    ax.axhline(report["true_height_m"], color="k", lw=0.8, ls="--")
    ax.set(ylabel="implied camera height above the road [m]", title="road motion shown by each flow (true: 1.65 m)")
    fig.tight_layout()
    with atomic.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


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
