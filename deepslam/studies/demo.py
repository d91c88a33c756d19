"""``make demo`` / ``python -m deepslam.studies.demo``: the whole harness end to end, in about 9 minutes on 2 cores (10 at most).

1. render a simulated street for training (single frames + depth) and a held-out street sequence
   that closes a loop (another seed: other buildings, other parked cars);
2. check the generator's geometry on the held-out render (synthesized vs true flow);
3. fit the Student-t motion model to KITTI's ground truth (../shared/data/kitti/poses);
4. train NN_cons and NN_loops on flow synthesized from the training frames' depth, and a second pair
   on the flow DIS gives for a second view rendered from each training frame: no video and no
   ground-truth pose of the training frames is used;
5. run SLAM (DIS flow -> NN_cons odometry -> BoVW relocalization -> NN_loops loop edges -> gtsam) on
   the held-out sequence with each pair, and with the simulator's exact flow, and score VO and SLAM
   against its ground truth;
6. score the published reference trajectories (metrics cross-check);
7. write ``out/demo/report.md`` with the metrics table and the trajectory plot.

Every step is a ``deepslam`` subcommand (printed before it runs, so it can be rerun by hand), and a
step whose output is already there is skipped: a killed demo resumes where it stopped.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import sys
import time
from pathlib import Path

from deepslam import cli
from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.core.paths import out_dir, shared_data_dir
from deepslam.core.readers import open_sequence
from deepslam.studies import demo_reference


@dataclasses.dataclass(frozen=True)
class DemoConfig:
    """Sizes of the demo; the defaults take about 9 minutes on 2 cores (the budget is 10)."""

    width: int = 414
    """Rendered image width in pixels (KITTI's 1241 / 3; the height follows KITTI's aspect)."""
    train_seeds: tuple[int, ...] = (1, 2)
    """Scene/trajectory seeds of the training renders (each a different town)."""
    train_frames: int = 150
    """Frames per training render (single frames: only their depth is used, not the motion)."""
    heldout_seed: int = 7
    """Seed of the held-out sequence."""
    heldout_frames: int = 300
    """Frames of the held-out sequence (the car route closes its loop within 300 frames)."""
    moving_objects: int = 0
    """Moving cars in the held-out sequence (0: the rigid scene the method assumes)."""
    train_samples_cons: int = 98_304
    """Training budget of NN_cons in samples (stage 1; 24 epochs of 4096, about 2.5 minutes here): a
    sample count, not minutes, so that the demo's numbers are the same run to run and machine to machine."""
    train_samples_loops: int = 61_440
    """Training budget of NN_loops in samples (15 epochs)."""
    dis_pool: int = 8192
    """Samples of the DIS-flow training pool (second views rendered from the single frames, DIS on each pair)."""
    train_samples_cons_dis: int = 106_496
    """Training budget of NN_cons on DIS flow in samples (13 passes over its pool of 8192)."""
    train_samples_loops_dis: int = 57_344
    """Training budget of NN_loops on DIS flow in samples (7 passes)."""
    samples_per_epoch: int = 4096
    """Synthetic samples per epoch."""
    threads: int = 2
    """torch threads of the training runs (fixed: bf16 sums depend on the thread count)."""
    nll_epochs: int = 4
    """Epochs of the second (uncertainty) stage on the held-out 10 %."""
    net: str = "cpu"
    """Network preset of vo.net (the paper's layout, narrowed to train on a CPU)."""
    seed: int = 0
    """Training seed."""


def command_line(args: list[str]) -> str:
    """The shell line of ``deepslam`` with ``args``."""
    return "deepslam " + " ".join(shlex.quote(a) for a in args)


def run_command(args: list[str], log: list[str]) -> None:
    cmd = command_line(args)
    print(f"\n$ {cmd}", flush=True)
    log.append(cmd)
    t0 = time.perf_counter()
    rc = cli.main(args)
    if rc != 0:
        raise SystemExit(f"deepslam demo: step failed with exit status {rc}: {cmd}")
    print(f"  ({time.perf_counter() - t0:.0f} s)", flush=True)


def render_once(scene: str, trajectory: str, frames: int, width: int, seed: int, out: Path, log: list[str],
                extra: tuple[str, ...] = ()) -> Path:
    """``deepslam render`` into ``out`` unless it is already complete (an interrupted one is resumed); the
    command that makes it goes to ``log`` either way (a report lists how to remake its data).

    A complete render made with another frame count or width is an error (InputError naming the
    folder), never silently reused."""
    args = ["render", "--scene", scene, "--trajectory", trajectory, "--frames", str(frames), "--width", str(width),
            "--seed", str(seed), *extra, "--out", str(out)]
    if (out / "poses.txt").is_file():
        seq = open_sequence(out)
        if (len(seq), seq.camera.width) != (frames, width):
            raise InputError(out, f"holds a render of {len(seq)} frames at {seq.camera.width} px, not {frames} at "
                                  f"{width}: delete it or choose another output folder")
        log.append(command_line(args))
    else:
        run_command(args + (["--resume"] if out.exists() else []), log)
    return out


def _fmt(x, spec=".3f") -> str:
    return "n/a" if x is None else format(x, spec)


def run(cfg: DemoConfig, out: Path, data: Path) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    atomic.write_json(out / "config.json", dataclasses.asdict(cfg))
    log: list[str] = []
    t_start = time.perf_counter()

    # 1. renders (resumable; a finished render is not redone)
    train_dirs = [str(render_once("street", "car", cfg.train_frames, cfg.width, s, out / f"street_train_s{s}", log))
                  for s in cfg.train_seeds]
    held = render_once("street", "car", cfg.heldout_frames, cfg.width, cfg.heldout_seed,
                       out / f"street_heldout_s{cfg.heldout_seed}", log, ("--moving-objects", str(cfg.moving_objects)))

    # 2. the generator's geometry against the simulator's true flow
    validation = out / "validate_flow.json"
    if not validation.is_file():
        print(f"\n$ deepslam validate-flow --sequence {held} --json", flush=True)
        log.append(f"deepslam validate-flow --sequence {held} --json")
        from deepslam.gen.validate import validate_sequence  # deferred: torch (~1 s); the demo's --help stays torch-free

        report = validate_sequence(open_sequence(held))
        report.pop("per_frame", None)
        atomic.write_json(validation, report)
    val = json.loads(validation.read_text())

    # 3. motion model from KITTI's ground truth (the paper's Figure 3)
    motion = out / "motion.json"
    if not motion.is_file():
        poses = sorted(str(p) for p in (data / "kitti" / "poses").glob("*.txt"))
        run_command(["fit-motion", "--poses", *poses, "--stride", "1", "--loops", "--out", str(motion),
                     "--plot", str(out / "motion.png")], log)

    # 4. NN_cons and NN_loops from single frames + depth + motion model: on exact synthetic flow (the
    #    paper), and on the flow DIS gives for a second view rendered from each single frame
    models = {}
    for which, budget, spec, dis in (("cons", cfg.train_samples_cons, str(motion), False),
                                     ("loops", cfg.train_samples_loops, f"{motion}:loops", False),
                                     ("cons_dis", cfg.train_samples_cons_dis, str(motion), True),
                                     ("loops_dis", cfg.train_samples_loops_dis, f"{motion}:loops", True)):
        d = out / f"nn_{which}"
        models[which] = d / "model.safetensors"
        if not models[which].is_file():
            extra = ["--synthetic-flow", "dis", "--sample-pool", str(cfg.dis_pool)] if dis else []
            run_command(["train", "--mode", "synthetic", "--source", *train_dirs, "--motion", spec, "--net", cfg.net,
                         "--max-samples", str(budget), "--threads", str(cfg.threads),
                         "--samples-per-epoch", str(cfg.samples_per_epoch),
                         "--nll-epochs", str(cfg.nll_epochs), "--seed", str(cfg.seed), "--out", str(d), *extra]
                        + (["--resume"] if (d / "checkpoint.safetensors").is_file() else []), log)

    # 5. SLAM on the held-out sequence: DIS flow with the models trained on DIS flow and with those
    #    trained on exact flow; those on the simulator's exact flow (what a perfect flow estimator gives)
    def slam(name: str, which: str, flow: str, plot: str) -> dict:
        rec_json = out / f"{name}.json"
        if not rec_json.is_file():
            run_command(["slam", "--sequence", str(held), "--model-cons", str(models[f"cons{which}"]),
                         "--model-loops", str(models[f"loops{which}"]), "--flow", flow, "--out", str(out / f"{name}.txt"),
                         "--plot", str(out / plot)], log)
        return json.loads(rec_json.read_text())

    rec = slam("slam", "_dis", "dis", "trajectories.png")
    rec_x = slam("slam_exactmodels", "", "dis", "trajectories_exactmodels.png")
    rec_gt = slam("slam_trueflow", "", "gt", "trajectories_trueflow.png")

    # 6. metrics cross-check on published trajectories
    print("\n$ python -m deepslam.studies.demo_reference", flush=True)
    demo_reference.run(data, out / "reference")

    # 7. the report
    mv, ms = rec["metrics_vo"], rec["metrics_slam"]
    xv, xs = rec_x["metrics_vo"], rec_x["metrics_slam"]
    gv, gs = rec_gt["metrics_vo"], rec_gt["metrics_slam"]
    rows = [("ATE [m]", "ate_m", ".3f"), ("RPE t [m/frame]", "rpe_t_m", ".4f"), ("RPE r [deg/frame]", "rpe_r_deg", ".4f"),
            ("KITTI t_err [%]", "kitti_t_err_pct", ".2f"), ("KITTI r_err [deg/100 m]", "kitti_r_err_deg_per_100m", ".2f")]
    minutes = (time.perf_counter() - t_start) / 60
    md = ["# deepslam demo", "",
          f"Held-out simulated street `{held.name}` ({rec['frames']} frames, {cfg.width} px wide, seed "
          f"{cfg.heldout_seed}); NN_cons and NN_loops trained only on synthetic flow from the single frames of "
          f"{len(train_dirs)} other simulated streets (seeds {', '.join(map(str, cfg.train_seeds))}) and the Student-t "
          "motion model fitted to KITTI's ground truth. Flow at test time: OpenCV DIS (what a user has), and "
          "the simulator's exact flow (what a perfect flow estimator would give: it separates the odometry "
          "network's error from the flow estimator's). For DIS flow, two pairs of models: trained on the flow "
          "DIS gives for a second view rendered from each single frame (`--synthetic-flow dis`), and trained on "
          "exact synthetic flow (the paper). Metrics after se3 alignment.", "",
          "| metric | VO, DIS flow | SLAM, DIS flow | VO, DIS flow, exact-flow models | SLAM, DIS flow, exact-flow models "
          "| VO, exact flow | SLAM, exact flow |", "|---|---|---|---|---|---|---|"]
    md += [f"| {name} | {_fmt(mv.get(k), f)} | {_fmt(ms.get(k), f)} | {_fmt(xv.get(k), f)} | {_fmt(xs.get(k), f)} | "
           f"{_fmt(gv.get(k), f)} | {_fmt(gs.get(k), f)} |" for name, k, f in rows]
    ratio = None if not mv.get("ate_m") else ms["ate_m"] / mv["ate_m"]
    ratio_gt = None if not gv.get("ate_m") else gs["ate_m"] / gv["ate_m"]
    md += ["", f"SLAM/VO ATE ratio: {_fmt(ratio, '.2f')} with DIS flow, {_fmt(ratio_gt, '.2f')} with exact flow. "
           f"Loop edges (DIS): {rec['n_loops']} ({rec['n_verified_ok']} of {rec['n_candidates']} candidates verified); "
           f"pipeline speed {rec['timings']['fps']:.1f} frames/s.", "",
           "![trajectories, DIS flow](trajectories.png)", "",
           "![trajectories, DIS flow, exact-flow models](trajectories_exactmodels.png)", "",
           "![trajectories, exact flow](trajectories_trueflow.png)", "",
           "## Generator geometry (synthesized vs simulator flow on the held-out sequence)", "",
           "| pixels | count | EPE mean [px] | EPE p95 [px] |", "|---|---|---|---|"]
    for key in ("static_visible", "static_occluded", "moving"):
        v = val[key]
        md.append(f"| {key.replace('_', ' ')} | {v['pixels']} | {_fmt(v['epe_mean_px'], '.2e')} | {_fmt(v['epe_p95_px'], '.2e')} |")
    md += ["", f"Target: static visible mean EPE < {val['target_epe_px']} px: {'met' if val['met'] else 'NOT met'}.", "",
           "## Motion model (Student-t per DoF, KITTI 00-10, stride 1)", "", "![motion model](motion.png)", "",
           "## Metrics cross-check on published trajectories", "",
           "See [reference/reference.md](reference/reference.md): ORB-SLAM2 on KITTI 00 scores the published "
           "0.70 % / 0.25 deg/100 m with these metrics.", "",
           "## Commands", "", "```"] + log + ["```", "", f"Total time of this run: {minutes:.1f} min."]
    report = out / "report.md"
    atomic.write_text(report, "\n".join(md) + "\n")
    return report


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
    os.environ.setdefault("DEEPSLAM_PROGRESS", "1")
    ap = argparse.ArgumentParser(prog="python -m deepslam.studies.demo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None, help="output folder (default: out/demo)")
    ap.add_argument("--data", type=Path, default=None, help="shared data folder (default: ../shared/data)")
    ap.add_argument("--quick", action="store_true", help="tiny sizes (a smoke run of a minute or two)")
    args = ap.parse_args(argv)
    cfg = DemoConfig()
    if args.quick:
        cfg = dataclasses.replace(cfg, width=207, train_seeds=(1,), train_frames=40, heldout_frames=300,
                                  train_samples_cons=2048, train_samples_loops=1024, train_samples_cons_dis=1024,
                                  train_samples_loops_dis=1024, dis_pool=512,
                                  samples_per_epoch=512, nll_epochs=1)
    data = args.data or shared_data_dir()
    out = args.out or out_dir() / "demo"
    try:
        if not (data / "kitti" / "poses").is_dir():
            raise InputError(data, "real data not found (expected ../shared/data beside the repository; "
                             "set DEEPSLAM_SHARED_DATA or --data)")
        report = run(cfg, out, data)
    except InputError as e:
        print(f"deepslam demo: error: {e.message()}", file=sys.stderr)
        return 2
    print(f"\nThe report is at {report.resolve()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
