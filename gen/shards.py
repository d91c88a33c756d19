"""``deepslam gen``: synthetic training samples written as deterministic tar shards plus a manifest.

Output folder::

    run.json              the resolved configuration, written first (``--resume`` checks it)
    shard-000000.tar      samples [0, S), S = samples_per_shard
    shard-000001.tar      samples [S, 2S) ...
    ledger.jsonl          while unfinished: {"shard", "sha256"} per shard written (fsynced); ``--resume``
                          keeps a shard only if its bytes still hash to that record, and rebuilds the rest
    manifest.json         written last: config, seed, counts, sha256 and size of every shard

Shard format (readable without this project; the WebDataset layout, so ``webdataset`` reads it too):
a POSIX ustar archive, members grouped by sample key ``KKKKKKKKK`` (the sample index, 9 digits) in
index order, each an ``.npy`` file (``numpy.load``) or JSON:

=================================== ================ =====================================================
member                              dtype, shape     meaning
=================================== ================ =====================================================
``KKKKKKKKK.flow.npy``              float32 (h,w,2)  flow[v, u] = (du, dv) in pixels at the output
                                                     resolution, from the source frame to the moved
                                                     camera; 0 where not valid
``KKKKKKKKK.valid.npy``             bool (h, w)      flow defined (depth known, in front, inside the
                                                     image [, not hidden with zbuffer])
``KKKKKKKKK.target.npy``            float32 (6,)     paper vector of cam1_from_cam0: euler x, y, z (rad,
                                                     R = Rz Ry Rx), t x, y, z (m); OpenCV axes
``KKKKKKKKK.intrinsics.npy``        float32 (4,)     fx, fy, cx, cy (pixels, output resolution)
``KKKKKKKKK.json``                  JSON             {"index", "frame" (source frame), "loop" (bool)}
=================================== ================ =====================================================

Determinism: sample i depends only on (seed, i) (see :mod:`gen.dataset`), workers run torch and
OpenCV single-threaded, and archive headers are fixed (mtime 0, uid/gid 0, no user names, mode
0644), so the same configuration gives byte-identical shards whatever the backend, the number of
workers, or interruptions. Every shard is written atomically (temporary file + rename); ``--resume``
deletes leftover temporary files, keeps finished shards and writes the missing ones.
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import io
import json
import os
import tarfile
from pathlib import Path
from typing import Callable, Iterator

import multiprocessing as mp
import numpy as np

from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.core.integrity import sha256_file
from deepslam.core.lock import output_lock
from deepslam.core.progress import progress as progress_bar
from deepslam.core.sequence import dataset_file
from deepslam.core.textio import loads_json
from deepslam.gen.motion import MotionModel
from deepslam.gen.stereo import opencv_threads

FORMAT = "deepslam-flow-shards"
VERSION = 1
SHARD_PATTERN = "shard-{:06d}.tar"
SYNTH_BATCH = 32
"""Samples synthesized per batched call inside a shard."""

SAMPLE_LAYOUT = {
    "flow.npy": {"dtype": "float32", "shape": ["h", "w", 2], "unit": "px",
                 "meaning": "flow[v, u] = (du, dv) from the source frame to the moved camera, 0 where not valid"},
    "valid.npy": {"dtype": "bool", "shape": ["h", "w"], "meaning": "flow defined"},
    "target.npy": {"dtype": "float32", "shape": [6], "unit": "rad, rad, rad, m, m, m",
                   "meaning": "cam1_from_cam0 as (euler_x, euler_y, euler_z, t_x, t_y, t_z), R = Rz Ry Rx, OpenCV axes"},
    "intrinsics.npy": {"dtype": "float32", "shape": [4], "unit": "px", "meaning": "fx, fy, cx, cy at output resolution"},
    "json": {"meaning": "{index, frame (source frame index), loop (motion from the loop distribution)}"},
}


@dataclasses.dataclass(frozen=True)
class GenConfig:
    """Everything that determines the bytes of the shards (workers and backend do not)."""

    source: str
    """Sequence folder the depth frames come from (as given on the command line)."""
    motion: dict
    """The motion model (its JSON content, not its path)."""
    num_samples: int
    """Total number of samples."""
    seed: int = 0
    """Base seed: sample i depends on (seed, i) only."""
    resolution_hw: tuple[int, int] | None = None
    """Output (height, width) in pixels; None keeps the source resolution."""
    samples_per_shard: int = 256
    """Samples per tar shard."""
    depth_from_stereo: str | None = None
    """``sgbm``/``dis``: compute depth from the stereo pair when the source has no depth files."""
    loop_fraction: float = 0.0
    """Share of motions drawn from the loop distribution."""
    zbuffer: bool = False
    """Mark flow hidden by nearer points as invalid."""

    def __post_init__(self):
        if self.num_samples < 1:
            raise ValueError(f"num_samples must be >= 1, got {self.num_samples}")
        if self.samples_per_shard < 1:
            raise ValueError(f"samples_per_shard must be >= 1, got {self.samples_per_shard}")
        if self.resolution_hw is not None:
            object.__setattr__(self, "resolution_hw", (int(self.resolution_hw[0]), int(self.resolution_hw[1])))

    @property
    def num_shards(self) -> int:
        return -(-self.num_samples // self.samples_per_shard)

    def shard_range(self, shard: int) -> range:
        return range(shard * self.samples_per_shard, min((shard + 1) * self.samples_per_shard, self.num_samples))

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["resolution_hw"] = None if self.resolution_hw is None else list(self.resolution_hw)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "GenConfig":
        d = dict(d)
        if d.get("resolution_hw") is not None:
            d["resolution_hw"] = tuple(d["resolution_hw"])
        return cls(**d)


# ------------------------------------------------------------------------------------ building shards

_DATASETS: dict[str, object] = {}


def make_dataset(config: GenConfig, source_path: str | None = None):
    """The :class:`gen.dataset.SyntheticFlowDataset` of a configuration (cached per process).

    ``source_path`` opens the source from another path than ``config.source`` (the absolute path, for
    workers whose working directory differs); it does not change what is generated.
    """
    # deferred: gen.dataset pulls torch; planning, resuming and the coordinating process stay torch-free
    from deepslam.gen.dataset import DatasetConfig, SyntheticFlowDataset, open_depth_frames

    key = json.dumps([config.to_dict(), source_path], sort_keys=True)
    if key not in _DATASETS:
        if len(_DATASETS) > 4:
            _DATASETS.clear()
        frames = open_depth_frames(source_path or config.source, config.depth_from_stereo)
        motion = MotionModel.from_dict(config.motion)
        _DATASETS[key] = SyntheticFlowDataset(
            frames, motion, config.num_samples, config.seed,
            DatasetConfig(resolution_hw=config.resolution_hw, loop_fraction=config.loop_fraction, zbuffer=config.zbuffer))
    return _DATASETS[key]


def _npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
    return buf.getvalue()


def _add(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    info.mtime = 0
    info.mode = 0o644
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    info.type = tarfile.REGTYPE
    tar.addfile(info, io.BytesIO(data))


@contextlib.contextmanager
def single_threaded() -> Iterator[None]:
    """torch and OpenCV on one thread inside the block (bit-identical results in every process)."""
    import torch  # deferred: torch (~1 s); importing gen.shards (the gen coordinator) stays torch-free

    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with opencv_threads(1):
            yield
    finally:
        torch.set_num_threads(old)


def build_shard(config: GenConfig, shard: int, source_path: str | None = None) -> bytes:
    """The bytes of shard ``shard`` (a tar archive, see the module docstring)."""
    ds = make_dataset(config, source_path)
    indices = list(config.shard_range(shard))
    buf = io.BytesIO()
    with single_threaded(), tarfile.open(fileobj=buf, mode="w", format=tarfile.USTAR_FORMAT) as tar:
        for s in range(0, len(indices), SYNTH_BATCH):
            batch = ds.get_batch(indices[s:s + SYNTH_BATCH])
            flow = batch["flow"].permute(0, 2, 3, 1).numpy()
            for k, idx in enumerate(batch["index"].tolist()):
                key = f"{idx:09d}"
                _add(tar, f"{key}.flow.npy", _npy_bytes(flow[k].astype(np.float32)))
                _add(tar, f"{key}.valid.npy", _npy_bytes(batch["valid"][k].numpy()))
                _add(tar, f"{key}.target.npy", _npy_bytes(batch["target"][k].numpy()))
                _add(tar, f"{key}.intrinsics.npy", _npy_bytes(batch["intrinsics"][k].numpy()))
                meta = {"index": idx, "frame": int(batch["frame"][k]), "loop": bool(batch["loop"][k])}
                _add(tar, f"{key}.json", json.dumps(meta, sort_keys=True).encode())
    return buf.getvalue()


def write_shard(config: GenConfig, shard: int, out_dir: str, source_path: str | None = None) -> tuple[int, str, int, int]:
    """Build shard ``shard`` and write it atomically into ``out_dir``: (shard, sha256, samples, bytes)."""
    data = build_shard(config, shard, source_path)
    atomic.write_bytes(Path(out_dir) / SHARD_PATTERN.format(shard), data)
    return shard, hashlib.sha256(data).hexdigest(), len(config.shard_range(shard)), len(data)


def _guarded(fn, *args):
    """Run ``fn(*args)`` in a worker; an InputError comes back as ("InputError", path, what, line), since
    core.errors.InputError does not survive pickling (its __init__ takes more than the message)."""
    try:
        return fn(*args)
    except InputError as e:
        return ("InputError", e.path, e.what, e.line)


def _reraise(result):
    if isinstance(result, tuple) and len(result) == 4 and result[0] == "InputError":
        raise InputError(result[1], result[2], line=result[3])
    return result


def _shard_ok(path: Path, config: GenConfig, shard: int) -> bool:
    """A finished shard holds exactly the expected members (atomic writes make anything else rare)."""
    try:
        with tarfile.open(path, mode="r:") as tar:
            names = tar.getnames()
    except (tarfile.TarError, OSError, EOFError):
        return False
    want = [f"{i:09d}.{ext}" for i in config.shard_range(shard)
            for ext in ("flow.npy", "valid.npy", "target.npy", "intrinsics.npy", "json")]
    return names == want


# ------------------------------------------------------------------------------------------- running

def _local_worker_init() -> None:
    import torch  # deferred: torch (~1 s); importing gen.shards (the gen coordinator) stays torch-free

    torch.set_num_threads(1)


def _run_local(config: GenConfig, todo: list[int], out_dir: Path, workers: int, on_done: Callable,
               source_path: str) -> None:
    if workers <= 1 or len(todo) <= 1:
        for shard in todo:
            on_done(*write_shard(config, shard, str(out_dir), source_path))
        return
    ctx = mp.get_context("spawn")  # no fork after torch/OpenMP threads exist
    with ctx.Pool(min(workers, len(todo)), initializer=_local_worker_init) as pool:
        results = [pool.apply_async(_guarded, (write_shard, config, shard, str(out_dir), source_path))
                   for shard in todo]
        for r in results:
            on_done(*_reraise(r.get()))


def _run_ray(config: GenConfig, todo: list[int], out_dir: Path, workers: int, on_done: Callable,
             source_path: str) -> None:
    import ray  # deferred: the [ray] extra, only for the ray backend

    if not ray.is_initialized():
        # RAY_ADDRESS set: join that cluster; otherwise start a local one with `workers` CPUs.
        if os.environ.get("RAY_ADDRESS"):
            ray.init(include_dashboard=False, log_to_driver=False)
        else:
            ray.init(num_cpus=max(1, workers), include_dashboard=False, log_to_driver=False)
    # Workers import deepslam from the same installation as the driver (site-packages or the editable
    # install's finder), so no PYTHONPATH is passed along.
    task = ray.remote(num_cpus=1)(_guarded)
    # Shard bytes come back to the driver, which writes them: no shared file system needed.
    max_in_flight = max(2, 2 * workers)
    pending: dict = {}
    queue = list(todo)
    while queue or pending:
        while queue and len(pending) < max_in_flight:
            shard = queue.pop(0)
            pending[task.remote(build_shard, config, shard, source_path)] = shard
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            shard = pending.pop(ref)
            data = _reraise(ray.get(ref))
            atomic.write_bytes(out_dir / SHARD_PATTERN.format(shard), data)
            on_done(shard, hashlib.sha256(data).hexdigest(), len(config.shard_range(shard)), len(data))


def generate(config: GenConfig, out_dir: str | Path, workers: int = 1, backend: str = "local",
             resume: bool = False, progress: bool | None = None) -> dict:
    """Write all shards and the manifest of ``config`` into ``out_dir``; returns the manifest.

    Args:
        config: what to generate.
        out_dir: output folder (created; must be empty unless ``resume``).
        workers: parallel shard builders (processes for ``local``, CPUs of a new local Ray instance).
        backend: ``local`` (process pool) or ``ray`` (Ray tasks; joins ``RAY_ADDRESS`` or an instance
            already initialised in this process, else starts a local one).
        resume: continue an interrupted run: the folder's run.json must hold the same config.
        progress: show a progress bar (None: the project's default policy, :mod:`core.progress`).

    Raises:
        InputError: bad source (not a sequence, no depth), non-empty folder without ``resume``, or a
            resume whose configuration differs.
    """
    if backend not in ("local", "ray"):
        raise ValueError(f"backend must be local or ray, got {backend!r}")
    out_dir = Path(out_dir)
    with output_lock(out_dir):  # one writer: a second gen into this folder is refused while this one runs
        return _generate_locked(config, out_dir, workers, backend, resume, progress)


def _generate_locked(config: GenConfig, out_dir: Path, workers: int, backend: str, resume: bool,
                     progress: bool | None) -> dict:
    run_json = out_dir / "run.json"
    source_path = str(Path(config.source).resolve())
    want = {"format": FORMAT, "version": VERSION, "config": config.to_dict(),
            "source_sha256": source_fingerprint(source_path)}
    if any(out_dir.iterdir()):
        if not resume:
            raise InputError(out_dir, "output folder is not empty (pass --resume to finish an interrupted run)")
        try:
            have = json.loads(run_json.read_text())
        except (OSError, json.JSONDecodeError):
            raise InputError(run_json, "cannot resume: run.json is missing or unreadable") from None
        if have.get("source_sha256") != want["source_sha256"] and have.get("config") == json.loads(json.dumps(want["config"])):
            raise InputError(Path(config.source), "cannot resume: the source's content changed since the interrupted "
                                                  f"run (its files no longer hash to {str(have.get('source_sha256'))[:12]}...)")
        if have != json.loads(json.dumps(want)):
            diff = sorted(k for k in set(have.get("config", {})) | set(want["config"])
                          if have.get("config", {}).get(k) != json.loads(json.dumps(want["config"])).get(k))
            raise InputError(run_json, f"cannot resume: settings differ from the interrupted run ({', '.join(diff) or 'format'})")
    # Fail on a bad source before anything is written (this also fills this process's cache).
    ds = make_dataset(config, source_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic.write_json(run_json, want)
    for stale in out_dir.glob(".*.tmp*"):          # temporary files of a killed run
        stale.unlink(missing_ok=True)
    recorded_by_manifest: dict[int, str] = {}
    if resume and (out_dir / "manifest.json").is_file():
        try:
            old = json.loads((out_dir / "manifest.json").read_text())
            recorded_by_manifest = {k: e["sha256"] for k, e in enumerate(old["shards"])}
        except (OSError, ValueError, KeyError, TypeError):
            pass
    (out_dir / "manifest.json").unlink(missing_ok=True)

    # Integrity on resume: a shard is kept only when its bytes hash to what this run's ledger recorded
    # when it wrote it (a damaged or foreign file is rebuilt, never re-hashed into the manifest).
    ledger_path = out_dir / LEDGER
    recorded = {**recorded_by_manifest, **_read_ledger(ledger_path)} if resume else {}
    if not resume:
        ledger_path.unlink(missing_ok=True)
    done: dict[int, tuple[str, int, int]] = {}
    todo = []
    for shard in range(config.num_shards):
        path = out_dir / SHARD_PATTERN.format(shard)
        if (path.is_file() and shard in recorded and _shard_ok(path, config, shard)
                and sha256_file(path) == recorded[shard]):
            done[shard] = (recorded[shard], len(config.shard_range(shard)), path.stat().st_size)
        else:
            todo.append(shard)
    ledger = open(ledger_path, "a", encoding="utf-8")

    bar_opts = {} if progress is None else {"disable": not progress}
    bar = progress_bar(total=config.num_samples, unit="sample", desc="gen", **bar_opts)
    bar.update(sum(v[1] for v in done.values()))

    def on_done(shard: int, sha: str, n: int, size: int) -> None:
        done[shard] = (sha, n, size)
        ledger.write(json.dumps({"shard": shard, "sha256": sha}) + "\n")
        ledger.flush()
        os.fsync(ledger.fileno())
        bar.update(n)

    try:
        if backend == "local":
            _run_local(config, todo, out_dir, workers, on_done, source_path)
        else:
            _run_ray(config, todo, out_dir, workers, on_done, source_path)
    except BaseException:
        if not done:  # nothing finished: leave nothing behind, so a plain rerun is not refused as "not empty"
            ledger.close()
            for name in (LEDGER, "run.json"):
                (out_dir / name).unlink(missing_ok=True)
        raise
    finally:
        bar.close()
        ledger.close()

    manifest = {
        "format": FORMAT, "version": VERSION,
        "config": config.to_dict(),
        "seed": config.seed,
        "source": ds.frames.describe(),
        "camera": ds.camera.to_dict(),
        "num_samples": config.num_samples,
        "num_shards": config.num_shards,
        "samples_per_shard": config.samples_per_shard,
        "sample_layout": SAMPLE_LAYOUT,
        "shards": [{"name": SHARD_PATTERN.format(s), "first_index": config.shard_range(s).start,
                    "num_samples": done[s][1], "bytes": done[s][2], "sha256": done[s][0]}
                   for s in range(config.num_shards)],
    }
    atomic.write_json(out_dir / "manifest.json", manifest)
    ledger_path.unlink(missing_ok=True)  # the manifest now holds the same record
    return manifest


def source_fingerprint(source: str | Path) -> str:
    """sha256 over the relative names, sizes and bytes of every file in the source folder (hidden files
    excluded): a resumed run must read the same content, not only the same path."""
    root = Path(source)
    if not root.is_dir():
        return "missing"
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if not p.is_file() or any(part.startswith(".") for part in rel.parts):
            continue
        h.update(f"{rel.as_posix()}\0{p.stat().st_size}\0".encode())
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


LEDGER = "ledger.jsonl"
"""While a run is unfinished: one line ``{"shard", "sha256"}`` per shard written, fsynced."""


def _read_ledger(path: Path) -> dict[int, str]:
    """{shard: sha256} of a ledger; lines that do not parse (a torn last line) are ignored."""
    out: dict[int, str] = {}
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return out
    for line in lines:
        try:
            rec = json.loads(line)
            out[int(rec["shard"])] = str(rec["sha256"])
        except (ValueError, KeyError, TypeError, RecursionError):
            continue
    return out


# -------------------------------------------------------------------------------------------- reading

def read_shard(path: str | Path) -> Iterator[dict[str, np.ndarray | dict]]:
    """Samples of one shard in order: dicts with ``flow`` (h, w, 2) float32, ``valid``, ``target``,
    ``intrinsics`` (numpy) and ``meta`` (the JSON record). Plain tarfile + numpy, as any reader would."""
    path = Path(path)
    try:
        tar = tarfile.open(path, mode="r:")
    except (tarfile.TarError, OSError) as e:
        raise InputError(path, f"not a readable tar shard ({e})") from None
    with tar:
        sample: dict = {}
        key = None
        for member in tar:
            k, _, ext = member.name.partition(".")
            if key is not None and k != key:
                yield sample
                sample = {}
            key = k
            data = tar.extractfile(member).read()
            if ext == "json":
                sample["meta"] = loads_json(data, path, f"sample {key}'s meta")
            else:
                sample[ext.removesuffix(".npy")] = np.load(io.BytesIO(data), allow_pickle=False)
        if sample:
            yield sample


def verify(out_dir: str | Path) -> dict:
    """Check every shard's sha256 against the manifest; InputError naming the first bad one."""
    out_dir = Path(out_dir)
    path = out_dir / "manifest.json"
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(path, f"cannot read manifest ({e})") from None
    manifest = loads_json(text, path, "manifest")  # bounded: size and nesting (core.textio)
    shards = manifest.get("shards") if isinstance(manifest, dict) else None
    if not isinstance(shards, list) or not all(isinstance(e, dict) and isinstance(e.get("name"), str)
                                                    and isinstance(e.get("sha256"), str) for e in shards):
        raise InputError(path, "not a shard manifest (no list of shards with names)")
    for entry in shards:
        shard = dataset_file(out_dir, entry["name"], path)  # never outside the shard folder
        if not shard.is_file():
            raise InputError(shard, "shard listed in the manifest is missing")
        if sha256_file(shard) != entry["sha256"]:
            raise InputError(shard, "sha256 differs from the manifest")
    return manifest


def load_samples(out_dir: str | Path) -> dict[str, np.ndarray]:
    """Every sample of a finished ``deepslam gen`` folder, verified against its manifest, as arrays in
    the layout the network trains on: ``flow`` (N, 2, h, w) float32 px, ``valid`` (N, h, w) bool,
    ``intrinsics`` (N, 4) float32, ``target`` (N, 6) float32, ``frame`` (N,) int64 source frame.

    Raises:
        InputError: no manifest (an unfinished run), a damaged or missing shard, a malformed sample.
    """
    out_dir = Path(out_dir)
    manifest = verify(out_dir)
    flows, valids, intr, target, frames = [], [], [], [], []
    for entry in manifest["shards"]:
        shard = out_dir / entry["name"]
        for s in read_shard(shard):
            try:
                flows.append(np.ascontiguousarray(np.moveaxis(s["flow"], -1, 0), dtype=np.float32))
                valids.append(np.asarray(s["valid"], dtype=bool))
                intr.append(np.asarray(s["intrinsics"], dtype=np.float32).reshape(4))
                target.append(np.asarray(s["target"], dtype=np.float32).reshape(6))
                frames.append(int(s["meta"]["frame"]))
            except (KeyError, ValueError, TypeError) as e:
                raise InputError(shard, f"malformed sample ({type(e).__name__}: {e})") from None
    if not flows:
        raise InputError(out_dir, "the shards hold no samples")
    shapes = {f.shape for f in flows}
    if len(shapes) != 1:
        raise InputError(out_dir, f"samples of different sizes: {sorted(shapes)}")
    return {"flow": np.stack(flows), "valid": np.stack(valids), "intrinsics": np.stack(intr),
            "target": np.stack(target), "frame": np.asarray(frames, dtype=np.int64)}


class ShardDataset:
    """The samples of a ``deepslam gen`` folder as a map-style dataset for a plain
    ``torch.utils.data.DataLoader`` (``len`` and ``[i]`` -> dict of tensors: ``flow`` (2, h, w),
    ``valid`` (h, w), ``intrinsics`` (4,), ``target`` (6,)). Loads and verifies everything up front."""

    def __init__(self, out_dir: str | Path):
        self.arrays = load_samples(out_dir)

    def __len__(self) -> int:
        return len(self.arrays["target"])

    def __getitem__(self, i: int) -> dict:
        import torch  # deferred: torch (~1 s); importing gen.shards (the gen coordinator) stays torch-free

        return {k: torch.from_numpy(self.arrays[k][i]) for k in ("flow", "valid", "intrinsics", "target")}
