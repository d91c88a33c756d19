"""The paper's method as a workflow: adapt the odometry to a camera from a sequence's single frames, no poses.

``deepslam adapt --sequence SEQ --out DIR`` starts from the shipped models for SEQ's camera kind (or the
user's) and trains them on SEQ's own single frames with their depth (sensor depth for RGB-D, depth from the
stereo pair for KITTI / EuRoC layouts, the rendered depth of our format), with the kind's motion model, by
the recipe the shipped model was made with (:data:`RECIPES`). It writes ``DIR/model.safetensors`` (NN_cons)
and ``DIR/loops.safetensors`` (NN_loops, for ``slam --model-loops``), the two training folders
(``DIR/cons/``, ``DIR/loops/``: checkpoints, history) and ``DIR/adapt.json``, the record of what it saw.

It never opens ground-truth poses: the frames are read through a view of the sequence folder
(:func:`frames_view`) that holds the images, depth and calibration and none of the pose files, so the
result is the same, bit for bit, whether the sequence comes with poses or not. The budget is a fixed
number of samples (deterministic: same seed, same bytes); ``max_minutes`` only stops a run on a much
slower machine (the models are then written from the best epoch reached). A killed run continues with
``resume``: each stage resumes from its checkpoint, a finished stage is skipped.
"""
from __future__ import annotations

import dataclasses
import shutil
import time
from pathlib import Path

from deepslam.core import atomic
from deepslam.core.camera import check_flow_size
from deepslam.core.errors import InputError
from deepslam.core.integrity import sha256_file
from deepslam.core.kinds import kind_for_sequence
from deepslam.core.lock import output_lock
from deepslam.core.outputs import check_output_not_input
from deepslam.core.readers import open_sequence
from deepslam.core.textio import read_json_object
from deepslam.models import models_dir
from deepslam.vo.data.recipe import SyntheticData, synthetic_sources
from deepslam.vo.modelfiles import modeltree
from deepslam.vo.modelfiles.modelio import load_model
from deepslam.vo.net import NetConfig
from deepslam.vo.train import train
from deepslam.vo.trainconfig import TrainConfig


@dataclasses.dataclass(frozen=True)
class Recipe:
    """How one network of a camera kind is adapted (the shipped model's own data recipe, on new frames)."""

    start: str
    """Shipped model file name the adaptation starts from."""
    motion: tuple[str, ...]
    """Motion model specs, relative to the shipped models' folder (``motion/X.json[:loops]``)."""
    synthetic_flow: str = "exact"
    """``exact`` or the flow estimator the start model records (its options come from that record)."""
    flow_options: tuple[tuple[str, object], ...] = ()
    """Options set on top of the start model's recorded ones (recorded in the adapted model: vo and slam set
    the flow up the same)."""
    appearance_noise: float = 0.0
    """Grey levels of noise on the rendered second view."""
    camera_tilt_deg: str | None = None
    """Random camera pitch and roll of each sample (``PMIN:PMAX[:ROLL]``)."""
    frame_scales: tuple[float, ...] = (1.0,)
    """Each frame also at these scales."""
    mirror_frames: bool = False
    """Every frame also mirrored left-right."""
    bf16: bool = True
    """bf16 autocast, as the start model was trained."""


RECIPES: dict[str, dict[str, Recipe]] = {
    "tum": {
        "cons": Recipe("tum_cons.safetensors", ("motion/euroc_s1_30hz.json",), "dis", appearance_noise=6.0, bf16=False),
        "loops": Recipe("tum_loops.safetensors", ("motion/euroc_s1_30hz.json:loops",)),
    },
    "kitti": {
        "cons": Recipe("kitti_cons_dis.safetensors", ("motion/kitti_no0607_s1.json",), "dis", appearance_noise=6.0,
                       camera_tilt_deg="-1:3:1", frame_scales=(1.0, 0.65), mirror_frames=True),
        "loops": Recipe("kitti_loops_dis.safetensors", ("motion/kitti_no0607_plainloops_s1.json:loops",), "dis",
                        frame_scales=(1.0, 0.65)),
    },
    "euroc": {
        "cons": Recipe("euroc_cons.safetensors", ("motion/euroc_s1.json", "motion/room_drone_s1.json")),
        "loops": Recipe("euroc_loops.safetensors", ("motion/euroc_s1.json:loops",)),
    },
}
"""Per camera kind, the recipe of NN_cons and NN_loops."""


@dataclasses.dataclass(frozen=True)
class AdaptConfig:
    """``deepslam adapt``'s settings."""

    seed: int = 0
    """Seed of the samples, the held-out split and the shuffling."""
    cons_samples: int = 6000
    """NN_cons: samples drawn once (the pool), trained on for ``cons_epochs``."""
    cons_epochs: int = 5
    """NN_cons: epochs over its pool."""
    loops_samples: int = 3000
    """NN_loops: samples of its pool."""
    loops_epochs: int = 3
    """NN_loops: epochs over its pool."""
    nll_epochs: int = 5
    """Epochs of the uncertainty stage (each network)."""
    lr_max: float = 3e-4
    """Peak learning rate (fine-tuning: below a training run's 1e-3)."""
    frame_step: int = 1
    """Every N-th frame of the sequence."""
    max_minutes: float = 20.0
    """Safety cap of the whole run (two thirds to NN_cons); the sample budget ends it first on 2 cores."""
    threads: int = 2
    """torch threads (fixed: bf16 sums depend on the count)."""
    loops: bool = True
    """Adapt NN_loops too (SLAM's loop edges)."""
    model: str | None = None
    """Start NN_cons from this model file instead of the shipped one (its kind's recipe still applies)."""
    motion: str | None = None
    """A motion model (gen.motion JSON) for NN_cons instead of the kind's; ``:loops`` of it for NN_loops."""


_POSE_FILES = ("groundtruth.txt", "poses.txt", "state_groundtruth_estimate0", "poses")


def frames_view(seq_dir: Path, parent: Path) -> Path:
    """A folder ``parent/<the sequence folder's name>`` (readers read the camera off some names, e.g. TUM's
    freiburg id) with links to everything in ``seq_dir`` but its ground-truth poses
    (``groundtruth.txt``, EuRoC's ``state_groundtruth_estimate0``; KITTI's poses sit outside the sequence
    folder and are not linked). Our format's reader needs a ``poses.txt``: the view's holds identity poses,
    which nothing in the synthetic data reads (frames, depth and the camera are all it takes).

    Returns the view's path."""
    if parent.exists():
        shutil.rmtree(parent)
    view = parent / seq_dir.resolve().name
    view.mkdir(parents=True)

    def link(src: Path, dst: Path) -> None:
        if src.name in _POSE_FILES:
            return
        if src.is_dir() and src.name == "mav0":  # EuRoC: descend to leave its ground-truth folder out
            dst.mkdir()
            for child in sorted(src.iterdir()):
                link(child, dst / child.name)
            return
        dst.symlink_to(src.resolve())

    for child in sorted(seq_dir.iterdir()):
        link(child, view / child.name)
    if (seq_dir / "sequence.json").is_file():
        n = len(list((seq_dir / "rgb").glob("*.png")))
        atomic.write_text(view / "poses.txt", "1 0 0 0 0 1 0 0 0 0 1 0\n" * n)
    return view


def _stage(which: str, recipe: Recipe, start: Path, frames: str, cfg: AdaptConfig, out: Path, minutes: float,
           resume: bool, progress: bool, tensorboard: Path | None = None) -> dict:
    """Fine-tune ``start`` on ``frames`` by ``recipe``; the model lands in ``out/model.safetensors`` (TensorBoard
    scalars in ``tensorboard``, None: none)."""
    tree = modeltree.read_header_tree(start)
    meta = modeltree.meta(tree)
    net = NetConfig.from_dict(modeltree.net_config(tree))
    motion = tuple(str(models_dir() / m) for m in recipe.motion)
    if cfg.motion:
        motion = (cfg.motion + (":loops" if which == "loops" else ""),)
    options = ()
    if recipe.synthetic_flow != "exact":
        options = tuple({**(meta.get("flow") or {}).get("options", {}), **dict(recipe.flow_options)}.items())
    samples = cfg.cons_samples if which == "cons" else cfg.loops_samples
    epochs = cfg.cons_epochs if which == "cons" else cfg.loops_epochs
    spec = SyntheticData(frames=(frames,), motion=motion, frame_step=cfg.frame_step, samples_per_epoch=samples,
                         holdout_samples=max(128, samples // 10), synthetic_flow=recipe.synthetic_flow,
                         flow_options=options, frame_scales=recipe.frame_scales, appearance_noise=recipe.appearance_noise,
                         data_threads=cfg.threads, sample_pool=samples if recipe.synthetic_flow != "exact" else 0,
                         camera_tilt_deg=recipe.camera_tilt_deg, mirror_frames=recipe.mirror_frames)
    train_cfg = TrainConfig(net=net, lr_max=cfg.lr_max, lr_min=cfg.lr_max / 10, max_epochs=epochs,
                            max_minutes=minutes, nll_epochs=cfg.nll_epochs, seed=cfg.seed, bf16=recipe.bf16,
                            threads=cfg.threads, init=str(start),
                            loss="mse")  # the shipped models it starts from were trained with the MSE
    train_src, hold_src, data_meta = synthetic_sources(spec, net, cfg.seed, progress)
    run_meta = {"mode": "adapt", **data_meta, "adapted_from": {"file": start.name, "sha256": sha256_file(start)}}
    if meta.get("pose"):
        run_meta["pose"] = meta["pose"]  # the start model's pose mode (deepslam set-pose) carries over
    res = train(train_cfg, train_src, hold_src, out, resume=resume, progress=progress, meta=run_meta,
                tensorboard=tensorboard)
    return {"model": str(res.model_path), "stop_reason": res.stop_reason, "best_val_loss": res.best_val_loss,
            "holdout_nll": res.holdout_nll, "epochs": sum(1 for h in res.history if h["stage"] == 1)}


def _run(seq_dir: Path, out: Path, cfg: AdaptConfig, resume: bool, progress: bool,
         tensorboard: Path | None) -> tuple[dict, str, int]:
    """The stages of :func:`adapt` into ``out``: (results per stage, camera kind, frames)."""
    view = frames_view(seq_dir, out / "frames_view")  # the frames without the pose files
    seq = open_sequence(view)
    check_flow_size(seq.camera.width, seq.camera.height, seq_dir)  # named in the user's folder, not the view
    kind = kind_for_sequence(seq)
    if kind not in RECIPES:
        raise InputError(seq_dir, f"no adaptation recipe for camera kind {kind!r}")
    settings = {"sequence": str(seq_dir.resolve()), "kind": kind, "config": dataclasses.asdict(cfg)}
    if (out / "settings.json").is_file():
        if read_json_object(out / "settings.json", "adapt settings") != settings:
            raise InputError(out / "settings.json", "cannot resume: another sequence or other settings")
    else:
        atomic.write_json(out / "settings.json", settings)
    stages = [("cons", cfg.max_minutes * (2 / 3 if cfg.loops else 1.0))]
    if cfg.loops:
        stages.append(("loops", cfg.max_minutes / 3))
    results = {}
    for which, minutes in stages:
        recipe = RECIPES[kind][which]
        start = Path(cfg.model) if which == "cons" and cfg.model else models_dir() / recipe.start
        stage_dir = out / which
        done = (stage_dir / "model.safetensors").is_file()
        if not done:
            results[which] = _stage(which, recipe, start, str(view), cfg, stage_dir, minutes,
                                    resume and stage_dir.exists(), progress,
                                    None if tensorboard is None else tensorboard / which)
        else:
            results[which] = {"model": str(stage_dir / "model.safetensors"), "stop_reason": "finished earlier"}
        target = out / ("model.safetensors" if which == "cons" else "loops.safetensors")
        shutil.copyfile(stage_dir / "model.safetensors", target)
        results[which].update(file=target.name, sha256=sha256_file(target), start=start.name)
    return results, kind, len(seq)


def adapt(seq_dir: str | Path, out: str | Path, cfg: AdaptConfig = AdaptConfig(), resume: bool = False,
          progress: bool = True, tensorboard: str | Path | None = None) -> dict:
    """Adapt NN_cons (and NN_loops) to the sequence ``seq_dir``; returns the record written to
    ``out/adapt.json``.

    ``tensorboard``: a folder for TensorBoard scalars of the training runs, one run per network
    (``cons/``, ``loops/``; the scalars of :func:`vo.train.train`). None: none. It is not a setting: the
    models are the same bytes with or without it, and a resumed run may add or drop it.

    Raises:
        InputError: the sequence cannot be read, has no depth for its frames, or ``out`` holds another run.
    """
    seq_dir, out = Path(seq_dir), Path(out)
    check_output_not_input(out, [("--sequence", seq_dir), ("--model", cfg.model), ("--motion", cfg.motion)])
    if not 0 <= cfg.seed < 2**32:
        raise InputError(None, f"--seed must be in 0..{2**32 - 1}, got {cfg.seed}")
    if cfg.model:
        load_model(cfg.model)  # the kind of file checked before any work: a pickle, a flow model, an ensemble
    t0 = time.perf_counter()
    record_path = out / "adapt.json"
    if out.exists() and any(out.iterdir()) and not resume:
        raise InputError(out, "output folder is not empty; pass --resume to continue an adapt run or choose another --out")
    if resume and out.exists() and any(out.iterdir()) and not (out / "settings.json").is_file():
        raise InputError(out, "holds no adapt run to resume (no settings.json)")
    created = not out.exists()
    # one run a folder: a second adapt into it is refused at once, naming the first
    with output_lock(out):
        try:
            results, kind, n_frames = _run(seq_dir, out, cfg, resume, progress,
                                           None if tensorboard is None else Path(tensorboard))
        except InputError:
            # bad input found before any training: the folder this run created goes (an interrupted run keeps
            # its checkpoints for --resume)
            if created and not any((out / w / f).is_file() for w in ("cons", "loops")
                                   for f in ("checkpoint.safetensors", "model.safetensors")):
                shutil.rmtree(out, ignore_errors=True)
            raise
        record = {"sequence": str(seq_dir.resolve()), "kind": kind, "frames": n_frames, "poses_opened": False,
                  "config": dataclasses.asdict(cfg), "stages": results, "seconds": round(time.perf_counter() - t0, 1)}
        atomic.write_json(record_path, record)
    return record
