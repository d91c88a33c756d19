"""Pose graph: covariance Jacobian, edge direction, loop closure, robustness, gauge."""
from __future__ import annotations

import gtsam
import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.metrics import ate
from deepslam.core.trajectory import Trajectory
from deepslam.slam.odometry import GroundTruthOdometry, NoiseConfig
from deepslam.slam.posegraph import (Edges, PoseGraphConfig, chain, euler6_covariance, euler6_jacobian, euler_rate_matrix,
                            loop_coverage, loop_residuals, measurement_covariance, measurement_jacobian,
                            optimize)
from deepslam.slam.synthetic import circle_trajectory, loop_graph

P0 = np.array([0.3, -0.4, 0.8, 1.0, -2.0, 0.5])


def _measurement_local(p0, p):
    """gtsam's own BetweenFactor error coordinates: Local(M(p0), M(p)) with M = inv(T(p))."""
    m0 = gtsam.Pose3(se3.inverse(se3.from_euler6(p0)))
    return m0.localCoordinates(gtsam.Pose3(se3.inverse(se3.from_euler6(p))))


@pytest.mark.parametrize("p0", [P0, np.zeros(6), np.array([-1.2, 1.1, 2.5, 0.0, 0.3, -4.0])])
def test_measurement_jacobian_matches_finite_differences_of_gtsam(p0):
    h = 1e-6
    fd = np.stack([(_measurement_local(p0, p0 + h * e) - _measurement_local(p0, p0 - h * e)) / (2 * h)
                   for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(measurement_jacobian(p0), fd, atol=1e-7)


def test_euler_jacobian_matches_finite_differences():
    t0 = gtsam.Pose3(se3.from_euler6(P0))
    h = 1e-6
    fd = np.stack([(t0.localCoordinates(gtsam.Pose3(se3.from_euler6(P0 + h * e)))
                    - t0.localCoordinates(gtsam.Pose3(se3.from_euler6(P0 - h * e)))) / (2 * h) for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(euler6_jacobian(P0), fd, atol=1e-7)
    # at zero angles the euler rates are the body rates
    np.testing.assert_allclose(euler_rate_matrix(np.zeros(3)), np.eye(3))


def test_covariance_matches_sampled_tangent_vectors():
    """Sample p ~ N(p0, Sigma_e), map to gtsam's tangent vectors, compare the empirical covariance."""
    rng = np.random.default_rng(0)
    std = np.array([0.01, 0.02, 0.015, 0.05, 0.03, 0.04])
    c_s, c_r = 2.0, 3.0
    sigma_e = euler6_covariance(std, c_s, c_r)
    np.testing.assert_allclose(np.diag(sigma_e), c_s * std ** 2 * np.array([c_r] * 3 + [1] * 3))
    samples = rng.multivariate_normal(P0, sigma_e, size=10000)
    tangent = np.array([_measurement_local(P0, p) for p in samples])
    empirical = np.cov(tangent.T)
    predicted = measurement_covariance(P0, std, c_s, c_r)
    assert np.linalg.norm(empirical - predicted) / np.linalg.norm(predicted) < 0.06
    # it is not the naive diagonal reordering: the rotation/translation coupling is large here
    naive = np.diag(np.diag(sigma_e))
    assert np.linalg.norm(naive - predicted) / np.linalg.norm(predicted) > 0.3


def test_direction_of_edges_recovers_ground_truth():
    """Odometry gives cam1_from_cam0; the graph must place world_from_cam1 exactly (measured = inverse)."""
    poses = circle_trajectory(30, radius_m=5.0, laps=0.5)
    poses[:, :3, 3] += np.linspace(0, 1, 30)[:, None] * np.array([0.3, -0.2, 0.1])
    gt = Trajectory(poses)
    odo = GroundTruthOdometry(NoiseConfig(std6=(0,) * 6), gt=gt)
    pairs = [(i, i + 1) for i in range(29)]
    m, s = odo.predict(None, pairs)
    np.testing.assert_allclose(se3.from_euler6(m), gt.relative_motions(1), atol=1e-12)
    cons = Edges(np.array(pairs), m, np.full_like(s, 0.01))
    lp = [(0, 20), (5, 29)]
    lm, _ = odo.predict(None, lp)
    res = optimize(30, cons, Edges(np.array(lp), lm, np.full((2, 6), 0.01)), PoseGraphConfig(), poses[0])
    np.testing.assert_allclose(res.world_from_cam, poses, atol=1e-6)
    np.testing.assert_allclose(chain(30, cons, poses[0]), poses, atol=1e-9)
    # the opposite convention (measured = cam1_from_cam0) would put the poses elsewhere
    wrong = Edges(np.array(pairs), se3.to_euler6(se3.inverse(se3.from_euler6(m))), cons.std6)
    assert np.abs(chain(30, wrong, poses[0]) - poses).max() > 0.1


def test_edges_from_poses_measure_the_poses_exactly():
    """Edges.from_poses gives cam_j_from_cam_i, as the odometry does: chained, they rebuild the poses."""
    poses = circle_trajectory(12, radius_m=4.0, laps=0.3)
    pairs = np.array([(i, i + 1) for i in range(11)] + [(0, 9)])
    edges = Edges.from_poses(poses, pairs, (0.01,) * 3 + (0.1,) * 3)
    m, _ = GroundTruthOdometry(NoiseConfig(std6=(0,) * 6), gt=Trajectory(poses)).predict(None, pairs.tolist())
    np.testing.assert_allclose(edges.mean6, m, atol=1e-12)
    np.testing.assert_allclose(edges.std6, np.tile([0.01] * 3 + [0.1] * 3, (12, 1)))
    np.testing.assert_allclose(chain(12, edges.subset(np.arange(12) < 11), poses[0]), poses, atol=1e-9)
    assert len(Edges.from_poses(poses, np.zeros((0, 2), int), np.ones(6))) == 0


def test_loop_closure_reduces_drift():
    g = loop_graph(n_frames=300, laps=2.0, radius_m=30.0, loop_every=5, seed=3)
    gt, cons, loops = g["gt"], g["cons"], g["loops"]
    vo = chain(300, cons, gt.world_from_cam[0])
    res = optimize(300, cons, loops, PoseGraphConfig(), gt.world_from_cam[0])
    ate_vo = ate(gt.world_from_cam, vo)["rmse_m"]
    ate_slam = ate(gt.world_from_cam, res.world_from_cam)["rmse_m"]
    assert ate_vo > 2.0
    assert ate_slam < 0.1 * ate_vo
    assert res.loop_inliers.all()
    # without loops the graph is dead reckoning
    res0 = optimize(300, cons, None, PoseGraphConfig(), gt.world_from_cam[0])
    np.testing.assert_allclose(res0.world_from_cam, vo, atol=1e-6)


def test_false_loops_hurt_little_with_robust_kernel():
    g = loop_graph(n_frames=300, laps=2.0, radius_m=30.0, loop_every=5, n_false=4, seed=4)
    gt, cons, loops, false = g["gt"], g["cons"], g["loops"], g["false_loops"]
    assert len(false) >= 0.1 * len(loops)
    w0 = gt.world_from_cam[0]
    both = Edges.concat(loops, false)
    clean = ate(gt.world_from_cam, optimize(300, cons, loops, PoseGraphConfig(), w0).world_from_cam)["rmse_m"]
    robust = optimize(300, cons, both, PoseGraphConfig(), w0)
    plain = optimize(300, cons, both, PoseGraphConfig(robust="none"), w0)
    ate_robust = ate(gt.world_from_cam, robust.world_from_cam)["rmse_m"]
    ate_plain = ate(gt.world_from_cam, plain.world_from_cam)["rmse_m"]
    assert ate_robust <= 1.1 * clean
    assert ate_plain > 3.0 * clean  # without the kernel the false loops do real damage
    assert not robust.loop_inliers[len(loops):].any()
    assert robust.loop_inliers[:len(loops)].mean() > 0.9


def test_loop_residuals_are_whitened():
    g = loop_graph(n_frames=200, laps=2.0, radius_m=20.0, loop_every=1, seed=5)
    r = loop_residuals(g["gt"].world_from_cam, g["loops"], PoseGraphConfig())
    # at the true poses the residual norm of honest 6-DoF noise is chi-distributed with 6 dof
    assert 2.0 < np.sqrt(np.mean(r ** 2)) < 3.0


def test_prior_fixes_the_gauge():
    g = loop_graph(n_frames=120, laps=2.0, radius_m=10.0, loop_every=4, seed=6)
    cons, loops = g["cons"], g["loops"]
    a = optimize(120, cons, loops, PoseGraphConfig())
    np.testing.assert_allclose(a.world_from_cam[0], np.eye(4), atol=1e-6)
    shift = se3.from_euler6(np.array([0.1, -0.7, 0.3, 5.0, -2.0, 1.0]))
    b = optimize(120, cons, loops, PoseGraphConfig(), world_from_cam0=shift)
    np.testing.assert_allclose(b.world_from_cam[0], shift, atol=1e-6)
    # the whole solution moves rigidly with the prior
    np.testing.assert_allclose(shift @ a.world_from_cam, b.world_from_cam, atol=1e-5)


def test_gauss_newton_and_lm_agree_and_bad_edges_raise():
    g = loop_graph(n_frames=100, laps=2.0, radius_m=10.0, loop_every=5, seed=7)
    lm = optimize(100, g["cons"], g["loops"], PoseGraphConfig(robust="none"))
    gn = optimize(100, g["cons"], g["loops"], PoseGraphConfig(robust="none", optimizer="gn"))
    np.testing.assert_allclose(lm.world_from_cam, gn.world_from_cam, atol=1e-5)
    with pytest.raises(ValueError, match="consecutive"):
        optimize(100, g["cons"].subset(slice(1, None)), None)
    with pytest.raises(ValueError, match="robust"):
        optimize(100, g["cons"], g["loops"], PoseGraphConfig(robust="tukey"))


def test_c_s_weighs_the_odometry_against_the_loops():
    """C_s scales the consecutive edges' covariance only: a common factor on every edge would not move
    the least-squares optimum, so C_s is the relative trust in odometry vs loop closures. With biased
    odometry (its std cannot show the bias) trusting the loops more (larger C_s) lowers the ATE."""
    g = loop_graph(n_frames=300, laps=2.0, radius_m=30.0, loop_every=5, seed=3)
    gt, w0 = g["gt"].world_from_cam, g["gt"].world_from_cam[0]
    plain = PoseGraphConfig(robust="none")
    ates = [ate(gt, optimize(300, g["cons"], g["loops"], PoseGraphConfig(robust="none", c_s=c), w0).world_from_cam)["rmse_m"]
            for c in (0.1, 1.0, 10.0)]
    assert ates[0] > ates[1] > ates[2]
    # the same factor on both kinds of edge: the same optimum
    a = optimize(300, g["cons"], g["loops"], plain, w0).world_from_cam
    b = optimize(300, g["cons"], g["loops"], PoseGraphConfig(robust="none", c_s=7.0, loop_cov_scale=7.0), w0).world_from_cam
    np.testing.assert_allclose(a, b, atol=1e-6)


@pytest.mark.parametrize("pairs,expected", [
    ([], [0] * 8),
    ([(1, 4)], [0, 1, 1, 1, 1, 0, 0, 0]),
    ([(5, 2), (6, 7)], [0, 0, 1, 1, 1, 1, 1, 1]),     # either order; cycles joined
])
def test_loop_coverage_marks_the_poses_a_loop_edge_closes(pairs, expected):
    assert loop_coverage(8, np.array(pairs)).tolist() == [bool(x) for x in expected]
    with pytest.raises(ValueError, match="0..7"):
        loop_coverage(8, np.array([(2, 8)]))
