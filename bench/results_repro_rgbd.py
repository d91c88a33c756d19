"""``python -m bench.results_repro_rgbd``: the paper's recipe on hand-held RGB-D cameras, rendered rooms and TUM teddy.

Scores the NN_cons models that ``SCENE=room scripts/train_paper_recipe.sh`` trains (the cpu preset at a 96 x 128
input, the paper's L1 loss, cyclic learning rate and stride mixture; synthetic: single frames of two rooms rendered
as a Kinect would see them, motions drawn from a kernel density fit of their camera's own motion with its mirror
images; supervised: the same renders' frame pairs, exact flow, ground-truth poses) with the network's own pose
(``vo --pose net``) on data none of them saw: another rendered room (Kinect-like depth) flown by the drone and the
same room walked hand-held (``render --trajectory handheld``: a hand-held camera's motion a frame, as teddy's), each
with the simulator's exact flow and with DIS flow, and the real TUM fr3/teddy slice with DIS flow. Beside them, on
the same data: the RGB-D default (``tum_cons``, what ``deepslam vo`` runs on a TUM sequence: the solve pose head with the frame's depth) and
``pnp`` (SIFT + PnP-RANSAC on the frame's depth: the render's Kinect-like depth, teddy's sensor depth).

The figures are the TUM benchmark's: ATE (m, se3-aligned) and RPE per frame (m, degrees), the path-length ratio,
and the share of pairs within the predicted 1-sigma; synthetic / supervised is the ratio of the RPE's translation
(the routes are a few metres long: a drift per 100 m means nothing there). Whether a rendered room ranks the
rows as teddy does: the Spearman rank correlation of their ATE with teddy's (DIS flow), and how many networks read
the room's path on the same side of 1 as teddy's. Whether a rendered room calibrates the std for teddy: each
network's std fitted per DoF on the drone's room and on the hand-held room (``deepslam calibrate``, DIS flow), then
the share of teddy's pairs within 1-sigma.

``--models DIR``: the training script's folder (default ``bench/paper_recipe``: ``room_{mode}_cons_s{SEED}/``
with ``model.safetensors``, or ``checkpoint.safetensors`` of a run still going). Writes ``results.json`` and
``results.md`` under ``--out``; evaluations are cached there (a killed run resumes; a model whose file changed is
scored again).
"""
from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

from scipy.stats import spearmanr

from bench.results_common import write_report
from bench.results_repro import (_model_file, _repo_path, calibrated_once, forget_if_retrained, learning_curve,
                                 main_with_models, model_card, own_pose_scores, pm, vo_scores)
from bench.results_vo import _agg, _cached
from deepslam.studies.demo import render_once

MODES = {"room_synthetic_mirror": "synthetic (single frames of the rooms, mirrored motions)",
         "room_synthetic": "synthetic (single frames of the rooms, their own motions)",
         "room_supervised": "supervised (the rooms' frame pairs, exact flow, poses)",
         "room_synthetic_mirror_depth": "synthetic, mirrored motions, the frame's depth as an input channel",
         "room_synthetic_speedscale_mirror_depth": "synthetic, mirrored motions at 0.15-1x the rooms' speed, the "
                                                   "frame's depth as an input channel",
         "room_supervised_depth": "supervised, the frame's depth as an input channel",
         "room_handheld_synthetic_mirror_depth": "synthetic, rooms walked hand-held (their motions, mirrored), the "
                                                 "frame's depth as an input channel",
         "room_handheld_supervised_depth": "supervised on the hand-held rooms' pairs, the frame's depth as an input "
                                           "channel"}
"""Training folders ``{mode}_cons_s{seed}`` of ``SCENE=room scripts/train_paper_recipe.sh`` (``_depth``: with
``DEPTH=1``, the first frame's inverse depth a third input channel; ``room_handheld_``: ``TRAJECTORY=handheld``,
the training rooms walked hand-held) and their labels."""
SYNTHETIC_OVER_SUPERVISED = (("room_synthetic_mirror", "room_supervised"), ("room_synthetic", "room_supervised"),
                             ("room_synthetic_mirror_depth", "room_supervised_depth"),
                             ("room_synthetic_speedscale_mirror_depth", "room_supervised_depth"),
                             ("room_handheld_synthetic_mirror_depth", "room_handheld_supervised_depth"))
"""The pairs whose ratio the table states (same renders, same recipe, same budget cap)."""
FIGURES = (("ATE [m]", "ate_m", ".3g"), ("RPE [m/frame]", "rpe_t_m", ".3g"), ("RPE [deg/frame]", "rpe_r_deg", ".3g"),
           ("path ratio", "path_length_ratio", ".3f"))
"""Columns of a case's table: (title, key of the ``vo`` record, format)."""
CASE_TITLES = {"room_exact": "unseen rendered room (room {room_seed}, Kinect-like depth, 30 Hz), exact flow",
               "room_dis": "unseen rendered room (room {room_seed}, Kinect-like depth, 30 Hz), DIS flow",
               "handheld_exact": "the same room walked hand-held (`--trajectory handheld`, {handheld_frames} frames at "
                                 "30 Hz), exact flow",
               "handheld_dis": "the same room walked hand-held (`--trajectory handheld`, {handheld_frames} frames at "
                               "30 Hz), DIS flow",
               "teddy_dis": "TUM fr3/teddy (real, never trained on), DIS flow"}
"""Title of each case (formatted with the config)."""
CALIBRATED_ON = {"calroom": "the drone's room", "calhandheld": "the hand-held room"}
"""Tag of a calibration (teddy scored with the network's std calibrated first: case ``teddy_dis_{tag}``) and on
which rendered room (DIS flow) it was fitted."""


@dataclasses.dataclass(frozen=True)
class ReproRGBDConfig:
    """What is scored and where."""

    models: str = "bench/paper_recipe"
    """Folder of the trained models (``SCENE=room scripts/train_paper_recipe.sh OUT``; relative to the repository)."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Training seeds to score (a row's mean +- std is over those present)."""
    room_seed: int = 51
    """Seed of the unseen room (the training rooms are 1 and 2; ``bench.results_adapt`` renders the same room)."""
    room_frames: int = 150
    """Frames of the unseen room (30 Hz)."""
    handheld_frames: int = 200
    """Frames of the same room walked hand-held (30 Hz; 200: teddy's 6.7 s); 0: no hand-held rows."""


def _render_room(cfg: ReproRGBDConfig, out: Path, log: list[str], trajectory: str = "drone") -> Path:
    """The unseen room as a Kinect would see it (640x480, f = 537 px, 30 Hz, ``--depth-noise kinect``), flown by
    the drone or walked hand-held (``trajectory``), in deepslam's own format so that the simulator's exact flow is
    there too; rendered once, resumed if killed; the command that makes it goes to ``log``."""
    flags = ("--height", "480", "--focal-px", "537", "--rate", "30", "--stereo-baseline", "0",
             "--depth-noise", "kinect", "--quiet")
    frames, folder = ((cfg.room_frames, f"room_s{cfg.room_seed}") if trajectory == "drone"
                      else (cfg.handheld_frames, f"room_{trajectory}_s{cfg.room_seed}"))
    return render_once("room", trajectory, frames, 640, cfg.room_seed, out / folder, log, flags)


def run(cfg: ReproRGBDConfig, out: Path, data: Path) -> dict:
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    models_dir = _repo_path(cfg.models)
    log: list[str] = []
    room = _render_room(cfg, out, log)
    cases = [("room_exact", room, "gt"), ("room_dis", room, "dis")]
    if cfg.handheld_frames:
        handheld = _render_room(cfg, out, log, "handheld")
        cases += [("handheld_exact", handheld, "gt"), ("handheld_dis", handheld, "dis")]
    teddy = data / "tum" / "rgbd_dataset_freiburg3_teddy"
    if (teddy / "rgb.txt").is_file():
        cases.append(("teddy_dis", teddy, "dis"))
    calibrators = {"calroom": room, **({"calhandheld": handheld} if cfg.handheld_frames else {})}
    rows: dict = {}
    trained: dict = {}
    for mode in MODES:
        for seed in cfg.seeds:
            folder = models_dir / f"{mode}_cons_s{seed}"
            model = _model_file(folder)
            if model is None:
                continue
            curve = learning_curve(folder / "history.json") if (folder / "history.json").is_file() else {}
            trained[f"{mode} s{seed}"] = model_card(model, curve)
            forget_if_retrained(out, f"{mode}_s{seed}", model)  # a model trained further (or again) is scored again
            rec = {"seed": seed}
            for name, seq, flow in cases:
                print(f"score {mode} seed {seed}: {name}", flush=True)
                rec[name] = own_pose_scores(out, f"{mode}_s{seed}_{name}_{seq.name}", seq, model, flow)
            for tag, cal_seq in calibrators.items():
                if seed != 0 or model.name != "model.safetensors" or "teddy_dis" not in rec:
                    continue  # seed 0 only; a checkpoint's std heads are untrained; no teddy, nothing to read
                # the std fitted per DoF on a rendered room with ground truth, then read on teddy
                print(f"calibrate {mode} seed {seed}: {tag}", flush=True)
                calibrated = calibrated_once(out, f"{mode}_s{seed}_{tag}", cal_seq, model)
                key = f"{mode}_s{seed}_teddy_dis_{tag}"
                rec[f"teddy_dis_{tag}"] = _cached(out / "eval" / f"{key}.json", lambda: vo_scores(
                    teddy, out / "runs" / f"{key}.txt", "--model", str(calibrated), "--flow", "dis", "--pose", "net"))
            rows.setdefault(mode, []).append(rec)
    beside: dict = {}
    for name, seq, flow in cases:
        tag = f"default_{name}_{seq.name}"
        beside.setdefault("default", {})[name] = _cached(out / "eval" / f"{tag}.json", lambda: vo_scores(
            seq, out / "runs" / f"{tag}.txt", "--model", "tum:cons", "--flow", flow))
        beside.setdefault("pnp", {})[name] = _cached(out / "eval" / f"pnp_{seq.name}.json", lambda: vo_scores(
            seq, out / "runs" / f"pnp_{seq.name}.txt", "--odometry", "pnp"))
    report = {"config": dataclasses.asdict(cfg), "commands": log, "models": trained, "rows": rows, "beside": beside,
              "cases": [c[0] for c in cases], "minutes": (time.perf_counter() - t0) / 60}
    report["ratio_synthetic_over_supervised"] = ratios(report)
    report["agreement_with_teddy"] = {case: rank_agreement(report, case) for case in ("room_dis", "handheld_dis")
                                      if case in report["cases"] and "teddy_dis" in report["cases"]}
    write_report(out, report, markdown)
    return report


def ratios(report: dict) -> dict:
    """``{"mine/other": {case: ratio}}``: the mean RPE translation of each synthetic mode over its supervised
    counterpart's, per case (None where either is missing)."""
    def ratio(mine: str, other: str, case: str) -> float | None:
        num, den = (_agg([r[case].get("rpe_t_m") for r in report["rows"][m]])["mean"] for m in (mine, other))
        return num / den if num is not None and den else None

    return {f"{mine}/{other}": {c: ratio(mine, other, c) for c in report["cases"]}
            for mine, other in SYNTHETIC_OVER_SUPERVISED if report["rows"].get(mine) and report["rows"].get(other)}


def _ate_and_path(report: dict, case: str) -> dict:
    """``{row: (ATE m, path ratio)}`` of every row on ``case``: each network mode's mean over seeds, the RGB-D
    default and ``pnp``; rows without a figure are left out."""
    rows = {}
    for mode, recs in report["rows"].items():
        ate = _agg([r[case].get("ate_m") for r in recs])["mean"]
        path = _agg([r[case].get("path_length_ratio") for r in recs])["mean"]
        if ate is not None:
            rows[mode] = (ate, path)
    for key, by_case in report.get("beside", {}).items():
        d = by_case.get(case) or {}
        if d.get("ate_m") is not None:
            rows[key] = (d["ate_m"], d.get("path_length_ratio"))
    return rows


def rank_agreement(report: dict, case: str, reference: str = "teddy_dis") -> dict:
    """How a rendered room's ``case`` ranks the rows against ``reference`` (teddy): ``{"rho": Spearman rank
    correlation of the rows' ATE (None under 3 rows), "rows": n, "same_side": networks whose path ratio is on the
    same side of 1 on both, "networks": networks with both ratios}``."""
    mine, ref = _ate_and_path(report, case), _ate_and_path(report, reference)
    common = [k for k in mine if k in ref]
    rho = float(spearmanr([mine[k][0] for k in common], [ref[k][0] for k in common])[0]) if len(common) >= 3 else None
    nets = [k for k in common if k in report["rows"] and mine[k][1] is not None and ref[k][1] is not None]
    same = sum((mine[k][1] > 1) == (ref[k][1] > 1) for k in nets)
    return {"rho": rho, "rows": len(common), "same_side": same, "networks": len(nets)}


def markdown(report: dict) -> str:
    cfg = report.get("config", {})
    md = ["The paper's recipe on a hand-held RGB-D camera (NN_cons, the cpu preset at a 96 x 128 input; `SCENE=room "
          "scripts/train_paper_recipe.sh`), scored with the network's own pose (`--pose net`) on data no model saw. "
          "A row is the mean ± std over the training seeds present (n). Models:"]
    md += [f"- {MODES[k.rsplit(' ', 1)[0]]} ({k.rsplit(' ', 1)[1]}): `{v['file']}`, {v['samples']:,} samples, "
           f"trained on {v.get('device', 'n/a')}, stopped: {v.get('stop', 'n/a')}"
           for k, v in report["models"].items()] or ["- none found (train them with `SCENE=room bash "
                                                      "scripts/train_paper_recipe.sh bench/paper_recipe`)"]
    names = {"default": "the RGB-D default (`tum_cons`: solve head with the frame's depth, on the same flow)",
             "pnp": "`pnp` (SIFT + PnP-RANSAC on the frame's depth; no flow)"}
    for case in report["cases"]:
        md += ["", f"**{CASE_TITLES.get(case, case).format(**cfg)}**", "",
               "| | " + " | ".join(t for t, _, _ in FIGURES) + " | within 1-sigma (rx, ry, rz, tx, ty, tz) |",
               "|---" * (len(FIGURES) + 2) + "|"]
        for mode, recs in report["rows"].items():
            shares = recs[0][case].get("within_1_sigma") if len(recs) == 1 else None
            md.append(f"| {MODES[mode]} (n={len(recs)}) | " + " | ".join(
                pm(_agg([r[case].get(k) for r in recs]), f) for _, k, f in FIGURES) + " | "
                + (", ".join(f"{x:.2f}" for x in shares) if shares else "") + " |")
        for key, label in names.items():
            d = report.get("beside", {}).get(key, {}).get(case)
            if d:
                md.append(f"| {label} | " + " | ".join(
                    "n/a" if d.get(k) is None else f"{d[k]:{f}}" for _, k, f in FIGURES) + " | |")
        md.append("")
        for pair, by_case in report.get("ratio_synthetic_over_supervised", {}).items():
            if by_case.get(case) is not None:
                mine, other = pair.split("/")
                md.append(f"- {MODES[mine]} / {MODES[other]} (RPE translation): x{by_case[case]:.2f}")
    agree = report.get("agreement_with_teddy", {})
    if agree:
        md += ["", "Does a rendered room rank the rows as teddy does (DIS flow)? Spearman rank correlation of the "
               "rows' ATE with teddy's, and the networks reading the path on teddy's side of 1 (long or short):", ""]
        for case, a in agree.items():
            rho = "n/a" if a["rho"] is None else f"{a['rho']:.2f}"
            md.append(f"- {CASE_TITLES.get(case, case).format(**cfg)}: rho {rho} over {a['rows']} rows; "
                      f"{a['same_side']} of {a['networks']} networks on teddy's side")
    cal = [(mode, tag, recs[0][f"teddy_dis_{tag}"]["within_1_sigma"]) for mode, recs in report["rows"].items()
           for tag in CALIBRATED_ON if (recs[0].get(f"teddy_dis_{tag}") or {}).get("within_1_sigma")]
    if cal:
        md += ["", "Calibration: share of teddy's pairs within the predicted 1-sigma (rx, ry, rz, tx, ty, tz; a "
               "calibrated Gaussian gives 0.68, the target 0.6-0.75), each network's std fitted per DoF on a rendered "
               "room first (`deepslam calibrate`, DIS flow; seed 0):", ""]
        md += [f"- {MODES[mode]}, calibrated on {CALIBRATED_ON[tag]}: " + ", ".join(f"{x:.2f}" for x in shares)
               + f" ({sum(0.6 <= x <= 0.75 for x in shares)} of 6 in 0.6-0.75)" for mode, tag, shares in cal]
    md += ["", "The paper (EuRoC, rigid rooms): synthetic / supervised about x1.",
           "", f"Run time: {report.get('minutes', 0):.1f} min."]
    return "\n".join(md) + "\n"


def main(argv: list[str] | None = None) -> int:
    return main_with_models("results_repro_rgbd", __doc__, ReproRGBDConfig(),
                            lambda cfg: dataclasses.replace(cfg, room_frames=12, handheld_frames=12), "repro_rgbd",
                            run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
