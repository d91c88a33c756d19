"""Hyperparameter search for C_s, C_r and T_loop, ranked by ATE on validation sequences.

A :class:`TuneProblem` is one validation sequence reduced to what the search needs: its ground truth
and a ``solve(params) -> world_from_cam`` (the pipeline's cached stages plus a pose-graph solve,
:func:`problem_from_prepared`). The objective of a parameter set is the mean over problems of the
ATE RMSE (se3 alignment; ``score="ate_ratio"``: ATE divided by that sequence's VO ATE, so long
sequences do not dominate). :func:`grid_search` tries every combination; :func:`coordinate_search`
optimises one parameter at a time over its grid values, cycling until no coordinate improves
(far fewer solves, may stop at a local optimum). Ties keep the earlier grid point. Every evaluation
is memoised.
"""
from __future__ import annotations

import dataclasses
import itertools
import time
from typing import Callable

import numpy as np

from deepslam.core import metrics
from deepslam.core.errors import InputError
from deepslam.core.progress import progress
from deepslam.core.trajectory import Trajectory
from deepslam.slam.pipeline import Prepared, SlamParams, solve
from deepslam.slam.posegraph import PoseGraphConfig, chain

SCORES = ("ate", "ate_ratio")


@dataclasses.dataclass(frozen=True)
class SearchSpace:
    """Values tried for each hyperparameter (the grid)."""

    c_s: tuple[float, ...] = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0)
    """C_s values."""
    c_r: tuple[float, ...] = (0.1, 1.0, 10.0, 100.0)
    """C_r values."""
    t_loop: tuple[int, ...] = (20, 50, 100, 200)
    """T_loop values (frames)."""

    def __post_init__(self) -> None:
        for name in ("c_s", "c_r", "t_loop"):
            vals = getattr(self, name)
            if not vals:
                raise ValueError(f"search space for {name} is empty")
        if min(self.c_s) <= 0 or min(self.c_r) <= 0 or min(self.t_loop) < 1:
            raise ValueError("C_s and C_r must be > 0 and T_loop >= 1")

    def size(self) -> int:
        return len(self.c_s) * len(self.c_r) * len(self.t_loop)


@dataclasses.dataclass
class TuneProblem:
    """One validation sequence for the search.

    Attributes:
        name: shown in the report.
        gt: ground truth world_from_cam (N, 4, 4) float64.
        solve: params -> estimated world_from_cam (N, 4, 4).
        vo_ate_m: ATE of the odometry alone (for ``ate_ratio`` and the report).
    """

    name: str
    gt: np.ndarray
    solve: Callable[[SlamParams], np.ndarray]
    vo_ate_m: float


@dataclasses.dataclass(frozen=True)
class TuneResult:
    """Outcome of a search: the best parameters, their score and every evaluation (rows)."""

    best: SlamParams
    best_score: float
    method: str
    score: str
    rows: list
    evaluations: int
    time_s: float

    def to_dict(self) -> dict:
        return {"method": self.method, "score": self.score, "best_score": self.best_score,
                "evaluations": self.evaluations, "time_s": self.time_s, "search": self.rows}


def problem_from_prepared(prep: Prepared, graph: PoseGraphConfig = PoseGraphConfig(), name: str | None = None) -> TuneProblem:
    """A TuneProblem from a prepared sequence with ground truth (solves the pose graph per params)."""
    gt = getattr(prep.seq, "gt", None)
    if gt is None:
        raise InputError(getattr(prep.seq, "root", None), "a validation sequence needs ground truth")
    first = gt.world_from_cam[0]

    def run(params: SlamParams) -> np.ndarray:
        return solve(prep, params, graph, first)[0].world_from_cam

    vo = chain(prep.n, prep.cons, first)
    return TuneProblem(name or getattr(prep.seq, "name", "sequence"), gt.world_from_cam, run,
                       metrics.ate(gt.world_from_cam, vo)["rmse_m"])


def make_objective(problems: list[TuneProblem], score: str = "ate") -> Callable[[SlamParams], tuple[float, dict]]:
    """params -> (score, {problem name: ATE m}); the score is the mean ATE (or ATE / VO ATE)."""
    if score not in SCORES:
        raise ValueError(f"score must be one of {SCORES}, got {score!r}")
    if not problems:
        raise ValueError("no validation problems")

    def objective(params: SlamParams) -> tuple[float, dict]:
        per = {}
        vals = []
        for p in problems:
            est = p.solve(params)
            a = metrics.ate(p.gt, est)["rmse_m"]
            per[p.name] = a
            vals.append(a / p.vo_ate_m if score == "ate_ratio" and p.vo_ate_m > 0 else a)
        return float(np.mean(vals)), per

    return objective


class _Memo:
    def __init__(self, objective, show_progress: bool, total: int | None):
        self.objective = objective
        self.cache: dict[tuple, tuple[float, dict]] = {}
        self.rows: list[dict] = []
        self.bar = progress(total=total, desc="tune-slam", unit="solve", disable=None if show_progress else True)

    def __call__(self, params: SlamParams) -> float:
        key = (params.c_s, params.c_r, params.t_loop)
        if key not in self.cache:
            val = self.objective(params)
            if not isinstance(val, tuple):
                val = (float(val), {})
            s = float(val[0]) if np.isfinite(val[0]) else float("inf")
            self.cache[key] = (s, val[1])
            self.rows.append({"c_s": params.c_s, "c_r": params.c_r, "t_loop": params.t_loop, "score": s,
                              "per_sequence_ate_m": val[1]})
            self.bar.update(1)
        return self.cache[key][0]


def grid_search(objective, space: SearchSpace = SearchSpace(), show_progress: bool = False,
                score_name: str = "ate") -> TuneResult:
    """Evaluate every combination; the best (lowest) score wins, ties to the earlier grid point.

    Args:
        objective: params -> score, or (score, details dict).
    """
    t0 = time.perf_counter()
    memo = _Memo(objective, show_progress, space.size())
    best, best_s = None, float("inf")
    # T_loop outermost: the pipeline's loop search is cached per T_loop
    for t_loop, c_s, c_r in itertools.product(space.t_loop, space.c_s, space.c_r):
        p = SlamParams(c_s=float(c_s), c_r=float(c_r), t_loop=int(t_loop))
        s = memo(p)
        if s < best_s or best is None:
            best, best_s = p, s
    memo.bar.close()
    return TuneResult(best, best_s, "grid", score_name, memo.rows, len(memo.rows), time.perf_counter() - t0)


def coordinate_search(objective, space: SearchSpace = SearchSpace(), start: SlamParams | None = None,
                      max_rounds: int = 4, show_progress: bool = False, score_name: str = "ate") -> TuneResult:
    """Coordinate descent over the grid values: for T_loop, C_s, C_r in turn, try every value of that
    coordinate with the others fixed and keep the best; repeat until a round changes nothing.

    Args:
        objective: params -> score, or (score, details dict).
        start: starting point (default: the middle value of each grid).
    """
    t0 = time.perf_counter()
    memo = _Memo(objective, show_progress, None)
    mid = lambda v: sorted(v)[len(v) // 2]  # noqa: E731
    cur = start or SlamParams(c_s=float(mid(space.c_s)), c_r=float(mid(space.c_r)), t_loop=int(mid(space.t_loop)))
    cur_s = memo(cur)
    for _ in range(max_rounds):
        changed = False
        for name, values in (("t_loop", space.t_loop), ("c_s", space.c_s), ("c_r", space.c_r)):
            for v in values:
                cand = dataclasses.replace(cur, **{name: int(v) if name == "t_loop" else float(v)})
                s = memo(cand)
                if s < cur_s:
                    cur, cur_s, changed = cand, s, True
        if not changed:
            break
    memo.bar.close()
    return TuneResult(cur, cur_s, "coordinate", score_name, memo.rows, len(memo.rows), time.perf_counter() - t0)


def tune(problems: list[TuneProblem], space: SearchSpace = SearchSpace(), method: str = "grid",
         score: str = "ate", show_progress: bool = False) -> TuneResult:
    """Search C_s, C_r, T_loop on the problems by ``method`` ("grid" or "coordinate")."""
    objective = make_objective(problems, score)
    if method == "grid":
        return grid_search(objective, space, show_progress, score)
    if method == "coordinate":
        return coordinate_search(objective, space, show_progress=show_progress, score_name=score)
    raise ValueError(f"method must be 'grid' or 'coordinate', got {method!r}")


def trajectory_problem(name: str, gt: Trajectory, solve_fn: Callable[[SlamParams], np.ndarray],
                       vo_world_from_cam: np.ndarray) -> TuneProblem:
    """A TuneProblem from any solver (tests and benchmarks with synthetic graphs)."""
    return TuneProblem(name, gt.world_from_cam, solve_fn, metrics.ate(gt.world_from_cam, vo_world_from_cam)["rmse_m"])
