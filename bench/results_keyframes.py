"""``python -m bench.results_keyframes``: relocalization on every k-th frame, against every frame.

``deepslam slam``'s defaults (shipped NN_cons / NN_loops on DIS flow, ``SlamParams()``, a vocabulary trained on the
sequence's own keyframes) with keyframe strides 1, 2 and 3, on street loop routes (``render --route laps``) and a
room, read as ``deepslam slam`` reads them. The consecutive odometry is computed once a sequence and shared by the
strides (the stride does not change it), so the seconds reported are relocalization's own: SIFT features, the
vocabulary, the database and the loop search. Loop recall: of the keyframes that revisit a place the same way
(ground truth: :class:`slam.reference.PerfectLoopsConfig`'s 3 m and 20 degrees, more than T_loop frames apart), the
share with an accepted loop edge. The rule is docs/experiments/2026-12-06_keyframe_stride.md, written before this
table. Writes results.json and results.md into ``out/results/keyframes``; renders and odometry are cached.
"""
from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from bench.results_common import results_main, write_report
from deepslam.core import atomic
from deepslam.core.readers import open_sequence
from deepslam.core.trajectory import revisit_pairs


@dataclasses.dataclass(frozen=True)
class ResultsKeyframesConfig:
    """What is rendered and compared."""

    street_seeds: tuple[int, ...] = (7441, 7442)
    """Street seeds driven on ``--route laps`` (chosen 2026-12-06 for this rule, never rendered before)."""
    street_frames: int = 1900
    """Frames per street (one round of the loop route and its start again, as the loop-route table)."""
    street_width: int = 414
    """Street render width (KITTI's camera / 3); read at 640 as ``deepslam slam`` reads it."""
    room_seeds: tuple[int, ...] = (7,)
    """Room seeds (the SLAM table's test room)."""
    room_frames: int = 600
    """Frames per room (20 Hz; 2.6 laps of the drone's route)."""
    room_width: int = 376
    """Room render width (EuRoC's camera / 2)."""
    strides: tuple[int, ...] = (1, 2, 3)
    """Keyframe strides compared."""


QUICK = ResultsKeyframesConfig(street_seeds=(7441,), street_frames=200, room_seeds=(), strides=(1, 2))


class SharedOdometry:
    """An odometry that computes the consecutive pairs once and answers later calls with the same pairs from
    memory (the variants of one sequence share it); other pairs go to the wrapped odometry."""

    def __init__(self, odometry):
        self.odometry = odometry
        self.name = odometry.name
        self._memo: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}

    def predict(self, seq, pairs):
        key = tuple(map(tuple, pairs))
        if key not in self._memo:
            self._memo[key] = self.odometry.predict(seq, pairs)
        return self._memo[key]


def loop_recall(gt_world_from_cam: np.ndarray, keyframes: list[int], loop_pairs: np.ndarray, t_loop: int) -> dict:
    """Of the keyframes j with a same-way revisit of a keyframe i (ground truth, j - i > ``t_loop``), how many
    have an accepted loop edge ``(i', j)`` joining views the same way: ``{"revisiting": n, "found": n,
    "recall": found / revisiting}``."""
    from deepslam.slam.reference import PerfectLoopsConfig

    cfg = PerfectLoopsConfig()
    kf = np.asarray(keyframes, np.int64)
    poses = np.asarray(gt_world_from_cam, np.float64)[kf]
    stride = int(kf[1] - kf[0]) if len(kf) > 1 else 1
    gap = int(np.ceil((t_loop + 1) / stride))  # in keyframes
    rev = revisit_pairs(poses, gap, cfg.max_distance_m, cfg.max_angle_deg, nearest_only=True)
    rev = rev[(kf[rev[:, 1]] - kf[rev[:, 0]]) > t_loop] if len(rev) else rev
    revisiting = set(kf[rev[:, 1]].tolist()) if len(rev) else set()
    pairs = np.asarray(loop_pairs, np.int64).reshape(-1, 2)
    gt = np.asarray(gt_world_from_cam, np.float64)
    same = np.einsum("ij,ij->i", gt[pairs[:, 0], :3, 2], gt[pairs[:, 1], :3, 2]) >= 0 if len(pairs) else []
    found = {int(j) for (i, j), s in zip(pairs, same) if s} & revisiting
    return {"revisiting": len(revisiting), "found": len(found),
            "recall": len(found) / len(revisiting) if revisiting else None}


def evaluate(seq, strides: tuple[int, ...]) -> dict:
    """{stride: record} of ``deepslam slam``'s defaults on ``seq`` (read as the command reads it)."""
    from bench.results_slam import _metrics, _odometry, as_slam_reads
    from deepslam.slam.pipeline import PipelineConfig, SlamParams, consecutive_pairs, prepare, solve
    from deepslam.slam.posegraph import chain

    seq = as_slam_reads(seq, "dis")
    cons, loops_odo = _odometry(seq, "dis")
    cons = SharedOdometry(cons)
    cons.predict(seq, consecutive_pairs(len(seq)))  # first, alone: every stride's relocalization then runs alone
    params = SlamParams()
    first = seq.gt.world_from_cam[0]
    got = {}
    for k in strides:
        t0 = time.perf_counter()
        prep = prepare(seq, cons, loops_odo, PipelineConfig(keyframe_stride=k), show_progress=False,
                       t_loop=params.t_loop)
        t1 = time.perf_counter()
        res, loops = solve(prep, params, world_from_cam0=first)
        t2 = time.perf_counter()
        kept = loops.pairs[res.loop_inliers] if len(loops) else np.zeros((0, 2), np.int64)
        got[str(k)] = {"slam": _metrics(seq, res.world_from_cam), "loop_edges": int(len(loops)),
                       "loop_edges_kept": int(len(kept)), "keyframes": len(prep.keyframes),
                       "recall": loop_recall(seq.gt.world_from_cam, prep.keyframes, kept, params.t_loop),
                       "reloc_s": {"prepare": t1 - t0, "loop_search_and_graph": t2 - t1,
                                   **{key: float(v) for key, v in prep.timings.items() if key.endswith("_s")}}}
        if "vo" not in got:
            got["vo"] = _metrics(seq, chain(prep.n, prep.cons, first))
    return got


def run(cfg: ResultsKeyframesConfig, out: Path) -> dict:
    from deepslam.studies.demo import render_once

    out.mkdir(parents=True, exist_ok=True)
    log: list[str] = []
    t0 = time.perf_counter()
    rows = {}
    cases = [("street", "car", s, cfg.street_frames, cfg.street_width, ("--route", "laps")) for s in cfg.street_seeds]
    cases += [("room", "drone", s, cfg.room_frames, cfg.room_width, ()) for s in cfg.room_seeds]
    for scene, trajectory, seed, frames, width, flags in cases:
        name = f"{scene}_s{seed}"
        path = out / "cases" / f"{name}.json"
        root = render_once(scene, trajectory, frames, width, seed, out / name, log, (*flags, "--quiet"))
        if path.is_file():
            rows[name] = json.loads(path.read_text())
            continue
        print(f"{name}: strides {cfg.strides}", flush=True)
        rows[name] = evaluate(open_sequence(root), cfg.strides)
        atomic.write_json(path, rows[name])
    report = {"config": dataclasses.asdict(cfg), "rows": rows, "commands": log, "rule": rule(rows, cfg.strides),
              "minutes": (time.perf_counter() - t0) / 60}
    write_report(out, report, markdown)
    return report


def rule(rows: dict, strides: tuple[int, ...]) -> dict:
    """The decision record's rule: {stride: met on every row}; ``chosen``: the largest stride meeting it."""
    met = {}
    for k in strides:
        ok = True
        for r in rows.values():
            base, this = r["1"], r[str(k)]
            ate_ok = this["slam"]["ate_m"] <= max(1.05 * base["slam"]["ate_m"], base["slam"]["ate_m"] + 0.05)
            b, t = base["recall"]["recall"], this["recall"]["recall"]
            recall_ok = b is None or (t is not None and t >= 0.9 * b)
            ok = ok and ate_ok and recall_ok
        met[str(k)] = ok
    chosen = max((k for k in strides if met[str(k)]), default=1)
    return {"met": met, "chosen": chosen}


def markdown(report: dict) -> str:
    strides = report["config"]["strides"]
    md = ["| sequence | stride | keyframes | VO ATE [m] | SLAM ATE [m] | loop edges kept | same-way revisiting "
          "keyframes | with a loop edge (recall) | relocalization s (features / vocabulary / database) |",
          "|---|---|---|---|---|---|---|---|---|"]
    for name, r in report["rows"].items():
        for k in strides:
            x = r[str(k)]
            rec, t = x["recall"], x["reloc_s"]
            recall = "n/a" if rec["recall"] is None else f"{rec['found']} ({rec['recall']:.2f})"
            md.append(f"| {name} | {k} | {x['keyframes']} | {r['vo']['ate_m']:.3g} | {x['slam']['ate_m']:.3g} | "
                      f"{x['loop_edges_kept']} | {rec['revisiting']} | {recall} | "
                      f"{t.get('features_thread_s', 0):.1f} / {t.get('vocabulary_s', 0):.1f} / "
                      f"{t.get('database_s', 0):.1f} |")
    res = report["rule"]
    md += ["", "Rule (SLAM ATE within max(1.05 x, + 0.05 m) of stride 1's and loop recall at least 0.9 x, every row): "
           + ", ".join(f"stride {k} {'met' if v else 'not met'}" for k, v in res["met"].items())
           + f"; chosen: {res['chosen']}."]
    return "\n".join(md)


def main(argv: list[str] | None = None) -> int:
    return results_main("results_keyframes", __doc__, ResultsKeyframesConfig(), QUICK, "keyframes",
                        lambda cfg, out, data: run(cfg, out), markdown, argv)


if __name__ == "__main__":
    sys.exit(main())
