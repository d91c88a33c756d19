"""Calibrating the predicted std (vo.calibration, ``deepslam calibrate``): the factor puts the asked share of a
sequence's errors within the scaled 1-sigma, is recorded in the model file and applied by every prediction."""
from __future__ import annotations

import json

import numpy as np
import pytest

from deepslam import cli
from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.vo import calibration
from deepslam.vo.modelfiles import models, modeltree
from deepslam.vo.pipeline import VOConfig, run_vo


def test_the_factor_puts_the_asked_share_within_the_scaled_sigma():
    rng = np.random.default_rng(0)
    std = np.full((2000, 6), 0.1)
    err = rng.normal(0.0, 1.0, (2000, 6)) * np.array([0.05, 0.1, 0.2, 0.4, 0.1, 0.1])  # std off by x0.5 .. x4
    scale = calibration.std_scale(err, std)
    assert scale == pytest.approx([0.5, 1.0, 2.0, 4.0, 1.0, 1.0], rel=0.08)
    assert calibration.within_one_sigma(err, std * scale) == pytest.approx(np.full(6, calibration.ONE_SIGMA), abs=0.01)
    with pytest.raises(ValueError, match="at least 10 pairs"):
        calibration.std_scale(err[:5], std[:5])
    with pytest.raises(ValueError, match="positive and finite"):
        calibration.std_scale(err, np.zeros_like(std))


def test_calibrate_records_the_factor_and_vo_predicts_the_scaled_std(plane_sequence, street_model, tmp_path):
    seq = open_sequence(plane_sequence)
    out = tmp_path / "calibrated.safetensors"
    assert cli.main(["calibrate", str(street_model), "--sequence", str(plane_sequence), "--out", str(out),
                     "--flow", "gt", "--json"]) == 0
    meta = modeltree.meta(modeltree.read_header_tree(out))
    scale = np.array(meta["std_scale"])
    assert scale.shape == (6,) and (scale > 0).all() and meta["std_calibrated_on"].endswith(plane_sequence.name)
    before = run_vo(seq, VOConfig(model=str(street_model), flow="gt", progress=False))
    after = run_vo(seq, VOConfig(model=str(out), flow="gt", progress=False))
    np.testing.assert_array_equal(before.mean6, after.mean6)                   # the motions are the model's own
    np.testing.assert_allclose(after.std6, before.std6 * scale, rtol=1e-12)   # every std scaled
    err = calibration.pair_errors(seq.gt.world_from_cam, after.pairs, after.mean6)
    share = calibration.within_one_sigma(err, after.std6)
    assert (share >= calibration.ONE_SIGMA).all()  # on the sequence it was fitted on (ties: all of them)


def test_a_malformed_factor_is_refused_naming_the_file(street_model, tmp_path):
    bad = tmp_path / "bad.safetensors"
    models.write_with_meta(street_model, bad, {"std_scale": [1.0, -2.0]})
    with pytest.raises(InputError, match="std_scale"):
        models.recorded_std_scale(modeltree.meta(modeltree.read_header_tree(bad)), bad)
    assert cli.main(["vo", "--sequence", str(tmp_path), "--model", str(bad), "--out", str(tmp_path / "x.txt")]) == 2
    assert json.loads(json.dumps(models.recorded_std_scale({}).tolist())) == [1.0] * 6


def test_widened_std_adds_the_disagreement_in_quadrature():
    std = np.full((3, 6), 0.3)
    d = np.zeros((3, 6))
    d[1, 2], d[2, 5] = 0.4, -0.4
    got = calibration.widened_std(std, d)
    np.testing.assert_array_equal(got[0], std[0])  # the readings agree: the network's std
    assert got[1, 2] == pytest.approx(0.5) and got[2, 5] == pytest.approx(0.5)
    with pytest.raises(ValueError, match="differ"):
        calibration.widened_std(std, d[:2])


def test_std_from_geometry_keeps_the_motions_and_widens_the_std_where_the_geometry_reads_otherwise(
        plane_sequence, street_model):
    seq = open_sequence(plane_sequence)
    plain = run_vo(seq, VOConfig(model=str(street_model), pose="net", progress=False))
    wide = run_vo(seq, VOConfig(model=str(street_model), pose="net", progress=False, std_from_geometry=True))
    fit = run_vo(seq, VOConfig(model=str(street_model), pose="epipolar", scale="road", progress=False))
    np.testing.assert_array_equal(wide.mean6, plain.mean6)  # the network's own motions
    np.testing.assert_allclose(wide.std6, calibration.widened_std(plain.std6, plain.mean6 - fit.mean6), rtol=1e-9)
    assert (wide.std6 >= plain.std6).all() and (wide.std6 > plain.std6 * 1.01).any()
    assert wide.record["std_from_geometry"] and not plain.record["std_from_geometry"]
    # with the epipolar pose: the fit's motions, the std widened by the same disagreement
    both = run_vo(seq, VOConfig(model=str(street_model), pose="epipolar", scale="road", progress=False,
                                std_from_geometry=True))
    np.testing.assert_array_equal(both.mean6, fit.mean6)
    np.testing.assert_allclose(both.std6, wide.std6, rtol=1e-9)
    with pytest.raises(InputError, match="--scale road"):
        run_vo(seq, VOConfig(model=str(street_model), pose="epipolar", scale="network", std_from_geometry=True,
                             progress=False))
