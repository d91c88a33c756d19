"""``python -m bench.results_lever``: does the recipe read KITTI's turns once its training towns' camera sits ahead of the
rear axle, as KITTI's does?

KITTI's camera is about 0.84 m ahead of the rear axle and slides sideways into every turn; the training towns'
camera rode on the axle (``render --camera-ahead 0``), so the recipe's prior never held that slide, and its flow
reads as extra yaw. ``scripts/train_paper_recipe.sh`` (``LEVER=0.84``, its default) trains the same recipe on towns rendered with the
lever (``lever_*`` models). This scores each model of :attr:`LeverConfig.model_names` with its own pose (``vo
--pose net``) on the held-out town 7 without and with the lever (exact and DIS flow) and on the KITTI 06 and 07
slices (DIS), beside ``deepslam vo``'s default: ATE, t_err (or the end-point drift on a route under 100 m), the path
ratio, the mean yaw error (read - true, degrees) of the pairs turning each way and of the straight pairs, and the
drift once the true rotation replaces the network's (what is left is its translation); each model's forward
distance on the straight pairs of the KITTI slices read at frame strides 1-3, by the true length of a pair; each
model on the KITTI slices with the principal point moved to the image's centre (``vo --centre-principal-point``);
the shares within 1-sigma of the DIS-flow models with the std widened by the geometry (``vo --std-from-geometry``);
seed ensembles (:attr:`LeverConfig.ensembles`) scored as models, and the mean +- std over the seeds of each recipe.

    python -m bench.results_lever [--models bench/paper_recipe] [--quick]

Writes ``results.json`` and ``results.md`` under ``out/results/lever`` (evaluations cached there: a killed run
resumes); docs/experiments/2026-12-07_lever_arm_training.md reads them.
"""
from __future__ import annotations

import dataclasses
import re
import sys
import time
from pathlib import Path

import numpy as np

from bench.results_common import write_report
from bench.results_repro import (TURN_RAD, _err, _predicted_and_true, _repo_path, calibrated_once, forget_if_retrained,
                                 main_with_models, origin_gain, own_pose_scores, pm, slam_scores, trained_models,
                                 vo_scores)
from bench.results_vo import _agg, _cached
from deepslam.core import metrics, se3
from deepslam.core.readers import open_sequence
from deepslam.vo.calibration import std_scale, within_one_sigma
from deepslam.vo.modelfiles.modelio import write_ensemble


@dataclasses.dataclass(frozen=True)
class LeverConfig:
    """What is scored and where."""

    models: str = "bench/paper_recipe"
    """Folder of the trained models (``scripts/train_paper_recipe.sh OUT``; relative to the repository)."""
    model_names: tuple[str, ...] = ("synthetic_mirror_cons_s0", "lever_synthetic_mirror_cons_s0",
                                    "synthetic_speedscale_mirror_cons_s0", "lever_synthetic_axlescale_mirror_cons_s0",
                                    "lever_synthetic_axlescale_mirror_cons_s1",
                                    "synthetic_dis_speedscale_mirror_body_cons_s0",
                                    "lever_synthetic_dis_axlescale_mirror_body_cons_s0",
                                    "lever_synthetic_dis_axlescale_mirror_body_mirrorframes_cons_s0",
                                    "lever_synthetic_dis_axlescale_mirror_body_mirrorframes_cons_s1",
                                    "lever_synthetic_dis_axlescale_mirror_body_mirrorframes_cons_s2",
                                    "lever_synthetic_dis_axlescale_mirror_body_mirrorframes_ppcrop_cons_s0",
                                    "supervised_cons_s0", "lever_supervised_cons_s0", "lever_supervised_cons_s1",
                                    "lever_supervised_cons_s2", "supervised_dis_cons_s0", "lever_supervised_dis_cons_s0",
                                    "lever_supervised_dis_cons_s1", "lever_supervised_dis_cons_s2")
    """Model folders under :attr:`models`, each trained on axle towns next to its ``lever_`` twin (the speed-freed
    models' twins scale the axle's motion: ``fit-motion --speed-scale-lever``; the ``_dis`` models trained on DIS flow,
    ``SYNTH_FLOW=dis``: the synthetic ones of views rendered from single frames, the supervised ones of the renders'
    pairs; ``_mirrorframes``: every single frame also flipped left-right, ``MIRROR_FRAMES=1``; ``_ppcrop``: trained on
    windows that move the principal point, with coordinate channels, ``PP_CROP=1``); absent ones skipped."""
    ensembles: tuple[tuple[str, tuple[str, ...]], ...] = (
        ("lever_synthetic_dis_axlescale_mirror_body_mirrorframes_cons_s0+s1",
         ("lever_synthetic_dis_axlescale_mirror_body_mirrorframes_cons_s0",
          "lever_synthetic_dis_axlescale_mirror_body_mirrorframes_cons_s1")),)
    """(name, member folders under :attr:`models`) of each seed ensemble scored as one more model (``deepslam
    ensemble-model``: the members' mean, the std their own plus their spread; written under ``out/eval``); one whose
    members have no finished ``model.safetensors`` each is skipped."""
    widened_cases: tuple[str, ...] = ("lever_dis", "kitti06_dis", "kitti07_dis")
    """Cases on which each model trained on DIS flow (``_dis_`` in its name) is read once more with its std widened by
    the geometry (``vo --std-from-geometry``) for the calibration block; () leaves it out."""
    mirror_average: bool = True
    """Each single model trained on mirrored frames (``_mirrorframes`` in its name) is read once more on every case with
    each flow also read mirrored and the two motions averaged (``vo --mirror-average on``), for the block that
    docs/experiments/2026-12-07_mirror_average.md's rule reads; False leaves it out."""
    lever_m: float = 0.84
    """Metres the held-out town's camera sits ahead of the rear axle in its lever render (KITTI's fit)."""
    heldout_seed: int = 7
    """Town of the held-out street (the training towns are 1 and 2)."""
    frames: int = 300
    """Frames of each held-out render (10 Hz)."""
    width: int = 414
    """Rendered width, pixels (the training renders')."""
    strides: tuple[int, ...] = (1, 2, 3)
    """Frame strides at which each model reads the KITTI slices for the distance table (:func:`straight_forward_gain`
    by the true length of a pair); () leaves the table out."""
    slam_seed: int = 7441
    """Town of the loop street (``render --route laps``, the camera :attr:`lever_m` ahead of the rear axle) on which
    ``deepslam slam`` runs each of :attr:`slam_models` with its own pose and the shipped NN_loops (0: none)."""
    slam_frames: int = 1900
    """Frames of the loop street (10 Hz; three laps of the town's block)."""
    slam_models: tuple[str, ...] = ("lever_synthetic_dis_axlescale_mirror_body_mirrorframes_cons",
                                    "lever_supervised_dis_cons")
    """Recipes (model names without the ``_sN`` seed) run through the SLAM on the loop street, every seed scored."""
    calibrated_cases: tuple[str, ...] = ("lever_dis", "kitti06_dis", "kitti07_dis")
    """Cases each model is read on with its std calibrated on the :attr:`calibration_seed` town (an unseen town
    rendered as KITTI's car moves, then the held-out town and the real slices)."""
    kitti_principal_point_px: tuple[float, float] | None = (203.0, 61.5)
    """Principal point (cx, cy) px of one more render of the held-out town with the lever (``render
    --principal-point``): KITTI 04-12's (601.89, 183.11 of 1226 x 370) at 414 x 125, to the half pixel: 3.5 px left
    of and 0.5 px above the centre. Read with DIS flow (case ``lever_pp_dis``) as read and centred, it asks whether
    the rendered street, given the real camera's principal point, predicts a model's KITTI figure; None: not
    rendered."""
    calibration_seed: int = 8101
    """Town on which each model's std is calibrated per DoF (``deepslam calibrate``, DIS flow, own pose), rendered
    as KITTI's car moves: the lever and KITTI's body pitch and roll (``--body-motion 1``); then read on the KITTI
    slices (0: none)."""


def turn_yaw_errors(mean6: np.ndarray, true6: np.ndarray) -> dict:
    """Mean yaw error (read - true, degrees) of the pairs turning left (true euler y > TURN_RAD), right (< -TURN_RAD)
    and of the rest (straight), with their counts; from (N, 6) float64 paper vectors of ``cam_j_from_cam_i`` (euler
    x, y, z in rad; t x, y, z in m). A reading that overshoots every turn gives a positive left and a negative right
    mean; None where no pair falls in a part."""
    err = np.degrees(mean6[:, 1] - true6[:, 1])
    parts = {"left": true6[:, 1] > TURN_RAD, "right": true6[:, 1] < -TURN_RAD}
    parts["straight"] = ~(parts["left"] | parts["right"])
    return {name: {"n": int(pick.sum()), "mean_deg": float(err[pick].mean()) if pick.any() else None,
                   "rms_deg": float(np.sqrt(np.mean(err[pick] ** 2))) if pick.any() else None}
            for name, pick in parts.items()}


def straight_forward_gain(mean6: np.ndarray, true6: np.ndarray, stride: int = 1) -> dict:
    """The forward distance read on the straight pairs: least-squares gain of read against true forward translation
    (t z of (N, 6) float64 paper vectors of ``cam_j_from_cam_i``, metres) over the pairs whose true yaw is at most
    ``stride`` x :data:`TURN_RAD` (a pair spans ``stride`` frames), with their count and mean true length (m). A
    network that reads every distance 10 % long gives 1.1 (:func:`bench.results_repro.origin_gain`); None where no
    pair is straight."""
    pick = np.abs(true6[:, 1]) <= stride * TURN_RAD
    true = true6[pick, 5]
    return {"n": int(pick.sum()), "gain": origin_gain(mean6[pick, 5], true),
            "true_m": float(np.abs(true).mean()) if pick.any() else None}


def drift_with_true_rotation(mean6: np.ndarray, true6: np.ndarray) -> dict:
    """:func:`core.metrics.drift` of consecutive pairs' motions (N, 6) chained with the true rotation (euler part of
    ``true6``) and the read translation, against the truth chained: the drift the network's translation alone
    leaves (path ratio, end-point drift in m and % of the path)."""
    mixed = np.c_[true6[:, :3], mean6[:, 3:]]
    return metrics.drift(se3.chain_euler6(true6), se3.chain_euler6(mixed))


def cross_calibrated(fit: tuple[np.ndarray, np.ndarray, np.ndarray], read: tuple[np.ndarray, np.ndarray, np.ndarray]
                     ) -> list[float]:
    """The per-DoF std factor fitted on one sequence's pairs (:func:`vo.calibration.std_scale`) applied to another's:
    the share of the other's pairs within the scaled 1-sigma, per DoF (euler x, y, z, t x, y, z; 0.68 calibrated).
    ``fit`` and ``read``: ``(mean6, std6, true6)``, (N, 6) float64 paper vectors each (rad, m;
    :func:`bench.results_repro._predicted_and_true`). What a user gets who calibrates on one recorded sequence of the
    camera and drives another."""
    scale = std_scale(fit[0] - fit[2], fit[1])
    return [float(x) for x in within_one_sigma(read[0] - read[2], read[1] * scale)]


def _cross_calibration(out: Path, kitti: Path, names: list[str]) -> dict:
    """Each model's (and the default's) std calibrated on one KITTI slice and read on the other, from the own-pose
    runs above: ``{name: {"06_on_07": [6 floats], "07_on_06": [...]}}``; none without both slices."""
    if not all((kitti / n).is_dir() for n in ("06", "07")):
        return {}
    table = {}
    for name in [*names, "default"]:
        runs = {n: _predicted_and_true(kitti / n, out / "runs" / f"{name}_kitti{n}_dis.motions.csv") for n in ("06", "07")}
        table[name] = {"06_on_07": cross_calibrated(runs["06"], runs["07"]),
                       "07_on_06": cross_calibrated(runs["07"], runs["06"])}
    return table


def _pair_figures(seq: Path, motions_csv: Path) -> dict:
    mean6, _, true6 = _predicted_and_true(seq, motions_csv)
    return {"turns": turn_yaw_errors(mean6, true6), "true_rotation": drift_with_true_rotation(mean6, true6)}


def run(cfg: LeverConfig, out: Path, data: Path) -> dict:
    from deepslam.studies.demo import render_once

    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    log: list[str] = []
    town = render_once("street", "car", cfg.frames, cfg.width, cfg.heldout_seed, out / f"street_s{cfg.heldout_seed}",
                       log, ("--quiet",))
    lever = render_once("street", "car", cfg.frames, cfg.width, cfg.heldout_seed,
                        out / f"street_s{cfg.heldout_seed}_lever", log, ("--camera-ahead", f"{cfg.lever_m:g}", "--quiet"))
    kitti = data / "kitti" / "sequences"
    cases = [("street_exact", town, "gt"), ("street_dis", town, "dis"), ("lever_exact", lever, "gt"),
             ("lever_dis", lever, "dis")]
    if cfg.kitti_principal_point_px is not None:
        pp = ",".join(f"{x:g}" for x in cfg.kitti_principal_point_px)
        cases.append(("lever_pp_dis", render_once(
            "street", "car", cfg.frames, cfg.width, cfg.heldout_seed, out / f"street_s{cfg.heldout_seed}_lever_pp", log,
            ("--camera-ahead", f"{cfg.lever_m:g}", "--principal-point", pp, "--quiet")), "dis"))
    cases += [(f"kitti{n}_dis", kitti / n, "dis") for n in ("06", "07") if (kitti / n).is_dir()]
    calibration = None if not cfg.calibration_seed else render_once(
        "street", "car", cfg.frames, cfg.width, cfg.calibration_seed, out / f"street_s{cfg.calibration_seed}_kitti_car",
        log, ("--camera-ahead", f"{cfg.lever_m:g}", "--body-motion", "1", "--quiet"))
    laps = None if not cfg.slam_seed else render_once(
        "street", "car", cfg.slam_frames, cfg.width, cfg.slam_seed, out / f"street_laps_s{cfg.slam_seed}_lever", log,
        ("--route", "laps", "--camera-ahead", f"{cfg.lever_m:g}", "--quiet"))
    off_centre = {case for case, seq, _ in cases if principal_point_off_centre(seq)}
    rows: dict = {}
    for name, model in trained_models(out, cfg.models, cfg.model_names) + _ensembles(cfg, out):
        rows[name] = {"file": str(model)}
        for case, seq, flow in cases:
            print(f"score {name}: {case}", flush=True)
            rec = own_pose_scores(out, f"{name}_{case}", seq, model, flow)
            rows[name][case] = {**rec, **_pair_figures(seq, out / "runs" / f"{name}_{case}.motions.csv")}
            if case in cfg.widened_cases and "_dis_" in name:
                rows[name][f"{case}_widened"] = own_pose_scores(out, f"{name}_{case}_widened", seq, model, flow,
                                                                "--std-from-geometry")
            if cfg.mirror_average and "_mirrorframes" in name and "+" not in name:  # a single mirror-trained model
                tag = f"{name}_{case}_mirrored"
                rec = own_pose_scores(out, tag, seq, model, flow, "--mirror-average", "on")
                rows[name][f"{case}_mirrored"] = {**rec, **_pair_figures(seq, out / "runs" / f"{tag}.motions.csv")}
            if case in off_centre:  # the principal point lies off the centre (KITTI's): read once more centred
                tag = f"{name}_{case}_centred"
                rec = own_pose_scores(out, tag, seq, model, flow, "--centre-principal-point")
                rows[name][f"{case}_centred"] = {**rec, **_pair_figures(seq, out / "runs" / f"{tag}.motions.csv")}
        if laps is not None and seed_stem(name) in cfg.slam_models:
            print(f"slam {name}: loop street {cfg.slam_seed}", flush=True)
            rows[name]["slam_laps_dis"] = _cached(out / "eval" / f"{name}_slam_laps.json", lambda: slam_scores(
                laps, out / "runs" / f"{name}_slam_laps.txt", "--model-cons", str(model), "--pose", "net"))
        if calibration is not None and model.name != "checkpoint.safetensors":  # a finished model or an ensemble
            calibrated = calibrated_once(out, f"{name}_cal", calibration, model)
            for case, seq, flow in cases:
                if case in cfg.calibrated_cases:
                    rows[name][f"{case}_cal"] = own_pose_scores(out, f"{name}_{case}_cal", seq, calibrated, flow)
    default = {}
    for case, seq, flow in cases:
        rec = _cached(out / "eval" / f"default_{case}.json",
                      lambda: vo_scores(seq, out / "runs" / f"default_{case}.txt", "--flow", flow))
        default[case] = {**rec, **_pair_figures(seq, out / "runs" / f"default_{case}.motions.csv")}
        if case in off_centre:
            tag = f"default_{case}_centred"
            rec = _cached(out / "eval" / f"{tag}.json", lambda: vo_scores(
                seq, out / "runs" / f"{tag}.txt", "--flow", flow, "--centre-principal-point"))
            default[f"{case}_centred"] = {**rec, **_pair_figures(seq, out / "runs" / f"{tag}.motions.csv")}
        if case in cfg.widened_cases:  # the default's own std (its network's) widened by its own geometry
            tag = f"default_{case}_widened"
            default[f"{case}_widened"] = _cached(out / "eval" / f"{tag}.json", lambda: vo_scores(
                seq, out / "runs" / f"{tag}.txt", "--flow", flow, "--std-from-geometry"))
    if laps is not None:
        print(f"slam default: loop street {cfg.slam_seed}", flush=True)
        default["slam_laps_dis"] = _cached(out / "eval" / "default_slam_laps.json",
                                           lambda: slam_scores(laps, out / "runs" / "default_slam_laps.txt"))
    report = {"config": dataclasses.asdict(cfg), "cases": [c for c, _, _ in cases], "models": rows,
              "default": default, "stride_gains": _stride_gains(cfg, out, rows, kitti),
              "cross_calibration": _cross_calibration(out, kitti, list(rows)), "renders": log,
              "minutes": (time.perf_counter() - t0) / 60}
    write_report(out, report, markdown)
    return report


def principal_point_off_centre(seq: Path) -> bool:
    """Whether the camera of sequence folder ``seq`` has its principal point more than a quarter pixel from the
    image's centre (KITTI's; a render with ``--principal-point``), so that ``vo --centre-principal-point`` moves it."""
    return max(abs(d) for d in open_sequence(seq).camera.principal_point_offset) > 0.25


def _ensembles(cfg: LeverConfig, out: Path) -> list[tuple[str, Path]]:
    """``(name, ensemble file)`` of each of :attr:`LeverConfig.ensembles` whose members all have a finished
    ``model.safetensors``, written to ``out/eval/{name}.safetensors`` (again each run: a member trained further makes
    another file, and :func:`bench.results_repro.forget_if_retrained` then clears the ensemble's evaluations)."""
    found = []
    for name, members in cfg.ensembles:
        files = [_repo_path(cfg.models) / m / "model.safetensors" for m in members]
        if all(f.is_file() for f in files):
            path = out / "eval" / f"{name}.safetensors"
            path.parent.mkdir(parents=True, exist_ok=True)
            write_ensemble(files, path)
            forget_if_retrained(out, name, path)
            found.append((name, path))
    return found


def _names(report: dict) -> list[str]:
    """The scored models of ``report`` in the config's order: the single models, then the ensembles."""
    cfg = report["config"]
    return [n for n in [*cfg["model_names"], *(e[0] for e in cfg.get("ensembles", ()))] if n in report["models"]]


def _stride_gains(cfg: LeverConfig, out: Path, rows: dict, kitti: Path) -> list[dict]:
    """Each scored model (and the default) on each KITTI slice at each of :attr:`LeverConfig.strides` (DIS flow,
    own pose; stride 1 is the slice's case above): :func:`straight_forward_gain` with the drift, by the pair's true
    length. Where a network's distance depends on the length of the motion (DIS's flow falls short of it the more
    the frames differ) and where on the sequence."""
    table = []
    for n in ("06", "07"):
        seq = kitti / n
        if not seq.is_dir():
            continue
        for stride in cfg.strides:
            for name in [*rows, "default"]:
                tag = f"{name}_kitti{n}_dis" + (f"_k{stride}" if stride != 1 else "")
                options = ("--flow", "dis", "--stride", str(stride))
                if name != "default":
                    options += ("--model", rows[name]["file"], "--pose", "net")
                rec = _cached(out / "eval" / f"{tag}.json", lambda: vo_scores(seq, out / "runs" / f"{tag}.txt", *options))
                mean6, _, true6 = _predicted_and_true(seq, out / "runs" / f"{tag}.motions.csv")
                table.append({"sequence": n, "stride": stride, "model": name, "drift_pct": rec["endpoint_drift_pct"],
                              **straight_forward_gain(mean6, true6, stride)})
    return table


CASE_TITLES = {"street_exact": "town 7 (camera on the rear axle), exact flow",
               "street_dis": "town 7 (camera on the rear axle), DIS flow",
               "lever_exact": "town 7 with the camera {lever_m:g} m ahead of the rear axle, exact flow",
               "lever_dis": "town 7 with the camera {lever_m:g} m ahead of the rear axle, DIS flow",
               "lever_pp_dis": "town 7 with the lever and KITTI's principal point, DIS flow",
               "kitti06_dis": "KITTI 06 slice (real), DIS flow", "kitti07_dis": "KITTI 07 slice (real), DIS flow"}


def _f(x, spec: str = ".3f") -> str:
    return "n/a" if x is None else format(x, spec)


def centred_ratios(report: dict, case: str) -> dict:
    """Per scored model of ``report`` with ``case`` read both ways: drift (t_err or end-point) centred / as read."""
    return {n: _err(r[f"{case}_centred"]) / _err(r[case]) for n, r in report["models"].items()
            if f"{case}_centred" in r and _err(r[case])}


def seed_stem(name: str) -> str | None:
    """The recipe of a model folder named ``{stem}_sN`` (one training seed): ``stem``; None for any other name (an
    ensemble ``_s0+s1``, a model without a seed)."""
    match = re.fullmatch(r"(.+)_s\d+", name)
    return match.group(1) if match else None


def seed_groups(names) -> dict[str, list[str]]:
    """The names that differ only in their seed suffix ``_sN``, grouped under the name without it (in order);
    groups of one left out."""
    groups: dict[str, list[str]] = {}
    for name in names:
        if stem := seed_stem(name):
            groups.setdefault(stem, []).append(name)
    return {stem: members for stem, members in groups.items() if len(members) > 1}


def _seeds_markdown(report: dict) -> list[str]:
    """Each recipe with several seeds scored: the mean +- std over its seeds of the drift and ATE of every case."""
    groups = seed_groups(_names(report))
    if not groups:
        return []
    readings = (("_centred", ", centred"), ("_mirrored", ", read also mirrored"))
    cases = [*report["cases"], *(c + suffix for suffix, _ in readings for c in report["cases"]
                                 if any(c + suffix in r for r in (report["default"], *report["models"].values())))]

    def title(case: str) -> str:
        for suffix, words in readings:
            if case.endswith(suffix):
                return CASE_TITLES[case.removesuffix(suffix)].format(**report["config"]) + words
        return CASE_TITLES[case].format(**report["config"])

    md = ["**Seeds of one recipe** (mean ± sample std over the seeds scored; t_err or drift [%], ATE [m]):", "",
          "| | seeds | " + " | ".join(title(c) for c in cases) + " |", "|---" * (2 + len(cases)) + "|"]
    for stem, members in groups.items():
        cells = []
        for c in cases:
            recs = [report["models"][m][c] for m in members if c in report["models"][m]]
            err, ate = _agg([_err(r) for r in recs]), _agg([r.get("ate_m") for r in recs])
            cells.append(f"{pm(err, '.2f')}, {pm(ate, '.2f')}" if err["n"] == ate["n"] == len(members) else "")
        seeds = ", ".join(m.rsplit("_s", 1)[1] for m in members)
        md.append(f"| {stem} | {seeds} | " + " | ".join(cells) + " |")
    md.append("")
    return md


def _short_title(case: str, report: dict) -> str:
    """The case's title up to its first comma (the flow left out), its lever filled in."""
    return CASE_TITLES[case].format(**report["config"]).split(",")[0]


def band_distance(shares) -> float:
    """Mean over the DoFs of |share within 1-sigma - 0.68| (0: a calibrated Gaussian on every DoF)."""
    return float(np.mean(np.abs(np.asarray(shares, dtype=np.float64) - 0.68)))


def in_band(shares) -> int:
    """How many DoFs' shares within 1-sigma lie in issue 56's band, 0.6-0.75."""
    return int(sum(0.6 <= x <= 0.75 for x in shares))


def _widened_markdown(report: dict) -> list[str]:
    """The block of the shares within 1-sigma as trained and with the std widened by the geometry."""
    cases = [c for c in report["cases"] if any(f"{c}_widened" in r for r in report["models"].values())]
    if not cases:
        return []
    md = ["**The std widened by the geometry** (`vo --std-from-geometry`: per DoF sqrt(std^2 + d^2), d the network's "
          "reading minus the epipolar fit's with the road's distance on the same flow; "
          "docs/experiments/2026-12-07_principal_point.md, section 5). Share of pairs within 1-sigma (euler x, y, z, "
          "t x, y, z; 0.68 calibrated), as trained -> widened, and the DoFs within 0.6-0.75:", "",
          "| | " + " | ".join(_short_title(c, report) for c in cases) + " |", "|---" * (1 + len(cases)) + "|"]
    for name, rec in [*((n, report["models"][n]) for n in _names(report)),
                      ("`deepslam vo`'s default", report["default"])]:
        if not any(f"{c}_widened" in rec for c in cases):
            continue
        cells = []
        for c in cases:
            a, b = rec[c]["within_1_sigma"], rec.get(f"{c}_widened", {}).get("within_1_sigma")
            cells.append("" if b is None else f"{', '.join(f'{x:.2f}' for x in a)} ({in_band(a)}) -> "
                         f"{', '.join(f'{x:.2f}' for x in b)} ({in_band(b)})")
        md.append(f"| {name} | " + " | ".join(cells) + " |")
    md.append("")
    for c in cases:
        pairs = [(r[c]["within_1_sigma"], r[f"{c}_widened"]["within_1_sigma"]) for r in report["models"].values()
                 if f"{c}_widened" in r]
        md.append(f"- {_short_title(c, report)}: median over {len(pairs)} models of the mean |share - 0.68| "
                  f"{np.median([band_distance(a) for a, _ in pairs]):.3f} -> {np.median([band_distance(b) for _, b in pairs]):.3f}; "
                  f"median DoFs within 0.6-0.75 {np.median([in_band(a) for a, _ in pairs]):g} -> "
                  f"{np.median([in_band(b) for _, b in pairs]):g}.")
    md.append("")
    return md


def _centred_markdown(report: dict) -> list[str]:
    """The block of each KITTI case read as recorded and with the principal point moved to the image's centre."""
    cases = [c for c in report["cases"] if f"{c}_centred" in report["default"]]
    if not cases:
        return []
    cfg = report["config"]
    md = ["**The principal point moved to the image's centre** (`vo --centre-principal-point`: the simulator renders "
          "every camera centred, KITTI 04-10's principal point lies 10.6 px left of the centre; "
          "docs/experiments/2026-12-07_principal_point.md). Drift [%], ATE [m] and the straight pairs' mean yaw error "
          "a pair [deg], as read -> centred:", "",
          "| | " + " | ".join(f"{_short_title(c, report)}: drift | ATE | straight yaw" for c in cases) + " |",
          "|---" * (1 + 3 * len(cases)) + "|"]
    named = [(n, report["models"][n]) for n in _names(report)]
    for name, rec in [*named, ("`deepslam vo`'s default", report["default"])]:
        cells = []
        for c in cases:
            a, b = rec[c], rec[f"{c}_centred"]
            cells += [f"{_f(_err(a), '.2f')} -> {_f(_err(b), '.2f')}", f"{_f(a['ate_m'])} -> {_f(b['ate_m'])}",
                      f"{_f(a['turns']['straight']['mean_deg'], '+.3f')} -> {_f(b['turns']['straight']['mean_deg'], '+.3f')}"]
        md.append(f"| {name} | " + " | ".join(cells) + " |")
    md.append("")
    for c in cases:
        ratios = centred_ratios(report, c)
        if ratios:
            md.append(f"- {_short_title(c, report)}: drift centred / as read, median over the models "
                      f"x{float(np.median(list(ratios.values()))):.2f} (range x{min(ratios.values()):.2f}-"
                      f"x{max(ratios.values()):.2f}); the default x{_err(report['default'][c + '_centred']) / _err(report['default'][c]):.2f}.")
    md.append("")
    return md


MIRROR_RULE = {"kitti": 0.90, "town": 1.05}
"""docs/experiments/2026-12-07_mirror_average.md, section 2: the mirror average becomes ``auto``'s default where the
median over the mirror-trained seeds of drift averaged / as read is at most this on each real slice (``kitti``) and
on each of the town's cases (``town``)."""
MIRROR_RULE_CASES = ("street_exact", "street_dis", "lever_exact", "lever_dis", "kitti06_dis", "kitti07_dis")
"""The cases that rule was written on (a case added later does not change its verdict)."""


def mirrored_ratios(report: dict) -> dict[str, dict[str, float]]:
    """``{case: {model: drift read also mirrored / as read}}`` of every model read both ways (t_err or drift)."""
    return {c: {n: _err(r[f"{c}_mirrored"]) / _err(r[c]) for n, r in report["models"].items()
                if f"{c}_mirrored" in r and _err(r[c]) and _err(r[f"{c}_mirrored"]) is not None}
            for c in report["cases"]}


def mirror_rule(report: dict) -> dict:
    """The rule of :data:`MIRROR_RULE` on ``report``: ``{"medians": {case: median ratio}, "passes": bool}`` (False
    where a case has no model read both ways)."""
    medians = {c: float(np.median(list(r.values()))) if r else None for c, r in mirrored_ratios(report).items()
               if c in MIRROR_RULE_CASES}
    passes = all(m is not None and m <= MIRROR_RULE["kitti" if c.startswith("kitti") else "town"]
                 for c, m in medians.items())
    return {"medians": medians, "passes": bool(medians) and passes}


def _mirrored_markdown(report: dict) -> list[str]:
    """The block of each mirror-trained model read as it is and with each flow also read mirrored."""
    named = [n for n in _names(report) if any(f"{c}_mirrored" in report["models"][n] for c in report["cases"])]
    if not named:
        return []
    cases = report["cases"]
    md = ["**Each flow read also mirrored** (`vo --mirror-average on`: the motion read from the flow mirrored left-right, "
          "mirrored back and averaged with the reading of the flow as it is; for models trained on mirrored frames; "
          "docs/experiments/2026-12-07_mirror_average.md). t_err or drift [%] as read -> averaged (ratio), and the "
          "shares within 1-sigma averaged:", "",
          "| | " + " | ".join(CASE_TITLES[c].format(**report["config"]) for c in cases) + " |",
          "|---" * (1 + len(cases)) + "|"]
    for name in named:
        rec = report["models"][name]
        cells = []
        for c in cases:
            a, b = rec.get(c), rec.get(f"{c}_mirrored")
            if not (a and b and _err(a) and _err(b) is not None):
                cells.append("")
                continue
            shares = ", ".join(f"{x:.2f}" for x in b.get("within_1_sigma") or [])
            cells.append(f"{_err(a):.2f} -> {_err(b):.2f} (x{_err(b) / _err(a):.2f}); {shares}")
        md.append(f"| {name} | " + " | ".join(cells) + " |")
    rule = mirror_rule(report)
    md += ["", "Median over the models of averaged / as read: " + ", ".join(
        f"{_short_title(c, report)}{', exact' if c.endswith('exact') else ', DIS' if c.endswith('dis') else ''} "
        + ("n/a" if m is None else f"x{m:.2f}") for c, m in rule["medians"].items())
        + f". The rule (at most x{MIRROR_RULE['kitti']:.2f} on each KITTI slice, x{MIRROR_RULE['town']:.2f} on each "
          f"town case): {'met' if rule['passes'] else 'not met'}.", ""]
    return md


def _slam_markdown(report: dict) -> list[str]:
    """The loop street's block: VO and SLAM ATE of each model run through ``deepslam slam``, and the default's."""
    rows = [(n, report["models"][n]["slam_laps_dis"]) for n in _names(report) if "slam_laps_dis" in report["models"][n]]
    default = report["default"].get("slam_laps_dis")
    if not rows and not default:
        return []
    cfg = report["config"]
    md = [f"**Loop street** (`render --route laps`, town {cfg['slam_seed']}, {cfg['slam_frames']} frames, the camera "
          f"{cfg['lever_m']:g} m ahead of the rear axle), DIS flow: `deepslam slam` with each NN_cons (its own pose) "
          "and the shipped NN_loops, and `deepslam slam`'s default", "",
          "| | VO ATE [m] | SLAM ATE [m] | SLAM / VO | VO path ratio | loop edges (kept) |", "|---|---|---|---|---|---|"]
    for name, r in [*rows, *([("`deepslam slam`'s default", default)] if default else [])]:
        md.append(f"| {name} | {_f(r['vo_ate_m'])} | {_f(r['slam_ate_m'])} | {_f(r['slam_over_vo'], '.2f')} | "
                  f"{_f(r['vo_path_ratio'])} | {r['loops']} ({r['loops_kept']}) |")
    md.append("")
    return md


def markdown(report: dict) -> str:
    cfg = report["config"]
    md = ["Each model's own pose (`vo --pose net`); t_err [%], or the end-point drift [% of path] on a route under "
          "100 m; the mean yaw error (read - true, deg) of the pairs turning left, right and of the straight ones "
          "(a reading that overshoots the turns: left > 0, right < 0); the drift once the true rotation replaces "
          "the network's; the share of pairs whose error is within the predicted 1-sigma, per DoF (a calibrated "
          "Gaussian: 0.68; the default's std is its own model's).", ""]
    for case in report["cases"]:
        md += [f"**{CASE_TITLES[case].format(**cfg)}**", "",
               "| | ATE [m] | t_err or drift [%] | path ratio | yaw error: left / right / straight [deg] | "
               "drift with the true rotation [%] | within 1-sigma: euler x, y, z, t x, y, z |", "|---|---|---|---|---|---|---|"]
        named = [(n, report["models"][n]) for n in _names(report)]
        for name, rec in [*named, ("`deepslam vo`'s default", report["default"])]:
            r = rec[case]
            turns = " / ".join(f"{_f(r['turns'][p]['mean_deg'], '+.3f')} ({r['turns'][p]['n']})"
                               for p in ("left", "right", "straight"))
            md.append(f"| {name} | {_f(r['ate_m'])} | {_f(_err(r), '.2f')} | {_f(r['path_length_ratio'])} | {turns} | "
                      f"{_f(r['true_rotation']['endpoint_drift_pct'], '.2f')} | "
                      f"{', '.join(_f(x, '.2f') for x in r.get('within_1_sigma') or [])} |")
        md.append("")
    md += _seeds_markdown(report)
    md += _slam_markdown(report)
    md += _centred_markdown(report)
    md += _mirrored_markdown(report)
    md += _widened_markdown(report)
    cal_cases = [c for c in report["cases"] if any(f"{c}_cal" in r for r in report["models"].values())]
    if cal_cases:
        md += [f"Each model's std calibrated per DoF on town {cfg['calibration_seed']} rendered as KITTI's car moves "
               f"(the camera {cfg['lever_m']:g} m ahead of the rear axle, `--body-motion 1`; `deepslam calibrate`, DIS "
               "flow), then the share of pairs within 1-sigma per DoF (euler x, y, z, t x, y, z; 0.68 calibrated) and "
               "the DoFs within 0.6-0.75:", "",
               "| | " + " | ".join(CASE_TITLES[c].format(**cfg) for c in cal_cases) + " |",
               "|---" * (1 + len(cal_cases)) + "|"]
        for n in _names(report):
            rec = report["models"][n]
            if any(f"{c}_cal" in rec for c in cal_cases):
                md.append(f"| {n} | " + " | ".join(
                    "" if f"{c}_cal" not in rec else ", ".join(f"{x:.2f}" for x in rec[f"{c}_cal"]["within_1_sigma"])
                    + f" ({in_band(rec[f'{c}_cal']['within_1_sigma'])})" for c in cal_cases) + " |")
        md.append("")
    cross = report.get("cross_calibration") or {}
    if cross:
        md += ["Each std calibrated per DoF on one real slice (`deepslam calibrate`'s factor, fitted on its pairs) and "
               "read on the other: the share of pairs within 1-sigma (euler x, y, z, t x, y, z; 0.68 calibrated):", "",
               "| | calibrated on KITTI 06, read on 07 | calibrated on KITTI 07, read on 06 |", "|---|---|---|"]
        for name, rec in cross.items():
            label = "`deepslam vo`'s default" if name == "default" else name
            md.append(f"| {label} | " + " | ".join(", ".join(f"{x:.2f}" for x in rec[k]) for k in ("06_on_07", "07_on_06"))
                      + " |")
        md.append("")
    gains = report.get("stride_gains") or []
    if gains:
        # a column's straight pairs, and so their true length, are the same for every model
        length = {(g["sequence"], g["stride"]): g["true_m"] for g in gains}
        cols = sorted(length, key=lambda c: length[c] or 0.0)
        md += ["**The distance against the length of the motion.** Each model on the KITTI slices at frame strides "
               f"{', '.join(map(str, cfg['strides']))} (DIS flow, own pose): the forward gain of the straight pairs "
               "(read against true forward translation, least squares; 1.00 reads the distance) and the drift [%], "
               "the columns by the mean true length of a straight pair:", "",
               "| | " + " | ".join(f"KITTI {q}, stride {k}" for q, k in cols) + " |", "|---" * (len(cols) + 1) + "|",
               "| true length of a pair [m] | " + " | ".join(_f(length[c], ".2f") for c in cols) + " |"]
        for name in dict.fromkeys(g["model"] for g in gains):
            by = {(g["sequence"], g["stride"]): g for g in gains if g["model"] == name}
            label = "`deepslam vo`'s default" if name == "default" else name
            md.append(f"| {label} | " + " | ".join(
                f"x{_f(by[c]['gain'])} ({_f(by[c]['drift_pct'], '.1f')})" if c in by else "" for c in cols) + " |")
        md.append("")
    md += ["Renders: " + "; ".join(f"`{c}`" for c in report["renders"]), "",
           f"Run time: {report['minutes']:.1f} min."]
    return "\n".join(md) + "\n"


def main(argv: list[str] | None = None) -> int:
    return main_with_models("results_lever", __doc__, LeverConfig(), lambda cfg: dataclasses.replace(
        cfg, frames=40, width=207, strides=(1, 2)), "lever", run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
