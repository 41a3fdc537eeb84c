"""A denoiser's training configuration (:class:`TrainConfig`: the paper's recipe by default, spec section 2), as
``training.train`` runs it and ``training.batches`` draws its batches, and how a stored one is read back (a config
file, a checkpoint to resume: :func:`stored_config`)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from .augment import check_axis
from .diffusion import DiffusionConfig

DATASETS = ("h36m", "humaneva")

# Keys that configs and checkpoints' stored train_config had until the GPU-call tooling was removed (git tag
# gpu-workflow-before-removal): batches drawn on the device, EMA probes and choose_average. At these values
# they did nothing, so they are dropped where they are read back (a config file, a checkpoint to resume);
# any other value asked for what this code no longer does, and is refused rather than ignored.
REMOVED_KEYS = {"batches": "host", "ema_probe_decays": [], "choose_average": False}


def without_removed_keys(d: dict, where) -> dict:
    """``d`` (a train config as a dict) without ``REMOVED_KEYS`` at their inert values; ValueError where one
    holds another value."""
    active = {k: d[k] for k in REMOVED_KEYS if k in d and d[k] != REMOVED_KEYS[k]}
    if active:
        raise ValueError(
            f"{where}: {active} asks for what was removed with the GPU-call tooling (batches on the "
            "device, EMA probes, choose_average); it is at git tag gpu-workflow-before-removal"
        )
    return {k: v for k, v in d.items() if k not in REMOVED_KEYS}


# Keys added to TrainConfig after checkpoints were committed, at the value that does what the code did before
# them: a checkpoint whose stored train_config lacks one was trained that way.
ADDED_KEYS = {
    "rotate_axis": "",
    "reset_output_head": False,
    "h36m_share": 0.0,
    "future_swap": 0.0,
    "future_swap_k": 25,
    "action_balance": 0.0,
    "imle_samples": 0,
    "imle_weight": 1.0,
    "imle_final_weight": 0.0,
    "imle_targets": 1,
    "imle_echo": 1,
}


def stored_config(d: dict, where) -> dict:
    """A checkpoint's stored train_config as today's ``asdict(TrainConfig)`` has it: removed keys dropped
    (:func:`without_removed_keys`), keys added since at the values that mean the old behaviour."""
    return {**ADDED_KEYS, **without_removed_keys(d, where)}


@dataclass
class TrainConfig:
    role: str = "short"  # short (50 -> 5), long (55 -> 20, teacher-forced), repair (50 -> 0)
    dataset: str = "h36m"  # "h36m" (Human3.6M, 22 joints, 25 fps) or "humaneva" (HumanEva-I, 14, 60 Hz)
    obs_len: int = 50  # observed frames (mask 1 unless occluded)
    pred_len: int = 5  # predicted frames (mask 0)
    model: dict = field(default_factory=dict)  # ModelConfig overrides
    diffusion: dict = field(default_factory=dict)  # DiffusionConfig overrides
    batch_size: int = 32
    lr: float = 1e-3
    weight_decay: float = 1e-6
    epochs: int = 50
    milestones: tuple = (0.75, 0.9)  # fractions of the epochs where the lr is multiplied by gamma
    gamma: float = 0.1
    train_stride: int = 1
    val_stride: int = 25
    val_every: int = 5  # epochs between validations (and always after the last one)
    val_timesteps: int = 0  # 0 = all T steps (the reference); n > 0: n evenly spaced steps
    val_max_windows: int = 0  # 0 = all validation windows
    steps_per_epoch: int = 0  # 0 = a full pass over the training windows
    mask_mix: list = field(default_factory=lambda: [["none", 1.0]])  # [[pattern, weight(, rate)], ...] per window
    seed: int = 0
    amp: bool = True  # bf16 autocast on CUDA
    compile: bool = False  # torch.compile the training forward (eager where compiling fails)
    ema_decay: float = 0.0  # > 0: exponential moving average of the weights, validated and exported
    warmup_steps: int = 0  # linear learning-rate warm-up over the first optimizer steps
    init_from: str = ""  # warm start: a checkpoint (.pt) or exported .safetensors whose weights
    # start this run
    prior: str = ""  # a cond_fill="prior" model's prior forecaster: prior.safetensors or
    # a training.prior last.pt
    rotate_axis: str = ""  # "" or the data's vertical axis: each training window turned about it
    # (training.augment; validation windows are not)
    h36m_share: float = 0.0  # HumanEva-I: the fraction of training windows from Human3.6M retargeted to
    # its skeleton (training.data.humaneva.training_mix; validation stays HumanEva-I)
    future_swap: float = 0.0  # the share of training windows whose future is another training window's, one
    # that arrives at the same pose and velocity (training.augment.swap_futures)
    future_swap_k: int = 25  # ... drawn from each window's future_swap_k nearest such windows
    action_balance: float = 0.0  # HumanEva-I: a training window drawn with weight n^-action_balance, n the
    # windows of its action (0: every window alike, 1: every action alike)
    imle_samples: int = 0  # > 0: each window also trains the one-step sampler (DDIM-1) by IMLE, the
    # nearest of this many one-step samples pulled to its future
    # (training.imle.imle_loss; x0-prediction only)
    imle_weight: float = 1.0  # ... that loss's weight beside the diffusion loss
    imle_final_weight: float = 0.0  # ... plus this weight x the same loss of the candidate nearest on the final
    # frame alone (what FDE's best sample is chosen by)
    imle_targets: int = 1  # > 1: each window's IMLE loss also pulls a nearest candidate to each of
    # imle_targets - 1 futures of its future_swap_k nearest windows (swap_futures)
    imle_echo: int = 1  # > 1: each batch's IMLE search (most of a step's cost) is echoed over this
    # many optimizer steps on the batch (docs/training.md, "Tried, not kept")
    reset_output_head: bool = False  # with init_from: the last 1x1 conv's weight and bias restart at zero; for a
    # warm start whose prediction_type changes (epsilon -> sample), so the run
    # starts at "no residual over the fill" instead of from noise estimates

    @classmethod
    def load(cls, path: str | Path) -> "TrainConfig":
        d = without_removed_keys(json.loads(Path(path).read_text()), path)
        known = set(cls.__dataclass_fields__)
        unknown = set(d) - known - {"comment"}
        if unknown:
            raise ValueError(f"{path}: unknown config keys {sorted(unknown)}")
        return cls(**{k: v for k, v in d.items() if k in known})

    def _imle_count(self, name: str, counts: str) -> None:
        """A count of the IMLE loss (imle_targets, imle_echo): at least 1, and above 1 only with imle_samples."""
        value = getattr(self, name)
        if value < 1 or (value > 1 and not self.imle_samples):
            raise ValueError(
                f"train config: {name} counts {counts}; it must be >= 1, and > 1 needs imle_samples > 0, got {value!r}"
            )

    def __post_init__(self):
        if self.dataset not in DATASETS:
            raise ValueError(f"train config: dataset must be one of {DATASETS}, got {self.dataset!r}")
        from .data.humaneva import check_h36m_share

        check_h36m_share(self.h36m_share, self.dataset, "train config")
        if not 0.0 <= self.ema_decay < 1.0:
            raise ValueError(f"train config: ema_decay must be in [0, 1), got {self.ema_decay!r}")
        if self.warmup_steps < 0:
            raise ValueError(f"train config: warmup_steps must be >= 0, got {self.warmup_steps!r}")
        check_axis(self.rotate_axis, "train config")
        if not 0.0 <= self.future_swap <= 1.0:
            raise ValueError(f"train config: future_swap must be a share in [0, 1], got {self.future_swap!r}")
        if not 0.0 <= self.action_balance <= 1.0:
            raise ValueError(f"train config: action_balance must be in [0, 1], got {self.action_balance!r}")
        if self.action_balance > 0 and (self.dataset != "humaneva" or self.h36m_share > 0):
            raise ValueError(
                "train config: action_balance weighs HumanEva-I's actions; it needs dataset 'humaneva' and h36m_share 0"
            )
        if self.future_swap_k < 1:
            raise ValueError(f"train config: future_swap_k must be >= 1, got {self.future_swap_k!r}")
        if self.future_swap > 0 and self.obs_len < 3:
            raise ValueError(
                f"train config: future_swap matches windows on their last 3 observed frames; obs_len is {self.obs_len}"
            )
        if self.imle_samples < 0 or self.imle_weight < 0 or self.imle_final_weight < 0:
            raise ValueError(
                "train config: imle_samples, imle_weight and imle_final_weight must be >= 0, got "
                f"{self.imle_samples!r}, {self.imle_weight!r} and {self.imle_final_weight!r}"
            )
        self._imle_count("imle_targets", "the futures each window's IMLE loss covers")
        if self.imle_targets > 1 and self.obs_len < 3:
            raise ValueError(
                "train config: imle_targets > 1 draws futures of windows matched on their last 3 "
                f"observed frames; obs_len is {self.obs_len}"
            )
        self._imle_count("imle_echo", "the optimizer steps of one batch's IMLE search")
        if self.imle_final_weight > 0 and not self.imle_samples:
            raise ValueError(
                "train config: imle_final_weight weighs a term of the IMLE loss; it needs imle_samples > 0"
            )
        if self.imle_samples and DiffusionConfig.from_dict(self.diffusion).prediction_type != "sample":
            raise ValueError(
                "train config: imle_samples trains the one-step sample of an x0-predicting model; "
                "set diffusion.prediction_type to 'sample'"
            )
        if self.reset_output_head and not self.init_from:
            raise ValueError("train config: reset_output_head resets a warm start's last layer; it needs init_from")
