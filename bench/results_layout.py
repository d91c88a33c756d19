"""``python -m bench.results_layout``: where in the image each network takes its distance from, and whether it reads a
scene's mirror image alike.

The recipe's towns keep their car to the right: left of the image's centre lies the open road, on the right the
near kerb, parked cars and facades. A network trained on their single frames (or their pairs) may learn that
layout with the geometry and read the distance from the patch where the towns' road usually is; on a street laid
out otherwise (KITTI 07: cars parked on both sides) the patch holds nearer surfaces, more flow a metre, and the
distance is over-read. On the straight pairs (true yaw under :data:`bench.results_repro.TURN_RAD`) of the held-out
town 7 (camera 0.84 m ahead of the axle, as the lever models trained) and the KITTI 06 and 07 slices, each on DIS
flow as ``deepslam vo`` computes it for the model (:func:`vo.modelfiles.models.flow_for_model`, frames read at
640 px), this reports for each model of :attr:`LayoutConfig.model_names`:

- the forward gain (read against true forward motion, least squares through the origin) of the flow as seen and
  of the same flow mirrored left-right (:func:`vo.attribution.mirror_input`): a network that reads geometry gives
  both alike;
- where the forward reading comes from: integrated gradients of t_z (:func:`vo.attribution.integrated_gradients`)
  per metre of true forward motion, summed over the image's top and bottom halves, the bottom half by thirds
  (left, centre, right), and a figure of the maps.

    python -m bench.results_layout [--models bench/paper_recipe] [--quick]

Writes ``results.json``, ``results.md`` and ``attribution.png`` under ``out/results/layout`` (the flows and each
model's figures are cached there: a killed run resumes; a model whose file changed is scored again).
docs/experiments/2026-12-07_lever_arm_training.md (section 9) reads them.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

from bench.results_common import write_report
from bench.results_repro import TURN_RAD, main_with_models, origin_gain, trained_models
from bench.results_vo import _cached
from deepslam.core import atomic, se3
from deepslam.core.readers import open_sequence


@dataclasses.dataclass(frozen=True)
class LayoutConfig:
    """What is probed and where."""

    models: str = "bench/paper_recipe"
    """Folder of the trained models (``scripts/train_paper_recipe.sh OUT``; relative to the repository)."""
    model_names: tuple[str, ...] = ("synthetic_dis_speedscale_mirror_body_cons_s0",
                                    "lever_synthetic_dis_axlescale_mirror_body_cons_s0",
                                    "lever_synthetic_dis_axlescale_mirror_body_mirrorframes_cons_s0",
                                    "lever_synthetic_dis_axlescale_mirror_body_mirrorframes_cons_s1",
                                    "lever_synthetic_dis_axlescale_mirror_body_mirrorframes_cons_s2",
                                    "lever_supervised_dis_cons_s0", "lever_synthetic_axlescale_mirror_cons_s0",
                                    "lever_supervised_cons_s0")
    """Model folders under :attr:`models` (flow-only networks); absent ones skipped."""
    lever_m: float = 0.84
    """Metres the held-out town's camera sits ahead of the rear axle (KITTI's fit, as the lever models trained)."""
    heldout_seed: int = 7
    """Town of the held-out street (the training towns are 1 and 2)."""
    frames: int = 300
    """Frames of the held-out render (10 Hz)."""
    width: int = 414
    """Rendered width, pixels (the training renders')."""
    steps: int = 32
    """Points of the integrated gradients' path from zero flow."""
    grid: tuple[int, int] = (6, 8)
    """Rows and columns of the attribution grid kept in results.json."""


def straight_pairs(world_from_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The consecutive frame pairs (i, i + 1) whose true yaw (euler y of ``cam_j_from_cam_i``) is at most
    :data:`TURN_RAD` in size, from (N, 4, 4) float64 ``world_from_cam`` (m): (P, 2) int64 pairs and (P, 6) float64
    their true paper vectors (rad, m)."""
    n = len(world_from_cam)
    pairs = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1)
    true6 = se3.to_euler6(se3.relative(world_from_cam[pairs[:, 1]], world_from_cam[pairs[:, 0]])).reshape(-1, 6)
    keep = np.abs(true6[:, 1]) <= TURN_RAD
    return pairs[keep], true6[keep]


def per_metre(attribution: np.ndarray, forward_m: np.ndarray) -> np.ndarray:
    """The (h, w) float64 map of forward reading per metre of true forward motion: ``attribution`` (P, h, w) float64
    (m, each pixel's share of a pair's forward reading, forward positive) divided by ``forward_m`` (P,) float64 (m,
    > 0), averaged over the pairs (unitless: a map summing to 1.0 reads the distance exactly, the reading at zero
    flow aside)."""
    return (np.asarray(attribution, dtype=np.float64) / np.asarray(forward_m, dtype=np.float64)[:, None, None]).mean(0)


def attribution_split(per_m: np.ndarray) -> dict:
    """Where a forward reading comes from: the (h, w) map of :func:`per_metre` summed over the image's top half and
    over the bottom half's left, centre and right thirds (:func:`vo.attribution.region_sums`)."""
    from deepslam.vo.attribution import region_sums  # deferred: torch loads only when a model is probed

    h = per_m.shape[0]
    left, centre, right = region_sums(per_m[None, h // 2:], 1, 3)[0, 0]
    return {"top": float(per_m[: h // 2].sum()), "bottom_left": float(left), "bottom_centre": float(centre),
            "bottom_right": float(right)}


def _case_flows(out: Path, case: str, seq_dir: Path, model: Path) -> dict:
    """The network inputs of ``seq_dir``'s straight pairs as ``deepslam vo`` makes them for ``model`` (DIS, the
    model's recorded options, frames read at 640 px), cached per estimator set-up and input size."""
    from deepslam.vo.data.prefetch import PairInputs, model_input  # deferred: torch and the flow workers
    from deepslam.vo.modelfiles import models
    from deepslam.vo.pipeline import VOConfig, read_view

    h, w, unknown = model_input(model)
    options = models.recorded_flow_options(model, "dis")
    key = json.dumps({"options": options, "input": [h, w, unknown]}, sort_keys=True)
    cache = out / "flows" / f"{case}_{hashlib.sha256(key.encode()).hexdigest()[:12]}.npz"
    seq = open_sequence(seq_dir)
    pairs, true6 = straight_pairs(seq.gt.world_from_cam)
    if cache.is_file():
        with np.load(cache) as z:
            if str(z["key"]) == key and np.array_equal(z["pairs"], pairs):
                return {"flow": z["flow"], "intrinsics": z["intrinsics"], "true6": true6}
    view = read_view(seq, VOConfig.read_width_px, model, "dis")
    flow = np.zeros((len(pairs), 2, h, w), np.float32)
    intr = np.zeros((len(pairs), 4), np.float32)
    with PairInputs(view, pairs, models.flow_for_model("dis", model, options), w, h, unknown=unknown) as inputs:
        for k, (f, i) in enumerate(inputs):
            flow[k], intr[k] = f, i
    with atomic.atomic_path(cache) as tmp:
        np.savez(tmp, flow=flow, intrinsics=intr, pairs=pairs, key=np.array(key))
    return {"flow": flow, "intrinsics": intr, "true6": true6}


@functools.lru_cache(maxsize=1)  # the model being probed, loaded once for all its cases
def _network(model_file: Path):
    from deepslam.vo.modelfiles.modelio import load_model  # deferred: torch loads only when a model is probed

    return load_model(model_file)[0].eval()


def probe(model_file: Path, flows: dict, steps: int, grid: tuple[int, int]) -> tuple[dict, np.ndarray]:
    """One model on one case's straight pairs: forward gains as seen and mirrored, the attribution split
    (:func:`attribution_split`) and its grid; and the (h, w) float64 map of forward reading per metre."""
    import torch  # deferred: torch loads only when a model is probed

    from deepslam.vo.attribution import integrated_gradients, mirror_input, region_sums

    net = _network(model_file)
    flow, intr, true6 = flows["flow"], flows["intrinsics"], flows["true6"]
    forward = -true6[:, 5]  # cam_j_from_cam_i moves the scene back (t_z < 0) as the camera drives forward

    def read(f, k):
        with torch.no_grad():
            return -net(torch.from_numpy(f), torch.from_numpy(k), None)[0][:, 5].double().numpy()

    attr, at_zero = integrated_gradients(net, flow, intr, output=5, steps=steps)
    attr, at_zero = -attr, -at_zero  # forward positive
    per_m = per_metre(attr, forward)
    rec = {"pairs": int(len(forward)), "true_forward_m": float(forward.mean()),
           "gain": origin_gain(read(flow, intr), forward), "gain_mirrored": origin_gain(read(*mirror_input(flow, intr)), forward),
           "at_zero_per_m": float((at_zero / forward).mean()), **attribution_split(per_m),
           "grid_per_m": region_sums(per_m[None], *grid)[0].round(4).tolist()}
    return rec, per_m


def run(cfg: LayoutConfig, out: Path, data: Path) -> dict:
    from deepslam.studies.demo import render_once

    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    log: list[str] = []
    town = render_once("street", "car", cfg.frames, cfg.width, cfg.heldout_seed, out / f"street_s{cfg.heldout_seed}_lever",
                       log, ("--camera-ahead", f"{cfg.lever_m:g}", "--no-flow", "--quiet"))
    kitti = data / "kitti" / "sequences"
    cases = [("town", town)] + [(f"kitti{n}", kitti / n) for n in ("07", "06") if (kitti / n).is_dir()]
    rows: dict = {}
    maps: dict = {}
    for name, model in trained_models(out, cfg.models, cfg.model_names):
        rows[name] = {"file": str(model)}
        for case, seq_dir in cases:
            print(f"probe {name}: {case}", flush=True)
            map_file = out / "eval" / f"{name}_{case}.map.npy"

            def work():
                rec, per_m = probe(model, _case_flows(out, case, seq_dir, model), cfg.steps, cfg.grid)
                atomic.write_npy(map_file, per_m)
                return rec

            rows[name][case] = _cached(out / "eval" / f"{name}_{case}.json", work)
            maps[(name, case)] = np.load(map_file) if map_file.is_file() else None
    figure = _figure(out / "attribution.png", rows, maps, [c for c, _ in cases])
    report = {"config": dataclasses.asdict(cfg), "cases": [c for c, _ in cases], "models": rows,
              "figure": figure, "renders": log, "minutes": (time.perf_counter() - t0) / 60}
    write_report(out, report, markdown)
    return report


def _figure(path: Path, rows: dict, maps: dict, cases: list[str]) -> str | None:
    """The maps of forward reading per metre, a model a row and a case a column, into ``path``; its name, or None
    when no map is on disk."""
    if not any(m is not None for m in maps.values()):
        return None
    import matplotlib  # deferred: plotting only here

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(rows)
    fig, axes = plt.subplots(len(names), len(cases), figsize=(4.2 * len(cases), 1.6 * len(names) + 0.4), squeeze=False)
    top = max(float(np.abs(m).max()) for m in maps.values() if m is not None)
    for r, name in enumerate(names):
        for c, case in enumerate(cases):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            m = maps.get((name, case))
            if m is not None:
                ax.imshow(m, cmap="RdBu_r", vmin=-top, vmax=top)
                rec = rows[name][case]
                ax.set_title(f"{case}: gain x{rec['gain']:.2f}, mirrored x{rec['gain_mirrored']:.2f}", fontsize=8)
            if c == 0:
                ax.set_ylabel(name.replace("_cons_s0", "").replace("_", "\n", 2), fontsize=6)
    fig.suptitle("Where the forward reading comes from: integrated gradients of t_z per metre of forward motion "
                 "(red: adds distance)", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path.name


CASE_TITLES = {"town": "town 7 (camera {lever_m:g} m ahead of the axle)", "kitti07": "KITTI 07", "kitti06": "KITTI 06"}


def _f(x, spec: str = ".3f") -> str:
    return "n/a" if x is None else format(x, spec)


def markdown(report: dict) -> str:
    cfg = report["config"]
    cases = report["cases"]
    titles = [CASE_TITLES[c].format(**cfg) for c in cases]
    md = ["Straight pairs (true yaw under 0.57 deg a frame) on DIS flow as `deepslam vo` computes it; each model's "
          "forward gain (read against true, least squares; 1.00 reads the distance) of the flow as seen and "
          "mirrored left-right. A network that reads the scene's geometry reads both alike.", "",
          "| forward gain: as seen / mirrored | " + " | ".join(titles) + " |", "|---" * (len(cases) + 1) + "|"]
    for name, rec in report["models"].items():
        md.append(f"| {name} | " + " | ".join(
            f"x{_f(rec[c]['gain'])} / x{_f(rec[c]['gain_mirrored'])}" for c in cases) + " |")
    md += ["", "Where the forward reading comes from (integrated gradients of t_z from zero flow, per metre of true "
           "forward motion, summed over the image's top half and the bottom half's left, centre and right thirds; "
           "with the reading at zero flow they add up to the gain):", "",
           "| top / bottom left / bottom centre / bottom right | " + " | ".join(titles) + " |",
           "|---" * (len(cases) + 1) + "|"]
    for name, rec in report["models"].items():
        md.append(f"| {name} | " + " | ".join(
            " / ".join(_f(rec[c][k], ".2f") for k in ("top", "bottom_left", "bottom_centre", "bottom_right"))
            for c in cases) + " |")
    md.append("")
    if report.get("figure"):
        md += [f"![where each model reads the distance from]({report['figure']})", ""]
    first = next(iter(report["models"].values()), {})
    md += ["Straight pairs: " + ", ".join(f"{t} {first[c]['pairs']} ({first[c]['true_forward_m']:.2f} m a pair)"
                                         for c, t in zip(cases, titles) if c in first) + ".",
           "", "Renders: " + "; ".join(f"`{c}`" for c in report["renders"]), "", f"Run time: {report['minutes']:.1f} min."]
    return "\n".join(md) + "\n"


def main(argv: list[str] | None = None) -> int:
    return main_with_models("results_layout", __doc__, LayoutConfig(), lambda cfg: dataclasses.replace(
        cfg, frames=40, width=207, steps=4), "layout", run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
