"""What ``deepslam slam`` reports of a run: its JSON record (parameters, configuration, loops, timings and, with
ground truth, the metrics of the odometry and of SLAM, split inside and outside the closed cycles, beside the
same graph with perfect loops), the series of its top-down plot and the text report.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

from deepslam.core import metrics
from deepslam.slam.posegraph import loop_coverage
from deepslam.slam.reference import loops_by_direction, perfect_loops_record


def slam_record(seq, sequence, res, config, odo_cons, odo_loops, out, vo_path, fmt: str,
                align: str) -> tuple[dict, dict]:
    """(record, aligned) of a :func:`slam.pipeline.run_slam` result ``res`` on ``seq`` (read from folder
    ``sequence``) with ``config`` (:class:`slam.pipeline.PipelineConfig`): ``out`` / ``vo_path`` the trajectories written in format ``fmt``,
    ``align`` the alignment before ATE / RPE. ``aligned`` holds, with ground truth, the (N, 4, 4) float64 poses
    ``gt``, ``vo`` and ``slam`` in the ground truth's world frame, metres (empty without)."""
    in_cycles = loop_coverage(len(seq), res.loops.pairs)    # the frames loop edges constrain
    record = {
        "sequence": str(Path(sequence).resolve()), "frames": len(seq), "trajectory": str(out),
        "trajectory_vo": str(vo_path),
        "format": fmt, "odometry_cons": odo_cons.name, "odometry_loops": getattr(odo_loops, "name", None),
        "params": res.params.to_dict(),
        "config": {**config.to_dict(), "reloc": dataclasses.asdict(res.reloc) if res.reloc else None},
        "loops": res.loops.pairs.tolist(), "n_loops": len(res.loops),
        "loops_not_rigid": res.loops_not_rigid.tolist(),
        "frames_in_closed_cycles": int(in_cycles.sum()),
        "loops_kept_by_pose_graph": None if res.loop_inliers is None else res.loop_inliers.tolist(),
        "flow_cons": getattr(getattr(odo_cons, "flow_estimator", None), "name", None),
        "flow_loops": getattr(getattr(odo_loops, "flow_estimator", None), "name", None),
        "n_candidates": len(res.candidates),
        "n_verified_ok": int(sum(c.verification.accepted for c in res.candidates)),
        "timings": res.timings, "graph_error": list(res.graph_error),
    }
    aligned: dict = {}
    if seq.gt is not None:
        for name, traj in (("vo", res.vo), ("slam", res.slam)):
            ev = metrics.evaluate(seq.gt, traj, align=align)
            record[f"metrics_{name}"] = {k: v for k, v in ev.items() if not k.startswith("_")}
            # the same ATE over the frames inside a closed cycle (what loop edges constrain) and the others
            inside, elsewhere = metrics.ate_parts(ev["_gt_poses"], ev["_est_aligned_poses"], in_cycles[ev["_est_index"]])
            record[f"metrics_{name}"].update(ate_in_closed_cycles_m=inside, ate_elsewhere_m=elsewhere)
            aligned[name] = ev["_est_aligned_poses"]
            aligned["gt"] = ev["_gt_poses"]
        # the same graph with an exact loop edge on every revisit: what loop closure gives on this route
        graph = dataclasses.replace(config.graph, c_s=res.params.c_s, c_r=res.params.c_r)
        perfect = perfect_loops_record(seq, res.cons, res.params.t_loop, graph, align)
        if perfect is not None:
            record["metrics_perfect_loops"] = perfect
            record["loops_by_direction"] = loops_by_direction(seq.gt.world_from_cam, res.loops.pairs)
    return record, aligned


def plot_series(seq, record: dict, aligned: dict, res, align: str) -> tuple[dict, str]:
    """(series, title) of the run's top-down plot (:func:`core.plots.plot_trajectories_topdown`): ground truth,
    VO and SLAM aligned as the metrics were (``aligned`` of :func:`slam_record`), or SLAM and VO as estimated
    without ground truth; positions (N, 3) float64, metres."""
    if aligned:
        series = {"ground truth": aligned["gt"][:, :3, 3], f"VO ({align})": aligned["vo"][:, :3, 3],
                  f"SLAM ({align})": aligned["slam"][:, :3, 3]}
        title = (f"{seq.name}: ATE VO {record['metrics_vo']['ate_m']:.3f} m, "
                 f"SLAM {record['metrics_slam']['ate_m']:.3f} m, {len(res.loops)} loops")
    else:
        series = {"SLAM": res.slam.positions, "VO": res.vo.positions}
        title = f"{seq.name}: {len(res.loops)} loops"
    return series, title


def format_report(r: dict) -> str:
    """The text report of a run's record (:func:`slam_record`): what ran, loops, speed, wrote, and with ground
    truth the metrics of VO and SLAM side by side."""
    t = r["timings"]
    lines = [f"sequence      {r['sequence']} ({r['frames']} frames)",
             f"odometry      cons {r['odometry_cons']}, loops {r['odometry_loops']}",
             f"parameters    C_s {r['params']['c_s']:g}, C_r {r['params']['c_r']:g}, T_loop {r['params']['t_loop']}",
             f"loops         {r['n_loops']} edges, {sum(r['loops_kept_by_pose_graph'] or [])} kept by the pose graph "
             f"({r['n_verified_ok']} of {r['n_candidates']} candidates passed verification; "
             f"{len(r['loops_not_rigid'])} left out, their flow fitting no rigid motion)",
             *([f"              {r['loops_by_direction']['same']} join views the same way, "
                f"{r['loops_by_direction']['opposite']} the opposite way (ground truth)"] if r.get("loops_by_direction")
               else []),
             f"closed cycles {r['frames_in_closed_cycles']} of {r['frames']} frames lie inside a cycle a loop edge closes "
             "(the rest only the odometry places)",
             f"speed         {t['fps']:.2f} frames/s ({t['total_s']:.2f} s; optimisation {t['optimize_s']:.3f} s)",
             f"wrote         {r['trajectory']}, {r['trajectory_vo']}"]
    if "metrics_slam" in r:
        mv, ms = r["metrics_vo"], r["metrics_slam"]

        def num(x, f=".4f"):
            return "n/a" if x is None else format(x, f)
        lines += ["", f"{'metric':<24}{'VO':>12}{'SLAM':>12}  unit",
                  f"{'ATE rmse':<24}{num(mv['ate_m']):>12}{num(ms['ate_m']):>12}  m",
                  f"{'  in closed cycles':<24}{num(mv.get('ate_in_closed_cycles_m')):>12}"
                  f"{num(ms.get('ate_in_closed_cycles_m')):>12}  m",
                  f"{'  elsewhere':<24}{num(mv.get('ate_elsewhere_m')):>12}{num(ms.get('ate_elsewhere_m')):>12}  m",
                  *([f"{'  with perfect loops':<24}{'':>12}{num(r['metrics_perfect_loops']['ate_m']):>12}  m "
                     f"(an exact loop edge on each of the route's {r['metrics_perfect_loops']['revisit_pairs']} "
                     "revisiting frames)"] if r.get("metrics_perfect_loops") else []),
                  *([f"{'  ... and both ways':<24}{'':>12}{num(r['metrics_perfect_loops']['ate_both_ways_m']):>12}  m "
                     f"(and on each of its {r['metrics_perfect_loops']['opposite_revisit_pairs']} frames passing "
                     "again the opposite way)"] if "ate_both_ways_m" in (r.get("metrics_perfect_loops") or {}) else []),
                  f"{'RPE trans rmse (d=1)':<24}{num(mv['rpe_t_m']):>12}{num(ms['rpe_t_m']):>12}  m",
                  f"{'RPE rot rmse (d=1)':<24}{num(mv['rpe_r_deg']):>12}{num(ms['rpe_r_deg']):>12}  deg"]
        if "kitti_t_err_pct" in ms:
            lines += [f"{'KITTI t_err':<24}{num(mv.get('kitti_t_err_pct')):>12}{num(ms['kitti_t_err_pct']):>12}  %",
                      f"{'KITTI r_err':<24}{num(mv.get('kitti_r_err_deg_per_100m')):>12}"
                      f"{num(ms['kitti_r_err_deg_per_100m']):>12}  deg/100 m"]
    if r.get("plot"):
        lines.append(f"plot          {r['plot']}")
    return "\n".join(lines) + "\n"
