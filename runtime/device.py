"""Which torch device to compute on: ``--device auto|cpu|cuda[:N]`` as the commands take it."""
from __future__ import annotations

import torch

from deepslam.core.errors import InputError

DEVICE_CHOICES = "auto, cpu, cuda or cuda:N"
"""What a ``--device`` flag accepts."""


def resolve_device(spec: str | None) -> torch.device:
    """The torch device of a ``--device`` value: ``auto`` is CUDA when ``torch.cuda.is_available()``,
    else the CPU; ``cuda``/``cuda:N`` must exist here.

    Raises:
        InputError: an unknown spec, or a CUDA device this machine does not have.
    """
    spec = (spec or "auto").strip().lower()
    if spec == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if spec == "cpu":
        return torch.device("cpu")
    if spec == "cuda" or spec.startswith("cuda:"):
        if not torch.cuda.is_available():
            raise InputError(None, f"--device {spec}: no CUDA device here (torch {torch.__version__}, "
                                   "torch.cuda.is_available() is False); use --device cpu or auto")
        try:
            dev = torch.device(spec)
        except RuntimeError:
            raise InputError(None, f"--device {spec!r} is not {DEVICE_CHOICES}") from None
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise InputError(None, f"--device {spec}: only {torch.cuda.device_count()} CUDA device(s) here")
        return dev
    raise InputError(None, f"--device {spec!r} is not {DEVICE_CHOICES}")
