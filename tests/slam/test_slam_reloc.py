"""Relocalization: vocabulary, BoW database, ratio matching, geometric check, revisit retrieval."""
from __future__ import annotations

import numpy as np
import pytest

from deepslam.core.camera import PinholeCamera
from deepslam.core.errors import InputError
from deepslam.slam.reloc import (BowDatabase, FeatureExtractor, Features, LoopDetector, RelocConfig, Vocabulary,
                        accepted_pairs, kmeans, naive_scores, ratio_matches, train_vocabulary, verify)
from deepslam.slam.synthetic import random_texture, revisit_image, small_motion

W, H = 160, 120
CAM = PinholeCamera.from_fov_y(W, H, 60.0)
CFG = RelocConfig(image_scale=1.0, n_features=300, vocabulary_size=200, n_candidates=5)


@pytest.fixture(scope="module")
def views():
    """Two views (a, b) of each of 10 random textures, related by small camera motions."""
    ext = FeatureExtractor(CFG)
    a, b = [], []
    for p in range(10):
        tex = random_texture(np.random.default_rng([0, p]), H, W)
        a.append(ext(revisit_image(tex, CAM.k, small_motion(np.random.default_rng([1, p])))))
        b.append(ext(revisit_image(tex, CAM.k, small_motion(np.random.default_rng([2, p])))))
    return a, b


@pytest.fixture(scope="module")
def vocab(views):
    return train_vocabulary([f.descriptors for f in views[0]], 200, np.random.default_rng(0))


def test_features_in_full_resolution_pixels():
    tex = random_texture(np.random.default_rng(3), H, W)
    full = FeatureExtractor(RelocConfig(image_scale=1.0))(tex)
    half = FeatureExtractor(RelocConfig(image_scale=0.5))(tex)
    assert len(full) > 100 and len(half) > 20
    assert full.descriptors.dtype == np.uint8 and full.descriptors.shape[1] == 128
    # keypoints of the half-size image are reported in full-size pixels: same extent
    assert half.keypoints_px[:, 0].max() > 0.8 * W and half.keypoints_px[:, 1].max() > 0.8 * H
    # a flat image has no features
    assert len(FeatureExtractor(CFG)(np.full((H, W), 128, np.uint8))) == 0


def test_vocabulary_save_load_round_trip(tmp_path, vocab, views):
    path = tmp_path / "voc.npz"
    vocab.save(path, meta={"note": "test"})
    back = Vocabulary.load(path)
    np.testing.assert_array_equal(back.centers, vocab.centers)
    np.testing.assert_array_equal(back.idf, vocab.idf)
    assert back.n_train_images == vocab.n_train_images == 10
    for f in views[1][:3]:
        for x, y in zip(back.bow(f.descriptors), vocab.bow(f.descriptors)):
            np.testing.assert_array_equal(x, y)
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="bad.npz"):
        Vocabulary.load(tmp_path / "bad.npz")
    with pytest.raises(InputError, match="missing"):
        Vocabulary.load(tmp_path / "none.npz")


def test_bow_vectors_are_normalised_tfidf(vocab, views):
    ids, w = vocab.bow(views[0][0].descriptors)
    assert np.all(np.diff(ids) > 0) and np.all(w > 0)
    assert abs(float(np.sum(w.astype(np.float64) ** 2)) - 1.0) < 1e-5
    words = vocab.assign(views[0][0].descriptors)
    counts = np.bincount(words, minlength=vocab.n_words)
    expect = counts * vocab.idf
    expect = expect / np.linalg.norm(expect)
    np.testing.assert_allclose(w, expect[ids], rtol=1e-5)


def test_kmeans_finds_separated_clusters():
    rng = np.random.default_rng(1)
    centres = rng.uniform(0, 200, (5, 128))
    x = np.concatenate([c + rng.normal(0, 1.0, (50, 128)) for c in centres])
    got = kmeans(x, 5, np.random.default_rng(2), iterations=5)
    means = x.reshape(5, 50, 128).mean(axis=1)  # the converged centres are the clusters' means
    d = np.linalg.norm(got[:, None] - means[None], axis=2)
    assert len(set(d.argmin(axis=1))) == 5 and np.all(d.min(axis=1) < 1e-3)


def _random_bow_rows(seed: int, n: int, k: int, draws: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """n sparse BoW vectors over k words: ``draws`` word draws each (unique ids ascending), weights of L2 norm 1."""
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(n):
        ids = np.unique(rng.integers(0, k, draws)).astype(np.int32)
        w = rng.uniform(0.1, 1, len(ids)).astype(np.float32)
        rows.append((ids, w / np.linalg.norm(w)))
    return rows


def test_database_scores_equal_naive_and_respect_visibility():
    k = 300
    rows = _random_bow_rows(0, 1500, k, 40)
    db = BowDatabase(k)
    for i, r in enumerate(rows):
        db.add(*r)
        if i in (100, 700, 900):  # while growing: newest rows only, inverted index only, and both
            q = rows[i // 2]
            np.testing.assert_allclose(db.scores(*q), naive_scores(rows[: i + 1], *q), atol=1e-5)
            if i == 900:
                assert 0 < db._n_indexed < len(db)
    assert db.rebuilds >= 1
    q = rows[42]
    np.testing.assert_allclose(db.scores(*q), naive_scores(rows, *q), atol=1e-5)
    top, s = db.query(*q, k=5)
    assert top[0] == 42 and s[0] == pytest.approx(1.0, abs=1e-5)
    top, _ = db.query(*q, k=5, n_visible=40)
    assert top.max() < 40
    assert len(db.query(*q, k=5, n_visible=0)[0]) == 0


def test_ratio_matches_equal_opencv_bruteforce(views):
    import cv2

    a, b = views[0][0], views[1][0]
    ia, ib = ratio_matches(a, b, 0.7)
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(a.descriptors.astype(np.float32), b.descriptors.astype(np.float32), k=2)
    ref = {(m[0].queryIdx, m[0].trainIdx) for m in knn if m[0].distance < 0.7 * m[1].distance}
    assert len(ref) > 50
    got = set(zip(ia.tolist(), ib.tolist()))
    assert len(got ^ ref) <= 2  # float rounding may flip a borderline ratio


def test_geometric_check_accepts_revisits_and_rejects_others(views):
    a, b = views
    for p in range(5):
        v = verify(a[p], b[p], CAM.k, CFG)
        assert v.accepted, v
        assert v.n_inliers >= 0.8 * v.n_matches
        wrong = verify(a[p], b[p + 1], CAM.k, CFG)
        assert not wrong.accepted and wrong.reason == "few matches"
    # same descriptors, scrambled geometry: the ratio test passes, the essential matrix does not
    rng = np.random.default_rng(0)
    scrambled = Features(b[0].keypoints_px[rng.permutation(len(b[0]))], b[0].descriptors)
    v = verify(a[0], scrambled, CAM.k, CFG)
    assert v.n_matches >= CFG.min_matches and not v.accepted
    assert v.reason in ("few inliers", "low inlier ratio")
    # N_th: the EuRoC-like default asks for more matches than the KITTI-like one
    assert RelocConfig.for_kind("euroc").min_matches == 40 and RelocConfig.for_kind("kitti").min_matches == 30


def test_detector_finds_the_revisit_and_excludes_recent_frames(views, vocab):
    a, b = views
    det = LoopDetector(vocab, CAM.k, CFG)
    for p, f in enumerate(a):  # frames 0..9: first visits
        det.add(p, f)
    for p in range(3):  # frames 100+p revisit place p
        cands = det.query(100 + p, b[p], exclude_recent=5)
        assert cands[0].i == p and cands[0].verification.accepted
        assert [c.i for c in cands if c.verification.accepted] == [p]
        assert accepted_pairs(cands, 3) == [(p, 100 + p)]
    # a query that may only see frames older than itself - 5: place 8 is too recent for frame 12
    cands = det.query(12, b[8], exclude_recent=5)
    assert all(c.i <= 7 for c in cands)
    assert not any(c.verification.accepted for c in cands)


def test_real_kitti_frames_close_pairs_verify_and_far_pairs_do_not(shared_data):
    from deepslam.core.readers import open_sequence

    seq = open_sequence(shared_data / "kitti" / "sequences" / "06")
    cfg = RelocConfig.for_kind(seq.kind)
    ext = FeatureExtractor(cfg)
    feats = {i: ext(seq.image(i)) for i in (0, 2, 20, 50)}
    near = verify(feats[0], feats[2], seq.camera.k, cfg)  # ~1.5 m apart: the same place
    assert near.accepted and near.n_inliers >= 0.8 * near.n_matches
    for a, b in ((0, 50), (20, 50)):  # tens of metres apart along the road
        assert not verify(feats[a], feats[b], seq.camera.k, cfg).accepted
    vocab = train_vocabulary([f.descriptors for f in feats.values()], 200, np.random.default_rng(0))
    det = LoopDetector(vocab, seq.camera.k, cfg)
    for i in (0, 20, 50):
        det.add(i, feats[i])
    cands = det.query(2, feats[2], exclude_recent=-60)  # let it see every frame
    assert cands[0].i == 0 and cands[0].verification.accepted


@pytest.mark.parametrize("stop", [True, False])
def test_verification_stops_at_the_first_accepted_candidate(views, vocab, stop):
    import dataclasses

    a, b = views
    det = LoopDetector(vocab, CAM.k, dataclasses.replace(CFG, stop_when_found=stop))
    for p, f in enumerate(a):
        det.add(p, f)
    cands = det.query(100, b[0], exclude_recent=5)
    assert cands[0].i == 0 and cands[0].verification.accepted
    assert len(cands) == (1 if stop else CFG.n_candidates)
    assert det.timings["verifications"] == len(cands)
    assert accepted_pairs(cands, 1) == [(0, 100)]


def test_compiled_posting_scores_equal_scipys_bit_for_bit(monkeypatch):
    """Past COMPILED_MIN_ROWS a compiled loop over the posting lists scores the query: the same float32 scores as
    scipy's column slice and mat-vec, and as the naive loop, at every visibility (rows not yet indexed too)."""
    from deepslam.slam import reloc

    k = 200
    rows = _random_bow_rows(3, 1200, k, 30)
    db = BowDatabase(k)
    db.add_many(rows)
    queries = [rows[7], rows[1100], (np.array([0, 5, 199], np.int32), np.array([0.6, 0.0, 0.8], np.float32))]
    for n_visible in (None, 1200, 1001, 600, 1):
        monkeypatch.setattr(reloc, "COMPILED_MIN_ROWS", 10**9)
        slow = [db.scores(*q, n_visible=n_visible) for q in queries]
        monkeypatch.setattr(reloc, "COMPILED_MIN_ROWS", 1)
        fast = [db.scores(*q, n_visible=n_visible) for q in queries]
        for a, b, q in zip(fast, slow, queries):
            assert a.dtype == np.float32 and np.array_equal(a, b)
            np.testing.assert_allclose(a, naive_scores(rows[: len(a)], *q), atol=1e-5)
    assert db.query(*rows[7], k=3)[0][0] == 7
