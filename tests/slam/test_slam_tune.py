"""Hyperparameter search: grid and coordinate search find known optima."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.slam.odometry import NoiseConfig
from deepslam.slam.pipeline import SlamParams
from deepslam.slam.posegraph import Edges, PoseGraphConfig, chain, optimize
from deepslam.slam.synthetic import loop_graph
from deepslam.slam.tune import SearchSpace, coordinate_search, grid_search, trajectory_problem, tune

SPACE = SearchSpace(c_s=(0.1, 1.0, 10.0, 100.0), c_r=(0.01, 0.1, 1.0, 10.0), t_loop=(5, 20, 50, 100))


def _bowl(p: SlamParams) -> float:
    """Separable objective with its minimum at (C_s 10, C_r 0.1, T_loop 20)."""
    return (np.log10(p.c_s) - 1.0) ** 2 + (np.log10(p.c_r) + 1.0) ** 2 + ((p.t_loop - 20) / 30.0) ** 2


def test_grid_and_coordinate_search_find_the_minimum():
    g = grid_search(_bowl, SPACE)
    assert g.best == SlamParams(c_s=10.0, c_r=0.1, t_loop=20)
    assert g.best_score == pytest.approx(0.0)
    assert g.evaluations == SPACE.size() == len(g.rows)
    c = coordinate_search(_bowl, SPACE)
    assert c.best == g.best
    assert c.evaluations < g.evaluations


def test_search_space_rejects_bad_values():
    with pytest.raises(ValueError):
        SearchSpace(c_s=())
    with pytest.raises(ValueError):
        SearchSpace(c_r=(0.0,))
    with pytest.raises(ValueError):
        SearchSpace(t_loop=(0,))


def test_tuning_picks_the_known_best_on_a_toy_slam_problem():
    """The odometry understates its rotation noise 10x (so a large C_r is right), and false loops exist
    only at gaps <= 60 frames while true loops are 150 apart (so T_loop 100 is right)."""
    n = 300
    cons_noise = NoiseConfig(std6=(0.003, 0.003, 0.003, 0.02, 0.02, 0.02), bias6=(0, 0.002, 0, 0, 0, 0),
                             claimed_std_scale=(0.1, 0.1, 0.1, 1, 1, 1), seed=0)
    g = loop_graph(n, 2.0, radius_m=30.0, loop_every=3, cons_noise=cons_noise, seed=0)
    gt, w0 = g["gt"], g["gt"].world_from_cam[0]
    fp = np.array([(i, i + 45 + (i % 16)) for i in range(10, 240, 40)])
    false = Edges(fp, np.tile([0, 0, 0, 0, 0, 0.5], (len(fp), 1)), np.tile(g["loops"].std6[0], (len(fp), 1)))
    all_loops = Edges.concat(g["loops"], false)
    gaps = all_loops.pairs[:, 1] - all_loops.pairs[:, 0]

    def solve(p: SlamParams) -> np.ndarray:
        cfg = PoseGraphConfig(robust="none", c_s=p.c_s, c_r=p.c_r)
        return optimize(n, g["cons"], all_loops.subset(gaps > p.t_loop), cfg, w0).world_from_cam

    problem = trajectory_problem("toy", gt, solve, chain(n, g["cons"], w0))
    space = SearchSpace(c_s=(1.0,), c_r=(0.01, 1.0, 100.0), t_loop=(10, 100))
    for method in ("grid", "coordinate"):
        res = tune([problem], space, method)
        assert res.best == SlamParams(c_s=1.0, c_r=100.0, t_loop=100), res.rows
        assert res.best_score < 0.2 * problem.vo_ate_m
