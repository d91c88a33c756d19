"""vo.data.prefetch: flows computed ahead in a thread are the serial flows, in order; failures reach the caller."""
from __future__ import annotations

import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from deepslam.core.errors import InputError
from deepslam.core.readers import open_sequence
from deepslam.flow import estimators as flow_estimators, images as flow_images, registry as flow_registry
from deepslam.flow.estimators import to_network_input
from deepslam.vo.data.prefetch import PairInputs, model_input

REPO = Path(__file__).resolve().parents[3]


class _Recording:
    """A DIS estimator that records the thread and order of its calls (its replicas record in the same list)."""

    def __init__(self, calls=None):
        self.inner = flow_registry.make("dis", preset="fast")
        self.calls: list[tuple[int, int, str]] = [] if calls is None else calls
        self.name = "recording"

    def pair_flow(self, seq, i, j):
        self.calls.append((i, j, threading.current_thread().name))
        return self.inner.pair_flow(seq, i, j)


class _Replicable(_Recording):
    def replica(self):
        return _Replicable(self.calls)


@pytest.mark.parametrize("ahead", [1, 3, 512])
def test_prefetched_inputs_equal_serial_ones_in_order(plane_sequence, ahead):
    seq = open_sequence(plane_sequence)
    pairs = [(0, 1), (4, 6), (1, 2), (10, 11), (2, 9)]
    rec = _Recording()
    got = list(PairInputs(seq, pairs, rec, 80, 24, ahead=ahead))
    serial = flow_registry.make("dis", preset="fast")
    assert len(got) == len(pairs)
    for (flow, intr), (i, j) in zip(got, pairs):
        want_flow, want_intr = to_network_input(serial.pair_flow(seq, i, j), seq.camera, 80, 24)
        np.testing.assert_array_equal(flow, want_flow)
        np.testing.assert_array_equal(intr, want_intr)
    assert [c[:2] for c in rec.calls] == pairs
    assert {c[2] for c in rec.calls} == {"deepslam-flow-prefetch"}


@pytest.mark.parametrize("workers", [2, 3, 8])
def test_several_workers_give_the_serial_inputs_in_order(plane_sequence, workers):
    """Worker w computes pairs w, w + W, ... with its own replica; the reader gets every pair in order, the
    same bytes as one thread; OpenCV's thread count is its own again after the close."""
    import cv2

    seq = open_sequence(plane_sequence)
    pairs = [(0, 1), (4, 6), (1, 2), (10, 11), (2, 9), (3, 4), (5, 6)]
    rec = _Replicable()
    before = cv2.getNumThreads()
    inputs = PairInputs(seq, pairs, rec, 80, 24, ahead=2, workers=workers)
    assert inputs.workers == min(workers, len(pairs))
    got = list(inputs)
    assert cv2.getNumThreads() == before
    serial = flow_registry.make("dis", preset="fast")
    for (flow, intr), (i, j) in zip(got, pairs, strict=True):
        want_flow, want_intr = to_network_input(serial.pair_flow(seq, i, j), seq.camera, 80, 24)
        np.testing.assert_array_equal(flow, want_flow)
        np.testing.assert_array_equal(intr, want_intr)
    by_thread: dict[str, list] = {}
    for i, j, name in rec.calls:
        by_thread.setdefault(name, []).append((i, j))
    w = inputs.workers
    assert by_thread == {f"deepslam-flow-prefetch-{k}": pairs[k::w] for k in range(w)}


def test_opencv_gets_its_threads_back_when_the_last_of_overlapping_inputs_closes(plane_sequence):
    import cv2

    seq = open_sequence(plane_sequence)
    pairs = [(k, k + 1) for k in range(4)]
    before = cv2.getNumThreads()
    a = PairInputs(seq, pairs, flow_registry.make("dis", preset="fast"), 80, 24, workers=2)
    b = PairInputs(seq, pairs, flow_registry.make("dis", preset="fast"), 80, 24, workers=2)
    assert cv2.getNumThreads() == 1
    a.close()
    assert cv2.getNumThreads() == 1  # b still runs
    list(b)
    assert cv2.getNumThreads() == before
    b.close()  # a second close changes nothing
    assert cv2.getNumThreads() == before


def test_a_constructor_that_fails_holds_nothing(plane_sequence):
    import cv2

    seq = open_sequence(plane_sequence)
    before = cv2.getNumThreads()
    with pytest.raises(TypeError):
        PairInputs(seq, [(0, 1), (1, 2)], flow_registry.make("dis", preset="fast"), 80, 24, ahead=None, workers=2)
    assert cv2.getNumThreads() == before


def test_a_replica_of_a_subclass_is_of_that_subclass(plane_sequence):
    """A plug-in that subclasses DISFlow and changes its flow keeps its change on every worker."""

    class Halved(flow_estimators.DISFlow):
        def estimate(self, img0, img1):
            return super().estimate(img0, img1) * np.float32(0.5)

    seq = open_sequence(plane_sequence)
    est = Halved("fast")
    assert type(est.replica()) is Halved
    pairs = [(k, k + 1) for k in range(4)]
    one = list(PairInputs(seq, pairs, Halved("fast"), 80, 24, workers=1))
    two = list(PairInputs(seq, pairs, Halved("fast"), 80, 24, workers=2))
    for (a, _), (b, _) in zip(one, two, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_failed_decode_is_not_cached(plane_sequence, tmp_path):
    import shutil

    root = tmp_path / "seq"
    shutil.copytree(plane_sequence, root)
    seq = open_sequence(root)
    saved = seq.image_paths[2].read_bytes()
    seq.image_paths[2].unlink()
    cache = flow_images.GreyCache()
    with pytest.raises(InputError):
        cache(seq, 2)
    seq.image_paths[2].write_bytes(saved)
    assert cache(seq, 2).shape == (seq.camera.height, seq.camera.width)


def test_dis_uses_one_worker_a_core_by_default_and_others_one(plane_sequence, monkeypatch):
    from deepslam.vo.data import prefetch

    seq = open_sequence(plane_sequence)
    pairs = [(k, k + 1) for k in range(6)]
    monkeypatch.setattr(prefetch, "default_workers", lambda: 2)
    assert PairInputs(seq, pairs, flow_registry.make("dis", preset="fast"), 80, 24).workers == 2
    assert PairInputs(seq, pairs, _Recording(), 80, 24).workers == 1  # no replica(): one thread
    with pytest.raises(ValueError, match="no replica"):
        PairInputs(seq, pairs, _Recording(), 80, 24, workers=2)
    with pytest.raises(ValueError, match="workers must be >= 1"):
        PairInputs(seq, pairs, flow_registry.make("dis", preset="fast"), 80, 24, workers=0)
    monkeypatch.undo()
    monkeypatch.delenv(prefetch.WORKERS_ENV, raising=False)
    assert 1 <= prefetch.default_workers() <= 8
    monkeypatch.setenv(prefetch.WORKERS_ENV, "3")
    assert prefetch.default_workers() == 3
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv(prefetch.WORKERS_ENV, bad)
        with pytest.raises(InputError, match=prefetch.WORKERS_ENV):
            prefetch.default_workers()


def test_a_dis_replica_gives_the_same_flows_and_shares_the_decoded_images(plane_sequence):
    seq = open_sequence(plane_sequence)
    dis = flow_registry.make("dis", preset="medium", min_texture=0.5)
    twin = dis.replica()
    assert twin is not dis and twin.name == dis.name and twin._grey is dis._grey
    np.testing.assert_array_equal(twin.pair_flow(seq, 2, 3), flow_registry.make("dis", preset="medium",
                                                                                  min_texture=0.5).pair_flow(seq, 2, 3))
    assert dis._grey(seq, 3) is twin._grey(seq, 3)  # decoded once


def test_the_grey_cache_decodes_each_frame_once_across_threads(plane_sequence, monkeypatch):
    seq = open_sequence(plane_sequence)
    decoded = []
    real = seq.image
    monkeypatch.setattr(seq, "image", lambda i: decoded.append(i) or real(i))
    cache = flow_images.GreyCache()
    barrier = threading.Barrier(2)

    def run(frames):
        barrier.wait()
        for i in frames:
            cache(seq, i)

    # four frames in all: the cache keeps four, so a second decode could only come from a race
    threads = [threading.Thread(target=run, args=([0, 1, 2],)), threading.Thread(target=run, args=([1, 2, 3],))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(decoded) == [0, 1, 2, 3]


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failure_in_the_worker_is_raised_to_the_reader(plane_sequence, tmp_path, workers):
    root = tmp_path / "seq"
    shutil.copytree(plane_sequence, root)
    seq = open_sequence(root)
    seq.image_paths[3].unlink()  # the fourth frame's image goes missing after the sequence was opened
    it = iter(PairInputs(seq, [(0, 1), (1, 2), (2, 3), (3, 4)], flow_registry.make("dis", preset="fast"), 80, 24,
                         workers=workers))
    next(it), next(it)  # the pairs before the missing frame come through
    with pytest.raises(InputError, match="000003"):
        next(it)


def test_closing_early_stops_the_worker(plane_sequence):
    seq = open_sequence(plane_sequence)
    rec = _Recording()
    inputs = PairInputs(seq, [(k, k + 1) for k in range(11)] * 20, rec, 80, 24, ahead=2)
    with inputs:
        next(iter(inputs))
    assert not any(t.is_alive() for t in inputs._threads)
    assert len(rec.calls) <= 5  # the one read, two queued, and at most the pair in hand


def test_model_input_reads_only_the_header(tmp_path):
    assert model_input(REPO / "models" / "kitti_cons_dis.safetensors") == (48, 160, "zero")
    assert model_input(REPO / "models" / "tum_cons.safetensors") == (96, 128, "nan")
    assert model_input(tmp_path / "missing.safetensors") is None
    (tmp_path / "junk.safetensors").write_bytes(b"\x00" * 64)
    assert model_input(tmp_path / "junk.safetensors") is None
    code = ("import sys; from deepslam.vo.data.prefetch import model_input; "
            f"print(model_input({str(REPO / 'models' / 'euroc_cons.safetensors')!r}), 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "(96, 160, 'zero') False"


class _Failing:
    """Raises on its third pair."""

    name = "failing"

    def __init__(self):
        self.calls = 0

    def pair_flow(self, seq, i, j):
        self.calls += 1
        if self.calls == 3:
            raise InputError("frame-3.png", "cannot be read")
        return np.zeros((seq.camera.height, seq.camera.width, 2), np.float32)


@pytest.mark.parametrize("read", [0, 1])
def test_a_worker_failing_on_a_full_queue_never_blocks_close(plane_sequence, read):
    """The worker fails while its queue is full and nobody reads (the model failed to load, Ctrl-C):
    close() returns at once; a second iteration says so instead of waiting forever."""
    import time

    seq = open_sequence(plane_sequence)
    inputs = PairInputs(seq, [(k, k + 1) for k in range(6)], _Failing(), 80, 24, ahead=1)
    it = iter(inputs)
    for _ in range(read):
        next(it)
    time.sleep(0.3)  # the worker fills the queue and then fails
    t0 = time.perf_counter()
    inputs.close()
    assert time.perf_counter() - t0 < 2.0 and not any(t.is_alive() for t in inputs._threads)
    with pytest.raises(RuntimeError, match="ended early"):
        list(PairInputs.__iter__(inputs))


def test_vo_reports_an_image_missing_mid_sequence_as_one_line(plane_sequence, tmp_path, capsys):
    """The worker's InputError reaches the command line: one line naming the file, exit 2, no traceback,
    no trajectory written."""
    from deepslam.cli import main

    root = tmp_path / "seq"
    shutil.copytree(plane_sequence, root)
    missing = open_sequence(root).image_paths[7]
    missing.unlink()
    out = tmp_path / "vo" / "t.txt"
    rc = main(["vo", "--sequence", str(root), "--model", "kitti", "--flow", "dis", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and missing.name in err and "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("ahead", [1, 2, 512])
def test_full_flow_results_come_in_pair_order_from_their_own_thread(plane_sequence, ahead):
    """``full_flow_fn`` (the epipolar fit) sees each pair's full-resolution flow, in a thread of its own; its
    results are in the order of the pairs, whatever the backlog bound."""
    import time

    seq = open_sequence(plane_sequence)
    pairs = [(0, 1), (4, 6), (1, 2), (10, 11), (2, 9)]
    serial = flow_registry.make("dis", preset="fast")
    threads = []

    def fn(flow, camera):
        threads.append(threading.current_thread().name)
        time.sleep(0.02)  # slower than the flow: the backlog bound is exercised
        return float(np.nansum(flow)), camera.width

    inputs = PairInputs(seq, pairs, flow_registry.make("dis", preset="fast"), 80, 24, ahead=ahead, full_flow_fn=fn)
    with pytest.raises(RuntimeError, match="after iterating"):
        inputs.side  # noqa: B018 - not before every pair was handed out
    assert len(list(inputs)) == len(pairs)
    assert inputs.side == [(float(np.nansum(serial.pair_flow(seq, i, j))), seq.camera.width) for i, j in pairs]
    assert set(threads) == {t for t in threads if t.startswith("deepslam-flow-side")} and threads


def test_a_failing_full_flow_fn_reaches_the_caller_and_an_early_close_drops_the_rest(plane_sequence):
    seq = open_sequence(plane_sequence)
    pairs = [(i, i + 1) for i in range(10)]

    def boom(flow, camera):
        raise ValueError("fit failed")

    inputs = PairInputs(seq, pairs, flow_registry.make("dis", preset="fast"), 80, 24, full_flow_fn=boom)
    list(inputs)
    with pytest.raises(ValueError, match="fit failed"):
        inputs.side  # noqa: B018
    calls = []
    inputs = PairInputs(seq, pairs, flow_registry.make("dis", preset="fast"), 80, 24, ahead=1,
                        full_flow_fn=lambda f, c: calls.append(1) or __import__("time").sleep(0.05))
    next(iter(inputs))
    inputs.close()  # returns without running the whole backlog: at most the running fit and the bounded ones
    assert len(calls) < len(pairs)


class _OffCentre:
    """``seq`` with its principal point 1.3 px left of where it is (the frames and flows its own)."""

    def __init__(self, seq):
        import dataclasses

        self._seq = seq
        self.camera = dataclasses.replace(seq.camera, cx=seq.camera.cx - 1.3)

    def __getattr__(self, name):
        return getattr(self._seq, name)


def test_prefetched_inputs_centre_the_principal_point_when_asked(plane_sequence):
    seq = _OffCentre(open_sequence(plane_sequence))
    pairs = [(0, 1), (3, 5)]
    got = list(PairInputs(seq, pairs, flow_registry.make("dis", preset="fast"), 80, 24, centre=True))
    serial = flow_registry.make("dis", preset="fast")
    for (flow, intr), (i, j) in zip(got, pairs, strict=True):
        full = serial.pair_flow(seq, i, j)
        want_flow, want_intr = to_network_input(full, seq.camera, 80, 24, centre=True)
        np.testing.assert_array_equal(flow, want_flow)
        np.testing.assert_array_equal(intr, want_intr)
        assert not np.array_equal(flow, to_network_input(full, seq.camera, 80, 24)[0])
        assert intr[2] == pytest.approx((80 - 1) / 2)
