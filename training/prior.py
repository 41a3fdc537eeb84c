"""The deterministic prior forecaster (issue 28): a siMLPe-class network, written here from the published
description (``../shared/spec/PRIOR.md``), trained on the CPU in resumable installments.

The network maps ``obs_len`` observed frames of the model joints (root-relative, metres; K = 3 x joints:
66 for Human3.6M's 22, 42 for HumanEva-I's 14) to the next ``chunk`` frames:

    x (B, obs_len, K) --DCT over time--> fc_in (K -> K, per frame)
        --> ``blocks`` x [ temporal FC (obs_len -> obs_len, per coordinate), layer norm over the K
            coordinates per frame, residual ]
        --> fc_out (K -> K) --inverse DCT--> first ``chunk`` frames + the last observed pose

``chunk`` is at most ``obs_len``: the inverse DCT has ``obs_len`` frames (HumanEva-I's 15 observed frames
give at most 15 at once; its 60 are rolled out).

No non-linearity anywhere: each block is linear but for its layer norm. fc_out and every temporal FC start
at (almost) zero, so the untrained network is Zero-Velocity. Longer horizons are rolled out: the
prediction is appended to the observation and the last ``obs_len`` frames predict the next chunk.

Training (``python -m training.prior``): random windows of ``obs_len + chunk`` frames (``obs_len +
loss_frames`` when set) from the training subjects of ``dataset`` (``"h36m"``: Human3.6M, the 22 model joints
at 25 fps; ``"humaneva"``: HumanEva-I's Train split, 14 root-relative joints at 60 Hz,
``training.data.humaneva.training_sequences``), reversed in time with probability ``flip_prob``; loss = mean
per-joint L2 distance of the chunk (of the ``loss_frames`` frames rolled out, when set) plus the same on its
frame-to-frame velocities; Adam with weight decay; the learning rate decays once at ``lr_decay_at`` of the
iterations (``lr`` -> ``lr_final``). Every draw is a pure function of (seed, iteration), so a resumed run
continues exactly where it stopped.

A **repair fill** (``"anchor": "window"``, ``chunk`` = ``obs_len``; docs/repair.md) is the same network over a
whole window, its output added to its input window instead of to the last pose: it trains on windows of
``obs_len`` frames, each hidden by a mask of ``mask_mix`` and filled by the natural cubic spline
(:func:`repair_batch`), with the loss over the hidden joints (:func:`hidden_loss`). Any run may validate on
held-out subjects (``val_subjects``, every ``val_every`` iterations; ``best.pt`` keeps the lowest).

    python -m training.prior --config training/configs/prior.json --out runs/prior [--resume]
                             [--max-minutes M] [--threads 1]
    python -m training.prior --config training/configs/humaneva_prior.json --out runs/humaneva_prior
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .augment import check_axis, mirror, mirror_permutation, resample, rotate_about, sequence_ends

NUM_JOINTS = 22
#: what a forward's output is added to (PriorConfig.anchor)
ANCHORS = ("last", "window")
#: how a repair fill fills a window's whole-frame gaps (PriorConfig.gap_fill; training.model.fill_gaps)
GAP_FILLS = ("none", "forecaster")
#: what a repair fill's training loss averages (PriorConfig.window_loss; hidden_loss)
WINDOW_LOSSES = ("pooled", "log_window")
#: the model joints of each dataset the prior trains on (Human3.6M: 22; HumanEva-I: joints 1..14 of 15)
DATASET_JOINTS = {"h36m": 22, "humaneva": 14}


@dataclass
class PriorConfig:
    obs_len: int = 50  # observed frames the network reads
    chunk: int = 10  # frames one forward predicts (rolled out to longer horizons)
    blocks: int = 48  # temporal FC + layer norm blocks
    lr: float = 3e-4
    lr_final: float = 1e-5
    lr_decay_at: float = 0.75  # fraction of the iterations after which lr_final is used
    weight_decay: float = 1e-4
    batch_size: int = 256
    iterations: int = 40_000
    flip_prob: float = 0.5  # temporal-flip augmentation
    rotate_axis: str = ""  # "" or the data's vertical axis: each window turned about it (training.augment)
    mirror_prob: float = 0.0  # the fraction of windows mirrored (left and right swapped; needs rotate_axis)
    obs_noise_mm: float = 0.0  # sigma of the Gaussian noise put on every observed coordinate of a noisy window
    obs_noise_prob: float = 0.0  # the fraction of windows made noisy (the target frames stay clean)
    speed_range: tuple = ()  # () or (lo, hi): each window played at a speed log-uniform in [lo, hi]
    velocity_weight: float = 1.0  # weight of the velocity term of the loss
    loss_frames: int = 0  # future frames the loss covers, rolled out chunk by chunk (0: one chunk)
    subjects: tuple = (1, 6, 7, 8, 9, 11)  # siMLPe's training subjects (S5 is the test subject); HumanEva: 1..3
    seed: int = 0
    init_from: str = ""  # a later installment: the last.pt (or exported prior.safetensors) whose weights
    # start this run (fresh Adam;
    # a deeper config grows it: load_grown)
    dataset: str = "h36m"  # "h36m" (Human3.6M, 22 joints) or "humaneva" (HumanEva-I Train split, 14 joints)
    h36m_share: float = 0.0  # HumanEva-I: the fraction of windows from Human3.6M retargeted to its skeleton
    # (training.data.humaneva.training_mix)
    val_subjects: tuple = ()  # held out from training: with val_every, the loss on val_windows fixed windows
    val_every: int = 0  # of theirs every val_every iterations, and best.pt keeps the weights with the
    val_windows: int = 512  # lowest (0: no validation; the repair fill oscillates without it)
    anchor: str = "last"  # "last": the next chunk, added to the last observed pose (the forecaster);
    # "window": chunk = obs_len, a correction added to the input window itself
    # (the repair fill: the spline-filled window of a masked observation in,
    # the repaired window out; see repair_batch)
    mask_mix: tuple = ()  # anchor "window": the masks trained on (training.masks.mix_entry entries)
    gap_fill: str = "none"  # anchor "window": "forecaster" fills runs of wholly hidden frames from the
    # prior forecaster beside it (training.model.fill_gaps, attach_gap_forecaster)
    inbetween_context: int = 0  # gap_fill "forecaster": the in-betweener's context frames (training.inbetween;
    inbetween_max_gap: int = 0  # its kernels, fitted after training, for gaps of 1 .. inbetween_max_gap frames)
    joint_inbetween_context: int = 0  # anchor "window": the joint in-betweener's (runs of one coordinate hidden
    joint_inbetween_max_gap: int = 0  # in frames with others seen; training.inbetween.fit_joint_runs)
    window_loss: str = "pooled"  # anchor "window": "pooled", the mean error over every hidden joint of the
    # batch; "log_window", the mean over windows of the log of each window's
    # mean error (scale-free: a window hiding nearly everything, tens of mm
    # off, no longer outweighs the few-mm occlusions; see docs/repair.md)
    val_mask_mix: tuple = ()  # anchor "window": validate on each of these patterns (mask_mix entries)
    # apart, scored by the geometric mean of their errors (empty: the mask_mix's
    # pooled loss)

    @classmethod
    def load(cls, path: str | Path) -> "PriorConfig":
        d = json.loads(Path(path).read_text())
        unknown = set(d) - set(cls.__dataclass_fields__) - {"comment"}
        if unknown:
            raise ValueError(f"{path}: unknown prior config keys {sorted(unknown)}")
        d = {k: v for k, v in d.items() if k != "comment"}
        for key in ("subjects", "speed_range", "mask_mix", "val_subjects", "val_mask_mix"):
            if key in d:
                d[key] = tuple(d[key])
        return cls(**d)

    def __post_init__(self):
        for name in ("obs_len", "chunk", "blocks", "batch_size", "iterations"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"prior config: {name} must be >= 1, got {getattr(self, name)!r}")
        if self.chunk > self.obs_len:
            raise ValueError(f"prior config: chunk ({self.chunk}) must not exceed obs_len ({self.obs_len})")
        if int(self.loss_frames) < 0:
            raise ValueError(f"prior config: loss_frames must be >= 0 (0: one chunk), got {self.loss_frames!r}")
        if not 0.0 <= self.flip_prob <= 1.0:
            raise ValueError(f"prior config: flip_prob must be in [0, 1], got {self.flip_prob!r}")
        check_axis(self.rotate_axis, "prior config")
        if not 0.0 <= self.mirror_prob <= 1.0:
            raise ValueError(f"prior config: mirror_prob must be in [0, 1], got {self.mirror_prob!r}")
        if self.mirror_prob > 0.0 and not self.rotate_axis:
            raise ValueError(
                "prior config: mirror_prob needs rotate_axis (the data's vertical, which the mirror plane holds)"
            )
        if not (math.isfinite(self.obs_noise_mm) and self.obs_noise_mm >= 0.0):
            raise ValueError(f"prior config: obs_noise_mm must be a finite number >= 0, got {self.obs_noise_mm!r}")
        if not 0.0 <= self.obs_noise_prob <= 1.0:
            raise ValueError(f"prior config: obs_noise_prob must be in [0, 1], got {self.obs_noise_prob!r}")
        if self.speed_range:
            lo, hi = (tuple(map(float, self.speed_range)) + (math.nan,))[:2]
            if len(self.speed_range) != 2 or not (0.0 < lo <= hi and math.isfinite(hi)):
                raise ValueError(
                    f"prior config: speed_range must be [] or [lo, hi] with 0 < lo <= hi, "
                    f"got {list(self.speed_range)!r}"
                )
        if self.dataset not in DATASET_JOINTS:
            raise ValueError(f"prior config: dataset must be one of {sorted(DATASET_JOINTS)}, got {self.dataset!r}")
        if self.dataset == "humaneva" and not set(self.subjects) <= {1, 2, 3}:
            raise ValueError(
                "prior config: a HumanEva-I prior trains on subjects among [1, 2, 3] (the Train split's "
                f'S1..S3); set "subjects": [1, 2, 3], got {list(self.subjects)}'
            )
        from .data.humaneva import check_h36m_share

        check_h36m_share(self.h36m_share, self.dataset, "prior config")
        if int(self.val_every) < 0 or int(self.val_windows) < 1:
            raise ValueError(
                f"prior config: val_every must be >= 0 and val_windows >= 1, got {self.val_every!r}, "
                f"{self.val_windows!r}"
            )
        if self.val_every and not self.val_subjects:
            raise ValueError("prior config: val_every needs val_subjects (the held-out subjects it validates on)")
        if set(self.val_subjects) & set(self.subjects):
            raise ValueError(
                f"prior config: val_subjects {list(self.val_subjects)} must be held out of subjects "
                f"{list(self.subjects)}"
            )
        if self.anchor not in ANCHORS:
            raise ValueError(f"prior config: anchor must be one of {list(ANCHORS)}, got {self.anchor!r}")
        if self.anchor == "window":
            if self.chunk != self.obs_len or int(self.loss_frames) != 0:
                raise ValueError(
                    'prior config: anchor "window" corrects its whole input: chunk must equal obs_len '
                    f"and loss_frames be 0, got chunk {self.chunk}, obs_len {self.obs_len}, "
                    f"loss_frames {self.loss_frames}"
                )
            if self.dataset != "h36m":  # training.masks draws masks over Human3.6M's 22 model joints
                raise ValueError(
                    f'prior config: anchor "window" (a repair fill) trains on Human3.6M, got dataset {self.dataset!r}'
                )
            from .masks import mix_entry

            for entry in self.mask_mix + tuple(self.val_mask_mix):
                mix_entry(entry)
            if self.obs_noise_prob > 0.0 or self.speed_range or self.mirror_prob > 0.0:
                raise ValueError(
                    'prior config: anchor "window" supports flips and rotations only (no obs_noise, '
                    "speed_range or mirror)"
                )
        elif self.mask_mix:
            raise ValueError('prior config: mask_mix is for anchor "window" (a forecaster sees whole frames)')
        if self.gap_fill not in GAP_FILLS:
            raise ValueError(f"prior config: gap_fill must be one of {list(GAP_FILLS)}, got {self.gap_fill!r}")
        if self.window_loss not in WINDOW_LOSSES:
            raise ValueError(
                f"prior config: window_loss must be one of {list(WINDOW_LOSSES)}, got {self.window_loss!r}"
            )
        if (self.window_loss != "pooled" or self.val_mask_mix) and self.anchor != "window":
            raise ValueError('prior config: window_loss and val_mask_mix are for a repair fill (anchor "window")')
        if self.gap_fill != "none" and self.anchor != "window":
            raise ValueError(
                'prior config: gap_fill is for a repair fill (anchor "window"); a forecaster fills no gaps'
            )
        # the two in-betweeners (training.inbetween), each on the fills it is for (the engine's check, the same)
        for name, fits, what in (
            (
                "inbetween",
                self.gap_fill == "forecaster",
                'the in-betweener corrects the gap fill (gap_fill "forecaster") of gaps',
            ),
            (
                "joint_inbetween",
                self.anchor == "window",
                'the joint in-betweener is a repair fill\'s (anchor "window"), for runs',
            ),
        ):
            context, max_gap = getattr(self, f"{name}_context"), getattr(self, f"{name}_max_gap")
            if (context > 0) != (max_gap > 0) or min(context, max_gap) < 0:
                raise ValueError(f"prior config: {name}_context and {name}_max_gap are both 0 or both >= 1")
            if max_gap and (not fits or max_gap >= self.obs_len):
                raise ValueError(f"prior config: {what} shorter than the window ({self.obs_len} frames)")

    @property
    def num_joints(self) -> int:
        """The model joints of the dataset (22 for Human3.6M, 14 for HumanEva-I)."""
        return DATASET_JOINTS[self.dataset]

    @property
    def future(self) -> int:
        """The future frames of a training window: ``loss_frames``, or one chunk when it is 0; none for a
        repair fill (anchor ``"window"``: its windows are its ``obs_len`` frames)."""
        if self.anchor == "window":
            return 0
        return int(self.loss_frames) or self.chunk

    @classmethod
    def from_dict(cls, d: dict) -> "PriorConfig":
        """The config of a checkpoint's dict (one written before ``dataset`` existed is a Human3.6M one)."""
        return cls(
            **{
                **d,
                "subjects": tuple(d["subjects"]),
                "speed_range": tuple(d.get("speed_range", ())),
                "mask_mix": tuple(d.get("mask_mix", ())),
                "val_subjects": tuple(d.get("val_subjects", ())),
                "val_mask_mix": tuple(d.get("val_mask_mix", ())),
            }
        )

    def to_dict(self) -> dict:
        d = asdict(self)
        d["subjects"] = list(self.subjects)
        d["speed_range"] = list(self.speed_range)
        d["mask_mix"] = json.loads(json.dumps(self.mask_mix))  # nested lists, as the config file has them
        d["val_subjects"] = list(self.val_subjects)
        d["val_mask_mix"] = json.loads(json.dumps(self.val_mask_mix))
        return d


def dct_matrix(n: int) -> np.ndarray:
    """The orthonormal DCT-II matrix (n, n): row k is the k-th cosine; its transpose is the inverse."""
    k = np.arange(n)[:, None]
    i = np.arange(n)[None, :]
    m = np.sqrt(2.0 / n) * np.cos(np.pi * (2 * i + 1) * k / (2 * n))
    m[0] /= np.sqrt(2.0)
    return m


class TemporalBlock(nn.Module):
    """x + LayerNorm_coords(x W^T + b): W mixes the frames (DCT coefficients) of every coordinate; the
    layer norm normalises the coordinates of every frame. Layout (B, coords, frames): the temporal FC is
    then one plain GEMM, 2.6x faster on the CPU than mixing frames in (B, frames, coords)."""

    def __init__(self, frames: int, coords: int, eps: float = 1e-5):
        super().__init__()
        self.fc = nn.Linear(frames, frames)
        self.norm_weight = nn.Parameter(torch.ones(coords))
        self.norm_bias = nn.Parameter(torch.zeros(coords))
        self.eps = eps
        nn.init.xavier_uniform_(self.fc.weight, gain=1e-8)  # start as the identity block
        nn.init.zeros_(self.fc.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, coords, frames)
        y = nn.functional.linear(x, self.fc.weight, self.fc.bias)
        mean = y.mean(dim=1, keepdim=True)
        var = (y - mean).square().mean(dim=1, keepdim=True)  # biased, as LayerNorm
        y = (y - mean) * torch.rsqrt(var + self.eps)
        return x + y * self.norm_weight[:, None] + self.norm_bias[:, None]


class PriorNet(nn.Module):
    def __init__(self, cfg: PriorConfig, joints: int | None = None):
        super().__init__()
        self.cfg = cfg
        K = 3 * (cfg.num_joints if joints is None else joints)
        self.register_buffer("dct", torch.from_numpy(dct_matrix(cfg.obs_len)).float(), persistent=False)
        self.fc_in = nn.Linear(K, K)
        self.blocks = nn.ModuleList([TemporalBlock(cfg.obs_len, K) for _ in range(cfg.blocks)])
        self.fc_out = nn.Linear(K, K)
        nn.init.xavier_uniform_(self.fc_out.weight, gain=1e-8)  # the untrained network is Zero-Velocity
        nn.init.zeros_(self.fc_out.bias)
        # the in-betweeners' kernels (training.inbetween), fitted after training: in the state dict, not trained
        from .inbetween import kernel_width

        for prefix, context, max_gap in (
            ("inbetween", cfg.inbetween_context, cfg.inbetween_max_gap),
            ("joint_inbetween", cfg.joint_inbetween_context, cfg.joint_inbetween_max_gap),
        ):
            for n in range(1, max_gap + 1):
                self.register_buffer(f"{prefix}_{n}", torch.zeros(n, kernel_width(n, context)))

    def inbetween_kernels(self, prefix: str = "inbetween") -> dict:
        """{n: the kernel (n, 3 (2 C + n) + 2) of an n-frame gap (``prefix`` "inbetween") or run (``prefix``
        "joint_inbetween") as a numpy array}; empty without that in-betweener."""
        max_gap = getattr(self.cfg, f"{prefix}_max_gap")
        return {n: getattr(self, f"{prefix}_{n}").numpy() for n in range(1, max_gap + 1)}

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """obs (B, obs_len, K) -> the next ``chunk`` frames (B, chunk, K); for anchor ``"window"`` the input
        window corrected (B, obs_len, K)."""
        x = nn.functional.linear(obs.transpose(1, 2), self.dct)  # (B, K, obs_len) DCT coefficients
        x = torch.matmul(self.fc_in.weight, x) + self.fc_in.bias[:, None]  # spatial FC, per coefficient
        for block in self.blocks:
            x = block(x)
        x = torch.matmul(self.fc_out.weight, x) + self.fc_out.bias[:, None]
        x = nn.functional.linear(x, self.dct.t()[: self.cfg.chunk])  # inverse DCT, first chunk frames
        return x.transpose(1, 2) + (obs if self.cfg.anchor == "window" else obs[:, -1:])

    def rollout(self, obs: torch.Tensor, horizon: int, step=None) -> torch.Tensor:
        """obs (B, T >= obs_len, K) -> (B, horizon, K): chunks predicted from the last obs_len frames,
        each appended to the history before the next. ``step``: the forward to call (a compiled one), else
        the module itself."""
        if self.cfg.anchor != "last":
            raise ValueError('rollout: a prior with anchor "window" corrects a window, it does not forecast')
        step = self if step is None else step
        hist = obs[:, -self.cfg.obs_len :]
        out = []
        n = 0
        while n < horizon:
            nxt = step(hist)
            out.append(nxt)
            n += nxt.shape[1]
            hist = torch.cat([hist, nxt], dim=1)[:, -self.cfg.obs_len :]
        return torch.cat(out, dim=1)[:, :horizon]


def attach_gap_forecaster(fill: nn.Module, forecaster: nn.Module) -> nn.Module:
    """Gives a repair fill with ``gap_fill: "forecaster"`` the forecaster it fills whole-frame gaps with
    (``training.model.fill_gaps``); returns ``fill``. Kept out of the module's children, so the fill's
    ``state_dict`` (what its file holds) stays its own."""
    if fill.cfg.anchor != "window" or forecaster.cfg.anchor != "last":
        raise ValueError('attach_gap_forecaster: a repair fill (anchor "window") and a forecaster (anchor "last")')
    vars(fill)["gap_forecaster"] = forecaster  # a plain attribute, not a registered submodule
    return fill


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


# ------------------------------------------------------------------------------------------ data


def dataset_joint_names(dataset: str) -> tuple:
    """The names of the model joints of ``dataset``, in the data's order (left/right are the subject's)."""
    if dataset == "humaneva":
        from .data.humaneva import HUMANEVA_MODEL_JOINT_NAMES

        return HUMANEVA_MODEL_JOINT_NAMES
    from tcd.layouts import get_layout

    return get_layout("h36m22").joint_names


def training_sequences(cfg: PriorConfig, data: str | None = None) -> list[np.ndarray]:
    """The training sequences of ``cfg.subjects`` in ``cfg.dataset``, (T, J, 3) float32 metres each."""
    if cfg.dataset == "humaneva":
        from .data.humaneva import training_mix

        return training_mix(cfg.h36m_share, cfg.obs_len + cfg.future, data, cfg.subjects)
    from .data.h36m import DEFAULT_H36M_DIR, H36M, SPLITS

    known = {s for subs in SPLITS.values() for s in subs}
    if set(cfg.subjects) - known or 5 in cfg.subjects:
        raise ValueError(
            f"prior config: subjects must be among {sorted(known - {5})} (S5 is the test subject), "
            f"got {list(cfg.subjects)}"
        )
    h = H36M(data or DEFAULT_H36M_DIR)
    return [
        seq
        for split in ("train", "val")
        for key, seq in h.sequences(split)
        if int(key.split("/")[0][1:]) in cfg.subjects
    ]


def training_frames(
    cfg: PriorConfig, data: str | None = None, seqs: list[np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """All training sequences (``seqs``, else :func:`training_sequences`) concatenated, (N, K) float32
    metres, and the start rows of every window of ``obs_len + future`` frames that lies inside one sequence."""
    seqs = training_sequences(cfg, data) if seqs is None else seqs
    L = cfg.obs_len + cfg.future
    frames, starts, offset = [], [], 0
    for seq in seqs:
        frames.append(seq.reshape(len(seq), -1))
        starts.extend(range(offset, offset + len(seq) - L + 1))
        offset += len(seq)
    if not starts:
        raise ValueError(f"no training window of {L} frames (obs_len + future) in the {cfg.dataset} data")
    return np.concatenate(frames).astype(np.float32), np.asarray(starts, dtype=np.int64)


def batch(cfg: PriorConfig, frames: np.ndarray, starts: np.ndarray, iteration: int) -> torch.Tensor:
    """Iteration ``iteration``'s windows (B, obs_len + future, K): uniform window starts, each reversed
    in time with probability ``flip_prob``, turned about ``rotate_axis`` when set, and with probability
    ``obs_noise_prob`` given N(0, obs_noise_mm^2) noise on its observed frames (metres: the data's units), so the
    prior learns to forecast from noisy keypoints (the protocol's noisy_25); a pure function of (seed, iteration)."""
    rng = np.random.default_rng([cfg.seed, iteration])
    rows = starts[rng.integers(0, len(starts), cfg.batch_size)]
    L = cfg.obs_len + cfg.future
    if cfg.speed_range:  # its own stream: configs without it keep their batches bit for bit
        lo, hi = np.log(cfg.speed_range)
        speeds = np.exp(np.random.default_rng([cfg.seed, iteration, 1]).uniform(lo, hi, cfg.batch_size))
        wins = resample(frames, rows, sequence_ends(starts, L)[np.searchsorted(starts, rows)], L, speeds)
    else:
        wins = frames[rows[:, None] + np.arange(L)]
    flip = rng.random(cfg.batch_size) < cfg.flip_prob
    wins[flip] = wins[flip, ::-1]
    if cfg.rotate_axis:  # drawn after the flips: configs without it keep their batches bit for bit
        B, T, K = wins.shape
        wins = rotate_about(wins.reshape(B, T, K // 3, 3), cfg.rotate_axis, rng).reshape(B, T, K)
    if cfg.mirror_prob > 0.0:  # drawn after the rotation, for the same reason
        B, T, K = wins.shape
        which = rng.random(cfg.batch_size) < cfg.mirror_prob
        perm = mirror_permutation(dataset_joint_names(cfg.dataset))
        wins = mirror(wins.reshape(B, T, K // 3, 3), cfg.rotate_axis, perm, which).reshape(B, T, K)
    if cfg.obs_noise_prob > 0.0:  # drawn last, for the same reason
        noisy = rng.random(cfg.batch_size) < cfg.obs_noise_prob
        noise = rng.normal(0.0, cfg.obs_noise_mm * 1e-3, (cfg.batch_size, cfg.obs_len, wins.shape[2]))
        wins[noisy, : cfg.obs_len] += noise[noisy].astype(wins.dtype)
    return torch.from_numpy(np.ascontiguousarray(wins))


def loss_fn(pred: torch.Tensor, target: torch.Tensor, velocity_weight: float) -> torch.Tensor:
    """Mean per-joint L2 distance of the positions plus ``velocity_weight`` x the same of the frame-to-frame
    velocities. (B, T, K) each, K = 3 J."""
    B, T, K = pred.shape
    pos = torch.linalg.vector_norm((pred - target).reshape(B, T, K // 3, 3), dim=-1).mean()
    if velocity_weight == 0.0 or T < 2:
        return pos
    dv = (pred[:, 1:] - pred[:, :-1]) - (target[:, 1:] - target[:, :-1])
    return pos + velocity_weight * torch.linalg.vector_norm(dv.reshape(B, T - 1, K // 3, 3), dim=-1).mean()


def repair_batch(cfg: PriorConfig, wins: torch.Tensor, iteration: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A repair fill's training input for ``wins`` (B, obs_len, K), anchor ``"window"``: each window given one
    mask of ``cfg.mask_mix`` (drawn by weight from the (seed, iteration, 2) stream, so the window draws of
    :func:`batch` are those of a forecaster's config) -> (the window with its hidden entries filled by the
    natural cubic spline through each coordinate's observed frames, the joint mask (B, obs_len, J): 1 observed).
    The spline is what the engine computes before the fill's forward (``tcd-core`` ``fill_spline``)."""
    from .masks import make_mask, mix_entry
    from .model import spline_fill

    mix = [mix_entry(e) for e in cfg.mask_mix]
    p = np.array([w for _, w, _ in mix], dtype=np.float64)
    rng = np.random.default_rng([cfg.seed, iteration, 2])
    B, L, K = wins.shape
    joint_mask = torch.from_numpy(
        np.stack([make_mask(mix[i][0], L, L, rng, rate=mix[i][2]) for i in rng.choice(len(mix), B, p=p / p.sum())])
    )
    mk = joint_mask.repeat_interleave(3, -1).transpose(1, 2)  # (B, K, L)
    return spline_fill(wins.transpose(1, 2), mk).transpose(1, 2).contiguous(), joint_mask


def hidden_loss(
    pred: torch.Tensor, target: torch.Tensor, joint_mask: torch.Tensor, how: str = "pooled"
) -> torch.Tensor:
    """The mean per-joint L2 distance over the hidden joints (joint_mask 0) of (B, L, K) windows: what
    ``benches/repair_quality.py`` scores (the observed entries are given back exactly). ``how="log_window"``:
    the mean over the windows with a hidden joint of the log of each one's mean distance instead."""
    B, L, K = pred.shape
    err = torch.linalg.vector_norm((pred - target).reshape(B, L, K // 3, 3), dim=-1)
    hidden = 1.0 - joint_mask
    if how == "pooled":
        return (err * hidden).sum() / hidden.sum().clamp(min=1.0)
    n = hidden.sum(dim=(1, 2))
    per_window = (err * hidden).sum(dim=(1, 2))[n > 0] / n[n > 0]
    return torch.log(per_window + 1e-6).mean()


def window_loss(cfg: PriorConfig, model: nn.Module, forward, wins: torch.Tensor, draw: int) -> torch.Tensor:
    """The training loss of the windows ``wins`` (:func:`batch`'s): a forecaster's (:func:`loss_fn` on its
    chunk, or on ``loss_frames`` rolled out), or a repair fill's (:func:`hidden_loss` over the masks of
    :func:`repair_batch`'s draw ``draw``). ``forward``: the forward to call (a compiled one), else ``model``."""
    if cfg.anchor == "window":  # a repair fill: the spline-filled masked window in, the window out
        filled, joint_mask = repair_batch(cfg, wins, draw)
        return hidden_loss(forward(filled), wins, joint_mask, cfg.window_loss)
    obs = wins[:, : cfg.obs_len]
    # loss_frames > chunk: the loss covers the rolled-out horizon the prior is used at (HumanEva-I rolls 15
    # frames out to 60), so the network learns to forecast from its own chunks, not only from the data's
    pred = forward(obs) if cfg.future == cfg.chunk else model.rollout(obs, cfg.future, forward)
    return loss_fn(pred, wins[:, cfg.obs_len :], cfg.velocity_weight)


def validation_windows(
    cfg: PriorConfig, data: str | None = None, frames: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[PriorConfig, torch.Tensor]:
    """The held-out windows of ``cfg.val_subjects`` a run validates on: ``val_windows`` of them, drawn once
    (draw 0 of a config of those subjects, without flips or turns), and that config (whose ``repair_batch``
    draw 0 gives a repair fill's masks). ``frames`` replaces those subjects' frames (tests)."""
    vcfg = replace(
        cfg,
        subjects=cfg.val_subjects,
        val_subjects=(),
        val_every=0,
        batch_size=cfg.val_windows,
        flip_prob=0.0,
        rotate_axis="",
        mirror_prob=0.0,
        h36m_share=0.0,
    )
    return vcfg, batch(vcfg, *(frames if frames is not None else training_frames(vcfg, data)), 0)


def validation_loss(vcfg: PriorConfig, model: nn.Module, val: torch.Tensor) -> float:
    """The validation score of ``model`` on the windows ``val`` (:func:`validation_windows`): its training
    loss on them; for a repair fill with ``val_mask_mix``, the geometric mean over those patterns of the
    pooled hidden error of each (every window masked by each pattern in turn: draw 0)."""
    if not vcfg.val_mask_mix:
        return window_loss(vcfg, model, model, val, 0).item()
    logs = [
        math.log(window_loss(replace(vcfg, mask_mix=(entry,), window_loss="pooled"), model, model, val, 0).item())
        for entry in vcfg.val_mask_mix
    ]
    return math.exp(sum(logs) / len(logs))


def learning_rate(cfg: PriorConfig, iteration: int) -> float:
    return cfg.lr if iteration < int(cfg.lr_decay_at * cfg.iterations) else cfg.lr_final


def same_run_so_far(old: PriorConfig, new: PriorConfig, iterations: int) -> bool:
    """Whether ``iterations`` iterations of ``old`` are exactly the first ones of ``new``: the configs differ
    at most in the schedule's length (``iterations``, ``lr_decay_at``) and every learning rate used so far is
    the same. Then a run may be resumed under ``new`` (a schedule shortened or lengthened before its decay):
    the batches are functions of (seed, iteration) only, so the result is the run ``new`` would have made."""
    schedule = {"iterations", "lr_decay_at"}
    if {k: v for k, v in old.to_dict().items() if k not in schedule} != {
        k: v for k, v in new.to_dict().items() if k not in schedule
    }:
        return False
    return all(learning_rate(old, i) == learning_rate(new, i) for i in range(iterations))


# ------------------------------------------------------------------------------------------ loop


def _save(path: Path, state: dict) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    tmp.replace(path)


def train(
    cfg: PriorConfig,
    out: str | Path,
    *,
    data: str | None = None,
    resume: bool = False,
    max_minutes: float | None = None,
    checkpoint_minutes: float = 5.0,
    compile: bool = False,
    frames: tuple[np.ndarray, np.ndarray] | None = None,
    val_frames: tuple[np.ndarray, np.ndarray] | None = None,
    log=print,
) -> dict:
    """Train (or resume) into ``out`` (``last.pt``: weights, optimizer, iteration, loss history, CPU
    seconds). Stops resumably after ``max_minutes``. ``compile``: ``torch.compile`` the forward (1.9x
    the windows/s of eager at 48 blocks on one Zen 5 core, after about 50 s of compiling; the weights are
    the eager module's). ``frames`` replaces the dataset, ``val_frames`` the validation subjects' (tests).
    With ``val_every``, ``best.pt`` (as ``last.pt``) holds the weights of the lowest validation loss."""
    if cfg.anchor == "window" and not cfg.mask_mix:
        raise ValueError('prior config: anchor "window" trains on a mask_mix (the occlusions it learns to fill)')
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    model = PriorNet(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    last = out / "last.pt"
    it, elapsed0, history = 0, 0.0, []
    if resume and last.is_file():
        ck = torch.load(last, map_location="cpu", weights_only=False)
        if PriorConfig.from_dict(ck["config"]).to_dict() != cfg.to_dict():  # (a config before `dataset`: h36m)
            if not same_run_so_far(PriorConfig.from_dict(ck["config"]), cfg, ck["iteration"]):
                raise ValueError(f"{last} was trained with another config; start a new --out or use the same config")
            log(
                f"{last}: the schedule changes to {cfg.iterations} iterations (decay at {cfg.lr_decay_at}); "
                f"its {ck['iteration']} iterations are the new schedule's first"
            )
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        it, elapsed0, history = ck["iteration"], ck["elapsed_s"], ck["history"]
        log(f"resumed from {last}: iteration {it}")
    elif cfg.init_from:
        if str(cfg.init_from).endswith(".safetensors"):  # an exported prior (a bundled one's run may be gone)
            from .export import load_prior_file

            init = {"model": load_prior_file(cfg.init_from)[0].state_dict(), "iteration": "exported"}
        else:
            init = torch.load(cfg.init_from, map_location="cpu", weights_only=False)
        grown = load_grown(model, init["model"])
        log(
            f"weights from {cfg.init_from} (iteration {init['iteration']} of its run)"
            + (f"; blocks {cfg.blocks - grown + 1}..{cfg.blocks} added as identities" if grown else "")
        )
    fr, starts = frames if frames is not None else training_frames(cfg, data)
    if fr.shape[1] != 3 * cfg.num_joints:
        raise ValueError(
            f"the {cfg.dataset} prior has {cfg.num_joints} joints ({3 * cfg.num_joints} coordinates), "
            f"the training frames {fr.shape[1]} coordinates"
        )
    forward = torch.compile(model) if compile else model
    log(
        f"prior: {count_parameters(model):,} parameters, {len(starts):,} training windows, "
        f"{torch.get_num_threads()} thread(s)"
    )

    if cfg.val_every:
        vcfg, val = validation_windows(cfg, data, val_frames)
        best_val = min((h["val"] for h in history if "val" in h), default=float("inf"))
        log(f"validation: {len(val)} windows of subjects {list(cfg.val_subjects)} every {cfg.val_every} iterations")

    def state() -> dict:
        return {
            "config": cfg.to_dict(),
            "model": model.state_dict(),
            "optimizer": opt.state_dict(),
            "iteration": it,
            "elapsed_s": elapsed0 + time.time() - t0,
            "history": history,
        }

    t0 = last_ck = time.time()
    run_loss, run_n = 0.0, 0
    while it < cfg.iterations:
        for g in opt.param_groups:
            g["lr"] = learning_rate(cfg, it)
        loss = window_loss(cfg, model, forward, batch(cfg, fr, starts, it), it)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        it += 1
        run_loss, run_n = run_loss + loss.item(), run_n + 1
        if it % 200 == 0 or it == cfg.iterations:
            history.append({"iteration": it, "loss": run_loss / run_n, "elapsed_s": elapsed0 + time.time() - t0})
            log(
                f"iteration {it}/{cfg.iterations}: loss {run_loss / run_n:.5f}, "
                f"{(elapsed0 + time.time() - t0) / 60:.1f} min"
            )
            run_loss, run_n = 0.0, 0
        if cfg.val_every and (it % cfg.val_every == 0 or it == cfg.iterations):
            with torch.no_grad():
                v = validation_loss(vcfg, model, val)
            history.append({"iteration": it, "val": v, "elapsed_s": elapsed0 + time.time() - t0})
            if v < best_val:
                best_val = v
                _save(out / "best.pt", state())
            log(f"iteration {it}: validation loss {v:.5f} (best {best_val:.5f})")
        now = time.time()
        if now - last_ck > 60 * checkpoint_minutes:
            _save(last, state())
            last_ck = now
        if max_minutes is not None and now - t0 > 60 * max_minutes:
            log(f"stopping after {max_minutes} min at iteration {it} (resume with --resume)")
            break
    _save(last, state())
    return {"iteration": it, "history": history, "done": it >= cfg.iterations}


def load_grown(model: PriorNet, state: dict) -> int:
    """Load ``state`` (a prior's weights) into ``model``, which may have more blocks than it: the extra blocks
    come last, each made the identity (layer-norm weight and bias zero: ``x + 0``), so the deeper network
    starts as the function ``state`` computes and training adds depth from there. Anything else that differs
    is an error. Returns the number of blocks added."""
    have = 1 + max((int(k.split(".")[1]) for k in state if k.startswith("blocks.")), default=-1)
    added = len(model.blocks) - have
    if added < 0:
        raise ValueError(f"init_from has {have} blocks, the config {len(model.blocks)}: a prior can grow, not shrink")
    try:
        missing, unexpected = model.load_state_dict(state, strict=False)
    except RuntimeError as e:  # shapes differ: another dataset, obs_len or joint count
        raise ValueError(f"init_from does not fit the config: {e}") from None
    new = {
        f"blocks.{i}.{name}"
        for i in range(have, len(model.blocks))
        for name in ("fc.weight", "fc.bias", "norm_weight", "norm_bias")
    }
    if unexpected or set(missing) != new:
        raise ValueError(
            f"init_from does not fit the config: missing {sorted(set(missing) - new)}, unexpected {sorted(unexpected)}"
        )
    with torch.no_grad():
        for block in model.blocks[have:]:
            block.norm_weight.zero_()
            block.norm_bias.zero_()
    return added


def load(path: str | Path) -> PriorNet:
    """A trained prior from a ``last.pt`` checkpoint, in eval mode."""
    ck = torch.load(path, map_location="cpu", weights_only=False)
    model = PriorNet(PriorConfig.from_dict(ck["config"]))
    model.load_state_dict(ck["model"])
    return model.eval()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m training.prior", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--config", required=True, help="prior config JSON (keys of PriorConfig)")
    ap.add_argument("--out", required=True, help="run directory (last.pt)")
    ap.add_argument(
        "--data",
        default=None,
        help="the config's dataset: the Human3.6M directory (default "
        "../shared/data/h36m) or the HumanEva-I directory or .npz (default ../shared/data/humaneva)",
    )
    ap.add_argument("--resume", action="store_true", help="continue from <out>/last.pt")
    ap.add_argument("--max-minutes", type=float, default=None)
    ap.add_argument("--checkpoint-minutes", type=float, default=5.0)
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1: keep a core free)")
    ap.add_argument("--no-compile", dest="compile", action="store_false", help="train the eager forward")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    res = train(
        PriorConfig.load(args.config),
        args.out,
        data=args.data,
        resume=args.resume,
        max_minutes=args.max_minutes,
        checkpoint_minutes=args.checkpoint_minutes,
        compile=args.compile,
        log=lambda m: print(m, flush=True),
    )
    print(json.dumps({k: v for k, v in res.items() if k != "history"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
