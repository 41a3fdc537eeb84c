"""The deterministic prior forecaster's network and its file: a siMLPe-class network, written from the published
description (``../shared/spec/PRIOR.md``), its configuration (:class:`PriorConfig`, which also holds its training
options: ``training.prior`` trains it) and ``prior.safetensors`` / ``repair_fill.safetensors`` (the shared format of
``training.fileformat``, role ``prior``).

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
prediction is appended to the observation and the last ``obs_len`` frames predict the next chunk. A repair fill
(``anchor`` ``"window"``) is the same network over a whole window, its output added to its input window.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .augment import check_axis
from . import fileformat  # source_revision through the module: tests fix it in one place
from .fileformat import (
    DATASET_JOINTS,
    FORMAT_VERSION,
    PRIOR_FILE,
    PRIOR_ROLE,
    h36m_data_meta,
    humaneva_data_meta,
    setting_a_data_meta,
    read_config,
    save_model_file,
)

NUM_JOINTS = 22
#: what a forward's output is added to (PriorConfig.anchor)
ANCHORS = ("last", "window")
#: how a repair fill fills a window's whole-frame gaps (PriorConfig.gap_fill; training.model.fill_gaps)
GAP_FILLS = ("none", "forecaster")
#: what a repair fill's training loss averages (PriorConfig.window_loss; training.prior.hidden_loss)
WINDOW_LOSSES = ("pooled", "log_window")


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
    dataset: str = "h36m"  # "h36m" (Human3.6M, 22 joints), "humaneva" (HumanEva-I Train split, 14 joints) or
    # "h36m-a" (Human3.6M Setting-A, 16 joints at 50 Hz: training.data.h36m_setting_a)
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
        if self.dataset == "h36m-a" and not (self.subjects and set(self.subjects) <= {1, 5, 6, 7, 8}):
            raise ValueError(
                "prior config: a Human3.6M Setting-A prior trains on subjects among [1, 5, 6, 7, 8] (S9 and S11 "
                f"are its test subjects), got {list(self.subjects)}"
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


def prior_data_meta(cfg) -> dict:
    """The ``data`` block of a prior trained with ``cfg`` (a ``training.prior.PriorConfig``): the denoisers'
    description of its dataset, naming the subjects the prior was trained on."""
    subjects = ",".join(f"S{s}" for s in cfg.subjects)
    if getattr(cfg, "dataset", "h36m") == "humaneva":
        from .data.humaneva import mix_description

        share = getattr(cfg, "h36m_share", 0.0)
        return humaneva_data_meta(mix_description(share, cfg.subjects), with_h36m=bool(share))
    if getattr(cfg, "dataset", "h36m") == "h36m-a":
        return setting_a_data_meta(training_data=f"Human3.6M {subjects} (exp-map, 50 fps, Setting-A)")
    return h36m_data_meta(training_data=f"Human3.6M {subjects} (exp-map, 25 fps)")


def build_prior_config(model, data: dict, training: dict | None = None) -> dict:
    """The ``tcd_config`` of a ``training.prior.PriorNet`` (docs/tcd_config.schema.json, role ``prior``)."""
    k = model.fc_in.in_features
    eps = {float(b.eps) for b in model.blocks}
    if len(eps) != 1:
        raise ValueError(f"the prior's blocks must share one layer-norm epsilon, got {sorted(eps)}")
    m = {
        "num_joints": k // 3,
        "coords": 3,
        "num_features": k,
        "obs_len": model.cfg.obs_len,
        "chunk": model.cfg.chunk,
        "blocks": len(model.blocks),
        "layer_norm_eps": eps.pop(),
    }
    if model.cfg.anchor != "last":  # a forecaster's file stays as before anchor existed (its default)
        m["anchor"] = model.cfg.anchor
    if model.cfg.gap_fill != "none":  # likewise every file written before gap_fill existed
        m["gap_fill"] = model.cfg.gap_fill
    for prefix in ("inbetween", "joint_inbetween"):  # and before the in-betweeners
        if getattr(model.cfg, f"{prefix}_max_gap"):
            m[f"{prefix}_context"] = getattr(model.cfg, f"{prefix}_context")
            m[f"{prefix}_max_gap"] = getattr(model.cfg, f"{prefix}_max_gap")
    return {
        "format_version": FORMAT_VERSION,
        "role": PRIOR_ROLE,
        "model": m,
        "data": data,
        "training": training or {},
        "source_revision": fileformat.source_revision(),
    }


def load_prior_file(path: str | Path):
    """(``training.prior.PriorNet`` in eval mode, its config) from a prior file, loaded strictly."""
    from safetensors.torch import load_file

    cfg = read_config(path, PRIOR_ROLE, "prior")
    m = cfg["model"]
    if m["coords"] != 3 or m["num_features"] != 3 * m["num_joints"]:
        raise ValueError(f"{path}: PriorNet takes 3 coordinates per joint, got {m}")
    model = PriorNet(
        PriorConfig(
            obs_len=m["obs_len"],
            chunk=m["chunk"],
            blocks=m["blocks"],
            anchor=m.get("anchor", "last"),
            gap_fill=m.get("gap_fill", "none"),
            **{
                k: m.get(k, 0)
                for k in (
                    "inbetween_context",
                    "inbetween_max_gap",
                    "joint_inbetween_context",
                    "joint_inbetween_max_gap",
                )
            },
        ),
        joints=m["num_joints"],
    )  # (files before anchor, gap_fill, the in-betweener)
    for b in model.blocks:
        b.eps = float(m["layer_norm_eps"])
    model.load_state_dict(load_file(str(path)), strict=True)
    if model.cfg.gap_fill == "forecaster":  # its forecaster is the model directory's, beside it
        forecaster = Path(path).parent / PRIOR_FILE
        if not forecaster.is_file():
            raise ValueError(
                f"{path}: the repair fill fills whole-frame gaps with the prior forecaster (gap_fill "
                f'"forecaster"), but {forecaster} is missing'
            )

        attach_gap_forecaster(model, load_prior_file(forecaster)[0])
    return model.eval(), cfg


def save_prior(path: str | Path, model, training: dict | None = None) -> Path:
    """Writes a ``training.prior.PriorNet`` as a prior file (its data block from its config's subjects)."""
    path = Path(path)
    save_model_file(path, model.eval(), build_prior_config(model, prior_data_meta(model.cfg), training))
    return path


def random_prior(
    blocks: int = 24, seed: int = 0, obs_len: int = 50, chunk: int = 10, joints: int = 22, anchor: str = "last"
):
    """A ``training.prior.PriorNet`` with every weight drawn from a seeded normal of unit-gain scale (std
    1/sqrt(fan_in) for the matrices, 0.1 for the biases, 1 + 0.1 N(0, 1) for the norm weights), fc_out then
    scaled by 1/20 so that the forecast lies a few tenths of a metre (rms) from the last pose, the scale of
    real motion (unscaled: metres): unlike the trained init (fc_out ~ 1e-8, i.e. Zero-Velocity) every
    weight shapes the output. ``anchor="window"`` (chunk = obs_len): a repair fill, its correction as far from
    its input window. A fixture for parity tests and benchmarks."""

    model = PriorNet(PriorConfig(obs_len=obs_len, chunk=chunk, blocks=blocks, anchor=anchor), joints=joints)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in model.named_parameters():
            z = torch.randn(p.shape, generator=g)
            if p.dim() == 2:
                p.copy_(z / math.sqrt(p.shape[1]))
            elif name.endswith("norm_weight"):
                p.copy_(1.0 + 0.1 * z)
            else:
                p.copy_(0.1 * z)
        model.fc_out.weight.mul_(0.05)
        model.fc_out.bias.mul_(0.05)
    return model.eval()
