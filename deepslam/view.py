"""The 3-D viewer behind ``deepslam view``: a sequence, or a ``vo`` / ``slam`` run, as a rerun recording.

A **sequence** (any folder :func:`deepslam.core.readers.open_sequence` opens) is logged frame by frame on two
timelines, ``frame`` (the index) and ``time`` (the frame time, seconds):

==================================  =====================================================================
entity                              what
==================================  =====================================================================
``world``                           view coordinates (static): z up, or KITTI's camera axes (RDF) for real
                                    KITTI, whose world is its first camera
``world/camera``                    Transform3D world_from_cam (ground truth, OpenCV axes)
``world/camera/image``              Pinhole of the sequence's intrinsics (static), camera axes RDF
``world/camera/image/rgb``          the (left) image
``world/camera/image/depth``        DepthImage, depth_z in metres (``meter=1``), 0 = none
``world/camera/image/flow``         forward flow coloured (:func:`deepslam.core.colorize.flow_to_rgb`,
                                    each frame saturated at its own 90th-percentile length, at least 1 px)
``world/camera/image/mask``         SegmentationImage of the instance ids (0 = static scene)
``world/camera/image/occlusion``    SegmentationImage, 1 = not visible in the next frame
``world/path``                      LineStrips3D of the ground-truth camera positions so far
==================================  =====================================================================

Only what the sequence has is logged (real KITTI: images and poses).

A **run** is a trajectory that ``deepslam vo`` or ``deepslam slam`` wrote, found through its record
(``<stem>.config.json`` of vo, ``<stem>.json`` of slam, both with ``written_by``): the trajectory file, the
record, or a folder holding exactly one such record. Logged (static): ``world/ground_truth`` (the
sequence's path), ``world/estimate`` (the trajectory aligned onto the ground truth as ``deepslam eval
--align`` does, after anchoring its first pose on the ground truth's, as ``vo`` scores it),
``world/odometry`` (slam only: its odometry-only trajectory, aligned the same way), ``world/loops/kept`` and
``world/loops/rejected`` (slam only: the loop edges of the pose graph between the estimated positions,
split by whether the graph's pruning kept them), ``world/loops/not_rigid`` (slam only: the loop pairs left
out because their flow fits no rigid motion) and ``metrics`` (a text panel: ATE, RPE); per frame,
``world/camera`` at the aligned estimate with the image at ``world/camera/image/rgb``.
"""
from __future__ import annotations

import dataclasses
import errno
import os
import sys
from pathlib import Path

import numpy as np

from deepslam.core import atomic, se3
from deepslam.core.colorize import flow_to_rgb
from deepslam.core.errors import InputError
from deepslam.core.metrics import ALIGN_MODES, Alignment, evaluate
from deepslam.core.outputs import check_output_not_input
from deepslam.core.progress import progress
from deepslam.core.readers import open_sequence
from deepslam.core.sequence import Sequence
from deepslam.core.textio import read_json_object
from deepslam.core.trajectory import Trajectory
from deepslam.core.trajio import read_trajectory

VO_COMMAND = "deepslam vo"
"""``written_by`` of a vo run's record, ``<stem>.config.json``."""
SLAM_COMMAND = "deepslam slam"
"""``written_by`` of a slam run's record, ``<stem>.json``."""
APPLICATION_ID = "deepslam"
"""rerun's application id of every recording."""

_COLOURS = {"ground_truth": (200, 200, 200), "estimate": (255, 140, 0), "odometry": (80, 160, 255),
            "kept": (60, 220, 60), "rejected": (230, 50, 50), "not_rigid": (160, 90, 230)}
"""RGB of the static paths and loop edges of a run."""


@dataclasses.dataclass(frozen=True)
class ViewConfig:
    """Which frames ``deepslam view`` logs and how a run's estimate is placed."""

    start: int = 0
    """First frame logged (as ``deepslam vo --start``)."""
    end: int | None = None
    """One past the last frame logged (as ``deepslam vo --end``); None: to the last frame."""
    every: int = 1
    """Log every K-th frame from ``start`` (a run's paths and loop edges are always whole)."""
    align: str = "se3"
    """Alignment of a run's estimate onto the ground truth: none, se3 or sim3 (as ``deepslam eval --align``)."""

    def validate(self) -> "ViewConfig":
        if self.start < 0:
            raise InputError(None, f"--start must be >= 0, got {self.start}")
        if self.end is not None and self.end <= self.start:
            raise InputError(None, f"--end must be greater than --start ({self.start}), got {self.end}")
        if self.every < 1:
            raise InputError(None, f"--every must be >= 1, got {self.every}")
        if self.align not in ALIGN_MODES:
            raise InputError(None, f"--align must be one of {', '.join(ALIGN_MODES)}, got {self.align!r}")
        return self

    def frames(self, n: int) -> np.ndarray:
        """(K,) int64 indices of the frames to log out of ``n``."""
        end = n if self.end is None else min(self.end, n)
        return np.arange(min(self.start, n), end, self.every, dtype=np.int64)


@dataclasses.dataclass(frozen=True)
class Run:
    """A ``vo`` or ``slam`` run found on disk (paths resolved; the sequence None where it is not found)."""

    command: str
    """``vo`` or ``slam``."""
    record_path: Path
    """The run's record (``<stem>.config.json`` / ``<stem>.json``)."""
    record: dict
    """Its content."""
    trajectory: Path
    """The estimated trajectory (slam: the pose graph's)."""
    odometry: Path | None
    """slam's odometry-only trajectory (``<stem>_vo<suffix>``) where it exists; None for vo."""
    sequence: Path | None
    """The sequence folder the run read, where it still exists."""


@dataclasses.dataclass
class ViewResult:
    """What :func:`view` logged."""

    kind: str
    """``sequence``, ``vo`` or ``slam``."""
    name: str
    """The sequence's name, or the run's trajectory file."""
    frames_logged: int
    """Frames logged on the timelines."""
    notes: list[str] = dataclasses.field(default_factory=list)
    """What could not be shown and why (a run's sequence is gone, no ground truth, ...), one line each."""
    saved: Path | None = None
    """The .rrd written (``save``), or None (the viewer was spawned)."""


def _rerun():
    """The rerun module; InputError naming the extra to install where it is missing."""
    # rerun-sdk is an optional dependency (the `viz` extra), imported only when a recording is made; its own
    # log lines (a failed file write is also an exception here, reported in one line) are off unless asked for
    os.environ.setdefault("RUST_LOG", "off")
    try:
        import rerun
    except ImportError:
        raise InputError(None, "the viewer needs rerun-sdk: pip install 'deepslam[viz]' (or pip install rerun-sdk)") \
            from None
    return rerun


def has_display() -> bool:
    """Whether a native window can open: on Linux and the BSDs an X11 or Wayland display must be set."""
    if sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


# ---------------------------------------------------------------------------------------------- finding a run


def _written_by(path: Path) -> str | None:
    """The ``written_by`` of the JSON object in ``path``, or None when it is no readable JSON object."""
    try:
        doc = read_json_object(path, "record")
    except InputError:
        return None
    value = doc.get("written_by")
    return value if isinstance(value, str) else None


def _existing(recorded, record_path: Path, beside: bool) -> Path | None:
    """A path a record names, where it exists. ``beside`` (a file the run wrote next to its record): by its name
    in the record's folder, else as written. Otherwise (the sequence): as written (relative to the working
    folder), else relative to the record's folder."""
    if not isinstance(recorded, str) or not recorded:
        return None
    p = Path(recorded).expanduser()
    tries = [p] if p.is_absolute() else [p, record_path.parent / p]
    if beside:
        tries.insert(0, record_path.parent / p.name)
    return next((t for t in tries if t.exists()), None)


def _run_from_record(record_path: Path) -> Run:
    record = read_json_object(record_path, "run record")
    command = {VO_COMMAND: "vo", SLAM_COMMAND: "slam"}.get(record.get("written_by"))
    if command is None:
        raise InputError(record_path, "is not the record of a `deepslam vo` or `deepslam slam` run (its written_by "
                                      f"is {record.get('written_by')!r})")
    key = "out" if command == "vo" else "trajectory"
    trajectory = _existing(record.get(key), record_path, beside=True)
    if trajectory is None or not trajectory.is_file():
        raise InputError(record_path, f"the trajectory this record names ({record.get(key)!r}) is missing")
    odometry = _existing(record.get("trajectory_vo"), record_path, beside=True) if command == "slam" else None
    sequence = _existing(record.get("sequence"), record_path, beside=False)
    return Run(command, record_path, record, trajectory, odometry, sequence)


def find_run(path: str | Path) -> Run | None:
    """The run ``path`` names (a trajectory with its record beside it, a record, or a folder holding exactly one
    record); None for a folder holding no record (it may be a sequence).

    Raises:
        InputError: a file that is neither a record nor a trajectory with one; a folder with several records.
    """
    path = Path(path)
    if path.is_dir():
        records = [p for p in sorted(path.glob("*.json")) if _written_by(p) in (VO_COMMAND, SLAM_COMMAND)]
        if len(records) > 1:
            names = ", ".join(p.name for p in records[:4]) + (", ..." if len(records) > 4 else "")
            raise InputError(path, f"holds {len(records)} vo/slam runs ({names}); name one of their trajectories")
        return _run_from_record(records[0]) if records else None
    if path.suffix.lower() == ".json":
        return _run_from_record(path)
    stem = path.with_suffix("")
    candidates = [(stem.with_name(f"{stem.name}.json"), SLAM_COMMAND),
                  (stem.with_name(f"{stem.name}.config.json"), VO_COMMAND)]
    if stem.name.endswith("_vo"):  # slam's odometry-only trajectory: its record is the slam run's
        candidates.append((stem.with_name(f"{stem.name[:-3]}.json"), SLAM_COMMAND))
    for record, command in candidates:
        if record.is_file() and _written_by(record) == command:
            return _run_from_record(record)
    raise InputError(path, "is neither a sequence folder nor a vo/slam run: a trajectory needs the record its run "
                           f"wrote beside it ({stem.name}.config.json of vo, {stem.name}.json of slam); to compare a "
                           "bare trajectory with ground truth use `deepslam eval --gt GT --est EST --plot PNG`")


def open_source(path: str | Path) -> Sequence | Run:
    """What ``deepslam view PATH`` shows: a :class:`Run` where ``path`` names one, else the sequence
    :func:`open_sequence` opens (its errors, for a folder that is neither, name the layouts it knows)."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "does not exist (expected a sequence folder or a vo/slam trajectory)")
    run = find_run(path)
    if run is not None:
        return run
    try:
        return open_sequence(path)
    except InputError as e:
        if e.path == str(path) and e.what.startswith("not a KITTI sequence"):
            raise InputError(path, "is neither a sequence folder (KITTI sequences/NN, EuRoC, TUM RGB-D, deepslam) "
                                   "nor a vo/slam run (a trajectory with its record)") from None
        raise


# ------------------------------------------------------------------------------------------------ logging


def _world_axes(rr, seq: Sequence):
    """Real KITTI's world is its first camera (x right, y down, z forward); every other world here is z up."""
    real_kitti = seq.kind == "kitti" and not (Path(seq.root) / "deepslam.json").exists()
    return rr.ViewCoordinates.RDF if real_kitti else rr.ViewCoordinates.RIGHT_HAND_Z_UP


def _set_time(rec, seq: Sequence, i: int) -> None:
    """The timelines of frame ``i``: ``frame`` (its index) and ``time`` (its time, seconds)."""
    rec.set_time("frame", sequence=int(i))
    rec.set_time("time", duration=float(seq.timestamps_s[i]))


def _log_pose(rr, rec, entity: str, world_from_cam: np.ndarray) -> None:
    """``world_from_cam`` (4, 4) float64, OpenCV axes, as the Transform3D of ``entity``."""
    rec.log(entity, rr.Transform3D(translation=world_from_cam[:3, 3], mat3x3=world_from_cam[:3, :3]))


def _log_pinhole(rr, rec, seq: Sequence) -> None:
    cam = seq.camera
    rec.log("world/camera/image", rr.Pinhole(image_from_camera=cam.k, resolution=[cam.width, cam.height],
                                             camera_xyz=rr.ViewCoordinates.RDF), static=True)


def log_sequence(rec, seq: Sequence, config: ViewConfig = ViewConfig(), show_progress: bool = False) -> int:
    """Log ``seq`` frame by frame into the rerun recording ``rec`` (module docstring); returns the frames logged.
    ``show_progress``: a progress bar on stderr (where the project's policy shows one)."""
    rr = _rerun()
    rec.log("world", _world_axes(rr, seq), static=True)
    _log_pinhole(rr, rec, seq)
    if seq.occlusion_paths is not None:
        rec.log("world/camera/image/occlusion", rr.AnnotationContext(
            [(0, "visible", (0, 0, 0, 0)), (1, "occluded", (255, 0, 255, 160))]), static=True)
    frames = config.frames(len(seq))
    path_so_far: list[np.ndarray] = []
    covered = [i for i in range(len(seq)) if seq.gt_pose(i) is not None] if seq.gt is not None else []
    k = 0
    for i in progress(frames, desc="logging", unit="frame", disable=None if show_progress else True):
        i = int(i)
        _set_time(rec, seq, i)
        pose = seq.gt_pose(i)
        if pose is not None:
            _log_pose(rr, rec, "world/camera", pose)
        while k < len(covered) and covered[k] <= i:
            path_so_far.append(seq.gt_pose(covered[k])[:3, 3])
            k += 1
        if len(path_so_far) >= 2:
            rec.log("world/path", rr.LineStrips3D([np.asarray(path_so_far)], colors=[_COLOURS["ground_truth"]]))
        rec.log("world/camera/image/rgb", rr.Image(seq.image(i)))
        if seq.depth_paths is not None:
            rec.log("world/camera/image/depth", rr.DepthImage(seq.depth(i), meter=1.0))
        if seq.flow_paths is not None:
            flow = seq.flow(i)
            rec.log("world/camera/image/flow",
                    rr.Clear(recursive=False) if flow is None else rr.Image(flow_to_rgb(flow)))
        if seq.mask_paths is not None:
            rec.log("world/camera/image/mask", rr.SegmentationImage(seq.mask(i)))
        if seq.occlusion_paths is not None:
            occ = seq.occlusion(i)
            rec.log("world/camera/image/occlusion",
                    rr.Clear(recursive=False) if occ is None else rr.SegmentationImage(occ.astype(np.uint8)))
    return len(frames)


def _estimate_frames(run: Run, n_poses: int) -> np.ndarray | None:
    """(n_poses,) frame index of each pose of the run's trajectory, from its record; None where the record's
    frames do not account for them."""
    rec = run.record
    try:
        if run.command == "vo":
            first, last = (int(x) for x in rec["frames"])
            frames = np.arange(first, last + 1, int(rec.get("stride", 1)), dtype=np.int64)
        else:
            frames = np.arange(int(rec["frames"]), dtype=np.int64)
    except (KeyError, TypeError, ValueError):
        return None
    return frames if len(frames) == n_poses else None


def place_estimate(seq: Sequence, est: Trajectory, frames: np.ndarray | None, align: str) -> tuple[np.ndarray, dict]:
    """The estimate moved into the ground truth's world, and its scores.

    With ``frames`` (the frame index of each pose): the first pose the ground truth covers is anchored on the
    ground truth's (as ``deepslam vo`` scores), then the estimate is aligned (``align``) on the covered frames
    as ``deepslam eval --align`` does. Without: matched as ``deepslam eval`` matches (timestamps, else index).

    Returns:
        (N, 4, 4) float64 world_from_cam of every pose of ``est`` in the ground truth's world, and the dict of
        :func:`deepslam.core.metrics.evaluate` (keys starting with ``_`` dropped).
    """
    poses = est.world_from_cam
    if frames is None:
        ev = evaluate(seq.gt, est, align=align)
    else:
        covered = [k for k, f in enumerate(frames) if seq.gt_pose(int(f)) is not None]
        if len(covered) < 2:
            raise InputError(seq.root, "the ground truth covers fewer than two of the run's frames")
        gt = np.stack([seq.gt_pose(int(frames[k])) for k in covered])
        times = np.asarray(seq.timestamps_s)[frames[covered]]
        poses = gt[0] @ se3.inverse(poses[covered[0]]) @ poses
        ev = evaluate(Trajectory(gt, times), Trajectory(poses[covered], times), align=align)
    alignment = Alignment(np.asarray(ev["rotation"], float), np.asarray(ev["translation"], float), float(ev["scale"]))
    return alignment.apply_to_poses(poses), {k: v for k, v in ev.items() if not k.startswith("_")}


def _metrics_text(run: Run, scores: dict, odometry_scores: dict | None) -> str:
    def line(name, s):
        return (f"| {name} | {s['ate_m']:.3f} m | {s['rpe_t_m']:.3f} m | {s['rpe_r_deg']:.3f} deg | "
                f"{s['n_matched']} |")
    rows = ["| trajectory | ATE rmse | RPE trans (d=1) | RPE rot (d=1) | poses |", "|---|---|---|---|---|",
            line(run.trajectory.name, scores)]
    if odometry_scores is not None:
        rows.append(line(f"{run.odometry.name} (odometry only)", odometry_scores))
    head = f"**{run.command}** run `{run.trajectory}` on `{run.sequence}`, aligned {scores['align']}"
    if run.command == "slam":
        head += f"; {run.record.get('n_loops', 0)} loop edges"
    return head + "\n\n" + "\n".join(rows) + "\n"


def log_run(rec, run: Run, config: ViewConfig = ViewConfig(), show_progress: bool = False) -> tuple[int, list[str]]:
    """Log a vo/slam run into the rerun recording ``rec`` (module docstring); ``show_progress`` as
    :func:`log_sequence`.

    Returns:
        (frames logged, notes): the notes say what could not be shown (no sequence, no ground truth).
    """
    rr = _rerun()
    notes: list[str] = []
    est = read_trajectory(run.trajectory, run.record.get("format"))
    odo = read_trajectory(run.odometry, run.record.get("format")) if run.odometry is not None else None
    frames = _estimate_frames(run, len(est))
    seq = open_sequence(run.sequence) if run.sequence is not None else None
    if seq is not None and frames is not None and len(frames) and frames[-1] >= len(seq):
        notes.append(f"the record's frames reach past the {len(seq)} frames of {seq.root}: matched by time instead")
        frames = None
    if seq is None:
        notes.append(f"the run's sequence {run.record.get('sequence')!r} is not found: the estimate is shown as "
                     "written, without ground truth or images")
    elif seq.gt is None:
        notes.append(f"the sequence {seq.root} has no ground truth: the estimate is shown as written")
    if seq is not None:
        rec.log("world", _world_axes(rr, seq), static=True)
    scores = odo_scores = None
    if seq is not None and seq.gt is not None:
        placed, scores = place_estimate(seq, est, frames, config.align)
        placed_odo = None
        if odo is not None:
            placed_odo, odo_scores = place_estimate(seq, odo, frames if len(odo) == len(est) else None, config.align)
        covered = [i for i in range(len(seq)) if seq.gt_pose(i) is not None]
        gt_positions = np.stack([seq.gt_pose(i)[:3, 3] for i in covered])
        rec.log("world/ground_truth", rr.LineStrips3D([gt_positions], colors=[_COLOURS["ground_truth"]],
                                                      labels=["ground truth"]), static=True)
        rec.log("metrics", rr.TextDocument(_metrics_text(run, scores, odo_scores), media_type="text/markdown"),
                static=True)
    else:
        placed, placed_odo = est.world_from_cam, odo.world_from_cam if odo is not None else None
    rec.log("world/estimate", rr.LineStrips3D([placed[:, :3, 3]], colors=[_COLOURS["estimate"]],
                                              labels=[f"{run.command} estimate"]), static=True)
    if placed_odo is not None:
        rec.log("world/odometry", rr.LineStrips3D([placed_odo[:, :3, 3]], colors=[_COLOURS["odometry"]],
                                                  labels=["odometry only"]), static=True)
    if run.command == "slam":
        _log_loops(rr, rec, run, placed, frames, notes)
    if seq is None or frames is None:
        if seq is not None:
            notes.append("the record's frames do not match the trajectory's poses: no per-frame cameras")
        return 0, notes
    _log_pinhole(rr, rec, seq)
    index_of = {int(f): k for k, f in enumerate(frames)}
    logged = 0
    for i in progress(config.frames(len(seq)), desc="logging", unit="frame",
                      disable=None if show_progress else True):
        k = index_of.get(int(i))
        if k is None:
            continue
        _set_time(rec, seq, int(i))
        _log_pose(rr, rec, "world/camera", placed[k])
        rec.log("world/camera/image/rgb", rr.Image(seq.image(int(i))))
        logged += 1
    return logged, notes


def _log_loops(rr, rec, run: Run, placed: np.ndarray, frames: np.ndarray | None, notes: list[str]) -> None:
    """slam's loop edges (record ``loops``: [i, j] frame pairs; ``loops_kept_by_pose_graph``: bools) and the loop
    pairs it left out (``loops_not_rigid``) as segments between the placed estimate's positions."""
    loops = run.record.get("loops") or []
    not_rigid = run.record.get("loops_not_rigid") or []
    if not loops and not not_rigid:
        return
    if frames is None:
        notes.append("the record's frames do not match the trajectory's poses: loop edges not drawn")
        return
    index_of = {int(f): k for k, f in enumerate(frames)}
    kept = run.record.get("loops_kept_by_pose_graph")
    groups: dict[str, list[np.ndarray]] = {"kept": [], "rejected": [], "not_rigid": []}
    for field, pairs in (("loops", loops), ("loops_not_rigid", not_rigid)):
        for n, pair in enumerate(pairs):
            try:
                a, b = index_of[int(pair[0])], index_of[int(pair[1])]
            except (KeyError, TypeError, ValueError, IndexError):
                raise InputError(run.record_path, f"{field}[{n}] ({pair!r}) names no frame of the trajectory") from None
            if field == "loops_not_rigid":
                group = "not_rigid"
            else:
                group = "kept" if not isinstance(kept, list) or n >= len(kept) or kept[n] else "rejected"
            groups[group].append(placed[[a, b], :3, 3])
    for name, segments in groups.items():
        if segments:
            rec.log(f"world/loops/{name}", rr.LineStrips3D(segments, colors=[_COLOURS[name]] * len(segments)),
                    static=True)


# ------------------------------------------------------------------------------------------------ entry point


def _inputs(source: Sequence | Run) -> list[tuple[str, Path | None]]:
    if isinstance(source, Run):
        return [("the run's trajectory", source.trajectory), ("the run's record", source.record_path),
                ("the run's odometry trajectory", source.odometry), ("the run's sequence", source.sequence)]
    return [("the sequence", Path(source.root))]


def check_save_path(save: str | Path, inputs: list[tuple[str, Path | None]]) -> None:
    """InputError naming ``save`` unless it is a file name ending in .rrd that is not, nor lies inside, an input."""
    save = Path(save)
    if save.suffix.lower() != ".rrd":
        raise InputError(save, "--save writes a rerun recording: give a file name ending in .rrd")
    if save.is_dir():
        raise InputError(save, "--save is a folder, expected a .rrd file name")
    check_output_not_input(save, inputs, "--save")


def view(path: str | Path, save: str | Path | None = None, config: ViewConfig = ViewConfig(),
         show_progress: bool = False) -> ViewResult:
    """Show ``path`` (a sequence folder, or a vo/slam run) in rerun: written to ``save`` (a .rrd, atomically)
    or, without ``save``, streamed to a spawned native viewer.

    Args:
        path: a sequence folder or a run (:func:`open_source`).
        save: the .rrd to write; None: spawn the viewer (InputError without a display).
        config: frames and alignment.
        show_progress: a progress bar on stderr while frames are logged.

    Raises:
        InputError: bad ``path``, a ``save`` that is not a .rrd name or lies inside an input, no display to
            spawn the viewer on, rerun-sdk missing.
    """
    config.validate()
    rr = _rerun()
    source = open_source(path)
    if save is not None:
        check_save_path(save, [("PATH", Path(path)), *_inputs(source)])
    elif not has_display():
        raise InputError(None, "no display to open the viewer on (DISPLAY is not set): write a recording with "
                               "--save FILE.rrd and open it with `rerun FILE.rrd` where there is a screen")
    rec = rr.RecordingStream(APPLICATION_ID)

    def log() -> ViewResult:
        if isinstance(source, Run):
            n, notes = log_run(rec, source, config, show_progress)
            return ViewResult(source.command, str(source.trajectory), n, notes)
        return ViewResult("sequence", source.name, log_sequence(rec, source, config, show_progress))

    if save is None:
        rr.spawn(recording=rec)
        result = log()
        rec.flush()
        return result
    # the recording's bytes are written here, not by rerun's file sink: a full disk is an OSError naming the
    # file (rerun's writer can stop silently, and its flush then waits forever). The stream is read once, at
    # the end: reading it while rerun still encodes gave files whose checksums fail. The recording is held in
    # memory until then (its encoded size: a few hundred MB for thousands of frames).
    stream = rec.binary_stream()
    try:
        result = log()
    finally:  # also when logging fails: a recording left connected would wait on its stream when collected
        rec.flush()
        data = stream.read(flush=True) or b""
        rec.disconnect()  # the end of the stream (its footer)
        data += stream.read(flush=False) or b""
    try:
        atomic.write_bytes(save, data)
    except OSError as e:
        why = "no space left on the device" if e.errno in (errno.ENOSPC, errno.EDQUOT) else (e.strerror or str(e))
        raise InputError(save, f"cannot write the recording: {why}; nothing was written") from None
    result.saved = Path(save)
    return result
