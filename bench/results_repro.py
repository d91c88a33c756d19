"""``python -m bench.results_repro``: the paper's recipe at scale, synthetic from single frames against supervised.

Scores the NN_cons models that ``scripts/train_paper_recipe.sh`` trains (the cpu preset, the paper's L1 loss,
cyclic learning rate and stride mixture, 2,000,000 samples a model; synthetic: single frames of two rendered
towns with motions drawn from a kernel density fit of their routes; supervised: the same renders' frame pairs
with exact flow and ground-truth poses) with the network's own pose (``vo --pose net``) on data none of them
saw: a held-out simulated street (another town, 10 Hz) with the simulator's exact flow and with DIS flow, and
the real KITTI 07 slice with DIS flow. Beside them, on the same data, the geometry default (``deepslam vo``'s
shipped model, essential matrix and road scale). Each model's learning curve (held-out RMSE of the forward
translation and of the yaw against samples seen) is plotted from its ``history.json`` with a power-law fit
of its second half, which says what twice the samples would give.

The paper preset's models (``NET=paper``, the paper's 96 x 320 network) are scored beside them from
``bench/paper_recipe_paper``.

``--models DIR``: the folder of the training script (default ``bench/paper_recipe``, where the trained files
are kept: ``{synthetic,supervised}_cons_s{SEED}/model.safetensors`` or ``checkpoint.safetensors`` of a run still
going, and their ``history.json``). Writes ``results.json``, ``results.md`` and ``learning_curve.png`` under
``--out``; evaluations are cached there (a killed run resumes; a model whose file changed, a checkpoint trained
further, is scored again).
"""
from __future__ import annotations

import argparse
import dataclasses
import glob
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from bench.results_common import write_report
from bench.results_vo import _agg, _cached, metric_subset
from deepslam.core import atomic, se3
from deepslam.core.integrity import sha256_file
from deepslam.core.readers import open_sequence
from deepslam.core.trajio import read_trajectory

SYNTHETIC_MODES = ("synthetic", "synthetic_mirror", "synthetic_speedscale_mirror", "synthetic_dis",
                   "synthetic_dis_speedscale", "synthetic_dis_mirror", "synthetic_dis_speedscale_mirror",
                   "synthetic_dis_mirror_body", "synthetic_dis_speedscale_mirror_body")
"""Training folders of single-frame training: on exact synthesized flow (the paper) and on DIS flow of the second
view rendered from each frame (``SYNTH_FLOW=dis``); ``_speedscale``: the motions' turn radius freed
(``SPEED_SCALE=0.4,1.5``: each drawn translation scaled by a log-uniform factor, ``fit-motion --speed-scale``);
``_mirror``: the motions fitted together with their left-right mirror images (``fit-motion --mirror``: the training
towns turn one way only), the recipe script's default prior (``MIRROR=0``: without); ``_body``: KITTI 00-05 and 08-10's
frame-to-frame pitch and roll added to each drawn motion (``BODY=1``, ``fit-motion --body-from``)."""
SUPERVISED_MODES = ("supervised", "supervised_samepatience", "supervised_dis")
"""Training folders of supervised training: by the recipe (its patience in epochs of its ~1,100 pairs), with
the patience in samples matched to the synthetic run's (186 epochs = 10 x 20,000 samples), which lets it train
for the same budget, and by the recipe on DIS flow of the same pairs (``SYNTH_FLOW=dis``: the frames read at
640 px as ``vo`` reads them), the comparison at equal flow for the synthetic models on DIS flow."""
MODES = SYNTHETIC_MODES + SUPERVISED_MODES
"""Training folders ``{mode}_cons_s{seed}``."""
MODE_LABELS = {"synthetic": "synthetic", "synthetic_mirror": "synthetic, turns both ways (mirrored motions)",
               "synthetic_speedscale_mirror": "synthetic, turn radius freed, turns both ways",
               "synthetic_dis": "synthetic on DIS flow of rendered views",
               "synthetic_dis_speedscale": "synthetic on DIS flow of rendered views, turn radius freed",
               "synthetic_dis_mirror": "synthetic on DIS flow of rendered views, turns both ways (mirrored motions)",
               "synthetic_dis_speedscale_mirror": "synthetic on DIS flow of rendered views, turn radius freed, turns both "
                                                  "ways",
               "synthetic_dis_mirror_body": "synthetic on DIS flow of rendered views, turns both ways, KITTI's body "
                                            "pitch and roll",
               "synthetic_dis_speedscale_mirror_body": "synthetic on DIS flow of rendered views, turn radius freed, "
                                                       "turns both ways, KITTI's body pitch and roll",
               "supervised": "supervised", "supervised_samepatience": "supervised, patience matched in samples",
               "supervised_dis": "supervised on DIS flow of the renders' pairs"}
PAPER_FIGURES = ("The paper's own figures (KITTI 00-10, its devkit's t_err [%] / r_err [deg/100 m], NN_cons with its "
                 "own pose): trained on single frames 5.57 ± 0.33 / 2.23 ± 0.15, supervised 2.07 ± 0.03 / 0.93 ± 0.04 "
                 "(x2.7); its SLAM 3.37 / 1.24 (single frames) and 1.54 / 0.74 (supervised); ORB-SLAM2 2.41 / 0.245. "
                 "Its network trained on single frames reads KITTI at 2.3x ORB-SLAM2's t_err.")
PAPER = "paper:"
"""Row-key prefix of the paper preset's models (96 x 320 input, 64 filters, 2 x 500 units a branch)."""


def label(key: str) -> str:
    """Table label of a row key (``mode`` or ``paper:mode``)."""
    if key.startswith(PAPER):
        return f"paper preset, {MODE_LABELS[key[len(PAPER):]]}"
    return f"cpu preset, {MODE_LABELS[key]}"


def compared_with(mode: str) -> tuple[str, ...]:
    """The supervised modes a synthetic mode's ratio is taken against: those trained on the same kind of flow
    (exact, or DIS for the synthetic models on DIS flow)."""
    if mode.startswith("synthetic_dis"):
        return ("supervised_dis",)
    return tuple(m for m in SUPERVISED_MODES if m != "supervised_dis")


CALIBRATED_ON = {"cal06": "KITTI 06", "calstreet": "another unseen street (town {calibration_seed})",
                 "calbody": "another unseen street with KITTI's body pitch and roll (town {calibration_seed})"}
"""Tag of a calibration (a case ``{case}_{tag}`` was scored with the model's std calibrated first), and on what."""


def _err(rec: dict) -> float | None:
    """The figure the issue's ratios read: t_err [%], or the end-point drift [% of path] on a route under 100 m."""
    return rec.get("kitti_t_err_pct") or rec.get("endpoint_drift_pct")


REPO = Path(__file__).resolve().parents[1]


@dataclasses.dataclass(frozen=True)
class ReproConfig:
    """What is scored and where."""

    models: str = "bench/paper_recipe"
    """Folder of the trained models (``scripts/train_paper_recipe.sh OUT``; relative to the repository)."""
    paper_models: str = "bench/paper_recipe_paper"
    """Folder of the paper preset's models (``NET=paper scripts/train_paper_recipe.sh OUT``; "" = none)."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Training seeds to score (a row's mean +- std is over those present)."""
    width: int = 414
    """Rendered width of the held-out street, pixels (the training renders' width)."""
    heldout_seed: int = 7
    """Town of the held-out street (the training towns are 1 and 2)."""
    heldout_frames: int = 300
    """Frames of the held-out street (10 Hz)."""
    body_motion: float = 1.0
    """The held-out street rendered a second time with the car body's pitch and roll (``render --body-motion``,
    a multiple of KITTI's), scored on DIS flow: the towns' car has none, KITTI's has (0: not rendered)."""
    slam_seed: int = 7441
    """Town of the loop street (``render --route laps``) on which VO and SLAM are compared (0: none)."""
    slam_frames: int = 1900
    """Frames of the loop street."""
    slam_modes: tuple[str, ...] = ("synthetic", "synthetic_mirror", "synthetic_dis", "synthetic_dis_speedscale",
                                   "synthetic_dis_mirror", "synthetic_dis_speedscale_mirror", "synthetic_dis_mirror_body",
                                   "synthetic_dis_speedscale_mirror_body", "supervised")
    """Training modes scored with SLAM (each seed present, both presets)."""
    calibration_seed: int = 8101
    """Town of a simulated street (as the held-out one) on which seed 0's std is calibrated per DoF and then read
    on town 7 and the KITTI slices, beside the calibration on KITTI 06 (0: none); with :attr:`body_motion` also
    on that street rendered with the body's pitch and roll."""
    decompose_seeds: tuple[int, ...] = (0,)
    """Seeds whose models are scored a second time on the DIS cases with the essential matrix's rotation and
    direction and the network's distance (``vo --pose epipolar --scale network``): the drift left is the
    network's reading of scale, the rest was its rotation."""


def _model_file(folder: Path) -> Path | None:
    for name in ("model.safetensors", "checkpoint.safetensors"):
        if (folder / name).is_file():
            return folder / name
    return None


def _repo_path(path: str) -> Path:
    """``path`` as given when absolute, else relative to the repository."""
    return Path(path) if Path(path).is_absolute() else REPO / path


def trained_models(out: Path, folder: str, names) -> list[tuple[str, Path]]:
    """``(name, model file)`` of each of ``names`` that has one under ``folder`` (relative to the repository unless
    absolute; :func:`_model_file`), in order, absent ones left out; the cached evaluations of one whose file
    changed are cleared under ``out`` (:func:`forget_if_retrained`)."""
    found = []
    for name in names:
        model = _model_file(_repo_path(folder) / name)
        if model is not None:
            forget_if_retrained(out, name, model)
            found.append((name, model))
    return found


def _run_json(command: str, seq_dir: Path, out_txt: Path, options: tuple[str, ...]) -> dict:
    """``deepslam COMMAND --sequence SEQ_DIR --out OUT_TXT OPTIONS --json`` as a user runs it (a child process):
    the record it prints. RuntimeError with the end of its stderr when it fails."""
    argv = [sys.executable, "-m", "deepslam", command, "--sequence", str(seq_dir), "--out", str(out_txt), *options,
            "--json", "--quiet"]
    p = subprocess.run(argv, capture_output=True, text=True, cwd=REPO)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(argv[2:])} failed: {p.stderr.strip()[-500:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def vo_scores(seq_dir: Path, out_txt: Path, *options: str) -> dict:
    """``deepslam vo`` (:func:`_run_json`): its metrics (se3-aligned): ATE, RPE, KITTI t_err / r_err, path ratio
    and end-point drift, and the share of pairs within the predicted 1-sigma."""
    m = _run_json("vo", seq_dir, out_txt, options)["metrics"]
    return {**metric_subset(m), "path_length_ratio": m.get("path_length_ratio"),
            "endpoint_drift_pct": m.get("endpoint_drift_pct"),
            "within_1_sigma": within_one_sigma(seq_dir, out_txt.with_suffix(".motions.csv"))}


def calibrated_once(out: Path, stem: str, cal_seq: Path, model: Path) -> Path:
    """``model`` with its predicted std fitted per DoF on ``cal_seq`` (``deepslam calibrate``, DIS flow, own pose),
    written to ``out/eval/{stem}.safetensors`` once (a killed run resumes; :func:`forget_if_retrained` clears it
    with the model's other evaluations)."""
    calibrated = out / "eval" / f"{stem}.safetensors"
    if not calibrated.is_file():
        _run_json("calibrate", cal_seq, calibrated, (str(model), "--pose", "net"))
    return calibrated


def own_pose_scores(out: Path, tag: str, seq_dir: Path, model: Path, flow: str, *options: str) -> dict:
    """:func:`vo_scores` of ``model``'s own pose (``vo --pose net``) on ``seq_dir`` with ``flow`` and any further
    ``vo`` ``options``, cached in ``out/eval/{tag}.json`` (a killed run resumes); the run's files are
    ``out/runs/{tag}.*``."""
    return _cached(out / "eval" / f"{tag}.json", lambda: vo_scores(
        seq_dir, out / "runs" / f"{tag}.txt", "--model", str(model), "--flow", flow, "--pose", "net", *options))


def forget_if_retrained(out: Path, stem: str, model: Path) -> None:
    """Clear the cached evaluations of ``stem`` (``out/eval/{stem}_*``, ``out/runs/{stem}_*``) when ``model`` is
    not the file they were scored from: ``out/eval/{stem}.sha256`` keeps the digest of the model file scored
    (written on first use, so a cache made before it is adopted as it stands). A checkpoint trained further, or a
    model trained again, is scored again."""
    digest = sha256_file(model)
    sidecar = out / "eval" / f"{stem}.sha256"
    if sidecar.is_file() and sidecar.read_text().strip() != digest:
        for folder in (out / "eval", out / "runs"):
            for stale in folder.glob(f"{glob.escape(stem)}_*"):
                stale.unlink()
    sidecar.parent.mkdir(parents=True, exist_ok=True)
    atomic.write_text(sidecar, digest + "\n")


def model_card(model: Path, curve: dict) -> dict:
    """What the table says of a trained model: its file (relative to the repository), the samples it saw (from
    its :func:`learning_curve`), why it stopped (``summary.json``; "still training" for a checkpoint) and where
    it was trained (``config.json``)."""
    folder = model.parent
    summary = json.loads((folder / "summary.json").read_text()) if (folder / "summary.json").is_file() else {}
    config = json.loads((folder / "config.json").read_text()) if (folder / "config.json").is_file() else {}
    return {"file": str(model.relative_to(REPO) if model.is_relative_to(REPO) else model),
            "samples": int((curve.get("samples") or [0])[-1]), "stop": summary.get("stop_reason", "still training"),
            "device": config.get("train", {}).get("device", "n/a")}


def slam_scores(seq_dir: Path, out_txt: Path, *options: str) -> dict:
    """``deepslam slam`` (:func:`_run_json`): VO and SLAM ATE (m, se3-aligned), the SLAM / VO ratio, the VO's path
    ratio and the loop edges found and kept."""
    r = _run_json("slam", seq_dir, out_txt, options)
    vo, slam = r["metrics_vo"]["ate_m"], r["metrics_slam"]["ate_m"]
    return {"vo_ate_m": vo, "slam_ate_m": slam, "slam_over_vo": slam / vo if vo else None, "loops": r["n_loops"],
            "loops_kept": int(sum(r.get("loops_kept_by_pose_graph") or [])),
            "vo_path_ratio": r["metrics_vo"].get("path_length_ratio")}


def _predicted_and_true(seq_dir: Path, motions_csv: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean6, std6, true6) per pair of a ``vo`` run's motions CSV: (N, 6) float64 paper vectors of
    ``cam_j_from_cam_i`` (euler x, y, z in rad; t x, y, z in m), the predicted std and the ground truth's. Where
    the sequence has a ground-truth pose per frame, a pair's are its frames'; else (TUM: the ground truth at its
    own times) they are interpolated at the pair's times, and the pairs outside the ground truth's time span are
    left out (N is then less than the CSV's rows)."""
    seq = open_sequence(seq_dir)
    rows = np.loadtxt(motions_csv, delimiter=",", skiprows=1, ndmin=2)
    gt = seq.gt
    if len(gt) == len(seq):  # a ground-truth pose per frame
        world_from_i, world_from_j = (gt.world_from_cam[rows[:, c].astype(int)] for c in (0, 1))
    else:  # ground truth at its own times (TUM): interpolated at the pair's, pairs outside it left out
        t0, t1 = gt.timestamps_s[0], gt.timestamps_s[-1]
        rows = rows[(rows[:, 2] >= t0) & (rows[:, 3] <= t1)]
        world_from_i, world_from_j = (gt.interpolate(rows[:, c]).world_from_cam for c in (2, 3))
    return rows[:, 4:10], rows[:, 10:16], se3.to_euler6(se3.relative(world_from_j, world_from_i)).reshape(-1, 6)


def within_one_sigma(seq_dir: Path, motions_csv: Path) -> list[float]:
    """Per DoF (euler x, y, z, t x, y, z), the share of pairs whose error against the ground truth's
    ``cam_j_from_cam_i`` is within the predicted 1-sigma (a calibrated Gaussian gives 0.68)."""
    mean6, std6, true6 = _predicted_and_true(seq_dir, motions_csv)
    return [float(x) for x in (np.abs(mean6 - true6) <= std6).mean(axis=0)]


TURN_RAD = 0.01
"""A pair turns if the ground truth's yaw (euler y of ``cam_j_from_cam_i``) exceeds this, radians (0.57 deg)."""


def origin_gain(read: np.ndarray, true: np.ndarray) -> float | None:
    """Least-squares ``read = gain * true`` through the origin of two (N,) float64 arrays (one DoF of N pairs, in
    the same unit): the share of ``true`` that ``read`` reads (1: all of it); None for no pair or an all-zero truth."""
    return float(read @ true / (true @ true)) if len(true) and true @ true > 0 else None


def gains(mean6: np.ndarray, true6: np.ndarray) -> dict:
    """Per pair, the read yaw (euler y, about the camera's vertical axis) and forward translation (t z) against the
    ground truth's, from (N, 6) float64 paper vectors of ``cam_j_from_cam_i`` (euler x, y, z in rad; t x, y, z in
    m): ``yaw`` and ``forward`` over all pairs, the gain (least-squares ``read = gain * true`` through the origin:
    for t z the share of the distance read, for the yaw the share of the turns read) and the RMS of ``read - true``
    (degrees for the yaw, metres for t z); ``left`` and ``right`` the yaw and forward gains on the turning pairs of
    each sign (euler y > TURN_RAD: a left turn, the way the training towns turn; < -TURN_RAD: a right turn) and their
    count ``n`` (gains None where no pair turns that way). Gain 1 and RMS 0 are a perfect reading."""
    out: dict = {}
    for name, k, unit in (("yaw", 1, np.degrees(1.0)), ("forward", 5, 1.0)):
        read, true = mean6[:, k], true6[:, k]
        out[name] = {"gain": origin_gain(read, true), "rms": float(np.sqrt(np.mean((read - true) ** 2)) * unit)}
    for side, pick in (("left", true6[:, 1] > TURN_RAD), ("right", true6[:, 1] < -TURN_RAD)):
        out[side] = {"n": int(pick.sum()), "yaw_gain": origin_gain(mean6[pick, 1], true6[pick, 1]),
                     "forward_gain": origin_gain(mean6[pick, 5], true6[pick, 5])}
    return out


def yaw_and_forward_fit(seq_dir: Path, motions_csv: Path) -> dict:
    """:func:`gains` of a ``vo`` run's motions CSV against the sequence's ground truth."""
    mean6, _, true6 = _predicted_and_true(seq_dir, motions_csv)
    return gains(mean6, true6)


def trajectory_fit(seq_dir: Path, trajectory_txt: Path) -> dict:
    """:func:`gains` (its dict) of consecutive frames' motions ``cam_{k+1}_from_cam_k`` read off a camera
    trajectory file (KITTI or TUM ``world_from_cam``, one pose per frame of the sequence, matched by index) against
    the sequence's ground truth."""
    est = read_trajectory(trajectory_txt)
    gt = open_sequence(seq_dir).gt
    if len(est) != len(gt):
        raise ValueError(f"{trajectory_txt}: {len(est)} poses for {len(gt)} frames")
    return gains(se3.to_euler6(est.relative_motions()), se3.to_euler6(gt.relative_motions()))


def learning_curve(history: Path) -> dict:
    """Held-out RMSE per stage-1 epoch of a run's ``history.json``: samples seen, forward translation t_z (m)
    and yaw (rad), with a power law ``rmse = a * samples^b`` fitted to the second half of the epochs and
    its value at twice the samples (what more training predicts)."""
    rows = [r for r in json.loads(history.read_text()) if r.get("stage") == 1 and r.get("val_rmse6")]
    samples = np.cumsum([r["samples"] for r in rows]).astype(np.float64)
    out = {"samples": samples.tolist(), "lr_max": [r["lr_max"] for r in rows]}
    for name, k in (("t_z_m", 5), ("yaw_rad", 1)):
        y = np.array([r["val_rmse6"][k] for r in rows])
        out[name] = y.tolist()
        half = slice(len(y) // 2, None)
        if len(y) >= 6 and (y[half] > 0).all():
            b, log_a = np.polyfit(np.log(samples[half]), np.log(y[half]), 1)
            out[f"{name}_fit"] = {"exponent": float(b), "at_2x": float(np.exp(log_a) * (2 * samples[-1]) ** b),
                                  "last": float(y[-1])}
    return out


def plot_curves(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for label, c in curves.items():
        for ax, key in zip(axes, ("t_z_m", "yaw_rad")):
            ax.loglog(c["samples"], c[key], label=label)
    axes[0].set(xlabel="training samples", ylabel="held-out RMSE of t_z [m]")
    axes[1].set(xlabel="training samples", ylabel="held-out RMSE of yaw [rad]")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(cfg: ReproConfig, out: Path, data: Path) -> dict:
    from deepslam.studies.demo import render_once

    models_dir = _repo_path(cfg.models)
    out.mkdir(parents=True, exist_ok=True)
    log: list[str] = []
    t0 = time.perf_counter()
    held = render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                       out / f"street_heldout_s{cfg.heldout_seed}", log, ("--quiet",))
    kitti = data / "kitti" / "sequences"
    cases = [("street_exact", held, "gt"), ("street_dis", held, "dis")]
    swaying = ("--body-motion", f"{cfg.body_motion:g}", "--quiet")  # render flags of the streets with body motion
    if cfg.body_motion:
        cases.append(("street_body_dis", render_once(
            "street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
            out / f"street_heldout_s{cfg.heldout_seed}_body", log, swaying), "dis"))
    cases += [(f"kitti{n}_dis", kitti / n, "dis") for n in ("06", "07") if (kitti / n).is_dir()]
    slam_seq = None if not cfg.slam_seed else render_once(
        "street", "car", cfg.slam_frames, cfg.width, cfg.slam_seed, out / f"street_laps_s{cfg.slam_seed}", log,
        ("--route", "laps", "--quiet"))
    calibration_seqs = {tag: seq for tag, seq in zip(CALIBRATED_ON, (
        kitti / "06" if (kitti / "06").is_dir() else None,
        render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.calibration_seed,
                    out / f"street_calibration_s{cfg.calibration_seed}", log, ("--quiet",))
        if cfg.calibration_seed else None,
        render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.calibration_seed,
                    out / f"street_calibration_s{cfg.calibration_seed}_body", log, swaying)
        if cfg.calibration_seed and cfg.body_motion else None)) if seq is not None}
    folders = [("", models_dir)]
    if cfg.paper_models:
        folders.append((PAPER, _repo_path(cfg.paper_models)))
    rows: dict = {}
    curves, trained = {}, {}
    for prefix, folder_root in folders:
        for mode in MODES:
            key = prefix + mode
            for seed in cfg.seeds:
                folder = folder_root / f"{mode}_cons_s{seed}"
                model = _model_file(folder)
                if model is None:
                    continue
                if (folder / "history.json").is_file():
                    curves[f"{key} s{seed}"] = learning_curve(folder / "history.json")
                trained[f"{key} s{seed}"] = model_card(model, curves.get(f"{key} s{seed}", {}))
                forget_if_retrained(out, f"{key}_s{seed}", model)
                rec = {"seed": seed}
                for name, seq, flow in cases:
                    print(f"score {key} seed {seed}: {name}", flush=True)
                    rec[name] = own_pose_scores(out, f"{key}_s{seed}_{name}", seq, model, flow)
                    if flow == "dis" and seed in cfg.decompose_seeds:
                        rec[f"{name}_fit"] = yaw_and_forward_fit(seq, out / "runs" / f"{key}_s{seed}_{name}.motions.csv")
                        rec[f"{name}_epipolar"] = _cached(
                            out / "eval" / f"{key}_s{seed}_{name}_epipolar.json", lambda: vo_scores(
                                seq, out / "runs" / f"{key}_s{seed}_{name}_epipolar.txt", "--model", str(model),
                                "--flow", flow, "--pose", "epipolar", "--scale", "network"))
                for tag, cal_seq in calibration_seqs.items():
                    if seed not in cfg.decompose_seeds or model.name != "model.safetensors":
                        continue
                    # the predicted std fitted per DoF on a validation sequence with ground truth (`deepslam
                    # calibrate`, DIS flow), then read on the DIS cases that sequence is not
                    calibrated = calibrated_once(out, f"{key}_s{seed}_{tag}", cal_seq, model)
                    for name, seq, flow in cases:
                        if flow == "dis" and seq != cal_seq:
                            rec[f"{name}_{tag}"] = _cached(
                                out / "eval" / f"{key}_s{seed}_{name}_{tag}.json", lambda: vo_scores(
                                    seq, out / "runs" / f"{key}_s{seed}_{name}_{tag}.txt", "--model", str(calibrated),
                                    "--flow", flow, "--pose", "net"))
                if slam_seq is not None and mode in cfg.slam_modes:
                    print(f"slam {key} seed {seed}: loop street {cfg.slam_seed}", flush=True)
                    rec["slam_laps_dis"] = _cached(out / "eval" / f"{key}_s{seed}_slam_laps.json", lambda: slam_scores(
                        slam_seq, out / "runs" / f"{key}_s{seed}_slam_laps.txt", "--model-cons", str(model),
                        "--pose", "net"))
                    if seed in cfg.decompose_seeds:
                        rec["slam_laps_dis_fit"] = _cached(
                            out / "eval" / f"{key}_s{seed}_slam_laps_fit.json",
                            lambda: trajectory_fit(slam_seq, out / "runs" / f"{key}_s{seed}_slam_laps_vo.txt"))
                rows.setdefault(key, []).append(rec)
    default = {name: _cached(out / "eval" / f"default_{name}.json",
                             lambda: vo_scores(seq, out / "runs" / f"default_{name}.txt", "--flow", flow))
               for name, seq, flow in cases}
    for name, seq, flow in cases:
        if flow == "dis":
            default[f"{name}_fit"] = yaw_and_forward_fit(seq, out / "runs" / f"default_{name}.motions.csv")
    # pnp (SIFT + PnP-RANSAC) needs depth: the render's exact depth on the street; the KITTI slices have none
    default["street_pnp"] = _cached(out / "eval" / "pnp_street.json", lambda: vo_scores(
        held, out / "runs" / "pnp_street.txt", "--odometry", "pnp"))
    if slam_seq is not None:
        print(f"slam default: loop street {cfg.slam_seed}", flush=True)
        default["slam_laps_dis"] = _cached(out / "eval" / "default_slam_laps.json",
                                           lambda: slam_scores(slam_seq, out / "runs" / "default_slam_laps.txt"))
        default["slam_laps_dis_fit"] = _cached(out / "eval" / "default_slam_laps_fit.json", lambda: trajectory_fit(
            slam_seq, out / "runs" / "default_slam_laps_vo.txt"))
    if curves:
        plot_curves(curves, out / "learning_curve.png")
    report = {"config": dataclasses.asdict(cfg), "models": trained, "rows": rows, "default": default,
              "curves": curves, "cases": [c[0] for c in cases], "minutes": (time.perf_counter() - t0) / 60}
    def err(key: str, name: str) -> dict:
        return _agg([_err(r[name]) for r in rows.get(key, [])])

    def ratio(num: float | None, den: float | None) -> float | None:
        return num / den if num is not None and den else None

    report["ratio_synthetic_over_supervised"] = {
        f"{prefix}{mine}/{prefix}{other}": {name: ratio(err(prefix + mine, name)["mean"], err(prefix + other, name)["mean"])
                                            for name in report["cases"]}
        for prefix, _ in folders for mine in SYNTHETIC_MODES for other in compared_with(mine)
        if rows.get(prefix + mine) and rows.get(prefix + other)}
    report["ratio_over_default"] = {key: {name: ratio(err(key, name)["mean"], _err(default[name]))
                                          for name in report["cases"]} for key in rows if rows[key]}
    write_report(out, report, markdown)
    return report


FIGURES = (("ATE [m]", "ate_m", ".3g"), ("t_err [%]", "kitti_t_err_pct", ".3g"),
           ("r_err [deg/100 m]", "kitti_r_err_deg_per_100m", ".3g"), ("drift [% of path]", "endpoint_drift_pct", ".3g"),
           ("path ratio", "path_length_ratio", ".3f"))
CASE_TITLES = {"street_exact": "held-out street (town 7, 10 Hz), exact flow",
               "street_dis": "held-out street (town 7, 10 Hz), DIS flow",
               "street_body_dis": "held-out street with KITTI's body pitch and roll (town 7, `--body-motion 1`), DIS flow",
               "kitti06_dis": "KITTI 06 slice (real, stereo, never trained on), DIS flow",
               "kitti07_dis": "KITTI 07 slice (real, never trained on), DIS flow"}


def turns_table(report: dict) -> list[str]:
    """Markdown lines: per scored model and seed (those with fits: ``decompose_seeds``) and the default, the yaw and
    forward gains on the left and the right turns of every DIS case (and the loop street) that has both
    (:func:`gains`); no lines where none has."""
    cases = [c for c in [*report["cases"], "slam_laps_dis"] if c.endswith("_dis")]
    recs = [(f"{label(key)} s{r['seed']}", r) for key, recs in report["rows"].items() for r in recs]
    recs.append(("`deepslam vo`'s default", report["default"]))
    def count(c: str, side: str) -> int:
        return max([(r.get(f"{c}_fit") or {}).get(side, {}).get("n", 0) for _, r in recs])

    both = [c for c in cases if count(c, "left") and count(c, "right")]
    if not both:
        return []

    def cell(side: dict | None) -> str:
        def x(g: float | None) -> str:
            return "n/a" if g is None else f"x{g:.2f}"
        return "n/a" if not side else f"yaw {x(side.get('yaw_gain'))}, forward {x(side.get('forward_gain'))}"

    titles = {**CASE_TITLES, "slam_laps_dis": "loop street (town {slam_seed}, `--route laps`), DIS flow".format(
        slam_seed=report.get("config", {}).get("slam_seed"))}
    head = [f"{titles.get(c, c)}: {side} ({count(c, side)})" for c in both for side in ("left", "right")]
    md = ["", "**Turns of each sign.** The training towns turn left only (the yaw of every training pair is >= "
          f"-0.005 rad). Per pair, the yaw and forward gains on the pairs turning left and right (|yaw| > {TURN_RAD} "
          "rad, their count in brackets); a model whose motions never turn right reads a right turn short and makes "
          "it up as distance:", "",
          "| | " + " | ".join(head) + " |", "|---" * (1 + len(head)) + "|"]
    for name, r in recs:
        if any(r.get(f"{c}_fit") for c in both):
            md.append(f"| {name} | " + " | ".join(
                cell((r.get(f"{c}_fit") or {}).get(side)) for c in both for side in ("left", "right")) + " |")
    return md


def pm(a: dict, f: str) -> str:
    """A row's cell from :func:`bench.results_vo._agg`'s record: ``mean ± std`` over n > 1 seeds, the value for one,
    ``n/a`` for none; ``f`` is the format of both numbers."""
    if a["mean"] is None:
        return "n/a"
    return f"{a['mean']:{f}} ± {a['std']:{f}}" if a["n"] > 1 else f"{a['mean']:{f}}"


def markdown(report: dict) -> str:
    md = ["The paper's recipe at scale (NN_cons: the cpu preset, 48 x 160 input, and the paper's 96 x 320 network; "
          "`scripts/train_paper_recipe.sh`), scored with the network's own pose (`--pose net`) on data no model saw. "
          "A row is the mean ± std over the training seeds present (n). Models:"]
    md += [f"- {label(k.rsplit(' ', 1)[0])} ({k.rsplit(' ', 1)[1]}): `{v['file']}`, {v['samples']:,} samples, "
           f"trained on {v.get('device', 'n/a')}, stopped: {v.get('stop', 'n/a')}"
           for k, v in report["models"].items()] or ["- none found"]
    for case in report["cases"]:
        md += ["", f"**{CASE_TITLES.get(case, case)}**", "",
               "| | " + " | ".join(t for t, _, _ in FIGURES) + " |", "|---" * (len(FIGURES) + 1) + "|"]
        for key, recs in report["rows"].items():
            if recs:
                md.append(f"| {label(key)} (n={len(recs)}) | " + " | ".join(
                    pm(_agg([r[case][k] for r in recs]), f) for _, k, f in FIGURES) + " |")
        beside = [("`deepslam vo`'s default on the same flow", report["default"].get(case))]
        if case.startswith("street_"):
            beside.append(("`pnp` (SIFT + PnP-RANSAC on the render's exact depth; no flow)",
                           report["default"].get("street_pnp")))
        for name, d in beside:
            if d:
                md.append(f"| {name} | " + " | ".join(
                    "n/a" if d.get(k) is None else f"{d[k]:{f}}" for _, k, f in FIGURES) + " |")
        md.append("")
        for pair, by_case in report["ratio_synthetic_over_supervised"].items():
            r = by_case.get(case)
            if r is not None:
                mine, other = pair.split("/")
                md.append(f"- {label(mine)} / {label(other)} (t_err, or drift where the route is under 100 m): x{r:.2f}")
        over = [(key, by_case.get(case)) for key, by_case in report.get("ratio_over_default", {}).items()
                if by_case.get(case) is not None]
        if over:
            md.append("- the network's own pose / the default (the target: at most x2): " + "; ".join(
                f"{label(key)} x{r:.1f}" for key, r in over))
    dis_cases = [c for c in report["cases"] if c.endswith("_dis")]
    if any(f"{c}_epipolar" in r for recs in report["rows"].values() for r in recs for c in dis_cases):
        md += ["", "**Rotation or distance?** The same models on the DIS cases with the essential matrix's rotation and "
               "direction of travel and the network's distance (`vo --pose epipolar --scale network`): t_err or drift "
               "[%] with the network's own pose -> with the essential matrix's rotation (path ratio); what remains is "
               "the network's reading of scale.", "",
               "| model | " + " | ".join(CASE_TITLES.get(c, c) for c in dis_cases) + " |", "|---" * (1 + len(dis_cases)) + "|"]
        for key, recs in report["rows"].items():
            for r in recs:
                if not any(f"{c}_epipolar" in r for c in dis_cases):
                    continue
                cells = []
                for c in dis_cases:
                    own, e = r.get(c), r.get(f"{c}_epipolar")
                    cells.append("n/a" if not (own and e) or _err(own) is None or _err(e) is None else
                                 f"{_err(own):.3g} -> {_err(e):.3g} (x{e['path_length_ratio']:.3f})")
                md.append(f"| {label(key)} s{r['seed']} | " + " | ".join(cells) + " |")
        md.append("| `deepslam vo`'s default (road scale) | " + " | ".join(
            f"{_err(report['default'][c]):.3g} (x{report['default'][c]['path_length_ratio']:.3f})"
            for c in dis_cases) + " |")
    fits = [(label(key) + f" s{r['seed']}", r) for key, recs in report["rows"].items() for r in recs
            if any(f"{c}_fit" in r for c in dis_cases)]
    if fits:
        fits.append(("`deepslam vo`'s default", report["default"]))

        def fit_cell(f: dict | None) -> str:
            if not f:
                return "n/a"
            y, z = f["yaw"], f["forward"]
            gain = "n/a" if y["gain"] is None else f"x{y['gain']:.2f}"
            return f"yaw {gain}, {y['rms']:.3f}°; forward x{z['gain']:.2f}, {z['rms']:.3f} m"

        md += ["", "Per pair against the ground truth, DIS flow: the share of the turns (yaw) and of the distance "
               "(forward translation) read, as the gain of `read = gain x true` through the origin, and the RMS error "
               "of a pair (a perfect reading: x1.00, 0):", "",
               "| | " + " | ".join(CASE_TITLES.get(c, c) for c in dis_cases) + " |", "|---" * (1 + len(dis_cases)) + "|"]
        md += [f"| {name} | " + " | ".join(fit_cell(r.get(f"{c}_fit")) for c in dis_cases) + " |" for name, r in fits]
    md += turns_table(report)
    slam_rows = [(key, recs) for key, recs in report["rows"].items() if recs and "slam_laps_dis" in recs[0]]
    if slam_rows:
        cfg = report["config"]
        md += ["", f"**Loop street (`render --route laps`, town {cfg['slam_seed']}, {cfg['slam_frames']} frames at "
               f"{cfg['width']} px), DIS flow: `deepslam slam` with each NN_cons (its own pose) and the shipped NN_loops**",
               "", "| | VO ATE [m] | SLAM ATE [m] | SLAM / VO | VO path ratio | loop edges (kept) |", "|---|---|---|---|---|---|"]
        for key, recs in slam_rows:
            r = [x["slam_laps_dis"] for x in recs]
            md.append(f"| {label(key)} (n={len(r)}) | " + " | ".join(
                pm(_agg([x[k] for x in r]), f) for k, f in (("vo_ate_m", ".3g"), ("slam_ate_m", ".3g"),
                                                             ("slam_over_vo", ".2f"), ("vo_path_ratio", ".3f")))
                      + f" | {np.mean([x['loops'] for x in r]):.0f} ({np.mean([x['loops_kept'] for x in r]):.0f}) |")
        d = report["default"].get("slam_laps_dis")
        if d:
            md.append(f"| `deepslam slam`'s default | {d['vo_ate_m']:.3g} | {d['slam_ate_m']:.3g} | "
                      f"{d['slam_over_vo']:.2f} | {d['vo_path_ratio']:.3f} | {d['loops']} ({d['loops_kept']}) |")
    cal = [(key, r["seed"], case, r[case].get("within_1_sigma")) for key, recs in report["rows"].items() for r in recs
           for case in [c + suffix for c in report["cases"] for suffix in ("", *(f"_{t}" for t in CALIBRATED_ON))]
           if r.get(case, {}).get("within_1_sigma")]
    if cal:
        md += ["", "Uncertainty: share of pairs whose error is within the predicted 1-sigma, per DoF (euler x, y, z, "
               "t x, y, z; a calibrated Gaussian gives 0.68):", ""]
        def title(case: str) -> str:
            for tag, where in CALIBRATED_ON.items():
                where = where.format(calibration_seed=report.get("config", {}).get("calibration_seed"))
                if case.endswith(f"_{tag}"):
                    return (f"{CASE_TITLES.get(case.removesuffix(f'_{tag}'), case)}, std calibrated on {where} "
                            "(`deepslam calibrate`)")
            return CASE_TITLES.get(case, case)

        md += [f"- {label(key)} s{seed}, {title(case)}: " + ", ".join(f"{x:.2f}" for x in c)
               for key, seed, case, c in cal]
    fits = [(k, c[f"{n}_fit"]) for k, c in report["curves"].items() for n in ("t_z_m",) if f"{n}_fit" in c]
    if report["curves"]:
        md += ["", "![learning curves](learning_curve.png)"]
    if fits:
        md += ["", "Learning curves: held-out RMSE of the forward translation, last epoch and a power law over the "
               "second half extrapolated to twice the samples (it follows the learning-rate halvings too, so it "
               "overstates what more samples at one rate give):", ""]
        md += [f"- {k}: {f['last']:.4f} m now, exponent {f['exponent']:.2f}, {f['at_2x']:.4f} m at 2x" for k, f in fits]
    md += ["", "The paper: synthetic / supervised x2.7 on KITTI (estimated flow), about x1 on EuRoC (rigid scenes). "
           + PAPER_FIGURES,
           "", f"Run time: {report.get('minutes', 0):.1f} min."]
    return "\n".join(md) + "\n"


def main_with_models(name: str, doc: str, config, quick, out_name: str, run, markdown, argv: list[str] | None) -> int:
    """:func:`bench.results_common.results_main` with ``--models DIR`` as well: ``config`` (a frozen dataclass with a
    ``models`` field) scored from DIR; ``quick`` (config -> config) makes the smoke run's sizes from it."""
    from bench.results_common import results_main

    ap = argparse.ArgumentParser(add_help=False)
    ap.add_argument("--models", default=None)
    known, rest = ap.parse_known_args(argv)
    cfg = config if known.models is None else dataclasses.replace(config, models=known.models)
    return results_main(name, doc, cfg, quick(cfg), out_name, run, markdown, rest)


def main(argv: list[str] | None = None) -> int:
    return main_with_models("results_repro", __doc__, ReproConfig(), lambda cfg: dataclasses.replace(
        cfg, heldout_frames=40, width=207, slam_seed=0, calibration_seed=0), "repro", run, markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
