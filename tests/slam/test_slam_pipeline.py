"""The odometry protocol, the params file and the whole pipeline on a synthetic revisit sequence."""
from __future__ import annotations

import json

import numpy as np
import pytest

from deepslam.core import se3
from deepslam.core.errors import InputError
from deepslam.core.metrics import ate
from deepslam.slam.odometry import GroundTruthOdometry, NoiseConfig, Odometry, VerifiedOdometry, check_prediction
from deepslam.slam.pipeline import PipelineConfig, SlamParams, prepare, run_slam, solve
from deepslam.slam.reloc import RelocConfig
from deepslam.slam.synthetic import synthetic_trajectory, write_loop_sequence

N, LAPS = 80, 2.0  # 40 frames per lap: frame i and i + 40 are the same place
RELOC = RelocConfig(image_scale=1.0, n_features=300, vocabulary_size=200, n_candidates=5)
# the pipelines below relocalize every frame: a synthetic place matches only its exact revisit, 40 frames later
# (not a multiple of the default keyframe stride)


@pytest.fixture(scope="module")
def loop_seq(tmp_path_factory):
    return write_loop_sequence(tmp_path_factory.mktemp("loopseq"), n_frames=N, laps=LAPS, lap_offset_m=0.2, seed=1)


def test_ground_truth_odometry_implements_the_protocol():
    gt = synthetic_trajectory(50, laps=1.0, radius_m=5.0)
    exact = GroundTruthOdometry(NoiseConfig(std6=(0,) * 6), gt=gt)
    assert isinstance(exact, Odometry)
    pairs = [(0, 1), (3, 40), (10, 11)]
    m, s = exact.predict(None, pairs)
    for (i, j), row in zip(pairs, m):  # rows are cam_j_from_cam_i
        want = se3.inverse(gt.world_from_cam[j]) @ gt.world_from_cam[i]
        np.testing.assert_allclose(se3.from_euler6(row), want, atol=1e-12)
    noisy = GroundTruthOdometry(NoiseConfig(std6=(0.01,) * 3 + (0.1,) * 3, seed=5), gt=gt)
    many = [(i, i + 1) for i in range(49)]
    m1, s1 = noisy.predict(None, many)
    m0, _ = exact.predict(None, many)
    err = (m1 - m0) / s1
    assert 0.7 < err.std() < 1.3  # honest std
    # the noise of a pair does not depend on which other pairs are asked for
    np.testing.assert_array_equal(noisy.predict(None, many[5:7])[0], m1[5:7])
    biased = GroundTruthOdometry(NoiseConfig(std6=(0,) * 6, bias6=(0, 0.01, 0, 0, 0, 0)), gt=gt)
    np.testing.assert_allclose(biased.predict(None, many)[0] - m0, np.tile([0, 0.01, 0, 0, 0, 0], (49, 1)), atol=1e-12)


def test_check_prediction_rejects_bad_answers():
    pairs = [(0, 1), (1, 2)]
    good = np.zeros((2, 6)), np.ones((2, 6))
    check_prediction("m", pairs, *good)
    with pytest.raises(ValueError, match="shape"):
        check_prediction("m", pairs, np.zeros((3, 6)), np.ones((2, 6)))
    with pytest.raises(ValueError, match="finite"):
        check_prediction("m", pairs, np.full((2, 6), np.nan), np.ones((2, 6)))
    with pytest.raises(ValueError, match="> 0"):
        check_prediction("m", pairs, np.zeros((2, 6)), np.zeros((2, 6)))


def test_params_json_round_trip_and_errors(tmp_path):
    p = SlamParams(c_s=3.0, c_r=10.0, t_loop=25)
    p.save(tmp_path / "p.json", extra={"note": 1})
    assert SlamParams.load(tmp_path / "p.json") == p
    (tmp_path / "bad.json").write_text(json.dumps({"format": "deepslam-slam-params-v1", "c_s": -1, "c_r": 1, "t_loop": 5}))
    with pytest.raises(InputError, match="bad.json"):
        SlamParams.load(tmp_path / "bad.json")
    (tmp_path / "other.json").write_text("{}")
    with pytest.raises(InputError, match="not a SLAM parameter file"):
        SlamParams.load(tmp_path / "other.json")
    with pytest.raises(InputError, match="missing"):
        SlamParams.load(tmp_path / "none.json")


def test_pipeline_closes_the_loop_on_a_revisit_sequence(loop_seq):
    cons = GroundTruthOdometry(NoiseConfig(bias6=(0, 0.004, 0, 0, 0, 0), seed=1))
    loops = GroundTruthOdometry(NoiseConfig(seed=2))
    res = run_slam(loop_seq, cons, loops, SlamParams(t_loop=20), PipelineConfig(reloc=RELOC, keyframe_stride=1), show_progress=False)
    pairs = {tuple(p) for p in res.loops.pairs.tolist()}
    per_lap = int(N / LAPS)
    true = {(i, i + per_lap) for i in range(N - per_lap)}
    assert pairs <= true  # no false loop passes the check
    assert len(pairs) >= 0.8 * len(true)
    ate_vo = ate(loop_seq.gt, res.vo)["rmse_m"]
    ate_slam = ate(loop_seq.gt, res.slam)["rmse_m"]
    assert ate_slam < 0.5 * ate_vo
    assert res.timings["fps"] > 0 and res.vocabulary is not None
    np.testing.assert_allclose(res.slam.world_from_cam[0], loop_seq.gt.world_from_cam[0], atol=1e-6)
    np.testing.assert_array_equal(res.slam.timestamps_s, loop_seq.timestamps_s)


def test_t_loop_filters_loops_and_prepared_stages_are_reused(loop_seq):
    cons = GroundTruthOdometry(NoiseConfig(bias6=(0, 0.004, 0, 0, 0, 0), seed=1))
    loops = GroundTruthOdometry(NoiseConfig(seed=2))
    prep = prepare(loop_seq, cons, loops, PipelineConfig(reloc=RELOC, keyframe_stride=1), show_progress=False)
    _, near = solve(prep, SlamParams(t_loop=20))
    _, far = solve(prep, SlamParams(t_loop=45))  # revisits are 40 frames apart: none is far enough
    assert len(near) > 0 and len(far) == 0
    verified = prep.detector.timings["verifications"]
    solve(prep, SlamParams(t_loop=20, c_s=3.0))  # cached: no new verification
    assert prep.detector.timings["verifications"] == verified


class _BrokenEvery3rd:
    """A loop odometry whose input breaks on every third pair (by frame i): those pairs read 5 m off."""

    name = "broken-every-3rd"

    def __init__(self):
        self.inner = GroundTruthOdometry(NoiseConfig(seed=2))

    def predict(self, seq, pairs):
        return self.predict_verified(seq, pairs)[:2]

    def predict_verified(self, seq, pairs):
        mean6, std6 = self.inner.predict(seq, pairs)
        rigid = np.array([i % 3 != 0 for i, _ in pairs], bool)
        mean6[~rigid, 5] += 5.0
        return mean6, std6, rigid


@pytest.mark.parametrize("loop_check", [True, False])
def test_loop_pairs_whose_flow_breaks_are_left_out(loop_seq, loop_check):
    assert isinstance(_BrokenEvery3rd(), VerifiedOdometry)
    assert not isinstance(GroundTruthOdometry(), VerifiedOdometry)
    cons = GroundTruthOdometry(NoiseConfig(bias6=(0, 0.004, 0, 0, 0, 0), seed=1))
    config = PipelineConfig(reloc=RELOC, keyframe_stride=1, loop_check=loop_check)
    res = run_slam(loop_seq, cons, _BrokenEvery3rd(), SlamParams(t_loop=20), config, show_progress=False)
    plain = run_slam(loop_seq, cons, GroundTruthOdometry(NoiseConfig(seed=2)), SlamParams(t_loop=20), config,
                     show_progress=False)
    every = {tuple(p) for p in plain.loops.pairs.tolist()}
    broken = {p for p in every if p[0] % 3 == 0}
    assert broken and len(plain.loops_not_rigid) == 0
    if loop_check:
        assert {tuple(p) for p in res.loops.pairs.tolist()} == every - broken
        assert {tuple(p) for p in res.loops_not_rigid.tolist()} == broken
    else:
        assert {tuple(p) for p in res.loops.pairs.tolist()} == every and len(res.loops_not_rigid) == 0


def test_pipeline_without_loops_is_dead_reckoning(loop_seq):
    cons = GroundTruthOdometry(NoiseConfig(seed=1))
    res = run_slam(loop_seq, cons, None, show_progress=False)
    np.testing.assert_allclose(res.slam.world_from_cam, res.vo.world_from_cam, atol=1e-6)
    assert len(res.loops) == 0 and res.vocabulary is None


def test_loop_search_in_the_background_equals_the_sequential_one(loop_seq):
    """With a given vocabulary the database and the loop search run in a second thread during the
    odometry; the loops and the trajectory are exactly those of the lazy, sequential search."""
    cons = GroundTruthOdometry(NoiseConfig(bias6=(0, 0.004, 0, 0, 0, 0), seed=1))
    loops = GroundTruthOdometry(NoiseConfig(seed=2))
    vocab = run_slam(loop_seq, cons, loops, SlamParams(t_loop=20), PipelineConfig(reloc=RELOC, keyframe_stride=1),
                     show_progress=False).vocabulary
    params = SlamParams(t_loop=20)
    res = run_slam(loop_seq, cons, loops, params, PipelineConfig(reloc=RELOC, keyframe_stride=1), vocabulary=vocab, show_progress=False)
    assert "loop_search_thread_s" in res.timings and "loop_search_s" not in res.timings
    prep = prepare(loop_seq, cons, loops, PipelineConfig(reloc=RELOC, keyframe_stride=1), vocabulary=vocab, show_progress=False)
    assert prep._loops_by_t == {}  # no t_loop given: nothing searched yet
    opt, lazy = solve(prep, params, world_from_cam0=loop_seq.gt.world_from_cam[0])
    assert len(lazy) > 0
    np.testing.assert_array_equal(res.loops.pairs, lazy.pairs)
    np.testing.assert_array_equal(res.slam.world_from_cam, opt.world_from_cam)
