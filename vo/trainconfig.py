"""The settings of a VO training run (:func:`deepslam.vo.train.train`), stored in every checkpoint."""
from __future__ import annotations

import dataclasses

from deepslam.vo.net import POSE_LOSSES, NetConfig


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings (the defaults are the paper's recipe)."""

    net: NetConfig = NetConfig()
    """Network shape."""
    batch_size: int = 128
    """Samples per optimisation step."""
    lr_min: float = 1e-4
    """Lower bound of the cyclic learning rate."""
    lr_max: float = 1e-3
    """Upper bound of the cyclic learning rate."""
    lr_half_cycle_steps: int = 0
    """Steps from the lower to the upper bound (CyclicLR step_size_up); 0 = one epoch's steps."""
    patience_epochs: int = 10
    """Epochs without a held-out improvement after which both bounds are halved."""
    lr_stop: float = 1e-5
    """Stage 1 ends when the lower bound falls below this."""
    max_epochs: int = 1000
    """Cap on stage-1 epochs."""
    max_minutes: float = 0.0
    """Cap on the whole training's wall time in minutes, both stages (0 = none), checked after every
    batch: stage 1 stops early enough to leave time for its last held-out evaluation and stage 2.
    A run stopped by time is not bit-reproducible (use ``max_samples`` for that)."""
    max_samples: int = 0
    """Cap on stage-1 training samples (0 = none), checked after every batch: the deterministic way to
    bound a run (same seed, same bytes)."""
    rot_weight: float = 50.0
    """Weight of the rotation (euler, radians) loss against the translation (metres) loss."""
    loss: str = "l1"
    """Stage-1 loss of each DoF: ``l1`` (mean absolute error, the paper's published code) or ``mse``
    (mean squared error; what files recorded before this field existed were trained with)."""
    holdout_fraction: float = 0.1
    """Fraction of the data held out: stage-1 validation and the stage-2 (NLL) training set."""
    nll_epochs: int = 20
    """Stage-2 epochs (the log-std heads only)."""
    nll_lr: float = 1e-3
    """Stage-2 learning rate (Adam, amsgrad)."""
    seed: int = 0
    """Seed of the initial weights, the data and the shuffling."""
    bf16: bool = True
    """Run forward/backward under torch.autocast("cpu", bfloat16) (weights and the loss stay float32)."""
    channels_last: bool = True
    """Keep convolution weights and inputs channels-last (NHWC)."""
    threads: int = 0
    """torch intra-op threads (0 = leave torch's default)."""
    device: str = "cpu"
    """torch device the network trains on ("cpu", "cuda", "cuda:N"; the command's ``--device auto``
    resolves to one). Weights are stored on the CPU, so a model trained on one device loads on any;
    the data is made on the CPU and each batch moved to the device (pinned memory where CUDA)."""
    init: str = ""
    """A single-network VO model file whose weights start the training (fine-tuning, ``deepslam adapt``); its
    network must be ``net``. Empty: random initial weights from ``seed``."""

    def __post_init__(self) -> None:
        if self.loss not in POSE_LOSSES:
            raise ValueError(f"loss must be one of {', '.join(POSE_LOSSES)}, got {self.loss!r}")

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["net"] = self.net.to_dict()
        if not d["init"]:
            del d["init"]  # runs from random weights record what they always recorded
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        d = dict(d)
        d["net"] = NetConfig.from_dict(d.get("net", {}))
        d.setdefault("loss", "mse")  # recorded before the loss was a setting: trained with the MSE
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown TrainConfig fields: {sorted(unknown)}")
        return cls(**d)
