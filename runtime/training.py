"""The training runner shared by :mod:`deepslam.vo.train` (the flow -> 6DoF network, two stages) and
:mod:`deepslam.flow.train` (the learned flow network).

A training module keeps what is its own: the network, the losses, the data, the optimiser and the stages,
and the loop that ties them. The runner (:func:`open_run` gives a :class:`Runner`) keeps what both share:

- the output folder: one writer (an exclusive lock), a finished or foreign folder never overwritten
  without ``--resume``, and the torch thread count for the run's length;
- the caps (:class:`Caps`: minutes, samples, epochs, steps) and the training clock, summed over resumes;
- resuming: the checkpoint's settings against the run's (naming those that may change), the torch RNG
  state stored in the checkpoint;
- the checkpoint file, written atomically by the module's own writer, with ``history.json`` beside it;
- the divergence check (:func:`check_finite`): a non-finite loss raises :class:`TrainingDiverged`
  before anything is written, so the last good checkpoint stays;
- the progress bar, the history rows, and the loggers that see every scalar (:class:`TensorBoardLogger`).

Nothing here draws a random number or touches a tensor of the model: a run with the runner's loggers
on trains the same bytes as one without them.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Callable, Iterable, Iterator, Mapping, Protocol

import torch
from tqdm import tqdm

from deepslam.core import atomic
from deepslam.core.errors import InputError
from deepslam.core.lock import output_lock

HISTORY = "history.json"
"""The history rows of a run, beside its checkpoint (rewritten with every checkpoint)."""

CAPS = ("max_epochs", "max_steps", "max_minutes", "max_samples")
"""The caps' names, in the order they are reported when several are reached at once."""


class TrainingDiverged(RuntimeError):
    """The loss became NaN or infinite; the message says where and what to try."""


def check_finite(value: torch.Tensor | float, what: str, where: str, hint: str, lr: float | None = None) -> None:
    """Raise :class:`TrainingDiverged` when ``value`` (a loss: a 0-d tensor or a float) is NaN or infinite.

    The message reads ``{what} is {value} {where} (learning rate {lr}); {hint}; the last good checkpoint
    is kept``: the caller raises before writing anything, so the checkpoint on disk is the last good one.
    """
    if isinstance(value, torch.Tensor):
        bad = not bool(torch.isfinite(value))
        shown = float(value.detach()) if bad else 0.0
    else:
        bad = not math.isfinite(value)
        shown = value
    if bad:
        rate = f" (learning rate {lr:.3g})" if lr is not None else ""
        raise TrainingDiverged(f"{what} is {shown} {where}{rate}; {hint}; the last good checkpoint is kept")


@dataclasses.dataclass(frozen=True)
class Caps:
    """Where a run stops, whichever cap comes first. A cap of None is no cap; a count reaches its cap
    when it is at least the cap (a cap of 0 epochs is reached before the first)."""

    max_epochs: int | None = None
    """Epochs (each a pass over the training data, or a part of one a later cap cut)."""
    max_steps: int | None = None
    """Optimisation steps."""
    max_minutes: float | None = None
    """Training time in minutes, summed over resumes."""
    max_samples: int | None = None
    """Training samples (over all data-parallel ranks)."""

    @property
    def limit_s(self) -> float:
        """The time cap in seconds (inf: none)."""
        return 60.0 * self.max_minutes if self.max_minutes is not None else math.inf

    def reached(self, elapsed_s: float, epochs: int = 0, steps: int = 0, samples: int = 0) -> list[str]:
        """The caps a run at ``epochs``, ``steps``, ``samples`` and ``elapsed_s`` seconds of training has
        reached, in :data:`CAPS` order (empty: none)."""
        hit = {"max_epochs": self.max_epochs is not None and epochs >= self.max_epochs,
               "max_steps": self.max_steps is not None and steps >= self.max_steps,
               "max_minutes": self.max_minutes is not None and elapsed_s >= self.limit_s,
               "max_samples": self.max_samples is not None and samples >= self.max_samples}
        return [c for c in CAPS if hit[c]]


class ScalarLogger(Protocol):
    """Where the runner sends every scalar besides the history (e.g. :class:`TensorBoardLogger`)."""

    def scalars(self, values: Mapping[str, float], step: int) -> None:
        """Record each ``tag -> value`` at ``step``."""

    def flush(self) -> None:
        """Make what was recorded readable (called with every checkpoint)."""

    def close(self) -> None:
        """Flush and release (called once, when the run ends or fails)."""


class TensorBoardLogger:
    """Scalars into a TensorBoard event file in ``log_dir`` (``torch.utils.tensorboard.SummaryWriter``;
    needs the ``tensorboard`` package). ``tensorboard --logdir DIR`` shows them."""

    def __init__(self, log_dir: str | Path):
        try:
            # deferred: tensorboard is an optional dependency, needed only with --tensorboard
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:
            raise InputError(None, "--tensorboard needs the tensorboard package (pip install tensorboard)") from None
        log_dir = Path(log_dir)
        if log_dir.exists() and not log_dir.is_dir():
            raise InputError(log_dir, "--tensorboard exists and is not a folder")
        self.log_dir = log_dir
        self.writer = SummaryWriter(str(log_dir))

    def scalars(self, values: Mapping[str, float], step: int) -> None:
        for tag, v in values.items():
            self.writer.add_scalar(tag, v, step)

    def flush(self) -> None:
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()


def _numbers(row: Mapping, skip: Iterable[str]) -> dict[str, float]:
    """The finite numbers of a history row as scalars: lists become ``key/0``, ``key/1`` ...; flags
    (bools) and ``skip`` are left out."""
    out: dict[str, float] = {}
    for k, v in row.items():
        if k in skip or isinstance(v, bool):
            continue
        if isinstance(v, (list, tuple)):
            out.update({f"{k}/{i}": float(x) for i, x in enumerate(v)
                        if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)})
        elif isinstance(v, (int, float)) and math.isfinite(v):
            out[k] = float(v)
    return out


def settings_differ(old: Mapping, new: Mapping, may_change: Iterable[str], recorded_only: bool = False) -> list[str]:
    """The settings (top-level keys) whose values differ between a checkpoint's config ``old`` and the
    run's ``new`` (compared as JSON: a tuple equals a list), leaving out ``may_change``, sorted.

    Args:
        recorded_only: compare only the keys ``old`` holds (a checkpoint written before a setting existed
            resumes with it); otherwise a key on one side only differs.
    """
    new = json.loads(json.dumps(dict(new)))
    keys = set(old) if recorded_only else set(old) | set(new)
    skip = set(may_change)
    return sorted(k for k in keys if k not in skip and old.get(k) != new.get(k))


class Runner:
    """One training run's shared machinery (made by :func:`open_run`); the training module drives it.

    Attributes:
        out_dir: the run's folder; checkpoint_path: its checkpoint file in it.
        caps: where the run stops; progress: whether bars and lines are shown.
        writer: whether this process writes the folder (data-parallel: rank 0 only; the others train).
        history: the run's history rows (the list object the module keeps in its checkpointed state).
    """

    def __init__(self, out_dir: Path, caps: Caps, checkpoint_name: str, progress: bool, writer: bool,
                 loggers: list[ScalarLogger]):
        self.out_dir = out_dir
        self.checkpoint_path = out_dir / checkpoint_name
        self.caps = caps
        self.progress = progress
        self.writer = writer
        self.loggers = loggers
        self.history: list[dict] = []
        self._clock0 = time.perf_counter()

    # ---- resuming and the clock

    def resume(self, load: Callable[[Path], dict], config: Mapping, may_change: Iterable[str],
               recorded_only: bool = False) -> dict | None:
        """The checkpoint to continue from (``load(checkpoint_path)``), or None when there is none; restores
        the torch RNG state it stores (``torch_rng``, :meth:`rng_states`).

        Args:
            load: reads the checkpoint file into its tree (which holds the run's settings under ``config``).
            config: this run's settings; may_change: those that may differ from the checkpoint's (caps,
                threads, device); recorded_only: see :func:`settings_differ`.

        Raises:
            core.errors.InputError: settings other than ``may_change`` differ.
        """
        if not self.checkpoint_path.is_file():
            return None
        ck = load(self.checkpoint_path)
        diff = settings_differ(ck.get("config") or {}, config, may_change, recorded_only)
        if diff:
            raise InputError(self.checkpoint_path, f"cannot resume: settings differ from the checkpoint's ({', '.join(diff)})")
        if ck.get("torch_rng") is not None:
            torch.set_rng_state(ck["torch_rng"])
        return ck

    def start(self, elapsed_s: float = 0.0, history: list[dict] | None = None) -> None:
        """Start the training clock at ``elapsed_s`` seconds already trained and adopt ``history`` (the
        list in the module's state, appended to by :meth:`record`)."""
        self._clock0 = time.perf_counter() - elapsed_s
        if history is not None:
            self.history = history

    def elapsed(self) -> float:
        """Seconds of training, summed over resumes."""
        return time.perf_counter() - self._clock0

    def time_left(self) -> float:
        """Seconds until the time cap (inf: no cap)."""
        return self.caps.limit_s - self.elapsed()

    def deadline(self) -> float | None:
        """The ``time.perf_counter()`` value at which the time cap is reached (None: no cap)."""
        return self._clock0 + self.caps.limit_s if math.isfinite(self.caps.limit_s) else None

    def reached(self, epochs: int = 0, steps: int = 0, samples: int = 0, elapsed_s: float | None = None) -> list[str]:
        """:meth:`Caps.reached` at this moment of the clock (or at ``elapsed_s``)."""
        return self.caps.reached(self.elapsed() if elapsed_s is None else elapsed_s, epochs, steps, samples)

    @staticmethod
    def rng_states() -> dict:
        """The RNG state a checkpoint stores for :meth:`resume`: ``torch_rng``, the global torch generator's
        (uint8 tensor)."""
        return {"torch_rng": torch.get_rng_state()}

    # ---- what the run shows and records

    def bar(self, total: int, desc: str, unit: str, initial: int = 0, leave: bool = True) -> tqdm:
        """A progress bar (hidden without ``progress``)."""
        return tqdm(total=total, initial=initial, desc=desc, unit=unit, disable=not self.progress, leave=leave,
                    dynamic_ncols=True)

    def say(self, text: str) -> None:
        """A line on stdout when the run shows progress."""
        if self.progress:
            print(text, flush=True)

    def log(self, values: Mapping[str, float], step: int) -> None:
        """Scalars to the loggers only (not the history): per-step figures such as the batch loss and
        the learning rate."""
        if self.writer and self.loggers:
            for logger in self.loggers:
                logger.scalars(values, step)

    def record(self, row: dict, step: int, prefix: str, skip: Iterable[str] = ()) -> None:
        """Append ``row`` to the history, and send its numbers (less ``skip``) to the loggers as
        ``prefix/key`` at ``step``."""
        self.history.append(row)
        if self.writer and self.loggers:
            self.log({f"{prefix}/{k}": v for k, v in _numbers(row, skip).items()}, step)

    # ---- files

    def write_history(self) -> None:
        """``history.json`` (atomically; the writer only)."""
        if self.writer:
            atomic.write_json(self.out_dir / HISTORY, self.history)

    def checkpoint(self, save: Callable[[Path], None]) -> None:
        """Write the checkpoint (``save(checkpoint_path)``, the module's atomic writer) and the history beside
        it, and flush the loggers; the writer only."""
        if not self.writer:
            return
        save(self.checkpoint_path)
        self.write_history()
        for logger in self.loggers:
            logger.flush()


@contextlib.contextmanager
def open_run(out_dir: str | Path, caps: Caps, *, resume: bool, checkpoint_name: str, what: str = "a training run",
             threads: int = 0, writer: bool = True, progress: bool = True, tensorboard: str | Path | None = None,
             refuse: Callable[[Path], None] | None = None) -> Iterator[Runner]:
    """The run's folder, locked, checked and ready, for the block's length.

    The writer holds :func:`core.lock.output_lock` on ``out_dir`` (creating it), calls ``refuse(out_dir)``
    (the module's own refusals), then refuses a folder holding a checkpoint without ``resume``, and a
    non-empty folder without a checkpoint to resume. Only then are the loggers opened (``tensorboard``:
    a :class:`TensorBoardLogger` in that folder, the writer only). The torch thread count is ``threads``
    (0: left as it is) until the block ends; the loggers are closed then, also when it raises.

    Args:
        out_dir: the run's folder; checkpoint_name: the checkpoint's file name in it.
        caps: where the run stops; what: the run's kind in messages ("a training run").
        writer: this process writes the folder (data-parallel training: rank 0 only; the others neither lock
            nor check it, and log nothing).

    Raises:
        core.errors.InputError: the folder is locked by another run, holds a run without ``resume``, or is
            not empty and holds no run.
    """
    out = Path(out_dir)
    threads_before = torch.get_num_threads()
    if threads > 0:
        torch.set_num_threads(threads)
    loggers: list[ScalarLogger] = []
    try:
        with output_lock(out) if writer else contextlib.nullcontext():
            run = Runner(out, caps, checkpoint_name, progress and writer, writer, loggers)
            if writer:
                if refuse is not None:
                    refuse(out)
                if not resume and run.checkpoint_path.exists():
                    raise InputError(run.checkpoint_path, f"{what} is already here; pass --resume to continue it or "
                                                          "choose another --out")
                if not resume and any(out.iterdir()):
                    raise InputError(out, "output folder is not empty and holds no training run; choose another --out")
                if tensorboard is not None:
                    loggers.append(TensorBoardLogger(tensorboard))
            try:
                yield run
            finally:
                for logger in loggers:
                    logger.close()
    finally:
        torch.set_num_threads(threads_before)
