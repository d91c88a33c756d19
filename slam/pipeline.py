"""The SLAM pipeline: flow -> odometry -> relocalization -> pose graph, on any core Sequence.

Stages (each causal in the frame order, run as batches):

1. Odometry of consecutive frames (NN_cons through the :class:`slam.odometry.Odometry` protocol; the
   odometry computes its own optical flow) -> ``cam_{t+1}_from_cam_t`` and its std; dead reckoning of
   those is the VO trajectory.
2. Relocalization on keyframes (every ``keyframe_stride``-th frame; run in a second thread while
   stage 1 runs, see :func:`prepare`): SIFT, a BoW vocabulary (given,
   or trained on the sequence's own keyframes when none is given), retrieval of the 20 most similar
   keyframes at least ``t_loop + 1`` frames older, ratio test, N_th and an essential-matrix check.
   The database holds every keyframe but a query only sees frames older than its exclusion window, so
   the result equals an online run where each frame is inserted after its own query.
3. Odometry of the accepted loop pairs (NN_loops) -> loop edges, only where the gap exceeds T_loop and,
   with ``loop_check``, where the loop pair's flow fits one rigid motion (the odometry tells:
   :class:`slam.odometry.VerifiedOdometry`).
4. Pose graph (gtsam, Levenberg-Marquardt) with the paper's covariances, robust kernel on loops.

The hyperparameters C_s, C_r and T_loop come from :class:`SlamParams` (a JSON file written by
``deepslam tune-slam``). :class:`Prepared` caches stages 1-3 so that the hyperparameter search only
reruns the cheap parts.
"""
from __future__ import annotations

import dataclasses
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.core.kinds import kind_for_sequence
from deepslam.core.progress import progress
from deepslam.core.textio import loads_json
from deepslam.core.trajectory import Trajectory
from deepslam.slam.odometry import Odometry, VerifiedOdometry, check_prediction
from deepslam.slam.posegraph import Edges, PoseGraphConfig, chain, optimize
from deepslam.slam.reloc import (FeatureExtractor, Features, LoopCandidate, LoopDetector, RelocConfig, Vocabulary,
                        accepted_pairs, train_vocabulary)

PARAMS_FORMAT = "deepslam-slam-params-v1"


@dataclasses.dataclass(frozen=True)
class SlamParams:
    """The paper's tuned hyperparameters (``deepslam tune-slam`` writes them as JSON)."""

    c_s: float = 1.0
    """C_s, scale of the consecutive (odometry) edges' covariance: the trust in the odometry relative to the loops."""
    c_r: float = 1.0
    """C_r, extra scale of the rotation variances."""
    t_loop: int = 50
    """T_loop: loop edges only between frames more than this many frames apart."""

    def to_dict(self) -> dict:
        return {"format": PARAMS_FORMAT, **dataclasses.asdict(self)}

    def save(self, path: str | Path, extra: dict | None = None) -> None:
        atomic.write_json(path, {**self.to_dict(), **(extra or {})})

    @staticmethod
    def load(path: str | Path) -> "SlamParams":
        """Read a params JSON; InputError names the file and the bad field."""
        path = Path(path)
        try:
            text = path.read_text()
        except FileNotFoundError:
            raise InputError(path, "parameter file is missing") from None
        except (OSError, UnicodeDecodeError) as e:
            raise InputError(path, f"cannot read parameter JSON ({e})") from None
        obj = loads_json(text, path, "parameter JSON")  # bounded: size and nesting (core.textio)
        if not isinstance(obj, dict) or obj.get("format") != PARAMS_FORMAT:
            raise InputError(path, f"not a SLAM parameter file (expected \"format\": \"{PARAMS_FORMAT}\")")
        try:
            p = SlamParams(c_s=float(obj["c_s"]), c_r=float(obj["c_r"]), t_loop=int(obj["t_loop"]))
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(path, f"bad or missing field ({type(e).__name__}: {e})") from None
        p.validate(path)
        return p

    def validate(self, path=None) -> None:
        if not (np.isfinite(self.c_s) and self.c_s > 0 and np.isfinite(self.c_r) and self.c_r > 0):
            raise InputError(path, f"C_s and C_r must be positive numbers, got {self.c_s}, {self.c_r}")
        if self.t_loop < 1:
            raise InputError(path, f"T_loop must be at least 1 frame, got {self.t_loop}")


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """Settings of the pipeline other than the tuned hyperparameters."""

    reloc: RelocConfig | None = None
    """Relocalization settings; None: :meth:`RelocConfig.for_kind` of the sequence (N_th 30 / 40)."""
    graph: PoseGraphConfig = PoseGraphConfig()
    """Pose-graph settings; its c_s / c_r are replaced by the :class:`SlamParams`."""
    keyframe_stride: int = 3
    """Every k-th frame is a relocalization keyframe. 3 by docs/experiments/2026-12-06_keyframe_stride.md: on loop
    routes and a room, strides 1, 2 and 3 found the same revisits (recall 0.95-1.00) and SLAM ATEs within 4 %, at a
    third of the features and loop search."""
    loops: bool = True
    """False: odometry only (the graph then equals dead reckoning)."""
    loop_check: bool = True
    """Leave out the loop pairs whose input the loop odometry finds fits no rigid motion (where it can tell,
    :class:`slam.odometry.VerifiedOdometry`: the network in the epipolar pose mode, where the essential-matrix fit
    of the loop pair's flow finds too few inliers). Between frames metres and many degrees apart DIS can lose the
    motion, and NN_loops, reading the same flow, is then 15-20 degrees or half the distance off
    (bench/criteria/2026-12-05_loop_edges.md)."""
    vocabulary_train_frames: int = 400
    """Without a given vocabulary, train one on at most this many evenly spaced keyframes."""
    seed: int = 0
    """Seed of the vocabulary training."""

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclasses.dataclass
class Prepared:
    """Stages 1-3 of one sequence, cached for repeated pose-graph solves (hyperparameter search).

    Attributes:
        seq: the sequence.
        n: frames.
        cons: consecutive edges (i, i+1) from NN_cons.
        detector: keyframe database with features and cached verifications (None without loops).
        keyframes: keyframe indices.
        odo_loops: the loop odometry.
        reloc: the relocalization settings used.
        timings: seconds per stage so far.
        loop_check: leave out loop pairs whose flow fits no rigid motion (:attr:`PipelineConfig.loop_check`).
    """

    seq: object
    n: int
    cons: Edges
    detector: LoopDetector | None
    keyframes: list[int]
    odo_loops: Odometry | None
    reloc: RelocConfig
    timings: dict
    loop_check: bool = True
    _loop_odo: dict = dataclasses.field(default_factory=dict)
    _loops_by_t: dict = dataclasses.field(default_factory=dict)

    def candidates(self, t_loop: int, show_progress: bool = False) -> list[LoopCandidate]:
        """Retrieval + verification of every keyframe against keyframes more than t_loop frames older."""
        if self.detector is None:
            return []
        if t_loop not in self._loops_by_t:
            t0 = time.perf_counter()
            self._loops_by_t[t_loop] = search_loops(self.detector, self.keyframes, t_loop, show_progress)
            self.timings["loop_search_s"] = self.timings.get("loop_search_s", 0.0) + time.perf_counter() - t0
        return self._loops_by_t[t_loop]

    def loop_pairs(self, t_loop: int, show_progress: bool = False) -> list[tuple[int, int]]:
        pairs = accepted_pairs(self.candidates(t_loop, show_progress), self.reloc.max_loops_per_query)
        return [(i, j) for i, j in pairs if j - i > t_loop]

    def loop_edges(self, t_loop: int, show_progress: bool = False) -> Edges:
        """Loop edges with gap > t_loop (without the pairs :meth:`unverified_pairs` names), their odometry
        predicted once per pair and cached."""
        pairs = self._predicted_loop_pairs(t_loop, show_progress)
        pairs = [p for p in pairs if self._loop_odo[p][2] or not self.loop_check]
        if not pairs:
            return Edges.empty()
        return Edges(np.array(pairs), np.array([self._loop_odo[p][0] for p in pairs]),
                     np.array([self._loop_odo[p][1] for p in pairs]))

    def unverified_pairs(self, t_loop: int) -> list[tuple[int, int]]:
        """Loop pairs with gap > t_loop left out because their flow fits no rigid motion (none without
        ``loop_check``)."""
        if not self.loop_check:
            return []
        return [p for p in self._predicted_loop_pairs(t_loop) if not self._loop_odo[p][2]]

    def _predicted_loop_pairs(self, t_loop: int, show_progress: bool = False) -> list[tuple[int, int]]:
        """:meth:`loop_pairs`, each with (mean6, std6, rigid) in the cache."""
        pairs = self.loop_pairs(t_loop, show_progress)
        missing = [p for p in pairs if p not in self._loop_odo]
        if missing and self.odo_loops is not None:
            t0 = time.perf_counter()
            if isinstance(self.odo_loops, VerifiedOdometry):
                mean6, std6, rigid = self.odo_loops.predict_verified(self.seq, missing)
                rigid = np.asarray(rigid, bool).reshape(-1)
                if rigid.shape != (len(missing),):
                    raise ValueError(f"odometry {self.odo_loops.name!r}: rigid has shape {rigid.shape}, "
                                     f"expected ({len(missing)},)")
            else:
                mean6, std6 = self.odo_loops.predict(self.seq, missing)
                rigid = np.ones(len(missing), bool)
            mean6, std6 = check_prediction(self.odo_loops.name, missing, mean6, std6)
            for p, m, s, r in zip(missing, mean6, std6, rigid):
                self._loop_odo[p] = (m, s, bool(r))
            self.timings["odometry_loops_s"] = self.timings.get("odometry_loops_s", 0.0) + time.perf_counter() - t0
        return pairs


@dataclasses.dataclass(frozen=True)
class SlamResult:
    """Output of :func:`run_slam`.

    Attributes:
        vo: dead reckoning of NN_cons (world_from_cam, OpenCV axes, timestamps of the sequence).
        slam: the optimised trajectory.
        cons: the consecutive edges.
        loops: the loop edges used in the graph.
        candidates: every retrieved candidate with its verification.
        params: the hyperparameters used.
        timings: seconds per stage and frames per second.
        graph_error: (initial, final) gtsam error.
        vocabulary: the BoW vocabulary used (None without loop closure).
        loop_inliers: (L,) bool, loop edges kept by the pose graph's pruning stage.
        reloc: the relocalization settings used (resolved for the sequence's kind).
        loops_not_rigid: (K, 2) int64 loop pairs left out because their flow fits no rigid motion
            (:attr:`PipelineConfig.loop_check`).
    """

    vo: Trajectory
    slam: Trajectory
    cons: Edges
    loops: Edges
    candidates: list
    params: SlamParams
    timings: dict
    graph_error: tuple[float, float]
    vocabulary: Vocabulary | None = None
    loop_inliers: np.ndarray | None = None
    reloc: RelocConfig | None = None
    loops_not_rigid: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2), np.int64))


def data_kind(seq) -> str:
    """The sequence's camera kind (:func:`core.kinds.kind_for_sequence`), which sets place recognition's
    defaults (:meth:`slam.reloc.RelocConfig.for_kind`)."""
    return kind_for_sequence(seq)


def search_loops(detector: LoopDetector, keyframes: list[int], t_loop: int, show_progress: bool = False) -> list[LoopCandidate]:
    """Query every keyframe against the keyframes more than ``t_loop`` frames older (retrieval + verification)."""
    out: list[LoopCandidate] = []
    it = progress(keyframes, desc="loop search", unit="frame", disable=None if show_progress else True)
    for row, j in enumerate(it):
        if j - t_loop - 1 >= 0:
            out.extend(detector.query(j, detector.features[row], exclude_recent=t_loop + 1, bow=detector.db.row(row)))
    return out


def consecutive_pairs(n: int) -> list[tuple[int, int]]:
    return [(i, i + 1) for i in range(n - 1)]


def prepare(seq, odo_cons: Odometry, odo_loops: Odometry | None, config: PipelineConfig = PipelineConfig(),
            vocabulary: Vocabulary | None = None, show_progress: bool = True, t_loop: int | None = None) -> Prepared:
    """Stages 1 and 2 (features, vocabulary, database); the loop search runs lazily per T_loop.

    Relocalization runs in a second thread while the odometry of stage 1 runs (OpenCV's SIFT, DIS and
    matching and torch all release the GIL): the keyframes' SIFT features and, when a vocabulary is
    given, the database and the loop search for ``t_loop`` too (without a vocabulary one is first
    trained on those features, after the odometry). The results are those of the sequential order.
    """
    n = len(seq)
    if n < 2:
        raise InputError(getattr(seq, "root", None), f"SLAM needs at least 2 frames, the sequence has {n}")
    if config.keyframe_stride < 1:
        raise InputError(None, f"keyframe stride must be >= 1, got {config.keyframe_stride}")
    timings: dict = {}
    reloc = config.reloc if config.reloc is not None else RelocConfig.for_kind(data_kind(seq))
    keyframes = list(range(0, n, config.keyframe_stride))
    with_loops = config.loops and odo_loops is not None
    pool = ThreadPoolExecutor(1) if with_loops else None
    background = None
    if pool is not None:
        extract = FeatureExtractor(reloc)

        def relocalization() -> dict:
            t = time.perf_counter()
            got: dict = {"feats": [extract(seq.image(i)) for i in
                                   progress(keyframes, desc="features", unit="frame", disable=None if show_progress else True)]}
            got["features_thread_s"] = time.perf_counter() - t
            if vocabulary is not None:
                got["detector"] = _database(vocabulary, seq.camera.k, reloc, keyframes, got["feats"])
                if t_loop is not None:
                    t = time.perf_counter()
                    got["loops"] = search_loops(got["detector"], keyframes, t_loop)
                    got["loop_search_thread_s"] = time.perf_counter() - t
            return got

        background = pool.submit(relocalization)
    t0 = time.perf_counter()
    try:
        pairs = consecutive_pairs(n)
        mean6, std6 = odo_cons.predict(seq, pairs)
        mean6, std6 = check_prediction(odo_cons.name, pairs, mean6, std6)
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
    cons = Edges(np.array(pairs), mean6, std6)
    timings["odometry_cons_s"] = time.perf_counter() - t0
    detector = None
    loops_by_t: dict = {}
    if with_loops:
        t1 = time.perf_counter()
        got = background.result()
        timings["features_s"] = time.perf_counter() - t1  # wall time spent waiting for them after the odometry
        timings.update({k: v for k, v in got.items() if k.endswith("_thread_s")})
        feats, detector = got["feats"], got.get("detector")
        if "loops" in got:
            loops_by_t[t_loop] = got["loops"]
        if vocabulary is None:
            t2 = time.perf_counter()
            step = max(1, int(np.ceil(len(feats) / config.vocabulary_train_frames)))
            if not any(len(f) for f in feats[::step]):
                raise InputError(getattr(seq, "root", None), "no SIFT keypoints in the keyframes: cannot build "
                                 "a BoW vocabulary (blank images?); pass one, or turn loop closure off")
            vocabulary = train_vocabulary([f.descriptors for f in feats[::step]], reloc.vocabulary_size,
                                          np.random.default_rng(config.seed))
            timings["vocabulary_s"] = time.perf_counter() - t2
        if detector is None:
            t3 = time.perf_counter()
            detector = _database(vocabulary, seq.camera.k, reloc, keyframes, feats)
            timings["database_s"] = time.perf_counter() - t3
    return Prepared(seq, n, cons, detector, keyframes, odo_loops, reloc, timings, config.loop_check,
                    _loops_by_t=loops_by_t)


def _database(vocabulary: Vocabulary, camera_k: np.ndarray, reloc: RelocConfig, keyframes: list[int],
              feats: list[Features]) -> LoopDetector:
    detector = LoopDetector(vocabulary, camera_k, reloc)
    for i, f in zip(keyframes, feats):
        detector.add(i, f)
    return detector


def solve(prep: Prepared, params: SlamParams, graph: PoseGraphConfig = PoseGraphConfig(),
          world_from_cam0: np.ndarray | None = None, show_progress: bool = False):
    """Stages 3-4 for one set of hyperparameters: (OptimizeResult, loop Edges)."""
    loops = prep.loop_edges(params.t_loop, show_progress) if prep.detector is not None else Edges.empty()
    cfg = dataclasses.replace(graph, c_s=params.c_s, c_r=params.c_r)
    res = optimize(prep.n, prep.cons, loops, cfg, world_from_cam0)
    return res, loops


def run_slam(seq, odo_cons: Odometry, odo_loops: Odometry | None = None, params: SlamParams = SlamParams(),
             config: PipelineConfig = PipelineConfig(), vocabulary: Vocabulary | None = None,
             show_progress: bool = True) -> SlamResult:
    """Run the whole pipeline on a sequence.

    Args:
        seq: a :class:`core.sequence.Sequence` (or anything with len(), .image(i), .camera, .timestamps_s,
            .kind, .gt that the odometry accepts).
        odo_cons: odometry for consecutive frames (NN_cons).
        odo_loops: odometry for loop pairs (NN_loops); None disables loop closure.
        params: C_s, C_r, T_loop.
        config: everything else.
        vocabulary: BoW vocabulary; None trains one on the sequence's keyframes.

    Returns:
        SlamResult; the first pose is frame 0's ground-truth pose when the sequence has one (a gauge
        choice only), else the identity.
    """
    params.validate()
    t_start = time.perf_counter()
    prep = prepare(seq, odo_cons, odo_loops, config, vocabulary, show_progress, t_loop=params.t_loop)
    gt_pose, gt = getattr(seq, "gt_pose", None), getattr(seq, "gt", None)
    if gt_pose is not None:
        first = gt_pose(0)  # None where the ground truth starts after frame 0 (TUM)
    else:
        first = gt.world_from_cam[0] if gt is not None else None
    res, loops = solve(prep, params, config.graph, first, show_progress)
    timings = dict(prep.timings)
    timings["optimize_s"] = res.time_s
    timings["graph_build_s"] = res.build_time_s
    timings["total_s"] = time.perf_counter() - t_start
    timings["fps"] = prep.n / timings["total_s"] if timings["total_s"] > 0 else float("nan")
    timings["optimizer_iterations"] = res.iterations
    if prep.detector is not None:
        timings.update({f"reloc_{k}": v for k, v in prep.detector.timings.items()})
    times = np.asarray(seq.timestamps_s, np.float64) if getattr(seq, "timestamps_s", None) is not None else None
    vo = Trajectory(chain(prep.n, prep.cons, first), times)
    cands = prep.candidates(params.t_loop) if prep.detector is not None else []
    return SlamResult(vo, Trajectory(res.world_from_cam, times), prep.cons, loops, cands, params, timings,
                      (res.initial_error, res.final_error),
                      prep.detector.vocabulary if prep.detector is not None else None, res.loop_inliers, prep.reloc,
                      np.array(prep.unverified_pairs(params.t_loop) if prep.detector is not None else [],
                               np.int64).reshape(-1, 2))


def pipeline_fps_frames(seq, odo_cons: Odometry, odo_loops: Odometry, params: SlamParams = SlamParams(),
                        config: PipelineConfig = PipelineConfig()) -> dict:
    """Frames per second of the whole pipeline on ``seq`` (used by bench_slam's pipeline-fps row)."""
    res = run_slam(seq, odo_cons, odo_loops, params, config, show_progress=False)
    return {"fps": res.timings["fps"], **res.timings}
