"""Many rendered sequences in one folder, drawn from a config and a seed (``deepslam dataset``).

What a user of Kubric, TartanAir or CARLA expects from a generator: a documented config, a seed that
fixes every sequence, one folder per sequence in a known layout, a manifest with the config, the seed
and per-sequence counts and sha256, resumption after a kill, and distribution over processes or
machines that does not change a byte of the result.

How:

- :func:`plan` draws every sequence's settings (scene, scene seed, movers, deformation, layout, exposure)
  from ``numpy.random.default_rng(SeedSequence([seed, 0xDA7A]))`` with a fixed number of draws per
  sequence (lighting and rolling shutter from ``SeedSequence([seed, 0xDA7B, k])`` for sequence k),
  so the plan of N sequences is the first N of the plan of N + M, and it does not depend on the
  backend or the number of workers. Scenes are dealt round-robin (``street, room, street, ...``).
- :func:`render_planned` renders one planned sequence into ``<out>/<name>`` with
  :func:`sim.writers.render_sequence` (``resume=True``: a retried or resumed sequence keeps its
  finished frames, renders are deterministic) and returns its record: counts, per-file sha256 folded
  into one sequence sha256, seconds and the process's peak resident memory.
- :func:`build` runs the plan on a backend: ``local`` (this process, one sequence after another) or
  ``ray`` (one Ray task per sequence on ``workers`` CPUs of a local Ray instance, or on an existing
  cluster at ``address``; a task whose worker dies is retried up to 3 times). The driver writes each
  finished sequence's record to ``<out>/records/<name>.json`` and, at the end, ``manifest.json``.

Layout of ``<out>``::

    dataset.json          the resolved config (written first; --resume refuses another config)
    seq_0000/ ...         one rendered sequence per planned entry, in --format's layout
    records/seq_0000.json that sequence's record (written once it is complete)
    manifest.json         config, seed, and per sequence: name, settings, frames, files, bytes, sha256

A sequence's sha256 is the sha256 of the lines ``"<sha256>  <relative path>\\n"`` over its files in
sorted path order (``sha256sum``'s format); the dataset's is that of the sequences' sha256 lines.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import resource
import shutil
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.core.integrity import file_digests
from deepslam.core.lock import output_lock
from deepslam.core.textio import read_json_object
from deepslam.scenes import SceneConfig
from deepslam.sim.config import FORMATS, RenderConfig, SimConfig, TrajectoryConfig
from deepslam.sim.writers import render_sequence

SCENES = ("street", "room")
BACKENDS = ("local", "ray")
CONFIG_FILE = "dataset.json"
MANIFEST_FILE = "manifest.json"
RECORDS_DIR = "records"


@dataclasses.dataclass(frozen=True)
class DatasetConfig:
    """What ``deepslam dataset`` renders. A JSON file (``--config``) holds any of these fields by name;
    flags override it."""

    scenes: tuple[str, ...] = SCENES
    """Scenes dealt round-robin to the sequences: ``street`` (car) and/or ``room`` (drone)."""
    sequences: int = 4
    """Number of sequences."""
    frames: int = 100
    """Frames per sequence."""
    width: int | None = None
    """Image width in pixels (None: the scene camera's 640, or from ``height``)."""
    height: int | None = None
    """Image height in pixels (None: from ``width`` and the scene camera's aspect)."""
    seed: int = 0
    """Seed of the whole dataset: every sequence's settings and scene seed derive from it."""
    moving_objects: tuple[int, int] = (0, 4)
    """Movers per sequence, drawn uniformly from this inclusive range (cars in the street, boxes in the room)."""
    deform_amplitude_m: tuple[float, float] = (0.0, 0.0)
    """Amplitude of the waving flags, metres, drawn uniformly from this range (0: rigid)."""
    varied_layout_fraction: float = 0.5
    """Fraction of street sequences in the narrow, crowded variant (KITTI-like residential streets)."""
    narrow_layout_fraction: float = 0.0
    """Fraction of the street sequences not in the varied layout that are narrow residential streets
    (``scenes.street.StreetLayout.narrow``)."""
    grainy_road_fraction: float = 0.0
    """Fraction of the street sequences with grainy asphalt (``scenes.textures.asphalt_grainy``: the
    road's texture contrast drawn per road stretch) instead of the near-uniform surface."""
    kitti_street_fraction: float = 0.0
    """Fraction of the street sequences in the KITTI look (``scene.street_style = "kitti"``: narrow
    residential streets and a long avenue, stop-and-go driving up to 30 m/s); the layout and road
    options above apply to the others (the town street)."""
    format: str = "ours"
    """Layout of each sequence: ``ours``, ``kitti``, ``euroc`` or ``tum``."""
    render_backend: str = "mujoco"
    """Renderer: ``mujoco`` or ``pyrender``."""
    flow: bool = True
    """Write forward/backward flow and occlusion ground truth."""
    exposure_ms: tuple[float, float] = (0.0, 0.0)
    """Motion-blur exposure per sequence, milliseconds, uniform in this range (0: sharp)."""
    sensor_noise: float = 0.0
    """Gaussian image noise, grey levels (every sequence)."""
    exposure_jitter: float = 0.0
    """Per-frame brightness gain, log-uniform in [1 / (1 + j), 1 + j] (every sequence)."""
    white_balance_jitter: float = 0.0
    """Per-frame colour channel gains, uniform in [1 - w, 1 + w] (every sequence)."""
    random_lighting_fraction: float = 0.0
    """Fraction of sequences lit by a lighting drawn from their scene seed (sun, shadows, brightness,
    colour temperature: ``scenes.lighting``) instead of the scene's fixed one."""
    rolling_shutter_ms: tuple[float, float] = (0.0, 0.0)
    """Rolling-shutter readout per sequence, milliseconds, uniform in this range (0: global shutter;
    cannot be combined with motion blur in one sequence: where both are drawn, the exposure wins)."""

    def validate(self) -> "DatasetConfig":
        """Self, or InputError naming the bad field."""
        if not self.scenes or any(s not in SCENES for s in self.scenes):
            raise InputError(None, f"scenes must be a non-empty list of {', '.join(SCENES)}, got {list(self.scenes)}")
        for name, value, lo, hi in (("sequences", self.sequences, 1, 100_000), ("frames", self.frames, 2, 1_000_000)):
            if not isinstance(value, int) or not lo <= value <= hi:
                raise InputError(None, f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
        mo = self.moving_objects
        if len(mo) != 2 or not all(isinstance(x, int) for x in mo) or not 0 <= mo[0] <= mo[1] <= 64:
            raise InputError(None, f"moving_objects must be [MIN, MAX] integers with 0 <= MIN <= MAX <= 64, got {list(mo)}")
        da = self.deform_amplitude_m
        if len(da) != 2 or not np.isfinite(da).all() or not 0 <= da[0] <= da[1] <= 0.3:
            raise InputError(None, f"deform_amplitude_m must be [MIN, MAX] with 0 <= MIN <= MAX <= 0.3, got {list(da)}")
        if not (np.isfinite(self.varied_layout_fraction) and 0 <= self.varied_layout_fraction <= 1):
            raise InputError(None, f"varied_layout_fraction must be in [0, 1], got {self.varied_layout_fraction}")
        if self.format not in FORMATS:
            raise InputError(None, f"format must be one of {', '.join(FORMATS)}, got {self.format!r}")
        ex = self.exposure_ms
        if len(ex) != 2 or not np.isfinite(ex).all() or not 0 <= ex[0] <= ex[1] <= 1000:
            raise InputError(None, f"exposure_ms must be [MIN, MAX] with 0 <= MIN <= MAX <= 1000, got {list(ex)}")
        if not (np.isfinite(self.narrow_layout_fraction) and 0 <= self.narrow_layout_fraction <= 1):
            raise InputError(None, f"narrow_layout_fraction must be in [0, 1], got {self.narrow_layout_fraction}")
        if not (np.isfinite(self.kitti_street_fraction) and 0 <= self.kitti_street_fraction <= 1):
            raise InputError(None, f"kitti_street_fraction must be in [0, 1], got {self.kitti_street_fraction}")
        if not (np.isfinite(self.grainy_road_fraction) and 0 <= self.grainy_road_fraction <= 1):
            raise InputError(None, f"grainy_road_fraction must be in [0, 1], got {self.grainy_road_fraction}")
        if not (np.isfinite(self.random_lighting_fraction) and 0 <= self.random_lighting_fraction <= 1):
            raise InputError(None, f"random_lighting_fraction must be in [0, 1], got {self.random_lighting_fraction}")
        rs = self.rolling_shutter_ms
        if len(rs) != 2 or not np.isfinite(rs).all() or not 0 <= rs[0] <= rs[1] <= 1000:
            raise InputError(None, f"rolling_shutter_ms must be [MIN, MAX] with 0 <= MIN <= MAX <= 1000, got {list(rs)}")
        if self.render_backend not in ("mujoco", "pyrender"):
            raise InputError(None, f"render_backend must be mujoco or pyrender, got {self.render_backend!r}")
        return self

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict, source=None) -> "DatasetConfig":
        """From a JSON object; InputError naming ``source`` for unknown fields or wrong types."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise InputError(source, f"unknown dataset config field(s) {', '.join(unknown)} (known: {', '.join(sorted(names))})")
        kw = {}
        for k, v in d.items():
            kw[k] = tuple(v) if isinstance(v, list) else v
        try:
            return cls(**kw).validate()
        except InputError as e:
            raise InputError(source, e.what) from None


@dataclasses.dataclass(frozen=True)
class PlannedSequence:
    """One sequence of the plan."""

    index: int
    """Position in the plan, 0-based."""
    name: str
    """Folder name, ``seq_NNNN``."""
    sim: dict
    """The :class:`sim.config.SimConfig` as a dict (scene, trajectory, render)."""


def plan(cfg: DatasetConfig) -> list[PlannedSequence]:
    """Every sequence's settings, from ``cfg.seed`` alone (see the module docstring)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(cfg.seed), 0xDA7A]))
    out = []
    for k in range(cfg.sequences):
        scene = cfg.scenes[k % len(cfg.scenes)]
        scene_seed = int(rng.integers(0, 2 ** 31))
        movers = int(rng.integers(cfg.moving_objects[0], cfg.moving_objects[1] + 1))
        deform = round(float(rng.uniform(*cfg.deform_amplitude_m)), 4)
        varied = bool(rng.random() < cfg.varied_layout_fraction) and scene == "street"
        exposure = round(float(rng.uniform(*cfg.exposure_ms)), 3)
        # later options draw from their own stream per sequence: the draws above stay as they were
        extra = np.random.default_rng(np.random.SeedSequence([int(cfg.seed), 0xDA7B, k]))
        lit = bool(extra.random() < cfg.random_lighting_fraction)
        readout = round(float(extra.uniform(*cfg.rolling_shutter_ms)), 3)
        readout = readout if exposure == 0 else 0.0  # drawn either way: a fixed number of draws per sequence
        narrow = bool(extra.random() < cfg.narrow_layout_fraction) and scene == "street" and not varied
        grainy = bool(extra.random() < cfg.grainy_road_fraction) and scene == "street"
        kitti = bool(extra.random() < cfg.kitti_street_fraction) and scene == "street"
        if kitti:
            varied = narrow = grainy = False
        sim = SimConfig(SceneConfig(name=scene, seed=scene_seed, moving_objects=movers, deform_amplitude_m=deform,
                                    varied_layout=varied, narrow_layout=narrow, random_lighting=lit,
                                    grainy_road=grainy, street_style="kitti" if kitti else "town"),
                        TrajectoryConfig(kind="auto", frames=cfg.frames),
                        RenderConfig(backend=cfg.render_backend, width=cfg.width, height=cfg.height, flow=cfg.flow,
                                     exposure_ms=exposure, sensor_noise=cfg.sensor_noise,
                                     exposure_jitter=cfg.exposure_jitter, white_balance_jitter=cfg.white_balance_jitter,
                                     rolling_shutter_ms=readout))
        out.append(PlannedSequence(k, f"seq_{k:04d}", sim.to_dict()))
    return out


def tree_digest(root: Path) -> tuple[str, int, int]:
    """(sha256, files, bytes) of every file under ``root`` (see the module docstring)."""
    files = sorted(p for p in root.rglob("*") if p.is_file())
    digests = file_digests(files, root)
    lines = "".join(f"{sha}  {rel}\n" for rel, sha in digests.items())
    return hashlib.sha256(lines.encode()).hexdigest(), len(files), sum(p.stat().st_size for p in files)


def render_planned(entry: dict, out_root: str, fmt: str) -> dict:
    """Render one planned sequence (``PlannedSequence`` as a dict) into ``out_root/name``; its record.

    Runs in a worker (any process with deepslam): renders with ``resume=True``, then hashes the
    sequence folder. The record holds ``name``, ``index``, ``settings`` (scene, seed, movers,
    deformation, layout), ``frames``, ``files``, ``bytes``, ``sha256``, ``seconds`` and
    ``peak_rss_mib`` (this process's peak resident memory so far).
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    t0 = time.perf_counter()
    folder = Path(out_root) / entry["name"]
    render_sequence(SimConfig.from_dict(entry["sim"]).validate(), folder, fmt=fmt, resume=True, progress=False)
    sha, files, size = tree_digest(folder)
    sc = entry["sim"]["scene"]
    return {"name": entry["name"], "index": entry["index"],
            "settings": {"scene": sc["name"], "seed": sc["seed"], "moving_objects": sc["moving_objects"],
                         "deform_amplitude_m": sc["deform_amplitude_m"], "varied_layout": sc["varied_layout"],
                         "exposure_ms": entry["sim"]["render"]["exposure_ms"],
                         "narrow_layout": sc.get("narrow_layout", False),
                         "random_lighting": sc.get("random_lighting", False),
                         "grainy_road": sc.get("grainy_road", False),
                         "street_style": sc.get("street_style", "town"),
                         "rolling_shutter_ms": entry["sim"]["render"].get("rolling_shutter_ms", 0.0)},
            "frames": entry["sim"]["trajectory"]["frames"], "files": files, "bytes": size, "sha256": sha,
            "seconds": round(time.perf_counter() - t0, 3),
            "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)}


def _record_still_valid(out: Path, rec: dict) -> bool:
    folder = out / rec.get("name", "")
    return folder.is_dir() and tree_digest(folder)[0] == rec.get("sha256")


def _frames_done(folder: Path) -> int:
    """Frames with a written record in a sequence folder being rendered (any layout)."""
    if not folder.is_dir():
        return 0
    return sum(1 for _ in folder.glob("frames/*.json")) + sum(1 for _ in folder.rglob(".deepslam_frames/*.json"))


def build(cfg: DatasetConfig, out_dir, backend: str = "local", workers: int = 2, address: str | None = None,
          resume: bool = False, progress: bool = True) -> dict:
    """Render the dataset of ``cfg`` into ``out_dir``; returns the manifest (also written as manifest.json).

    Args:
        cfg: the dataset config (validated here).
        out_dir: output folder: new or empty, or an interrupted run of the same config with ``resume``.
        backend: ``local`` or ``ray``.
        workers: Ray worker processes (CPUs of the local Ray instance; ignored by ``local``).
        address: an existing Ray cluster's address (None: start a local instance).
        resume: finish an interrupted run: finished sequences whose files still hash to their record are
            kept, a finished sequence whose files changed is rendered again from scratch, and one that
            was being rendered carries on from its last complete frame.
        progress: a progress bar over all frames of all sequences.
    """
    cfg = cfg.validate()
    if backend not in BACKENDS:
        raise InputError(None, f"unknown backend {backend!r} (local or ray)")
    if not isinstance(workers, int) or not 1 <= workers <= 1024:
        raise InputError(None, f"--workers must be an integer in [1, 1024], got {workers!r}")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(out, "output exists and is not a folder")
    with output_lock(out):
        cfg_path = out / CONFIG_FILE
        if resume and cfg_path.is_file():
            old = read_json_object(cfg_path)
            if old != cfg.to_dict():
                diff = sorted(k for k in set(old) | set(cfg.to_dict()) if old.get(k) != cfg.to_dict().get(k))
                raise InputError(cfg_path, f"cannot resume: the config differs from the interrupted run's ({', '.join(diff)})")
        elif any(out.iterdir()):
            raise InputError(out, "output folder is not empty" + ("" if resume else " (use --resume to finish an interrupted run)"))
        atomic.write_json(cfg_path, cfg.to_dict())
        entries = plan(cfg)
        records: dict[str, dict] = {}
        for e in entries:
            rp = out / RECORDS_DIR / f"{e.name}.json"
            if rp.is_file():
                try:
                    rec = json.loads(rp.read_text())
                except (OSError, json.JSONDecodeError):
                    rec = None
                if rec and _record_still_valid(out, rec):
                    records[e.name] = rec
                else:  # finished once, changed since: render it again from scratch
                    rp.unlink(missing_ok=True)
                    shutil.rmtree(out / e.name, ignore_errors=True)
        todo = [e for e in entries if e.name not in records]
        bar = tqdm(total=cfg.sequences * cfg.frames, desc="dataset", unit="frame", disable=not progress,
                   dynamic_ncols=True, initial=len(records) * cfg.frames)

        def finished(rec: dict) -> None:
            atomic.write_json(out / RECORDS_DIR / f"{rec['name']}.json", rec)
            records[rec["name"]] = rec

        if backend == "local":
            for e in todo:
                before = _frames_done(out / e.name)
                rec = render_planned(dataclasses.asdict(e), str(out), cfg.format)
                finished(rec)
                bar.update(cfg.frames - min(before, cfg.frames))
        else:
            _run_ray(todo, out, cfg, workers, address, finished, bar)
        bar.close()
        ordered = [records[e.name] for e in entries]
        manifest = {"generator": "deepslam dataset", "config": cfg.to_dict(), "seed": cfg.seed,
                    "sequences": ordered, "frames": sum(r["frames"] for r in ordered),
                    "sha256": hashlib.sha256("".join(f"{r['sha256']}  {r['name']}\n" for r in ordered).encode()).hexdigest()}
        atomic.write_json(out / MANIFEST_FILE, manifest)
        return manifest


def _run_ray(todo: list[PlannedSequence], out: Path, cfg: DatasetConfig, workers: int, address: str | None,
             finished, bar) -> None:
    """One Ray task per sequence; the bar follows the frames written on disk."""
    import ray  # deferred: the [ray] extra, only for the ray backend

    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    started_here = not ray.is_initialized()
    if started_here:
        kwargs = dict(include_dashboard=False, log_to_driver=False, logging_level="ERROR", configure_logging=False)
        try:
            if address:
                ray.init(address=address, **kwargs)
            else:
                ray.init(num_cpus=workers, **kwargs)
        except Exception as e:  # noqa: BLE001 - Ray's own errors are many
            raise InputError(None, f"cannot start or reach Ray{f' at {address}' if address else ''} "
                                   f"({type(e).__name__}: {e})") from None
    try:
        task = ray.remote(num_cpus=1, max_retries=3, retry_exceptions=False)(render_planned)
        pending = {task.remote(dataclasses.asdict(e), str(out), cfg.format): e for e in todo}
        shown = {e.name: 0 for e in todo}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
            for ref in ready:
                e = pending.pop(ref)
                try:
                    rec = ray.get(ref)
                except ray.exceptions.RayTaskError as err:
                    cause = err.cause if getattr(err, "cause", None) is not None else err
                    if isinstance(cause, InputError):
                        raise InputError(cause.path, cause.what) from None
                    raise
                finished(rec)
                bar.update(cfg.frames - shown[e.name])
                shown[e.name] = cfg.frames
            for e in pending.values():  # frames written so far by the running tasks
                n = min(_frames_done(out / e.name), cfg.frames - 1)
                if n > shown[e.name]:
                    bar.update(n - shown[e.name])
                    shown[e.name] = n
    finally:
        if started_here:
            ray.shutdown()
