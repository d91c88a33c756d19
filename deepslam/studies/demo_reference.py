"""Scoring of the published reference trajectories of ../shared/data/reference with this project's
metrics: a table, top-down plots and the KITTI per-length errors. ``make demo`` (deepslam/studies/demo.py)
includes it as the metrics cross-check; ``python -m deepslam.studies.demo_reference`` runs it alone.

Pairs: ORB-SLAM2 and S-PTAM (stereo) on KITTI 00 against the official poses (the published
ORB-SLAM2 figures are t_err 0.70 %, r_err 0.25 deg/100 m); an estimate on EuRoC V1_02 (TUM, seconds)
against the ASL ground truth (ns), which needs timestamp association; OpenVINS on EuRoC V1_01.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from deepslam.core import atomic, metrics, plots
from deepslam.core.errors import InputError
from deepslam.core.paths import out_dir, shared_data_dir
from deepslam.core.trajio import read_trajectory_and_format

PAIRS = (
    # (name, ground truth, estimate, alignment)
    ("KITTI 00 ORB-SLAM2", "kitti/poses/00.txt", "reference/KITTI_00_ORB.txt", "se3"),
    ("KITTI 00 S-PTAM", "kitti/poses/00.txt", "reference/KITTI_00_SPTAM.txt", "se3"),
    ("EuRoC V1_02 (evo's V102)", "reference/V102_groundtruth.csv", "reference/V102.txt", "se3"),
    ("EuRoC V1_01 OpenVINS", "reference/V101_gt.txt", "reference/V101_openvins.txt", "se3"),
)


def _fmt(x, spec=".3f") -> str:
    return "-" if x is None else format(x, spec)


def run(data: Path, out: Path) -> int:
    rows, results = [], {}
    for name, gt_rel, est_rel, align in PAIRS:
        gt, gt_fmt = read_trajectory_and_format(data / gt_rel)
        est, est_fmt = read_trajectory_and_format(data / est_rel)
        t0 = time.perf_counter()
        r = metrics.evaluate(gt, est, align=align, gt_path=data / gt_rel, est_path=data / est_rel)
        r["seconds"] = time.perf_counter() - t0
        r["gt_format"], r["est_format"] = gt_fmt, est_fmt
        results[name] = r
        rows.append((name, align, r["n_matched"], r["ate_m"], r["rpe_t_m"], r["rpe_r_deg"],
                     r.get("kitti_t_err_pct"), r.get("kitti_r_err_deg_per_100m")))

    header = ("trajectory", "align", "matched", "ATE [m]", "RPE t [m]", "RPE r [deg]", "t_err [%]", "r_err [deg/100m]")
    table = [header] + [(n, a, str(m), _fmt(ate), _fmt(rt, ".4f"), _fmt(rr, ".4f"), _fmt(te), _fmt(re))
                        for n, a, m, ate, rt, rr, te, re in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(header))]
    text = "\n".join("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(row, widths)))
                     for row in table)
    print(text)

    out.mkdir(parents=True, exist_ok=True)
    kitti = [n for n in results if n.startswith("KITTI")]
    first = results[kitti[0]]
    traj_plots = {"ground truth (poses/00.txt)": first["_gt_poses"][:, :3, 3]}
    traj_plots.update({n: results[n]["_est_aligned_poses"][:, :3, 3] for n in kitti})
    plots.plot_trajectories_topdown(out / "kitti00_topdown.png", traj_plots, title="KITTI 00, se3-aligned")
    plots.plot_kitti_per_length(out / "kitti00_per_length.png", {n: results[n]["kitti_per_length"] for n in kitti},
                                title="KITTI 00: error per segment length (devkit definition)")
    v102 = results["EuRoC V1_02 (evo's V102)"]
    plots.plot_trajectories_topdown(out / "euroc_v102_topdown.png",
                                    {"ground truth (ASL csv)": v102["_gt_poses"][:, :3, 3],
                                     "estimate V102.txt": v102["_est_aligned_poses"][:, :3, 3]},
                                    title="EuRoC V1_02, se3-aligned")

    md = ["# deepslam demo: reference trajectories scored with deepslam's metrics", "",
          f"Data: `{data}`. ATE = RMSE of position error after se3 (Umeyama) alignment; RPE over 1 frame "
          "(evo's definition); KITTI t_err/r_err exactly as the devkit's evaluate_odometry.cpp "
          "(segments 100..800 m every 10 frames; shown where the ground truth is longer than 100 m).", "",
          "| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    md += ["| " + " | ".join(row) + " |" for row in table[1:]]
    md += ["", "Published ORB-SLAM2 stereo on KITTI 00: t_err 0.70 %, r_err 0.25 deg/100 m.", "",
           "## KITTI 00 per segment length", "",
           "| trajectory | length [m] | segments | t_err [%] | r_err [deg/100m] |", "|---|---|---|---|---|"]
    for n in kitti:
        for pl in results[n]["kitti_per_length"]:
            md.append(f"| {n} | {pl['length_m']:.0f} | {pl['n_segments']} | {pl['t_err_pct']:.3f} | "
                      f"{pl['r_err_deg_per_100m']:.3f} |")
    md += ["", "![KITTI 00 top-down](kitti00_topdown.png)", "", "![KITTI 00 per length](kitti00_per_length.png)", "",
           "![EuRoC V1_02 top-down](euroc_v102_topdown.png)", "",
           "## Inputs", ""]
    for name, gt_rel, est_rel, align in PAIRS:
        r = results[name]
        md.append(f"- {name}: `{gt_rel}` ({r['gt_format']}, {r['n_gt']} poses) vs `{est_rel}` ({r['est_format']}, "
                  f"{r['n_est']} poses), {r['n_matched']} matched by {r['matched_by']}, {r['seconds'] * 1000:.0f} ms")
    report = out / "reference.md"
    atomic.write_text(report, "\n".join(md) + "\n")
    print(f"\nreport: {report}")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m deepslam.studies.demo_reference", description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=None, help="shared data folder (default: ../shared/data)")
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: out/demo)")
    args = ap.parse_args(argv)
    data = args.data or shared_data_dir()
    out = args.out or out_dir() / "demo"
    try:
        if not (data / "reference").is_dir():
            raise InputError(data, "real data not found (expected ../shared/data/reference beside the repository; "
                             "set DEEPSLAM_SHARED_DATA or --data)")
        return run(data, out)
    except InputError as e:
        print(f"deepslam demo: error: {e.message()}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
