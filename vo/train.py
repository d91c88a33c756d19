"""Two-stage training of a :class:`vo.net.PoseNet` (either pose head) with the paper's recipe, checkpoints and resume.

Stage 1 (motion): Adam with amsgrad, batch 128, a cyclic learning rate (triangular, between
``lr_min`` and ``lr_max``, torch's CyclicLR stepped every batch), loss
``rot_weight * L1(euler) + L1(translation)`` with ``rot_weight = 50`` (``loss="mse"``: squared errors). After every epoch the loss on
the held-out samples is measured; after ``patience_epochs`` epochs without improvement both bounds of
the cycle are halved; training stops when the lower bound falls below ``lr_stop`` (1e-5), or at the
``max_epochs`` / ``max_samples`` / ``max_minutes`` caps. The sample and time caps are checked after
every batch: a capped epoch ends early, is evaluated on the held-out set like a full one (its history
row says ``partial``), and the time cap leaves room for that evaluation and stage 2, so a run takes
about ``max_minutes`` of training. The weights with the best held-out loss are kept.

Stage 2 (uncertainty): everything but the per-DoF log-std heads is frozen (``requires_grad=False``, and
only the heads are given to the optimizer, so frozen weights stay bit-identical); the heads are trained
on the held-out samples (10 % of the data, never used for a gradient in stage 1) with the Gaussian
negative log-likelihood for ``nll_epochs`` epochs. As the trunk is frozen, its features over the
held-out set are computed once (:func:`head_inputs`) and each stage-2 epoch runs only the two small
heads: the stage costs one forward pass over the held-out set, not ``nll_epochs`` of them.

Every epoch ends with an atomic checkpoint (``checkpoint.safetensors``: model, optimizer, scheduler, best
weights, epoch, stage, history, RNG states, config). Data batches are a function of (seed, epoch)
(:mod:`vo.data.samples`), so a run killed at any moment and resumed from its checkpoint ends with exactly
the weights of an uninterrupted run (same threads, same machine). A non-finite loss raises
:class:`TrainingDiverged` and leaves the last good checkpoint in place.

The output folder, caps, clock, checkpoint and history files, resume checks, divergence check, progress
and loggers (``tensorboard``) are the shared training runner's (:mod:`deepslam.runtime.training`, also
behind :mod:`deepslam.flow.train`); this module keeps the network, losses, data and stages.
"""
from __future__ import annotations

import copy
import dataclasses
import math
import time
from pathlib import Path
from typing import Iterator, Protocol

import torch
import torch.distributed as dist

from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.core.plots import new_figure, save_figure
from deepslam.runtime.training import CAPS, Caps, Runner, check_finite, open_run
from deepslam.runtime.training import TrainingDiverged  # noqa: F401 - part of this module's API
from deepslam.vo.data.samples import epoch_seed
from deepslam.vo.distributed import agree, world
from deepslam.vo.modelfiles.modelio import load_checkpoint, load_model, make_net, save_checkpoint, save_model
from deepslam.vo.net import PoseNet, gaussian_nll, pose_loss
from deepslam.vo.trainconfig import TrainConfig


CHECKPOINT = "checkpoint.safetensors"
MODEL = "model.safetensors"
LEGACY_CHECKPOINT = "checkpoint.pt"
"""The pickle-based checkpoint of older versions (refused; ``deepslam convert-model`` converts it)."""
CONFIG = "config.json"
HISTORY = "history.json"


class Source(Protocol):
    """A deterministic supplier of batches (see :mod:`vo.data.samples`, :mod:`vo.data.synthetic`)."""

    def __len__(self) -> int: ...

    def batches(self, epoch: int, batch_size: int, rank: int = 0, world: int = 1) -> Iterator[dict[str, torch.Tensor]]: ...


@dataclasses.dataclass
class TrainResult:
    out_dir: Path
    model_path: Path
    history: list[dict]
    stop_reason: str
    best_val_loss: float
    holdout_nll: float | None


def initial_weights(cfg: TrainConfig) -> PoseNet:
    """The network of the model file ``cfg.init`` (the start of a fine-tuning run); InputError when the file is
    not a single-network VO model or holds another network than ``cfg.net``."""
    start, _ = load_model(cfg.init)
    if not isinstance(start, PoseNet):
        raise InputError(cfg.init, "is not a single-network VO model (an ensemble cannot start a training run)")
    if start.cfg.to_dict() != cfg.net.to_dict():
        raise InputError(cfg.init, "its network differs from the one to train; cannot start from it")
    return start


def new_model(cfg: TrainConfig) -> PoseNet:
    """The initial network, its weights drawn from ``cfg.seed`` (the global RNG is left as it was)."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        return make_net(cfg.net)


def _autocast(cfg: TrainConfig):
    return torch.autocast(torch.device(cfg.device).type, dtype=torch.bfloat16, enabled=cfg.bf16)


def _on(cfg: TrainConfig, b: dict) -> dict:
    """A batch on the training device (pinned and non-blocking to CUDA; untouched on the CPU and where a
    tensor is there already, as synthetic flow made on the GPU)."""
    dev = torch.device(cfg.device)
    if dev.type == "cpu":
        return b
    return {k: v if v.device.type == dev.type else v.pin_memory().to(dev, non_blocking=True) for k, v in b.items()}


def _step_size(cfg: TrainConfig, n_train: int) -> int:
    if cfg.lr_half_cycle_steps > 0:
        return cfg.lr_half_cycle_steps
    return max(1, math.ceil(n_train / cfg.batch_size))


def _stage1_optim(model: PoseNet, cfg: TrainConfig, n_train: int):
    opt = torch.optim.Adam(model.motion_parameters(), lr=cfg.lr_min, amsgrad=True)
    sched = torch.optim.lr_scheduler.CyclicLR(opt, base_lr=cfg.lr_min, max_lr=cfg.lr_max,
                                              step_size_up=_step_size(cfg, n_train), mode="triangular",
                                              cycle_momentum=False)
    return opt, sched


def _stage2_optim(model: PoseNet, cfg: TrainConfig):
    for p in model.motion_parameters():
        p.requires_grad_(False)
    return torch.optim.Adam(model.uncertainty_parameters(), lr=cfg.nll_lr, amsgrad=True)


@torch.no_grad()
def evaluate(model: PoseNet, source: Source, cfg: TrainConfig) -> dict:
    """Held-out figures: pose loss, Gaussian NLL, RMSE per DoF (weighted by batch sizes)."""
    model.eval()
    n, loss, nll, se = 0, 0.0, 0.0, torch.zeros(6, dtype=torch.float64)
    for b in source.batches(0, cfg.batch_size):
        b = _on(cfg, b)
        with _autocast(cfg):
            mean, log_std = model(b["flow"], b["intrinsics"], b.get("inv_depth"))
        k = len(b["target"])
        loss += float(pose_loss(mean, b["target"], cfg.rot_weight, cfg.loss)) * k
        nll += float(gaussian_nll(mean, log_std, b["target"])) * k
        se += ((mean.double() - b["target"].double()) ** 2).sum(0).cpu()
        n += k
    return {"loss": loss / max(n, 1), "nll": nll / max(n, 1), "rmse6": (se / max(n, 1)).sqrt().tolist()}


@dataclasses.dataclass
class HeadInputs:
    """What the frozen trunk gives for a fixed sample set: stage 2 trains the log-std heads on it
    without running the convolutions again (they cannot change while frozen).

    hr, ht: (N, hidden_units) float32 features of the rotation and translation branches (for a solve-head
        network, :class:`vo.geometry.posesolve.FlowSolvePoseNet`: (N, 6) the solved pose and its log-std feature).
    mean: (N, 6) float32 predicted paper vectors; target: (N, 6) float32 labels.
    """

    hr: torch.Tensor
    ht: torch.Tensor
    mean: torch.Tensor
    target: torch.Tensor

    def __len__(self) -> int:
        return len(self.target)

    def rmse6(self) -> torch.Tensor:
        """(6,) float64 root-mean-square error of ``mean`` against ``target`` per DoF, on their device."""
        return ((self.mean.double() - self.target.double()) ** 2).mean(0).sqrt()


@torch.no_grad()
def head_inputs(model: PoseNet, source: Source, cfg: TrainConfig) -> HeadInputs:
    """One pass of the trunk over ``source`` (its epoch-0 batches, in their order)."""
    model.eval()
    parts: list[tuple[torch.Tensor, ...]] = []
    for b in source.batches(0, cfg.batch_size):
        b = _on(cfg, b)
        with _autocast(cfg):
            hr, ht = model.trunk(b["flow"], b["intrinsics"], b.get("inv_depth"))
        parts.append((hr, ht, model.mean_head(hr, ht), b["target"].float()))
    return HeadInputs(*(torch.cat([p[i] for p in parts]) for i in range(4)))


@torch.no_grad()
def evaluate_heads(model: PoseNet, hi: HeadInputs, cfg: TrainConfig) -> dict:
    """:func:`evaluate`'s figures from cached trunk features."""
    log_std = model.log_std_head(hi.hr, hi.ht)
    return {"loss": float(pose_loss(hi.mean, hi.target, cfg.rot_weight, cfg.loss)),
            "nll": float(gaussian_nll(hi.mean, log_std, hi.target)), "rmse6": hi.rmse6().cpu().tolist()}


def uncertainty_epoch(model: PoseNet, hi: HeadInputs, cfg: TrainConfig, opt: torch.optim.Optimizer, epoch: int,
                      deadline: float | None = None) -> tuple[float, bool]:
    """One stage-2 epoch: the Gaussian NLL through the log-std heads only (``opt`` holds just their
    parameters), over the cached features in an order drawn from (seed, epoch).

    Returns:
        (mean NLL over the batches run, whether ``deadline`` (time.perf_counter()) cut the epoch short).
    """
    model.train()
    g = torch.Generator().manual_seed(epoch_seed(cfg.seed, epoch, 0x2))
    order = torch.randperm(len(hi), generator=g).to(hi.target.device)
    nll_sum, n_seen = 0.0, 0
    for step, s in enumerate(range(0, len(hi), cfg.batch_size)):
        idx = order[s:s + cfg.batch_size]
        loss = gaussian_nll(hi.mean[idx], model.log_std_head(hi.hr[idx], hi.ht[idx]), hi.target[idx])
        _check_finite(loss, "stage-2 (NLL)", epoch, step, cfg.nll_lr)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        nll_sum += float(loss.detach()) * len(idx)
        n_seen += len(idx)
        if deadline is not None and time.perf_counter() >= deadline:
            return nll_sum / max(n_seen, 1), True
    return nll_sum / max(n_seen, 1), False


def fit_uncertainty(model: PoseNet, source: Source, cfg: TrainConfig, epochs: int) -> list[float]:
    """The whole second stage on a trained model: freeze all but the log-std heads, start them at
    log(held-out RMSE), train them ``epochs`` epochs with the NLL. Returns the NLL per epoch."""
    hi = head_inputs(model, source, cfg)
    init_log_std(model, hi)
    opt = _stage2_optim(model, cfg)
    return [uncertainty_epoch(model, hi, cfg, opt, ep)[0] for ep in range(epochs)]


@torch.no_grad()
def init_log_std(model: PoseNet, hi: HeadInputs) -> list[float]:
    """Start stage 2 calibrated to the held-out RMSE per DoF (the model's ``calibrate_log_std``: for the
    paper's network a constant log(RMSE); for the solve head its own log-std feature shifted to it)."""
    rmse = hi.rmse6().float().clamp_min(1e-5)
    model.calibrate_log_std(hi.ht, rmse)
    return rmse.tolist()


MAY_CHANGE = ("max_epochs", "max_minutes", "max_samples", "threads", "device")
"""The settings a resumed run may change: its caps and where it runs."""

DIVERGED_HINT = "lower --lr-max or check the training data for NaN/inf"


def caps(cfg: TrainConfig) -> Caps:
    """Stage 1's caps (the time cap spans both stages)."""
    return Caps(max_epochs=cfg.max_epochs, max_minutes=cfg.max_minutes if cfg.max_minutes > 0 else None,
                max_samples=cfg.max_samples if cfg.max_samples > 0 else None)


def _check_finite(loss: torch.Tensor, stage: str, epoch: int, step: int, lr: float) -> None:
    check_finite(loss, f"{stage} loss", f"at epoch {epoch + 1}, step {step + 1}", DIVERGED_HINT, lr)


def train(cfg: TrainConfig, train_source: Source, holdout_source: Source, out_dir: str | Path,
          resume: bool = False, progress: bool = True, meta: dict | None = None,
          half_weights: bool = False, tensorboard: str | Path | None = None) -> TrainResult:
    """Run both stages, writing ``checkpoint.safetensors`` every epoch and ``model.safetensors`` at the end.

    Args:
        cfg: the training configuration.
        train_source, holdout_source: deterministic batch sources (:mod:`vo.data.samples`, :mod:`vo.data.synthetic`);
            the holdout set is stage 1's validation set and stage 2's training set.
        out_dir: output folder (``config.json``, ``checkpoint.safetensors``, ``history.json``, ``model.safetensors``,
            ``loss.png``).
        resume: continue from ``out_dir/checkpoint.safetensors`` (whose config must equal ``cfg``).
        meta: JSON-able description of the data, stored in config.json and the model file.
        half_weights: store the model file's weights as float16.
        tensorboard: a folder for TensorBoard scalars (:class:`runtime.training.TensorBoardLogger`): per
            stage-1 step ``stage1/step/loss`` and ``stage1/step/lr`` (x: training samples), per epoch every
            number of the history row as ``stage1/<field>`` and ``stage2/<field>`` (x: epoch). None: none.

    Raises:
        TrainingDiverged: a non-finite loss.
        core.errors.InputError: ``resume`` with a checkpoint of another configuration.
    """
    rank, _ = world()
    out = Path(out_dir)

    def refuse(folder: Path) -> None:
        if (folder / LEGACY_CHECKPOINT).is_file() and not (folder / CHECKPOINT).exists():
            raise InputError(folder / LEGACY_CHECKPOINT, "a pickle-based checkpoint of an older version; convert it "
                             f"once with `deepslam convert-model {folder / LEGACY_CHECKPOINT}` (or choose another --out)")

    # one writer: a second run into this folder is refused while this one runs (data-parallel: rank 0 is
    # the writer and checks the folder; the other ranks only train)
    with open_run(out, caps(cfg), resume=resume, checkpoint_name=CHECKPOINT, threads=cfg.threads, writer=rank == 0,
                  progress=progress, tensorboard=tensorboard, refuse=refuse) as run:
        return _train(cfg, train_source, holdout_source, run, resume, meta, half_weights)


def _train(cfg: TrainConfig, train_source: Source, holdout_source: Source, run: Runner, resume: bool,
           meta: dict | None, half_weights: bool) -> TrainResult:
    rank, n_ranks = world()
    out_dir = run.out_dir
    meta = dict(meta or {})
    ckpt_path = run.checkpoint_path
    model = new_model(cfg)
    if cfg.init and not (resume and ckpt_path.is_file()):
        model.load_state_dict(initial_weights(cfg).state_dict())
    model = model.to(torch.device(cfg.device))
    if cfg.channels_last:
        model.set_channels_last(True)
    if n_ranks > 1:
        dist.barrier()  # rank 0 has checked the folder
        # stage 1 trains the motion only: the log-std heads stay out of DDP's gradient reduction
        for p in model.uncertainty_parameters():
            p.requires_grad_(False)
        step_model = torch.nn.parallel.DistributedDataParallel(
            model, device_ids=[torch.device(cfg.device).index] if torch.device(cfg.device).type == "cuda" else None)
        for p in model.uncertainty_parameters():
            p.requires_grad_(True)
    else:
        step_model = model
    n_train = len(train_source)
    if n_train == 0 or len(holdout_source) == 0:
        raise InputError(None, f"no training data ({n_train} training and {len(holdout_source)} held-out samples)")
    opt, sched = _stage1_optim(model, cfg, n_train)
    state = {"stage": 1, "epoch": 0, "nll_epoch": 0, "best_val": math.inf, "best_state": None,
             "since_best": 0, "history": [], "elapsed_s": 0.0, "stop_reason": None, "halvings": 0, "samples": 0,
             "eval_s": None}
    stage1_saved: dict | None = None  # stage 1's last model/optimizer/scheduler, kept through stage 2
    ck = run.resume(load_checkpoint, cfg.to_dict(), MAY_CHANGE) if resume else None
    if ck is not None:
        state = ck["train_state"]
        stage1_saved = ck.get("stage1")
        stopped = str(state["stop_reason"]).partition(";")[0]
        cap_raised = stopped in CAPS and stopped not in run.reached(state["epoch"], samples=state["samples"],
                                                                    elapsed_s=state["elapsed_s"])
        if cap_raised and stage1_saved is not None:
            # stage 1 stopped at a cap that is now higher: go back to its end and carry on
            state["stage"], state["nll_epoch"], state["stop_reason"] = 1, 0, None
            state["history"] = [h for h in state["history"] if h["stage"] == 1]
            model.load_state_dict(stage1_saved["model"])
            opt.load_state_dict(stage1_saved["optimizer"])
            sched.load_state_dict(stage1_saved["scheduler"])
        else:
            model.load_state_dict(ck["model"])
            if state["stage"] == 1:
                opt.load_state_dict(ck["optimizer"])
                sched.load_state_dict(ck["scheduler"])
        run.say(f"resuming {ckpt_path}: stage {state['stage']}, epoch {state['epoch']}, "
                f"{state['nll_epoch']} NLL epochs")
    config_doc = {"train": cfg.to_dict(), "data": meta, "torch": torch.__version__,
                  "threads": torch.get_num_threads(), "data_parallel_ranks": n_ranks}
    if run.writer:
        atomic.write_json(out_dir / CONFIG, config_doc)

    def checkpoint(opt_, sched_):
        nonlocal stage1_saved
        if state["stage"] == 1:
            stage1_saved = {"model": model.state_dict(), "optimizer": opt_.state_dict(), "scheduler": sched_.state_dict()}
        run.checkpoint(lambda path: save_checkpoint(path, {
            "config": cfg.to_dict(), "model": model.state_dict(), "train_state": state, "optimizer": opt_.state_dict(),
            "scheduler": sched_.state_dict() if sched_ else None, "stage1": stage1_saved, **run.rng_states(),
            "meta": meta}))

    run.start(state["elapsed_s"], state["history"])  # training time so far, over resumes
    n_hold = len(holdout_source)

    # ---------------- stage 1: motion
    while state["stage"] == 1:
        reached = run.reached(state["epoch"], samples=state["samples"])
        reason = reached[0] if reached else ("lr_below_stop" if sched.base_lrs[0] < cfg.lr_stop else None)
        if reason is not None:
            state["stop_reason"] = reason
            break
        epoch = state["epoch"]
        model.train()
        t0 = time.perf_counter()
        n_seen, n_local, loss_sum = 0, 0, 0.0
        planned = n_train if cfg.max_samples <= 0 else min(n_train, cfg.max_samples - state["samples"])
        bar = run.bar(planned, f"epoch {epoch + 1}", "sample", leave=False)
        # (a source of one's own needs the rank arguments only for data-parallel training)
        epoch_batches = (train_source.batches(epoch, cfg.batch_size) if n_ranks == 1
                         else train_source.batches(epoch, cfg.batch_size, rank, n_ranks))
        for step, b in enumerate(epoch_batches):
            b = _on(cfg, b)
            with _autocast(cfg):
                mean, _ = step_model(b["flow"], b["intrinsics"], b.get("inv_depth"))
            loss = pose_loss(mean, b["target"], cfg.rot_weight, cfg.loss)
            _check_finite(loss, "stage-1", epoch, step, sched.get_last_lr()[0])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            k_local = len(b["target"])
            n_local += k_local
            step_loss = float(loss.detach())
            loss_sum += step_loss * k_local  # this rank's samples (the bar shows rank 0's loss)
            sps = (n_seen + k_local * n_ranks) / (time.perf_counter() - t0)
            # time left for training once the last held-out evaluation and stage 2 are paid for:
            # each is about one forward pass over the held-out set (forward ~3x a training step)
            eval_s = state.get("eval_s") or n_hold / (3.0 * sps)
            left_s = run.time_left() - 2.2 * eval_s - 3.0
            samples_after = state["samples"] + k_local * n_ranks  # exact once the ranks agree below
            stop = (cfg.max_samples > 0 and samples_after >= cfg.max_samples) or left_s <= 0
            k, stop = agree(k_local, stop, torch.device(cfg.device))  # every rank stops at the same step
            n_seen += k
            state["samples"] += k
            if stop:
                reason = "max_samples" if cfg.max_samples > 0 and state["samples"] >= cfg.max_samples else "max_minutes"
            if math.isfinite(left_s):  # the bar ends where the time cap will end the epoch
                bar.total = max(n_seen, min(planned, n_seen + int(sps * max(left_s, 0.0))))
            bar.update(k)
            bar.set_postfix(loss=f"{loss_sum / max(n_local, 1):.4g}", sps=f"{sps:.0f}", lr=f"{sched.get_last_lr()[0]:.2g}")
            run.log({"stage1/step/loss": step_loss, "stage1/step/lr": sched.get_last_lr()[0]}, state["samples"])
            if reason is not None:
                break
        bar.close()
        dt = time.perf_counter() - t0
        te = time.perf_counter()
        val = evaluate(model, holdout_source, cfg)
        state["eval_s"] = time.perf_counter() - te
        check_finite(val["loss"], "held-out loss", f"after epoch {epoch + 1}", "lower --lr-max or check the data")
        improved = val["loss"] < state["best_val"]
        if improved:
            state["best_val"] = val["loss"]
            state["best_state"] = copy.deepcopy(model.state_dict())
            state["since_best"] = 0
        else:
            state["since_best"] += 1
            if state["since_best"] >= cfg.patience_epochs:
                sched.base_lrs = [x / 2 for x in sched.base_lrs]
                sched.max_lrs = [x / 2 for x in sched.max_lrs]
                state["since_best"] = 0
                state["halvings"] += 1
        state["epoch"] = epoch + 1
        state["elapsed_s"] = run.elapsed()
        row = {"stage": 1, "epoch": epoch + 1, "train_loss": loss_sum / max(n_local, 1), "val_loss": val["loss"],
               "val_rmse6": val["rmse6"], "lr_min": sched.base_lrs[0], "lr_max": sched.max_lrs[0],
               "samples_per_s": n_seen / dt, "seconds": dt, "samples": n_seen, "partial": n_seen < n_train}
        run.record(row, epoch + 1, "stage1", skip=("stage", "epoch"))
        run.say(f"epoch {epoch + 1}: train {row['train_loss']:.4g}  held-out {val['loss']:.4g}"
                f"{' *' if improved else ''}  lr [{row['lr_min']:.2g}, {row['lr_max']:.2g}]  "
                f"{row['samples_per_s']:.0f} samples/s" + (f"  ({n_seen} of {n_train} samples)" if row["partial"] else ""))
        if reason is not None:
            state["stop_reason"] = reason
        checkpoint(opt, sched)
        if reason is not None:
            break

    # ---------------- stage 2: uncertainty (the log-std heads on cached trunk features)
    if state["stage"] == 1:
        if state["best_state"] is not None:
            model.load_state_dict(state["best_state"])
        state["stage"] = 2
        hi = head_inputs(model, holdout_source, cfg)
        init_log_std(model, hi)
        opt2 = _stage2_optim(model, cfg)
        state["elapsed_s"] = run.elapsed()
        checkpoint(opt2, None)
    else:
        opt2 = _stage2_optim(model, cfg)
        if state["stage"] == 2 and ck is not None:
            opt2.load_state_dict(ck["optimizer"])
        hi = head_inputs(model, holdout_source, cfg)
    deadline = run.deadline()
    while state["stage"] == 2 and state["nll_epoch"] < cfg.nll_epochs:
        if deadline is not None and time.perf_counter() >= deadline:
            state["stop_reason"] = f"{state['stop_reason']}; stage 2 cut by the time cap after {state['nll_epoch']} of " \
                                   f"{cfg.nll_epochs} epochs"
            break
        ep = state["nll_epoch"]
        nll, cut = uncertainty_epoch(model, hi, cfg, opt2, ep, deadline)
        state["nll_epoch"] = ep + 1
        state["elapsed_s"] = run.elapsed()
        run.record({"stage": 2, "epoch": ep + 1, "holdout_nll": nll, "partial": cut}, ep + 1, "stage2",
                   skip=("stage", "epoch"))
        checkpoint(opt2, None)
    if state["stage"] == 2:
        state["stage"] = 3
        checkpoint(opt2, None)

    final = evaluate_heads(model, hi, cfg)
    summary = {"stop_reason": state["stop_reason"], "epochs": state["epoch"], "nll_epochs": state["nll_epoch"],
               "best_val_loss": state["best_val"], "holdout": final, "lr_halvings": state["halvings"],
               "train_seconds": run.elapsed(), "train_samples": state["samples"]}
    # the model file holds no wall time: same seed, same bytes (the time is in summary.json beside it)
    meta_out = {**meta, "train": cfg.to_dict(), "summary": {k: v for k, v in summary.items() if k != "train_seconds"}}
    model_path = out_dir / MODEL
    if run.writer:
        save_model(model_path, model, meta_out, half=half_weights)
        atomic.write_json(out_dir / "summary.json", summary)
        _plot_history(out_dir / "loss.png", state["history"], cfg.loss, cfg.rot_weight)
    run.say(f"stopped: {_why(state['stop_reason'])} after {state['epoch']} epochs ({state.get('samples', 0)} samples, "
            f"{run.elapsed() / 60:.1f} min); held-out loss {final['loss']:.4g}, NLL {final['nll']:.4g}; wrote {model_path}")
    return TrainResult(out_dir, model_path, state["history"], state["stop_reason"], state["best_val"], final["nll"])


_WHY = {"max_epochs": "the epoch cap (--max-epochs)", "max_minutes": "the time cap (--max-minutes)",
        "max_samples": "the sample cap (--max-samples)", "lr_below_stop": "the learning rate fell below --lr-stop"}


def _why(reason: str | None) -> str:
    head, _, rest = str(reason).partition(";")
    return _WHY.get(head, str(reason)) + (f"; {rest.strip()}" if rest else "")


def stage1_loss_title(loss: str, rot_weight: float) -> str:
    """The pose loss a run trains on, as the loss plot names it (``loss``: ``"l1"`` or ``"mse"``)."""
    kind = {"l1": "L1", "mse": "MSE"}.get(loss, loss)
    return f"{rot_weight:g} {kind}(euler) + {kind}(t)"


def _plot_history(path: Path, history: list[dict], loss: str, rot_weight: float) -> None:
    s1 = [h for h in history if h["stage"] == 1]
    s2 = [h for h in history if h["stage"] == 2]
    fig = new_figure((10, 4))
    axes = fig.subplots(1, 2)
    if s1:
        axes[0].semilogy([h["epoch"] for h in s1], [h["train_loss"] for h in s1], label="train")
        axes[0].semilogy([h["epoch"] for h in s1], [h["val_loss"] for h in s1], label="held-out")
    axes[0].set(title=f"stage 1: {stage1_loss_title(loss, rot_weight)}", xlabel="epoch")
    axes[0].legend()
    if s2:
        axes[1].plot([h["epoch"] for h in s2], [h["holdout_nll"] for h in s2])
    axes[1].set(title="stage 2: Gaussian NLL (held-out)", xlabel="epoch")
    fig.tight_layout()
    save_figure(fig, path, dpi=90)


def speed_summary(cfg, preset: str, data_meta: dict, n_train: int, n_hold: int) -> str:
    """The settings that decide training speed, as the run's first lines (network, input, threads,
    bf16, layout, data source, caps)."""
    net = cfg.net
    threads = cfg.threads or torch.get_num_threads()
    if "shards" in data_meta:
        source = f"deepslam gen shards in {data_meta['shards']}"
    elif "toy_samples" in data_meta:
        source = f"{data_meta['toy_samples']} toy ground-plane samples"
    elif "frames" in data_meta:
        flow = data_meta.get("synthetic_flow") or f"exact synthetic flow at {data_meta.get('synth_factor')}x, pooled"
        pool = f", a pool of {data_meta['sample_pool']} samples" if data_meta.get("sample_pool") else ", fresh every epoch"
        source = f"{data_meta['n_train_frames']} single frames -> {flow}{pool}"
    else:
        source = f"{data_meta.get('n_pairs')} real frame pairs ({data_meta.get('flow')} flow)"
    caps = [f"{cfg.max_epochs} epochs"] + ([f"{cfg.max_samples} samples"] if cfg.max_samples else []) \
        + ([f"{cfg.max_minutes:g} min"] if cfg.max_minutes else [])
    return (f"network: {preset} preset, input {net.input_height}x{net.input_width}, {net.filters} filters, "
            f"{net.hidden_units} units; batch {cfg.batch_size}; device {cfg.device}; torch threads {threads}; "
            f"bf16 {'on' if cfg.bf16 else 'off'}; channels-last {'on' if cfg.channels_last else 'off'}\n"
            f"data: {source}; {n_train} training + {n_hold} held-out samples per epoch; "
            f"stops at {' / '.join(caps)} (whichever first), or when the learning rate falls below {cfg.lr_stop:g}")
