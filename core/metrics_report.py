"""The reports of ``deepslam eval``: one estimate's metrics as a table, several estimates as rows, the plot's
curves, and short names for the estimates."""
from __future__ import annotations

from pathlib import Path


def labels(paths: list) -> list[str]:
    """Short names for the estimates: file names, or whole paths where two file names are equal."""
    names = [p.name for p in paths]
    return [n if names.count(n) == 1 else str(p) for n, p in zip(names, paths)]


def plot_curves(gt, gt_path: Path, est_paths: list[Path], results: list[dict], align: str) -> tuple[dict, str]:
    """(curves, title) of ``deepslam eval --plot``: positions (N, 3) float64 metres in the ground truth's world
    frame, one estimate over the matched ground truth, or several aligned estimates over the whole ground truth
    ``gt`` (:class:`core.trajectory.Trajectory`); ``results`` the :func:`core.metrics.evaluate` dicts."""
    if len(results) == 1:
        curves = {f"ground truth ({gt_path.name})": results[0]["_gt_poses"][:, :3, 3],
                  f"estimate ({est_paths[0].name}, {align})": results[0]["_est_aligned_poses"][:, :3, 3]}
        title = f"ATE {results[0]['ate_m']:.3f} m"
    else:
        # every aligned estimate lies in the ground truth's world: draw them over the whole ground truth
        curves = {f"ground truth ({gt_path.name})": gt.world_from_cam[:, :3, 3]}
        names = labels(est_paths)
        for name, res in zip(names, results):
            curves[f"{name} ({align}, ATE {res['ate_m']:.3f} m)"] = res["_est_aligned_poses"][:, :3, 3]
        title = f"{len(results)} estimates, {align} alignment"
    return curves, title



def format_table(r: dict) -> str:
    """A readable table of one estimate's metrics, the dict ``deepslam eval --json`` prints."""
    def num(x, fmt):
        return "n/a" if x is None else format(x, fmt)

    lines = [
        f"ground truth  {r['gt']}  ({r['gt_format']}, {r['n_gt']} poses)",
        f"estimate      {r['est']}  ({r['est_format']}, {r['n_est']} poses)",
        f"matched       {r['n_matched']} poses by {r['matched_by']}"
        + (f" (max diff {r['max_diff_s']:g} s)" if r.get("max_diff_s") else "")
        + f"; ground truth length {r['gt_length_m']:.1f} m",
        f"alignment     {r['align']}" + (f" (scale {r['scale']:.4f})" if r["align"] == "sim3" else ""),
        "",
        f"{'metric':<28}{'value':>12}  unit",
        f"{'ATE rmse':<28}{num(r['ate_m'], '.4f'):>12}  m",
        f"{'ATE mean / median / max':<28}{num(r['ate_mean_m'], '.4f'):>12}  / {num(r['ate_median_m'], '.4f')}"
        f" / {num(r['ate_max_m'], '.4f')} m",
        f"{'RPE trans rmse (d=' + str(r['rpe_delta']) + ')':<28}{num(r['rpe_t_m'], '.4f'):>12}  m",
        f"{'RPE rot rmse (d=' + str(r['rpe_delta']) + ')':<28}{num(r['rpe_r_deg'], '.4f'):>12}  deg",
    ]
    if "kitti_t_err_pct" in r:
        lines += [
            f"{'KITTI t_err':<28}{num(r['kitti_t_err_pct'], '.4f'):>12}  %",
            f"{'KITTI r_err':<28}{num(r['kitti_r_err_deg_per_100m'], '.4f'):>12}  deg/100 m",
            "",
            f"{'length [m]':>10}{'segments':>10}{'t_err [%]':>12}{'r_err [deg/100m]':>18}",
        ]
        for row in r.get("kitti_per_length", []):
            lines.append(f"{row['length_m']:>10.0f}{row['n_segments']:>10d}{num(row['t_err_pct'], '.4f'):>12}"
                         f"{num(row['r_err_deg_per_100m'], '.4f'):>18}")
    else:
        lines.append(f"(KITTI t_err/r_err: ground truth is {r['gt_length_m']:.1f} m, not longer than 100 m)")
    if r.get("plot"):
        lines += ["", f"plot          {r['plot']}"]
    return "\n".join(lines) + "\n"


def format_rows(results: list[dict]) -> str:
    """One table row per estimate (several ``--est``) of the dicts ``deepslam eval --json`` prints."""
    def num(x, fmt):
        return "n/a" if x is None else format(x, fmt)

    r0 = results[0]
    names = labels([Path(r["est"]) for r in results])
    width = max(12, *(len(n) for n in names)) + 2
    delta = r0["rpe_delta"]
    lines = [
        f"ground truth  {r0['gt']}  ({r0['gt_format']}, {r0['n_gt']} poses; length {r0['gt_length_m']:.1f} m)",
        f"alignment     {r0['align']}; RPE over {delta} frame{'s' if delta > 1 else ''}",
        "",
        f"{'estimate':<{width}}{'format':>7}{'matched':>9}{'scale':>8}{'ATE [m]':>10}{'RPE t [m]':>11}"
        f"{'RPE r [deg]':>13}{'t_err [%]':>11}{'r_err [deg/100m]':>18}",
    ]
    for name, r in zip(names, results):
        lines.append(f"{name:<{width}}{r['est_format']:>7}{r['n_matched']:>9d}{num(r['scale'], '.4f'):>8}"
                     f"{num(r['ate_m'], '.4f'):>10}{num(r['rpe_t_m'], '.4f'):>11}{num(r['rpe_r_deg'], '.4f'):>13}"
                     f"{num(r.get('kitti_t_err_pct'), '.4f'):>11}{num(r.get('kitti_r_err_deg_per_100m'), '.4f'):>18}")
    if not any("kitti_t_err_pct" in r for r in results):
        lines.append("(KITTI t_err/r_err: n/a, ground truth not longer than 100 m)")
    if r0.get("plot"):
        lines += ["", f"plot          {r0['plot']}"]
    return "\n".join(lines) + "\n"
