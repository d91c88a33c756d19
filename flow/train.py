"""Training the flow network (:class:`deepslam.flow.net.FlowNet`) on rendered pairs with exact flow.

Training (:func:`train_flow`): pairs of rendered frames (i -> i+1 with the stored forward flow, and
i+1 -> i with the stored backward flow, so both directions are seen), random crops, horizontal flips,
and photometric augmentation (brightness, contrast, gamma shared by the pair, sometimes an exposure
change between the two, Gaussian noise per image), a
multi-scale end-point-error loss against the exact flow (robust: Charbonnier). Checkpoints every
``checkpoint_steps`` (safetensors, :mod:`models.modelfile`), ``--resume``, step and time caps.

The output folder, caps, clock, checkpoint and history files, resume checks, divergence check, progress
and loggers (``tensorboard``) are the shared training runner's (:mod:`deepslam.runtime.training`, also behind
:mod:`deepslam.vo.train`); this module keeps the network's data, augmentation, losses and loop.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
import torch.utils.data
from tqdm import tqdm

from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.flow.augment import crop_pair, photometric_pair
from deepslam.flow.images import to_grey
from deepslam.flow.net import CHECKPOINT_FORMAT, MODEL_FORMAT, FlowNet, FlowNetConfig, load_flow_model
from deepslam.flow.unsup import unsupervised_loss
from deepslam.runtime.training import Caps, check_finite, open_run
from deepslam.models import modelfile

CHECKPOINT = "checkpoint.safetensors"
MODEL = "flow.safetensors"

# ---------------------------------------------------------------------------------------------------
# training


@dataclasses.dataclass(frozen=True)
class FlowTrainConfig:
    """How the flow network is trained."""

    net: FlowNetConfig = FlowNetConfig()
    """The network."""
    crop: tuple[int, int] = (128, 320)
    """Training crop (height, width) in pixels of the renders, multiples of 32."""
    batch_size: int = 8
    """Pairs per step."""
    lr: float = 1e-3
    """Adam learning rate (cosine decay to 1/20 of it over ``max_steps``)."""
    max_steps: int = 20000
    """Steps to train (the schedule's length)."""
    max_minutes: float = 0.0
    """Stop after this much training time (0: no cap); the schedule still spans ``max_steps``."""
    stop_after_steps: int = 0
    """Stop after this many steps (0: at ``max_steps``); the schedule still spans ``max_steps``. A step
    count, unlike minutes, gives the same model on every machine."""
    level_weights: tuple[float, ...] = (0.32, 0.08, 0.02, 0.01)
    """Loss weight of each estimate, finest first (PWC-Net's, per pixel of that level)."""
    seed: int = 0
    """Seed of the crops, flips and photometric draws."""
    checkpoint_steps: int = 250
    """Write a checkpoint every this many steps."""
    threads: int = 2
    """torch CPU threads."""
    device: str = "cpu"
    """Torch device to train on (``cpu``, ``cuda``, ``cuda:N``)."""
    bf16: bool = True
    """bf16 autocast of the network's forward pass (``train-flow --bf16 auto`` turns it on with CUDA and on CPUs
    that compute bf16 natively: elsewhere it is emulated, about 10x slower than float32)."""
    loader_workers: int = 0
    """Processes that build the batches ahead of the training step (0: built in the training process).
    Each step's batch is drawn from its own seed stream, so the batches (and the model) are the same
    for any count; on a GPU machine the crops and photometric draws, not the network, bound the speed."""
    init: str = ""
    """A flow model file (or training checkpoint) whose weights start the training: fine-tuning a trained
    estimator on new data (its network must be ``net``). Empty: random initialisation from ``seed``."""
    real_batch_size: int = 0
    """Real (unlabelled) pairs per step for the unsupervised loss (:mod:`flow.unsup`); 0: none."""
    real_weight: float = 1.0
    """Weight of the unsupervised loss on the real pairs against the supervised one on the renders."""
    smooth_weight: float = 4.0
    """Weight of the edge-aware smoothness term inside the unsupervised loss."""
    smooth_order: int = 1
    """Order of that smoothness term: 1 (first differences) or 2 (second differences: a linearly varying
    flow, as a plane's, is free)."""

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["net"] = self.net.to_dict()
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def initial_weights(cfg: FlowTrainConfig) -> FlowNet:
    """The network ``cfg.init`` names (fine-tuning's start); InputError when the file is missing, not a
    flow model, or holds another network than ``cfg.net``."""
    start, _ = load_flow_model(cfg.init)
    if start.cfg.to_dict() != cfg.net.to_dict():
        raise InputError(cfg.init, "its network differs from the one to train; cannot start from it")
    return start


class FlowPairs:
    """Rendered frame pairs with exact flow, in memory: (grey0, grey1, flow) uint8, uint8, float16.

    Every consecutive pair (i, i+1) of each sequence gives two samples: forward with ``flow/``, and
    backward (i+1 -> i) with ``flow_backward/`` where the sequence has it. Non-finite flow (a point
    behind the next camera) is stored as NaN and left out of the loss.
    """

    def __init__(self, sequences, progress: bool = True):
        self.grey0, self.grey1, self.flow, self.names = [], [], [], []
        for seq in sequences:
            if seq.flow_paths is None:
                raise InputError(seq.root, "sequence has no ground-truth flow (render it with flow)")
            greys = [to_grey(seq.image(i)) for i in tqdm(range(len(seq)), desc=f"images {seq.name}", leave=False,
                                                          disable=not progress)]
            for i in range(len(seq) - 1):
                f = seq.flow(i)
                if f is not None:
                    self._add(greys[i], greys[i + 1], f, f"{seq.name}:{i}>{i + 1}")
                b = seq.flow_backward(i + 1) if seq.flow_backward_paths is not None else None
                if b is not None:
                    self._add(greys[i + 1], greys[i], b, f"{seq.name}:{i + 1}>{i}")
        if not self.flow:
            raise InputError(None, "no frame pairs with flow to train on")

    def _add(self, g0, g1, flow, name):
        self.grey0.append(g0)
        self.grey1.append(g1)
        flow = np.asarray(flow, np.float32)
        # float16 holds |x| < 65504: a larger (non-physical) flow is stored as NaN, left out of the loss
        self.flow.append(np.where(np.abs(flow) < np.finfo(np.float16).max, flow, np.nan).astype(np.float16))
        self.names.append(name)

    def __len__(self) -> int:
        return len(self.flow)

    def min_size(self) -> tuple[int, int]:
        """(height, width) of the smallest frame, pixels."""
        return min(g.shape[0] for g in self.grey0), min(g.shape[1] for g in self.grey0)

    def batch(self, rng: np.random.Generator, n: int, crop: tuple[int, int]) -> dict[str, torch.Tensor]:
        """``n`` augmented crops: img0, img1 (n, 1, h, w) float in [0, 1], flow (n, 2, h, w) px (NaN: no label)."""
        ch, cw = crop
        i0, i1, fl = [], [], []
        for k in rng.integers(0, len(self), n):
            a, b, (y, x) = crop_pair(rng, self.grey0[k], self.grey1[k], crop, "frames")
            ff = self.flow[k][y:y + ch, x:x + cw].astype(np.float32).transpose(2, 0, 1).copy()
            if rng.random() < 0.5:  # mirror: u flips sign
                a, b, ff = a[:, ::-1], b[:, ::-1], ff[:, :, ::-1]
                ff[0] = -ff[0]
            a, b = photometric_pair(a, b, rng)
            i0.append(a)
            i1.append(b)
            fl.append(np.ascontiguousarray(ff))
        return {"img0": torch.from_numpy(np.stack(i0)[:, None]), "img1": torch.from_numpy(np.stack(i1)[:, None]),
                "flow": torch.from_numpy(np.stack(fl))}


class _StepBatch(torch.utils.data.Dataset):
    """Item ``i``: the batch of training step ``first + i``, drawn from the step's own seed stream."""

    def __init__(self, pairs, cfg: "FlowTrainConfig", first: int, last: int):
        self.pairs, self.cfg, self.first, self.last = pairs, cfg, first, last

    def __len__(self) -> int:
        return max(0, self.last - self.first)

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        rng = np.random.default_rng([self.cfg.seed, self.first + i])
        return self.pairs.batch(rng, self.cfg.batch_size, self.cfg.crop)


def step_batches(pairs, cfg: "FlowTrainConfig", first: int, last: int, pin: bool = False):
    """Generator of the training batches of steps ``first`` .. ``last - 1`` in order, each from
    ``np.random.default_rng([cfg.seed, step])``: the same tensors whether ``cfg.loader_workers`` processes
    build them ahead (torch DataLoader, ``pin``: page-locked for a fast copy to the GPU) or this one does."""
    steps = _StepBatch(pairs, cfg, first, last)
    if cfg.loader_workers <= 0:
        for i in range(len(steps)):
            yield steps[i]
        return
    loader = torch.utils.data.DataLoader(steps, batch_size=None, shuffle=False, num_workers=cfg.loader_workers,
                                         pin_memory=pin, prefetch_factor=4, persistent_workers=False)
    it = iter(loader)
    try:
        yield from it
    finally:
        del it  # stops the workers when training ends before the last step (a time cap)


def multiscale_loss(outs: list[torch.Tensor], flow_gt: torch.Tensor, weights) -> torch.Tensor:
    """Sum over levels of weight * mean Charbonnier end-point error against the label averaged down
    to that level (its values scaled to that level's pixels); NaN labels are left out."""
    valid = torch.isfinite(flow_gt).all(1, keepdim=True).float()
    gt = torch.nan_to_num(flow_gt, nan=0.0)
    total = flow_gt.new_zeros(())
    for out, wgt in zip(reversed(outs), weights):  # finest first
        h, w = out.shape[-2:]
        s = flow_gt.shape[-1] / w
        v = F.adaptive_avg_pool2d(valid, (h, w))
        g = F.adaptive_avg_pool2d(gt * valid, (h, w)) / v.clamp_min(1e-6) / s
        epe = torch.sqrt(((out - g) ** 2).sum(1, keepdim=True) + 1e-6)
        m = (v > 0.5).float()
        total = total + wgt * (epe * m).sum() / m.sum().clamp_min(1.0) * (h * w) ** 0.5 / 16.0
    return total


MAY_CHANGE = ("max_minutes", "threads", "stop_after_steps", "device", "loader_workers")
"""The settings a resumed run may change: its caps and where (and with how many loader processes) it runs."""


def caps(cfg: FlowTrainConfig) -> Caps:
    """Where the training stops: ``stop_after_steps`` (when below ``max_steps``) or ``max_steps``, and
    ``max_minutes``."""
    last = cfg.stop_after_steps if 0 < cfg.stop_after_steps < cfg.max_steps else cfg.max_steps
    return Caps(max_steps=last, max_minutes=cfg.max_minutes if cfg.max_minutes > 0 else None)


def train_flow(cfg: FlowTrainConfig, pairs: FlowPairs, out_dir: str | Path, resume: bool = False,
               progress: bool = True, meta: dict | None = None, real_pairs=None,
               tensorboard: str | Path | None = None) -> Path:
    """Train, checkpointing to ``out_dir/checkpoint.safetensors``; writes ``flow.safetensors`` at the end
    (or when a cap stops it) and ``history.json``. Returns the model file's path.

    With ``real_pairs`` (a :class:`flow.unsup.RealPairs`) and ``cfg.real_batch_size`` > 0, each step
    adds ``cfg.real_weight`` times the unsupervised census + smoothness loss of that many real pairs
    (drawn from their own random stream, so the supervised batches are those of a run without them).

    ``tensorboard``: a folder for TensorBoard scalars (:class:`runtime.training.TensorBoardLogger`): per step
    ``flow/step/loss`` and ``flow/step/lr`` (and ``flow/step/real_census`` with real pairs), per history row
    (every ``checkpoint_steps``) ``flow/loss`` (and ``flow/real_census``); x: the step. None: none.

    Raises:
        runtime.training.TrainingDiverged: a non-finite loss (the last checkpoint is kept).
        core.errors.InputError: a crop larger than the frames, a folder holding another run, ``resume``
            with other settings.
    """
    out = Path(out_dir)
    use_real = real_pairs is not None and cfg.real_batch_size > 0
    for what, src in (("frame", pairs), ("real frame at the network's width", real_pairs if use_real else None)):
        min_size = getattr(src, "min_size", None)
        if min_size is not None and (min_size()[0] < cfg.crop[0] or min_size()[1] < cfg.crop[1]):
            raise InputError(None, f"the training crop {cfg.crop[0]}x{cfg.crop[1]} is larger than the smallest {what} "
                                   f"({min_size()[0]}x{min_size()[1]}); choose a smaller --crop")
    with open_run(out, caps(cfg), resume=resume, checkpoint_name=CHECKPOINT, what="a flow training run",
                  threads=max(1, cfg.threads), progress=progress, tensorboard=tensorboard) as run:
        ck = run.checkpoint_path
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(cfg.seed)
            model = FlowNet(cfg.net)
        if cfg.init and not (resume and ck.is_file()):
            model.load_state_dict(initial_weights(cfg).state_dict())
        dev = torch.device(cfg.device)
        model = model.to(dev)
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.max_steps, eta_min=cfg.lr / 20)
        state = {"step": 0, "seconds": 0.0, "history": []}
        # (a checkpoint written before a setting existed resumes: only the settings it records are compared)
        d = run.resume(lambda p: modelfile.load(p, (CHECKPOINT_FORMAT,))[1], cfg.to_dict(), MAY_CHANGE,
                       recorded_only=True) if resume else None
        if d is not None:
            started = (d.get("meta") or {}).get("init_sha256")
            if cfg.init and started and started != (meta or {}).get("init_sha256", started):
                raise InputError(cfg.init, "differs from the flow model this run started from (sha256); cannot resume")
            model.load_state_dict({k: v.to(dev) for k, v in d["state_dict"].items()})
            opt.load_state_dict(d["optimizer"])
            sched.load_state_dict(d["scheduler"])
            state = d["state"]
        atomic.write_json(out / "config.json", {"train": cfg.to_dict(), "meta": meta or {}, "pairs": len(pairs)})

        def tree(kind: str) -> dict:
            # the model file holds no wall time (same seed, same bytes); a checkpoint keeps it in its state
            t = {"net": cfg.net.to_dict(), "state_dict": model.state_dict(), "meta": {**(meta or {}), "train": cfg.to_dict(),
                 "steps": state["step"]}}
            if kind == CHECKPOINT_FORMAT:
                t.update(config=cfg.to_dict(), optimizer=opt.state_dict(), scheduler=sched.state_dict(), state=state)
            return t

        def checkpoint() -> None:
            run.checkpoint(lambda path: modelfile.save(path, CHECKPOINT_FORMAT, tree(CHECKPOINT_FORMAT)))

        bar = run.bar(cfg.max_steps, "flow training", "step", initial=state["step"])
        run.start(state["seconds"], state["history"])
        run_loss, run_n, run_census = 0.0, 0, 0.0
        model.train()
        batches = step_batches(pairs, cfg, state["step"], run.caps.max_steps, pin=dev.type == "cuda")
        while not run.reached(steps=state["step"]):
            b = next(batches)
            if dev.type != "cpu":
                b = {k: v.pin_memory().to(dev, non_blocking=True) for k, v in b.items()}
            with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=cfg.bf16):
                outs = model(b["img0"], b["img1"])
            loss = multiscale_loss([o.float() for o in outs], b["flow"], cfg.level_weights)
            scalars = {}
            if use_real:
                rb = real_pairs.batch(np.random.default_rng([cfg.seed, state["step"], 1]), cfg.real_batch_size, cfg.crop)
                if dev.type != "cpu":
                    rb = {k: v.to(dev) for k, v in rb.items()}
                uloss, parts = unsupervised_loss(model, rb["img0"], rb["img1"], rb["aug0"], rb["aug1"],
                                                 cfg.smooth_weight, dev.type, cfg.smooth_order, cfg.bf16)
                run_census += parts["census"]
                scalars["flow/step/real_census"] = parts["census"]
                loss = loss + cfg.real_weight * uloss
            check_finite(loss, "flow loss", f"at step {state['step'] + 1}",
                         "lower --lr or check the training data for NaN/inf", sched.get_last_lr()[0])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
            opt.step()
            sched.step()
            state["step"] += 1
            state["seconds"] = run.elapsed()
            step_loss = float(loss.detach())
            run_loss += step_loss
            run_n += 1
            bar.update(1)
            if state["step"] % 50 == 0:
                bar.set_postfix(loss=f"{run_loss / run_n:.3g}")
            run.log({"flow/step/loss": step_loss, "flow/step/lr": sched.get_last_lr()[0], **scalars}, state["step"])
            if state["step"] % cfg.checkpoint_steps == 0:
                entry = {"step": state["step"], "loss": run_loss / max(run_n, 1), "seconds": state["seconds"]}
                if use_real:
                    entry["real_census"] = run_census / max(run_n, 1)
                run.record(entry, state["step"], "flow", skip=("step", "seconds"))
                run_loss, run_n, run_census = 0.0, 0, 0.0
                checkpoint()
        bar.close()
        batches.close()
        checkpoint()
        model_path = out / MODEL
        model.eval()
        modelfile.save(model_path, MODEL_FORMAT, tree(MODEL_FORMAT))
    return model_path
