"""Which torch device to compute on: ``--device auto|cpu|cuda[:N]`` as the commands take it."""
from __future__ import annotations

import functools
from pathlib import Path

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


@functools.lru_cache(maxsize=1)
def cpu_has_native_bf16() -> bool:
    """True when this CPU computes bf16 natively (AVX512-BF16 or AMX), where bf16 autocast pays off; on other
    CPUs autocast emulates bf16, about 10x slower than float32."""
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


def resolve_bf16(spec: str, device: torch.device) -> bool:
    """bf16 autocast for a ``--bf16 auto|on|off`` value on ``device``: ``auto`` is on with CUDA and on CPUs that
    compute bf16 natively (:func:`cpu_has_native_bf16`)."""
    if spec == "auto":
        return device.type == "cuda" or cpu_has_native_bf16()
    return spec == "on"
