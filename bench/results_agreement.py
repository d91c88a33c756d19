"""Does the simulator predict reality? The same odometry variants on simulated streets and on real KITTI, side by side.

For each variant of the KITTI-camera odometry (the shipped default and the alternatives a user can pick:
the network's own pose, another flow, another model), ``deepslam vo`` runs end to end (flow between the
frames, the network, the chained trajectory) on

- simulated streets no model was trained on (the default KITTI-look street, seeds ``sim_seeds``, rendered
  at 10 Hz for ``sim_frames`` frames: residential streets at up to 10 m/s, stops, then the avenue up to
  about 30 m/s), and
- the real KITTI 06 and 07 slices in ../shared/data (06's single frames were in the shipped models'
  training, without poses; 07's were not; both have informed decisions: validation data),

at frame strides 1, 2 and 3 (10, 5 and 3.33 Hz: a stride k reads k times the motion per pair, as at k
times the speed). Per row: the path-length ratio (estimate / truth, SE3-aligned; 1 = distance read right)
and the end-point drift (% of the path); at a stride k, each the mean over the k start frames 0..k-1 (which
frames a strided run keeps moves the default's drift by 0.5-11 %, more than most variants move it:
bench/criteria/2026-12-05_phase_averaged_rows.md). Per variant, its mean ``|ratio - 1|`` on the simulated and on the
real rows, and over the variants the rank agreement (Spearman's rho) of the two: the simulator is a good
stand-in when its ranking of methods predicts the real ranking. Also the DIS flow's end-point error against
the simulator's exact flow at each stride (how hard the flow is; real slices have no reference flow).

Writes results.json and results.md into ``out/results/agreement``
(``python -m bench.results_agreement [--quick]``, about 35 minutes on 2 cores). Each row is also appended to
``rows.jsonl`` there as it is measured: a killed run started again at the same commit (no uncommitted
changes) reuses the rows measured with the same variant, data, stride and sizes.
"""
from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from bench.results_common import results_main, write_report
from bench.stamp import stamp
from deepslam.core.readers import open_sequence


@dataclasses.dataclass(frozen=True)
class ResultsAgreementConfig:
    """Sizes of the comparison."""

    sim_seeds: tuple[int, ...] = (901, 902, 903, 904, 906, 907, 908)
    """Towns of the simulated streets (no model was trained on them; 901-904 informed or saw road-scale
    decisions; 906 and 907 were rendered after road-scale decisions and are reported, never deciding, in the
    rules since (906 from the image road scale, 907 from the turn rule of bench/criteria/2026-12-05_road_turns.md):
    seen, but no default was chosen on them; 908 was first rendered after the road-gaps rule of
    bench/criteria/2026-12-05_road_gaps.md was decided: unseen by every decision)."""
    sim_frames: int = 360
    """Frames per simulated street (10 Hz; 360: the residential block, a stop and the avenue at full speed)."""
    width: int = 620
    """Rendered width, pixels (the KITTI camera at half size)."""
    strides: tuple[int, ...] = (1, 2, 3)
    """Frame strides scored."""
    every_start: bool = True
    """At a stride k, average each row over the runs from start frames 0..k-1 (False: start frame 0 only)."""
    variants: tuple[tuple[str, tuple[str, ...]], ...] = (
        ("default (kitti_cons_dis: DIS, epipolar pose, road scale)", ()),
        ("road from the flow only (--scale road-flow)", ("--scale", "road-flow")),
        ("network distance (--scale network)", ("--scale", "network")),
        ("network pose (--pose net)", ("--pose", "net")),
        ("DIS patch stride 4, network distance", ("--dis-patch-stride", "4", "--scale", "network")),
        ("learned flow, network distance", ("--flow", "learned", "--scale", "network")),
        ("exact-flow model (kitti_cons)", ("--model", "{models}/kitti_cons.safetensors")),
    )
    """(name, extra ``deepslam vo`` arguments) of each variant; ``{models}`` is the shipped models' folder."""
    real: tuple[str, ...] = ("06", "07")
    """KITTI slices of ../shared/data/kitti/sequences."""


QUICK = ResultsAgreementConfig(sim_seeds=(901,), sim_frames=16, width=320, strides=(1, 2),
                               variants=ResultsAgreementConfig.variants[:3:2], real=("07",))


def _vo(seq: Path, stride: int, extra: tuple[str, ...], out: Path, start: int = 0) -> dict:
    """``deepslam vo`` on ``seq`` at ``stride`` from frame ``start``; its metrics (path_length_ratio,
    endpoint_drift_pct, ...)."""
    from deepslam.cli import main

    traj = out / "t.txt"
    rc = main(["vo", "--sequence", str(seq), "--stride", str(stride), "--start", str(start), "--out", str(traj),
               "--quiet", *extra])
    if rc != 0:
        raise RuntimeError(f"deepslam vo failed on {seq} (stride {stride}, {' '.join(extra)})")
    return json.loads((out / "t.metrics.json").read_text())


def _dis_epe(seq_dir: Path, stride: int, pairs: int = 8) -> float:
    """Mean end-point error (px) of DIS medium against the exact flow of frame pairs ``stride`` apart, over
    the pixels whose exact flow lands inside the second image (as KITTI's flow benchmark labels: a point
    that leaves the view, a parked car beside the camera at speed, has no flow to find)."""
    from deepslam.flow.estimators import DISFlow, exact_pair_flow
    from deepslam.flow.metrics import endpoint_error

    seq = open_sequence(seq_dir)
    dis = DISFlow("medium")
    firsts = np.unique(np.linspace(0, len(seq) - 1 - stride, pairs).astype(int))
    h, w = seq.camera.height, seq.camera.width
    v, u = np.mgrid[0:h, 0:w]

    def in_view(flow: np.ndarray) -> np.ndarray:
        x, y = u + flow[..., 0], v + flow[..., 1]
        inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
        return np.where(inside[..., None], flow, np.nan)

    return float(np.mean([endpoint_error(dis.pair_flow(seq, int(i), int(i) + stride),
                                         in_view(exact_pair_flow(seq, int(i), int(i) + stride)))["epe"]
                          for i in firsts]))


def _measured_rows(path: Path) -> dict:
    """Rows an earlier run appended to ``rows.jsonl``, by key (a line cut short by a kill is skipped)."""
    done = {}
    if path.is_file():
        for line in path.read_text().splitlines():
            try:
                rec = json.loads(line)
                done[rec["key"]] = rec["row"]
            except (ValueError, KeyError, TypeError):
                continue
    return done


def run(cfg: ResultsAgreementConfig, out: Path, data_dir: Path) -> dict:
    from deepslam.models import models_dir
    from deepslam.studies.demo import render_once

    out.mkdir(parents=True, exist_ok=True)
    log: list[str] = []
    sets: dict[str, tuple[str, Path]] = {}
    for s in cfg.sim_seeds:
        sets[f"sim street {s}"] = ("sim", render_once("street", "car", cfg.sim_frames, cfg.width, s, out / f"street_s{s}",
                                                      log))
    for k in cfg.real:
        d = data_dir / "kitti" / "sequences" / k
        if (d / "calib.txt").is_file():
            sets[f"KITTI {k}"] = ("real", d)
    rows = []
    done = _measured_rows(out / "rows.jsonl")
    commit = stamp()["commit"]
    with tempfile.TemporaryDirectory(prefix="agreement-") as tmp:
        for name, extra_spec in cfg.variants:
            extra = tuple(a.replace("{models}", str(models_dir())) for a in extra_spec)
            for set_name, (side, seq) in sets.items():
                for k in cfg.strides:
                    starts = list(range(k)) if cfg.every_start else [0]
                    key = json.dumps([commit, list(extra_spec), set_name, k, starts, cfg.sim_frames, cfg.width])
                    if key in done and not commit.endswith("-dirty"):
                        rows.append({**done[key], "variant": name})
                        continue
                    runs = []
                    for start in starts:
                        work = Path(tmp) / f"{len(rows)}_{start}"
                        work.mkdir()
                        m = _vo(seq, k, extra, work, start)
                        runs.append({"start": start, "path_ratio": m.get("path_length_ratio"),
                                     "drift_pct": m.get("endpoint_drift_pct"), "ate_m": m.get("ate_m")})
                    rows.append({"variant": name, "data": set_name, "side": side, "stride": k,
                                 **{f: float(np.mean([r[f] for r in runs])) for f in ("path_ratio", "drift_pct", "ate_m")},
                                 "per_start": runs})
                    with open(out / "rows.jsonl", "a") as f:
                        f.write(json.dumps({"key": key, "row": rows[-1]}) + "\n")
                    print(f"{name} | {set_name} stride {k}: x{rows[-1]['path_ratio']:.3f}, drift "
                          f"{rows[-1]['drift_pct']:.1f} %", flush=True)
    summary = {}
    for name, _ in cfg.variants:
        dev = {side: [abs(r["path_ratio"] - 1) for r in rows if r["variant"] == name and r["side"] == side]
               for side in ("sim", "real")}
        summary[name] = {f"{side}_mean_abs_dev": float(np.mean(v)) if v else None for side, v in dev.items()}
    sims = [summary[n]["sim_mean_abs_dev"] for n, _ in cfg.variants]
    reals = [summary[n]["real_mean_abs_dev"] for n, _ in cfg.variants]
    rho = None
    if len(cfg.variants) > 2 and None not in sims + reals:
        rho = float(spearmanr(sims, reals).statistic)
    epe = {f"{set_name} stride {k}": _dis_epe(seq, k) for set_name, (side, seq) in sets.items() if side == "sim"
           for k in cfg.strides}
    report = {"config": dataclasses.asdict(cfg), "rows": rows, "summary": summary, "spearman_rho": rho,
              "dis_epe_px": epe,
              "seen": {"KITTI 06": "single frames in the shipped KITTI models' training (no poses); validation data",
                       "KITTI 07": "never trained on; has informed decisions: validation data",
                       "sim streets": "KITTI-look streets no model was trained on; 901-904 informed or were "
                                      "seen before road-scale decisions (validation); 906 and 907 rendered after "
                                      "road-scale decisions, reported but never deciding since; 908 rendered "
                                      "after the last road-scale decision (unseen)"}}
    write_report(out, report, markdown)
    return report


def markdown(report: dict) -> str:
    cfg = report["config"]
    sets = list(dict.fromkeys(r["data"] for r in report["rows"]))
    head = "| variant | " + " | ".join(f"{s} x{k}" for s in sets for k in cfg["strides"]) + " | sim mean abs(ratio-1) | real mean abs(ratio-1) |"
    lines = ["path-length ratio (estimate / truth) and end-point drift %, by data and frame stride (x1 = 10 Hz)"
             + ("; at a stride k, the mean over the runs from start frames 0..k-1" if cfg.get("every_start") else
                "; from start frame 0"), "",
             head, "|---|" + "---|" * (len(sets) * len(cfg["strides"]) + 2)]
    for name, _ in cfg["variants"]:
        cells = []
        for s in sets:
            for k in cfg["strides"]:
                r = next(r for r in report["rows"] if r["variant"] == name and r["data"] == s and r["stride"] == k)
                cells.append(f"{r['path_ratio']:.3f} / {r['drift_pct']:.1f} %")
        sm = report["summary"][name]
        fmt = lambda v: "" if v is None else f"{v:.3f}"  # noqa: E731
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {fmt(sm['sim_mean_abs_dev'])} | {fmt(sm['real_mean_abs_dev'])} |")
    rho = report["spearman_rho"]
    lines += ["", "Rank agreement of the variants, simulated against real (Spearman's rho of mean abs(ratio - 1)): "
              + ("n/a (fewer than 3 variants)" if rho is None else f"{rho:.2f}"), "",
              "DIS medium's end-point error against the exact flow (pixels that stay in view) on the simulated streets: "
              + ", ".join(f"{k} {v:.2f} px" for k, v in report["dis_epe_px"].items()), "",
              "What each real slice is: " + "; ".join(f"{k}: {v}" for k, v in report["seen"].items()) + "."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    return results_main("results_agreement", __doc__, ResultsAgreementConfig(), QUICK, "agreement", run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
