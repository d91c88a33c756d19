"""SLAM benchmarks: pose-graph optimisation time, BoW retrieval time, false-loop robustness, pipeline fps.

Rows (each against a baseline measured in the same run):

- optimisation of a 5,000-pose graph with 500 loop edges: the default (LM, Cauchy kernel with a
  Huber warm start and pruning) vs Gauss-Newton without kernel on the same graph (target < 2 s), and
  plain LM vs the same graph without loop edges;
- retrieval per query at 10k and 50k database frames (inverted index) vs a naive per-frame loop
  (target: at least 10x faster);
- robustness: ATE with 10 % false loop candidates injected vs without (target: at most +10 %), and
  SLAM ATE vs odometry ATE on the synthetic loop trajectory (target: at most half);
- :func:`vo_end_to_end_fps`: ``deepslam vo`` on the real KITTI 07 slice as a user runs it (a fresh
  process, the default flow and model, start-up, reading, trajectory and plot included) against DIS
  alone on the same pairs (target: >= 30 frames/s end to end), and, in turn with it, ``deepslam slam`` (target:
  >= 20 frames/s and >= 0.8x vo), the network's pose and the flows on one worker; skipped without the slice;
- :func:`pipeline_fps`: frames per second of the whole pipeline on KITTI-size frames (target >= 10), and at
  keyframe stride 1 with the flows on one worker (``DEEPSLAM_FLOW_WORKERS=1``) right after.
  It uses the shipped VO models with DIS flow when ``vo.modelfiles.models`` can load them, otherwise the
  ground-truth odometry (the row's name says which), so until the models exist it measures
  relocalization + pose graph only.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from unittest import mock

import numpy as np

from deepslam.core.metrics import ate
from deepslam.core.paths import base_dir, shared_data_dir
from deepslam.core.readers import open_sequence


def _row(name, value, unit, baseline=None, baseline_value=None, target=None, met=None, **extra):
    ratio = None if baseline_value in (None, 0) or value is None else value / baseline_value
    return {"name": name, "value": value, "unit": unit, "baseline": baseline, "baseline_value": baseline_value,
            "ratio": ratio, "target": target, "met": met, **extra}


def _median_time(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def bench_optimisation(quick: bool) -> list[dict]:
    from deepslam.slam.posegraph import PoseGraphConfig, optimize
    from deepslam.slam.synthetic import loop_graph

    n, laps = 5000, 5.0
    g = loop_graph(n_frames=n, laps=laps, radius_m=100.0, loop_every=8, seed=0)
    cons, loops, w0 = g["cons"], g["loops"], g["gt"].world_from_cam[0]
    assert len(loops) == 500, len(loops)
    reps = 1 if quick else 3

    def solve(cfg, with_loops=True):
        return optimize(n, cons, loops if with_loops else None, cfg, w0)

    t_default, r_default = _median_time(lambda: solve(PoseGraphConfig()), reps)
    t_gn, _ = _median_time(lambda: solve(PoseGraphConfig(robust="none", optimizer="gn")), reps)
    t_lm, _ = _median_time(lambda: solve(PoseGraphConfig(robust="none")), reps)
    t_noloop, _ = _median_time(lambda: solve(PoseGraphConfig(robust="none"), with_loops=False), reps)
    return [
        _row("pose graph 5000 poses + 500 loops: LM + Cauchy (Huber warm start) + pruning, build + solve",
             t_default, "s", "Gauss-Newton, no kernel, same graph", t_gn, "< 2 s", t_default < 2.0,
             solve_only_s=r_default.time_s, stages=r_default.stages, iterations=r_default.iterations),
        _row("pose graph 5000 poses + 500 loops: LM, no kernel, build + solve", t_lm, "s",
             "LM, same graph without loop edges", t_noloop, "< 2 s", t_lm < 2.0),
    ]


def _bow_rows(rng: np.random.Generator, n: int, n_words: int = 1000, n_features: int = 400):
    """n sparse tf-idf-like vectors: 400 words per frame drawn from a Zipf-like word distribution."""
    p = 1.0 / np.arange(1, n_words + 1) ** 0.8
    p /= p.sum()
    rows = []
    for _ in range(n):
        words = rng.choice(n_words, size=n_features, p=p)
        ids, counts = np.unique(words, return_counts=True)
        w = counts * np.log(1.0 / p[ids] / n_words + 1.0)
        rows.append((ids.astype(np.int32), (w / np.linalg.norm(w)).astype(np.float32)))
    return rows


def bench_retrieval(quick: bool) -> list[dict]:
    from deepslam.slam import reloc
    from deepslam.slam.reloc import BowDatabase, naive_scores

    rng = np.random.default_rng(0)
    sizes = (10_000,) if quick else (10_000, 50_000)
    rows = _bow_rows(rng, max(sizes))
    queries = _bow_rows(rng, 20)
    out = []
    db = BowDatabase(1000)
    for size in sizes:
        t0 = time.perf_counter()
        for r in rows[len(db):size]:
            db.add(*r)
        add_s = (time.perf_counter() - t0) / size
        db.query(*queries[0], k=20)  # builds the inverted index
        t0 = time.perf_counter()
        for q in queries:
            top, _ = db.query(*q, k=20)
        fast = (time.perf_counter() - t0) / len(queries)
        n_naive = 3 if quick else 5
        t0 = time.perf_counter()
        for q in queries[:n_naive]:
            s = naive_scores(rows[:size], *q)
            naive_top = np.argsort(-s, kind="stable")[:20]
        naive = (time.perf_counter() - t0) / n_naive
        assert set(naive_top[:5]) == set(db.query(*queries[n_naive - 1], k=20)[0][:5])
        out.append(_row(f"BoW retrieval, top-20 of {size} frames (inverted index), per query", fast * 1e3, "ms",
                        "naive Python loop over frames", naive * 1e3, ">= 10x faster", naive / fast >= 10,
                        mean_words_per_frame=float(np.mean([len(r[0]) for r in rows[:size]])),
                        add_us_per_frame=add_s * 1e6))
        if size >= reloc.COMPILED_MIN_ROWS:  # the compiled posting-list loop against scipy's slice and mat-vec
            with mock.patch.object(reloc, "COMPILED_MIN_ROWS", 10**12):
                t0 = time.perf_counter()
                for q in queries:
                    db.query(*q, k=20)
                scipy_s = (time.perf_counter() - t0) / len(queries)
            out.append(_row(f"BoW retrieval, top-20 of {size} frames, compiled posting-list loop (numba; "
                            "the default from reloc.COMPILED_MIN_ROWS rows), per query", fast * 1e3, "ms",
                            "scipy column slice + mat-vec (below that size), in turn", scipy_s * 1e3,
                            "<= 5 ms a query", fast * 1e3 <= 5))
    return out


def bench_robustness(quick: bool) -> list[dict]:
    from deepslam.slam.posegraph import Edges, PoseGraphConfig, chain, optimize
    from deepslam.slam.synthetic import loop_graph

    seeds = range(2) if quick else range(5)
    ratios, ratios_plain, slam_ates, vo_ates, dirty_ates = [], [], [], [], []
    for seed in seeds:
        n = 1000
        g = loop_graph(n_frames=n, laps=2.0, radius_m=50.0, loop_every=5, seed=seed)
        n_false = int(round(0.1 * len(g["loops"]) / 0.9))  # 10 % of all loop candidates are false
        g = loop_graph(n_frames=n, laps=2.0, radius_m=50.0, loop_every=5, n_false=n_false, seed=seed)
        gt, w0 = g["gt"].world_from_cam, g["gt"].world_from_cam[0]
        clean = ate(gt, optimize(n, g["cons"], g["loops"], PoseGraphConfig(), w0).world_from_cam)["rmse_m"]
        both = Edges.concat(g["loops"], g["false_loops"])
        dirty = ate(gt, optimize(n, g["cons"], both, PoseGraphConfig(), w0).world_from_cam)["rmse_m"]
        plain = ate(gt, optimize(n, g["cons"], both, PoseGraphConfig(robust="none"), w0).world_from_cam)["rmse_m"]
        ratios.append(dirty / clean)
        dirty_ates.append(dirty)
        ratios_plain.append(plain / clean)
        slam_ates.append(clean)
        vo_ates.append(ate(gt, chain(n, g["cons"], w0))["rmse_m"])
    worst = float(max(ratios))
    return [
        _row("ATE with 10 % false loop candidates injected (Cauchy + pruning), mean of seeds", float(np.mean(dirty_ates)),
             "m", "ATE without false loops (mean)", float(np.mean(slam_ates)), "worst ratio <= 1.10", worst <= 1.10,
             worst_ratio=worst, ratios=[float(r) for r in ratios], ratios_without_kernel=[float(r) for r in ratios_plain]),
        _row("SLAM ATE on a 2-lap synthetic loop trajectory (1000 frames, drifting odometry)", float(np.mean(slam_ates)),
             "m", "odometry alone (dead reckoning)", float(np.mean(vo_ates)), "ratio <= 0.5",
             float(np.mean(slam_ates)) <= 0.5 * float(np.mean(vo_ates))),
    ]


# ---------------------------------------------------------------------------------------------------
# PIPELINE FPS (KITTI-size frames). Uses the shipped VO models when vo.modelfiles.models can load them.

def _odometry_for_fps(seq, **flow_options):
    """(cons, loops, label): the shipped KITTI models with DIS flow if loadable, else ground truth;
    ``flow_options``: DIS options over the files' records (``patch_stride=4``)."""
    try:
        from deepslam.vo.modelfiles import models
        from deepslam.vo.odometry import model_odometry

        # each shipped model on DIS as its file records
        cons, loops = (model_odometry(models.shipped_path("kitti", which, "dis"), "dis", True, pose=pose,
                                       flow_options=flow_options)
                       for which, pose in (("cons", None), ("loops", "net")))
        return cons, loops, "shipped VO models + DIS flow"
    except Exception:  # models not shipped yet (or vo incomplete): measure the SLAM back end alone
        from deepslam.slam.odometry import GroundTruthOdometry, NoiseConfig

        return (GroundTruthOdometry(NoiseConfig(bias6=(0, 0.002, 0, 0, 0, 0), seed=0)),
                GroundTruthOdometry(NoiseConfig(seed=1)), "ground-truth odometry (VO models not available)")


def pipeline_fps(quick: bool) -> list[dict]:
    """Frames per second of the whole pipeline on a KITTI-size (1241 x 376) synthetic revisit sequence.

    The BoW vocabulary is trained beforehand on another sequence (as a vocabulary is built offline);
    its training time is reported beside the row, not counted in the frames per second.
    """
    from deepslam.slam.pipeline import PipelineConfig, SlamParams, run_slam
    from deepslam.slam.reloc import FeatureExtractor, RelocConfig, train_vocabulary
    from deepslam.slam.synthetic import write_loop_sequence
    from deepslam.vo.data.prefetch import WORKERS_ENV, default_workers

    n = 40 if quick else 120
    reloc = RelocConfig()
    with tempfile.TemporaryDirectory(prefix="bench_slam_") as tmp:
        train = write_loop_sequence(f"{tmp}/train", n_frames=40, laps=1.0, width=1241, height=376, seed=100)
        extract = FeatureExtractor(reloc)
        t0 = time.perf_counter()
        vocab = train_vocabulary([extract(train.image(i)).descriptors for i in range(len(train))],
                                 reloc.vocabulary_size, np.random.default_rng(0))
        vocab_s = time.perf_counter() - t0
        seq = write_loop_sequence(f"{tmp}/run", n_frames=n, laps=2.0, width=1241, height=376, radius_m=30.0, seed=0)
        cons, loops, label = _odometry_for_fps(seq)
        params = SlamParams(t_loop=10)
        rows = []
        base = run_slam(seq, cons, None, params, PipelineConfig(loops=False), show_progress=False)
        fps = {}
        default = PipelineConfig().keyframe_stride
        for stride in sorted({1, default}):
            res = run_slam(seq, cons, loops, params, PipelineConfig(keyframe_stride=stride), vocabulary=vocab,
                           show_progress=False)
            t = res.timings
            fps[stride] = t["fps"]
            what = " (the default)" if stride == default else ""
            rows.append(_row(f"pipeline frames/s on 1241x376 frames ({n} frames, keyframe stride {stride}{what}, "
                             f"{label})", t["fps"], "frames/s", "odometry only (no relocalization, no loops)",
                             base.timings["fps"], ">= 0.8x odometry alone and >= 20 frames/s",
                             t["fps"] >= 0.8 * base.timings["fps"] and t["fps"] >= 20, loops=len(res.loops),
                             vocabulary_training_s=vocab_s,
                             stage_seconds={k: v for k, v in t.items() if k.endswith("_s")}))
        # the flows on one worker (DIS on OpenCV's threads), right after
        with mock.patch.dict(os.environ, {WORKERS_ENV: "1"}):
            one = run_slam(seq, cons, loops, params, PipelineConfig(), vocabulary=vocab, show_progress=False)
        rows.append(_row(f"pipeline frames/s, keyframe stride {default}, {default_workers()} flow workers (the default) "
                         f"against one ({WORKERS_ENV}=1), run after it", fps[default], "frames/s", "one flow worker",
                         one.timings["fps"]))
        # the speed option for a slow CPU (slam --dis-patch-stride 4: DIS matching a patch every 4 pixels, not 3)
        cons4, loops4, label4 = _odometry_for_fps(seq, patch_stride=4)
        if label4 == label:
            s4 = run_slam(seq, cons4, loops4, params, PipelineConfig(), vocabulary=vocab, show_progress=False)
            rows.append(_row(f"pipeline frames/s, keyframe stride {default}, DIS with --dis-patch-stride 4 against the "
                             f"models' recorded DIS, run after it ({label})", s4.timings["fps"], "frames/s",
                             "recorded DIS (patch stride 3)", fps[default], ">= 10 frames/s", s4.timings["fps"] >= 10))
    return rows


def vo_end_to_end_fps(quick: bool) -> list[dict]:
    """``deepslam vo --sequence <KITTI 07>`` with no flags (the shipped model's recorded pose: epipolar, and
    DIS as the model records it: its working width; one flow worker a core) in a fresh process, median wall
    time of 1 or 3 runs, against that DIS alone on the same consecutive pairs in this process (images read
    beforehand, OpenCV's threads); and, run in turn with it, ``deepslam slam`` with no flags, the same vo with
    ``--pose net``, with DIS on the
    full-size frames (``--dis-max-width 0``; only where the shipped model records a working width), with one
    flow worker (``DEEPSLAM_FLOW_WORKERS=1``: DIS on OpenCV's threads), with ``--scale network`` (the network's
    distance: what reading the distance from the road costs), with ``--flow learned``, and with
    ``--dis-patch-stride 4`` (DIS matching a patch every 4 pixels, not the preset's 3: the speed option the README
    documents, run on the shipped model, which was trained on stride 3)."""
    from deepslam.flow import images as flow_images
    from deepslam.slam.pipeline import PipelineConfig
    from deepslam.vo.data.prefetch import WORKERS_ENV, default_workers
    from deepslam.vo.modelfiles import models

    root = shared_data_dir() / "kitti" / "sequences" / "07"
    if not (root / "calib.txt").is_file():
        return []
    seq = open_sequence(root)
    n = len(seq)
    env = {k: v for k, v in os.environ.items() if k != WORKERS_ENV}
    dis = models.flow_for_model("dis", models.shipped_path("kitti", "cons", "dis"))  # as `vo` sets it up
    variants = {"default": ("vo", [], env), "slam": ("slam", [], env), "net": ("vo", ["--pose", "net"], env),
                "network distance": ("vo", ["--scale", "network"], env),
                "one worker": ("vo", [], {**env, WORKERS_ENV: "1"}), "learned": ("vo", ["--flow", "learned"], env),
                "stride 4": ("vo", ["--dis-patch-stride", "4"], env)}
    if dis.max_width:  # the shipped model runs DIS on downscaled frames: time it against full-size frames too
        variants["full width"] = ("vo", ["--dis-max-width", "0"], env)
    times: dict[str, list[float]] = {k: [] for k in variants}
    with tempfile.TemporaryDirectory(prefix="bench_vo_") as tmp:
        for _ in range(1 if quick else 3):  # in turn, so a change in the machine's load hits every variant alike
            for name, (command, extra, run_env) in variants.items():
                cmd = [sys.executable, "-m", "deepslam", command, "--sequence", str(root), "--out",
                       f"{tmp}/{command}.txt", "--quiet", *extra]
                t, _ = _median_time(lambda: subprocess.run(cmd, cwd=base_dir(), check=True, capture_output=True,
                                                           env=run_env), 1)
                times[name].append(t)
    wall = {k: float(np.median(v)) for k, v in times.items()}
    fps = {k: n / v for k, v in wall.items()}
    greys = [flow_images.to_grey(seq.image(i)) for i in range(n)]
    dis_s, _ = _median_time(lambda: [dis.estimate(greys[i], greys[i + 1]) for i in range(n - 1)], 1)
    size = f"{seq.camera.width}x{seq.camera.height}"
    workers = default_workers()
    full_width = [] if "full width" not in fps else [
        _row(f"deepslam vo end to end (no flags: {dis.name}) against DIS on the full-size frames "
             f"(--dis-max-width 0), KITTI 07 slice, fresh processes in turn", fps["default"], "frames/s",
             "DIS on full-size frames", fps["full width"], None, None, full_width_runs_s=times["full width"])]
    return [_row(f"deepslam vo end to end, KITTI 07 slice ({n} frames, {size}, no flags: the shipped model, DIS flow "
                 f"({dis.name}), its recorded epipolar pose, {workers} flow workers; a fresh process)", fps["default"],
                 "frames/s", f"{dis.name} alone on the same pairs", (n - 1) / dis_s, ">= 30 frames/s",
                 fps["default"] >= 30, wall_s=wall["default"], runs_s=times["default"]),
            _row(f"deepslam slam end to end, KITTI 07 slice ({n} frames, {size}, no flags: the shipped models, "
                 f"relocalization at keyframe stride {PipelineConfig().keyframe_stride}, loops, the pose graph; a "
                 "fresh process)", fps["slam"], "frames/s", "deepslam vo (no flags) in turn", fps["default"],
                 ">= 20 frames/s and >= 0.8x vo", fps["slam"] >= 20 and fps["slam"] >= 0.8 * fps["default"],
                 wall_s=wall["slam"], runs_s=times["slam"]),
            *full_width,
            _row(f"deepslam vo --pose net end to end, KITTI 07 slice ({n} frames, {size}, a fresh process)", fps["net"],
                 "frames/s", "deepslam vo (no flags: epipolar pose) in turn", fps["default"], ">= 20 frames/s",
                 fps["net"] >= 20, wall_s=wall["net"], runs_s=times["net"]),
            _row(f"deepslam vo end to end (no flags: the distance read from the road) against --scale network (the "
                 f"network's distance, no road read), KITTI 07 slice, fresh processes in turn", fps["default"],
                 "frames/s",
                 "--scale network in turn", fps["network distance"], ">= 0.85x (the road costs at most 15 %)",
                 fps["default"] >= 0.85 * fps["network distance"], wall_s=wall["default"],
                 network_distance_runs_s=times["network distance"]),
            _row(f"deepslam vo --flow learned end to end, KITTI 07 slice ({n} frames, {size}, {workers} flow workers; "
                 "a fresh process)", fps["learned"], "frames/s", "deepslam vo (no flags: DIS) in turn", fps["default"],
                 ">= 20 frames/s (or an option, the miss measured)", fps["learned"] >= 20,
                 wall_s=wall["learned"], runs_s=times["learned"]),
            _row(f"deepslam vo end to end with {workers} flow workers (the default) against one (DIS on OpenCV's "
                 f"threads; {WORKERS_ENV}=1), KITTI 07 slice, fresh processes in turn", fps["default"], "frames/s",
                 "one flow worker", fps["one worker"], None, None, wall_s=wall["default"],
                 one_worker_runs_s=times["one worker"]),
            _row(f"deepslam vo --dis-patch-stride 4 end to end (the shipped model, DIS matching a patch every 4 "
                 f"pixels instead of its preset's 3), KITTI 07 slice ({n} frames, {size}), fresh processes in turn",
                 fps["stride 4"], "frames/s", "deepslam vo (no flags) in turn", fps["default"],
                 ">= 20 frames/s", fps["stride 4"] >= 20, wall_s=wall["stride 4"],
                 runs_s=times["stride 4"])]


def run(quick: bool = False) -> list[dict]:
    rows = []
    rows += vo_end_to_end_fps(quick)
    rows += bench_optimisation(quick)
    rows += bench_retrieval(quick)
    rows += bench_robustness(quick)
    rows += pipeline_fps(quick)
    return rows


if __name__ == "__main__":
    for r in run(quick="--quick" in sys.argv):
        print(json.dumps(r, default=str))
