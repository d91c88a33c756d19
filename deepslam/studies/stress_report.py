"""The stress study's report: the flat table, the conclusion, the side-by-side entries, and the files
``stress.json``, ``stress.md``, ``report.html`` (the table, the conclusion and the plots on one page) and the
four plots of the errors against the fraction of dynamic pixels (:func:`write_outputs`).

Everything here reads the per-setting results of :mod:`deepslam.studies.stress` (plain dicts) and the
study's odometries (anything with ``kind``, ``description``, ``note``, ``cons`` and ``plugins``, as
:class:`deepslam.studies.stress.OdometrySet`).
"""
from __future__ import annotations

import dataclasses
import html
from pathlib import Path

import numpy as np

from deepslam.core import atomic, plots
from deepslam.core.atomic import json_safe

RESULT_FORMAT = "deepslam-stress-v1"
"""The ``format`` of ``stress.json`` and ``config.json``."""
HTML_NAME = "report.html"
"""The HTML page written beside ``stress.md``."""


def table_rows(rows: list[dict]) -> list[dict]:
    """Flat rows for the table: one per setting, sorted by the fraction of dynamic pixels."""
    flat = []
    for r in rows:
        s, f = r["setting"], r["flow"]
        row = {"setting": s["name"], "axis": s["axis"], "objects": s["moving_objects"], "size": s["object_scale"],
               "deform_m": s["deform_amplitude_m"], "dynamic_pct": 100.0 * f["dynamic_fraction"],
               "epe_static_px": f["static_visible"]["epe_mean_px"], "epe_dynamic_px": f["moving"]["epe_mean_px"],
               "epe_dynamic_p95_px": f["moving"]["epe_p95_px"], "dynamic_pixels_compared": f["moving"]["pixels"]}
        for flow in r["vo"]:
            vo, sl = r["vo"].get(flow), r["slam"].get(flow)
            if vo is None:
                continue
            row[f"vo_ate_{flow}_m"] = vo["ate_m"]
            row[f"vo_rpe_t_{flow}_m"] = vo["rpe_t_m"]
            row[f"vo_rpe_r_{flow}_deg"] = vo["rpe_r_deg"]
            row[f"vo_t_err_{flow}_pct"] = vo.get("kitti_t_err_pct")
            row[f"vo_r_err_{flow}_deg_per_100m"] = vo.get("kitti_r_err_deg_per_100m")
            row[f"slam_ate_{flow}_m"] = sl["ate_m"]
            row[f"slam_loops_{flow}"] = r["loops"][flow]["loop_edges_kept"]
        flat.append(row)
    flat.sort(key=lambda x: (x["dynamic_pct"], x["setting"]))
    return flat


def conclusion(flat: list[dict]) -> dict:
    """Numbers of the conclusion: the static baseline against the setting with the most dynamic pixels."""
    if not flat:
        return {"text": "no settings were measured"}
    static = [r for r in flat if r["objects"] == 0 and r["deform_m"] == 0]
    base = static[0] if static else flat[0]
    worst = max(flat, key=lambda r: r["dynamic_pct"])
    c = {"baseline": base["setting"], "worst": worst["setting"], "baseline_dynamic_pct": base["dynamic_pct"],
         "worst_dynamic_pct": worst["dynamic_pct"]}
    for k in ("epe_static_px", "epe_dynamic_px", "vo_ate_gt_m", "vo_ate_dis_m", "vo_rpe_t_gt_m", "vo_rpe_t_dis_m",
              "slam_ate_gt_m", "slam_ate_dis_m"):
        c[f"baseline_{k}"] = base.get(k)
        c[f"worst_{k}"] = worst.get(k)
    # least-squares slope of each error against the dynamic percentage (over all settings)
    x = np.array([r["dynamic_pct"] for r in flat])
    for k in ("vo_ate_gt_m", "vo_ate_dis_m", "slam_ate_gt_m", "slam_ate_dis_m", "epe_dynamic_px"):
        y = np.array([np.nan if r.get(k) is None else r[k] for r in flat], dtype=np.float64)
        ok = np.isfinite(y)
        if ok.sum() >= 2 and np.ptp(x[ok]) > 0:
            c[f"slope_{k}_per_pct"] = float(np.polyfit(x[ok], y[ok], 1)[0])
    # where it breaks: the fewest dynamic pixels at which the VO error on exact flow doubles
    for k in ("vo_ate_gt_m", "vo_ate_dis_m"):
        b = base.get(k)
        if b is None:
            continue
        over = [r for r in flat if r.get(k) is not None and r[k] > 2.0 * b and r is not base]
        if over:
            first = min(over, key=lambda r: r["dynamic_pct"])
            c[f"break_{k}"] = {"setting": first["setting"], "dynamic_pct": first["dynamic_pct"], "value": first[k]}
    c["text"] = _conclusion_text(c)
    return c


def _fmt(v, f=".3g", unit="") -> str:
    return "n/a" if v is None else f"{format(v, f)}{unit}"


def _ratio(a, b) -> str:
    if a is None or b is None or b <= 0 or a / b > 1e4:
        return ""
    return f" (x{a / b:.3g})"


def _conclusion_text(c: dict) -> str:
    parts = [f"Rigid-scene assumption: from the static scene ({c['baseline']}, {c['baseline_dynamic_pct']:.2f} % "
             f"dynamic pixels) to {c['worst']} ({c['worst_dynamic_pct']:.2f} % dynamic pixels), the flow synthesized "
             f"from depth + true camera motion is off by {_fmt(c['worst_epe_dynamic_px'])} px (mean EPE) on dynamic "
             f"pixels while static pixels stay at {_fmt(c['worst_epe_static_px'])} px"]
    for label, k in (("VO ATE on ground-truth flow", "vo_ate_gt_m"), ("VO ATE on DIS flow", "vo_ate_dis_m"),
                     ("SLAM ATE on ground-truth flow", "slam_ate_gt_m"), ("SLAM ATE on DIS flow", "slam_ate_dis_m")):
        a, b = c.get(f"baseline_{k}"), c.get(f"worst_{k}")
        if a is None and b is None:
            continue
        slope = c.get(f"slope_{k}_per_pct")
        extra = "" if slope is None else f", {slope:+.3g} m per % of dynamic pixels over the sweep"
        parts.append(f"{label} goes from {_fmt(a)} m to {_fmt(b)} m{_ratio(b, a)}{extra}")
    text = "; ".join(parts) + "."
    brk = c.get("break_vo_ate_gt_m")
    if brk is not None:
        text += (f" The VO error on exact flow already doubles at {brk['dynamic_pct']:.2f} % dynamic pixels "
                 f"({brk['setting']}: ATE {brk['value']:.3g} m vs {c['baseline_vo_ate_gt_m']:.3g} m).")
    elif c.get("baseline_vo_ate_gt_m") is not None:
        text += " The VO error on exact flow never doubled over the sweep."
    return text



def odometry_columns(odometries) -> dict:
    """{column key: label} of every odometry the study measured: the main one on each flow source and
    each plug-in."""
    # the learned odometry runs as `deepslam vo --flow F` does by default (each model with its recorded pose)
    main = "deepslam vo (default)" if odometries.kind == "model" else odometries.kind
    cols = {f: f"{main} on {'ground-truth' if f == 'gt' else 'DIS'} flow" for f in odometries.cons}
    cols.update({k: f"{o.name} (plug-in)" for k, o in odometries.plugins.items()})
    return cols


def side_by_side(flat: list[dict], odometries) -> list[dict]:
    """One entry per setting and odometry (the ``--json`` settings list): ``name``, ``odometry``,
    ``dynamic_fraction``, ``flow_epe_dynamic_px``, ``vo_ate_m``, ``vo_rpe_t_m``, ``vo_rpe_r_deg``,
    ``slam_ate_m``, ``loop_edges_kept``."""
    out = []
    for r in flat:
        for key, label in odometry_columns(odometries).items():
            if r.get(f"vo_ate_{key}_m") is None:
                continue
            out.append({"name": r["setting"], "odometry": label, "odometry_key": key,
                        "dynamic_fraction": r["dynamic_pct"] / 100.0, "flow_epe_dynamic_px": r["epe_dynamic_px"],
                        "vo_ate_m": r[f"vo_ate_{key}_m"], "vo_rpe_t_m": r.get(f"vo_rpe_t_{key}_m"),
                        "vo_rpe_r_deg": r.get(f"vo_rpe_r_{key}_deg"), "slam_ate_m": r.get(f"slam_ate_{key}_m"),
                        "loop_edges_kept": r.get(f"slam_loops_{key}")})
    return out


def build_report(config, settings, rows: list[dict], odometries, elapsed_s: float,
                 notes: list[str] | None = None) -> dict:
    """The whole report (``stress.json``): config, odometries, notes, settings, the flat table (``rows``),
    the per-setting results, the side-by-side entries, the conclusion and the elapsed seconds."""
    flat = table_rows(rows)
    return json_safe({"format": RESULT_FORMAT, "config": config.to_dict(), "odometry": odometries.kind,
                      "odometry_description": odometries.description, "odometry_note": odometries.note,
                      "plugins": {k: o.name for k, o in odometries.plugins.items()},
                      "side_by_side": side_by_side(flat, odometries),
                      "notes": list(notes or []),
                      "settings": [dataclasses.asdict(s) for s in settings], "rows": flat, "results": rows,
                      "conclusion": conclusion(flat), "elapsed_s": elapsed_s})



TABLE_LEGEND = ("Flow EPE: flow synthesized from frame t's depth and the true camera motion (the rigid-scene "
                "assumption) against the simulator's exact flow; static = static visible pixels (control), dyn = "
                "moving/deforming pixels. VO and SLAM: SE3-aligned ATE (m) and RPE per frame (m, deg) on the "
                "ground-truth flow (gt) and on DIS flow (dis); t_err (%) where the path is longer than 100 m; "
                "loops = loop edges kept by the pose graph.")
SETTINGS_LEGEND = "Settings: `kK_sS_aA` = K moving objects scaled by S, flags waving with amplitude A m."
SIDE_BY_SIDE_LEGEND = "VO ATE / SLAM ATE, m, SE3-aligned; plug-ins read the images themselves"
PLOT_TITLES = {"stress_flow_epe.png": "flow EPE", "stress_vo_ate.png": "VO ATE", "stress_vo_rpe.png": "VO RPE",
               "stress_slam_ate.png": "SLAM ATE"}
"""The plots in the order the pages show them: {file name: short title}."""


def main_table(report: dict) -> tuple[list[str], list[list[str]]]:
    """(header, rows of cells) of the table: one row per setting, in the order of ``report["rows"]``."""
    has_terr = any(r.get("vo_t_err_gt_pct") is not None or r.get("vo_t_err_dis_pct") is not None for r in report["rows"])
    head = ["setting", "axis", "dyn %", "EPE static px", "EPE dyn px", "VO ATE gt m", "VO ATE dis m",
            "RPE gt m / deg", "RPE dis m / deg"]
    if has_terr:
        head += ["t_err gt %", "t_err dis %"]
    head += ["SLAM ATE gt m", "SLAM ATE dis m", "loops gt/dis"]
    body = []
    for r in report["rows"]:
        cells = [r["setting"], r["axis"], f"{r['dynamic_pct']:.2f}", _fmt(r["epe_static_px"], ".2g"),
                 _fmt(r["epe_dynamic_px"]), _fmt(r.get("vo_ate_gt_m")), _fmt(r.get("vo_ate_dis_m")),
                 f"{_fmt(r.get('vo_rpe_t_gt_m'))} / {_fmt(r.get('vo_rpe_r_gt_deg'))}",
                 f"{_fmt(r.get('vo_rpe_t_dis_m'))} / {_fmt(r.get('vo_rpe_r_dis_deg'))}"]
        if has_terr:
            cells += [_fmt(r.get("vo_t_err_gt_pct")), _fmt(r.get("vo_t_err_dis_pct"))]
        cells += [_fmt(r.get("slam_ate_gt_m")), _fmt(r.get("slam_ate_dis_m")),
                  f"{r.get('slam_loops_gt', 'n/a')}/{r.get('slam_loops_dis', 'n/a')}"]
        body.append(cells)
    return head, body


def side_by_side_table(report: dict) -> tuple[list[str], list[list[str]]] | None:
    """(header, rows of cells) of the side-by-side table (VO ATE / SLAM ATE of every odometry per setting),
    or None when the study measured no plug-in."""
    if not report.get("plugins"):
        return None
    keys = sorted({e["odometry_key"] for e in report["side_by_side"]}, key=lambda k: (k not in ("gt", "dis"), k))
    labels = {e["odometry_key"]: e["odometry"] for e in report["side_by_side"]}
    by = {(e["name"], e["odometry_key"]): e for e in report["side_by_side"]}
    head = ["setting", "dyn %"] + [labels[k] for k in keys]
    body = []
    for r in report["rows"]:
        cells = [f"{_fmt(by[(r['setting'], k)]['vo_ate_m'])} / {_fmt(by[(r['setting'], k)]['slam_ate_m'])}"
                 if (r["setting"], k) in by else "n/a" for k in keys]
        body.append([r["setting"], f"{r['dynamic_pct']:.2f}"] + cells)
    return head, body


def _title(report: dict) -> str:
    return f"Stress study: moving and deforming objects ({report['config']['scene']})"


def _summary(report: dict) -> str:
    cfg = report["config"]
    return (f"{cfg['frames']} frames per setting at {cfg['width']} px wide, seed {cfg['seed']}, "
            f"{len(report['rows'])} settings, {report['elapsed_s']:.0f} s in all.")


def markdown(report: dict) -> str:
    """``stress.md``: the summary, odometry, notes, conclusion, the table(s) and the plots."""
    lines = [f"# {_title(report)}", "", _summary(report), "", f"Odometry: {report['odometry_description']}."]
    if report.get("odometry_note"):
        lines += ["", f"**Note: {report['odometry_note']}.**"]
    for note in report.get("notes", []):
        lines += ["", f"Note: {note}."]
    lines += ["", "**Conclusion.** " + report["conclusion"]["text"], "", TABLE_LEGEND, ""]
    head, body = main_table(report)
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(cells) + " |" for cells in body]
    side = side_by_side_table(report)
    if side is not None:
        head, body = side
        lines += ["", f"**Side by side** ({SIDE_BY_SIDE_LEGEND}):", "",
                  "| " + " | ".join(head) + " |", "|---|---|" + "---|" * (len(head) - 2)]
        lines += ["| " + " | ".join(cells) + " |" for cells in body]
    lines += ["", SETTINGS_LEGEND, ""] + [f"![{title}]({name})" for name, title in PLOT_TITLES.items()] + [""]
    return "\n".join(lines)


def _html_table(head: list[str], body: list[list[str]]) -> list[str]:
    e = html.escape
    out = ["<table>", "<thead><tr>" + "".join(f"<th>{e(h)}</th>" for h in head) + "</tr></thead>", "<tbody>"]
    out += ["<tr>" + "".join(f"<td>{e(c)}</td>" for c in cells) + "</tr>" for cells in body]
    return out + ["</tbody>", "</table>"]


def html_page(report: dict) -> str:
    """``report.html``: what ``stress.md`` says, as one plain HTML page (no script, nothing fetched from
    elsewhere) that shows the plots beside it, each image linking to its PNG."""
    e = html.escape
    lines = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">', f"<title>{e(_title(report))}</title>",
             "<style>body{font-family:sans-serif;max-width:75em;margin:1em auto;padding:0 1em}"
             "table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #bbb;padding:.2em .5em;"
             "text-align:right}th:first-child,td:first-child{text-align:left}img{max-width:100%}"
             "figure{display:inline-block;margin:.5em}</style>",
             "</head>", "<body>", f"<h1>{e(_title(report))}</h1>", f"<p>{e(_summary(report))}</p>",
             f"<p>Odometry: {e(report['odometry_description'])}.</p>"]
    if report.get("odometry_note"):
        lines.append(f"<p><strong>Note: {e(report['odometry_note'])}.</strong></p>")
    lines += [f"<p>Note: {e(note)}.</p>" for note in report.get("notes", [])]
    lines += [f"<p><strong>Conclusion.</strong> {e(report['conclusion']['text'])}</p>", f"<p>{e(TABLE_LEGEND)}</p>"]
    lines += _html_table(*main_table(report))
    side = side_by_side_table(report)
    if side is not None:
        lines += ["<h2>Side by side</h2>", f"<p>{e(SIDE_BY_SIDE_LEGEND)}.</p>"] + _html_table(*side)
    lines += [f"<p>{e(SETTINGS_LEGEND.replace('`', ''))}</p>", "<h2>Plots</h2>"]
    lines += [f'<figure><a href="{e(name)}"><img src="{e(name)}" alt="{e(title)}"></a>'
              f"<figcaption>{e(title)}</figcaption></figure>" for name, title in PLOT_TITLES.items()]
    lines += ["</body>", "</html>", ""]
    return "\n".join(lines)


PLOTS = {
    "stress_flow_epe.png": ("synthesized-vs-true flow EPE (mean, px)",
                            [("epe_dynamic_px", "dynamic pixels"), ("epe_static_px", "static pixels (control)")], True),
    "stress_vo_ate.png": ("VO ATE (m, SE3-aligned)",
                          [("vo_ate_gt_m", "ground-truth flow"), ("vo_ate_dis_m", "DIS flow")], False),
    "stress_vo_rpe.png": ("VO RPE per frame (m)",
                          [("vo_rpe_t_gt_m", "ground-truth flow"), ("vo_rpe_t_dis_m", "DIS flow")], False),
    "stress_slam_ate.png": ("SLAM ATE (m, SE3-aligned)",
                            [("slam_ate_gt_m", "ground-truth flow"), ("slam_ate_dis_m", "DIS flow")], False),
}
AXIS_MARKERS = {"objects": "o", "size": "s", "deform": "^", "combined": "*"}


def plot_error(path: Path, rows: list[dict], ylabel: str, series: list[tuple[str, str]], log_y: bool, title: str) -> None:
    """One PNG: each error series against the percentage of dynamic pixels; marker = sweep axis."""
    # deferred: matplotlib is imported only when a plot is drawn: it is the heaviest import of the report
    from matplotlib.lines import Line2D

    fig = plots.new_figure((7.0, 4.6), dpi=110)
    ax = fig.add_subplot(1, 1, 1)
    colours = ["tab:red", "tab:blue", "tab:green", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:olive"]
    handles = []
    x_all = np.array([r["dynamic_pct"] for r in rows])
    order = np.argsort(x_all, kind="stable")
    for (key, label), colour in zip(series, colours):
        x = np.array([rows[i]["dynamic_pct"] for i in order])
        y = np.array([np.nan if rows[i].get(key) is None else rows[i][key] for i in order], dtype=np.float64)
        if log_y:
            y = np.where(y > 0, y, np.nan)
        if not np.isfinite(y).any():
            continue
        ax.plot(x[np.isfinite(y)], y[np.isfinite(y)], "-", color=colour, alpha=0.35, lw=1)
        for i, xi, yi in zip(order, x, y):
            if np.isfinite(yi):
                ax.plot([xi], [yi], AXIS_MARKERS.get(rows[i]["axis"], "o"), color=colour, ms=7)
        handles.append(Line2D([], [], color=colour, marker="o", ls="-", label=label))
    for axis, m in AXIS_MARKERS.items():
        if any(r["axis"] == axis for r in rows):
            handles.append(Line2D([], [], color="grey", marker=m, ls="", label=f"sweep: {axis}"))
    if log_y:
        ax.set_yscale("log")
    ax.set_xlabel("dynamic pixels (% of all pixels)")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    if handles:
        ax.legend(handles=handles, fontsize=8, loc="best")
    fig.tight_layout()
    with atomic.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")


def write_outputs(out: Path, report: dict) -> None:
    """stress.json, stress.md, report.html and the four plots, each atomically."""
    cfg = report["config"]
    title = f"stress study ({cfg['scene']}, {report['odometry']})"
    plugins = report.get("plugins", {})
    for name, (ylabel, series, log_y) in PLOTS.items():
        key = series[0][0]
        if key.startswith(("vo_", "slam_")) and plugins:
            series = series + [(key.replace("_gt_", f"_{k}_"), f"{n} (plug-in)") for k, n in plugins.items()]
        plot_error(out / name, report["rows"], ylabel, series, log_y, title)
    atomic.write_json(out / "stress.json", report)
    atomic.write_text(out / "stress.md", markdown(report))
    atomic.write_text(out / HTML_NAME, html_page(report))
