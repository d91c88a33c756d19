"""Network inputs for a list of frame pairs, computed ahead in a background thread.

The flow estimator (DIS: OpenCV, which releases the GIL) and the image reading run in threads of
their own (for DIS one a core, each on every W-th pair) while the caller runs the network on the
previous chunk, or loads torch and the model (``deepslam vo`` starts the flows before it imports
torch). The import holds the GIL for long
stretches, so the thread gets little done then (measured on KITTI 07: 14 of 159 pairs during torch's
1.6 s import; a spawned child process instead gained nothing, its own start-up and the data's
transfer cost as much). The flows come out in the order of the pairs and are bit-identical to
computing them in the caller's thread: each estimator object (the caller's, or a replica) is used by
one thread only.

This module does not import torch.
"""
from __future__ import annotations

import os
import queue
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from deepslam.core.errors import InputError
from deepslam.flow.estimators import to_network_input, unknown_flow
from deepslam.vo.modelfiles import modeltree


class _Failed:
    """What the worker puts in the queue when the estimator or a reader raised."""

    def __init__(self, error: BaseException):
        self.error = error


WORKERS_ENV = "DEEPSLAM_FLOW_WORKERS"
"""Environment variable that sets :func:`default_workers` (like ``OMP_NUM_THREADS`` for torch)."""


def default_workers() -> int:
    """Flow workers for :class:`PairInputs` when not given: ``$DEEPSLAM_FLOW_WORKERS`` where set (an integer
    >= 1), else the CPU cores this process may use, at most 8."""
    given = os.environ.get(WORKERS_ENV, "").strip()
    if given:
        try:
            n = int(given)
        except ValueError:
            n = 0
        if n < 1:
            raise InputError(None, f"{WORKERS_ENV} must be an integer >= 1, got {given!r}")
        return n
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(8, cores))


_OPENCV_LOCK = threading.Lock()
_OPENCV_HOLDERS = [0, None]  # [PairInputs with several workers alive, OpenCV's thread count before the first]


def _opencv_single_threaded(on: bool) -> None:
    """OpenCV single-threaded while at least one multi-worker :class:`PairInputs` is alive (a process-wide
    setting, counted: the last one to close gives OpenCV back the thread count it had before the first)."""
    with _OPENCV_LOCK:
        if on:
            if _OPENCV_HOLDERS[0] == 0:
                _OPENCV_HOLDERS[1] = cv2.getNumThreads()
                cv2.setNumThreads(1)
            _OPENCV_HOLDERS[0] += 1
        else:
            _OPENCV_HOLDERS[0] -= 1
            if _OPENCV_HOLDERS[0] == 0:
                cv2.setNumThreads(_OPENCV_HOLDERS[1])


class PairInputs:
    """Iterates ``(flow_chw, intrinsics)`` for each pair (i, j) of ``pairs``, in order: flow float32
    (2, height, width) px at network resolution and intrinsics float32 (4,) fx, fy, cx, cy at that
    resolution (:func:`flow.estimators.to_network_input` of ``estimator.pair_flow(seq, i, j)``).

    Args:
        seq: a :class:`core.sequence.Sequence`.
        pairs: (P, 2) int frame indices.
        estimator: a flow estimator (``pair_flow(seq, i, j)``); only the worker threads call it.
        width, height: the network's input size, pixels.
        unknown: how unknown flow is resized (:data:`flow.estimators.UNKNOWN_FLOW`; the network's
            :attr:`vo.net.NetConfig.unknown_flow`).
        ahead: how many pairs the workers may run ahead of the reader (bounds memory: 256 KB a pair at
            96 x 320).
        full_flow_fn: optional ``f(flow, camera) -> object`` applied to each pair's full-resolution flow
            (H, W, 2) px (the epipolar fit of :mod:`vo.geometry.epipolar`) in a thread of its own, beside the flow
            threads (OpenCV releases the GIL: on 2 cores the fit overlaps the next pair's DIS); its
            results, in the order of the pairs, are :attr:`side` once the iteration is done.
        workers: flow threads; None: :func:`default_workers` where the estimator offers ``replica()``
            (DIS), else 1. With W > 1, worker w computes pairs w, w + W, ... with its own replica, and
            OpenCV runs single-threaded while the workers run (given back by the last :meth:`close`): on 2
            cores two single-threaded DIS on two pairs do 1.33x the pairs a second of one DIS on two
            threads (KITTI 07, 1226x370, medium: 24.9 against 33.2 ms a pair). The flows are the same,
            bit for bit, whatever W.

    The workers start at construction. An exception raised in a worker (a missing image: InputError)
    is raised again by the iterator, in the caller's thread, at the pair where it happened. Iterate
    once; :meth:`close` (or leaving a ``with`` block) stops the workers early.
    """

    def __init__(self, seq, pairs, estimator, width: int, height: int, ahead: int = 512, unknown: str = "zero",
                 full_flow_fn=None, workers: int | None = None, centre: bool = False):
        self.seq, self.estimator = seq, estimator
        self.full_flow_fn = full_flow_fn
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        self.width, self.height = int(width), int(height)
        self.unknown = unknown
        self.centre = bool(centre)
        can_replicate = callable(getattr(estimator, "replica", None))
        if workers is None:
            workers = default_workers() if can_replicate else 1
        if int(workers) < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if int(workers) > 1 and not can_replicate:
            raise ValueError(f"the flow estimator {getattr(estimator, 'name', estimator)!r} has no replica() for "
                             "more than one worker")
        n_workers = max(1, min(int(workers), len(self.pairs)))
        self.workers = n_workers
        estimators = [estimator] + [estimator.replica() for _ in range(n_workers - 1)]
        self._side_futures: list = [None] * len(self.pairs)
        self._side_pool = None
        self._finished = False
        if full_flow_fn is not None:
            self._side_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="deepslam-flow-side")
            # full-resolution flows wait for their fit: at most ``ahead`` of them (3.6 MB each on KITTI)
            self._side_slots = threading.BoundedSemaphore(max(1, int(ahead)))
        per_queue = max(1, -(-int(ahead) // n_workers))
        self._queues = [queue.Queue(maxsize=per_queue) for _ in range(n_workers)]
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._work, args=(w, estimators[w]), daemon=True,
                                          name="deepslam-flow-prefetch" + (f"-{w}" if n_workers > 1 else ""))
                         for w in range(n_workers)]
        # held last, once nothing before can fail; released by close()
        self._single_threaded_opencv = n_workers > 1
        if self._single_threaded_opencv:
            _opencv_single_threaded(True)
        try:
            for t in self._threads:
                t.start()
        except BaseException:
            self.close()
            raise

    def _work(self, w: int, estimator) -> None:
        q = self._queues[w]
        try:
            for k in range(w, len(self.pairs), self.workers):
                if self._stop.is_set():
                    return
                i, j = self.pairs[k]
                flow = estimator.pair_flow(self.seq, int(i), int(j))
                if self._side_pool is not None:
                    while not self._side_slots.acquire(timeout=0.1):
                        if self._stop.is_set():
                            return
                    future = self._side_pool.submit(self.full_flow_fn, flow, self.seq.camera)
                    future.add_done_callback(lambda _: self._side_slots.release())
                    self._side_futures[k] = future
                if not self._put(q, to_network_input(flow, self.seq.camera, self.width, self.height, self.unknown,
                                                       self.centre)):
                    return
        except BaseException as e:  # noqa: BLE001 - handed to the reading thread, raised there
            self._put(q, _Failed(e))

    def _put(self, q: queue.Queue, item) -> bool:
        """Queue ``item`` unless the reader stops first (never blocks a :meth:`close`); False when stopped."""
        while not self._stop.is_set():
            try:
                q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def __len__(self) -> int:
        return len(self.pairs)

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        try:
            for k in range(len(self.pairs)):
                w = k % self.workers
                while True:
                    try:
                        item = self._queues[w].get(timeout=0.1)
                        break
                    except queue.Empty:
                        if not self._threads[w].is_alive() and self._queues[w].empty():
                            raise RuntimeError("the flow prefetch thread ended early (closed, or iterated twice)") from None
                if isinstance(item, _Failed):
                    raise item.error
                self._finished = k == len(self.pairs) - 1  # every pair handed out: their fits are wanted
                yield item
        finally:
            self.close()

    @property
    def side(self) -> list:
        """``full_flow_fn``'s results for every pair, in their order, once the iteration has gone through all
        of them (waits for the ones still running; raises what ``full_flow_fn`` raised)."""
        if not self._finished:
            raise RuntimeError("PairInputs.side is read after iterating over every pair")
        return [f.result() for f in self._side_futures]

    def close(self) -> None:
        """Stop the workers (each finishes the pair it is on), wait for them, and give OpenCV its threads back."""
        self._stop.set()
        for t in self._threads:
            if t.ident is not None:  # started
                t.join()
        if self._side_pool is not None:  # an early close drops the fits not started
            self._side_pool.shutdown(wait=True, cancel_futures=not self._finished)
        with _OPENCV_LOCK:  # two threads closing at once give the count back once
            release, self._single_threaded_opencv = self._single_threaded_opencv, False
        if release:
            _opencv_single_threaded(False)

    def __enter__(self) -> "PairInputs":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def model_input(path: str | Path) -> tuple[int, int, str] | None:
    """(height, width, unknown) of the input the VO model file at ``path`` reads: its size in pixels and
    how its unknown flow is resized (:attr:`vo.net.NetConfig.unknown_flow`), from the file's header
    alone (:mod:`vo.modelfiles.modeltree`: no torch, no tensors read); None when the file is missing or not a
    readable model file (the loader then says what is wrong)."""
    try:
        net = modeltree.net_config(modeltree.read_header_tree(path))
        return int(net["input_height"]), int(net["input_width"]), unknown_flow(bool(net.get("valid_channel")))
    except Exception:  # noqa: BLE001 - any unreadable file: no prefetch, the loader reports it
        return None
