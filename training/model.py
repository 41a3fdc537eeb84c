"""The CSDI/TCD denoiser (spec TCD_REFERENCE.md section 1), written from the spec.

Every coordinate of a frame is a token: a window is a (B, K, L) tensor with K = 3 x joints.
The network predicts the noise added to the entries that are not conditioned (mask 0).

state_dict keys mirror the reference structure (section 10.1):
``embed_layer.weight`` and ``diffmodel.*``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import torch
from torch import nn
import torch.nn.functional as F


COND_FILLS = ("zero", "linear", "spline", "prior")
TARGETS = ("absolute", "linear_residual", "spline_residual", "prior_residual")


@dataclass
class ModelConfig:
    num_joints: int = 22  # joints in the model layout (Human3.6M: 22)
    coords: int = 3  # coordinates per joint
    channels: int = 64  # residual channels C
    num_layers: int = 12  # residual blocks (H36M 12, AMASS 4)
    num_heads: int = 8  # attention heads of both transformers
    ffn_dim: int = 64  # feed-forward width of the transformer layers
    diffusion_embedding_dim: int = 128  # step embedding width (table and projections)
    time_embedding_dim: int = 128  # sinusoidal frame-index embedding channels
    feature_embedding_dim: int = 16  # learned per-coordinate embedding channels
    layer_norm_eps: float = 1e-5  # PyTorch default of nn.TransformerEncoderLayer
    dropout: float = 0.1  # transformer dropout (training only; the reference keeps PyTorch's default)
    cond_fill: str = "zero"  # what the observed channel holds at masked entries: "zero" (CSDI/TCD),
    # "linear" (interpolated along time from the observed frames, PriSTI-style)
    # or "spline" (the natural cubic spline through them, spline_fill)
    # or "prior" (prior_fill: the spline over the observed frames, the
    # prior forecaster's rollout over the frames after them)
    target: str = "absolute"  # what the diffusion generates: "absolute" (the poses, TCD) or
    # "linear_residual": target_scale * (poses - linear_fill(observed, mask)),
    # "spline_residual": the same over spline_fill,
    # "prior_residual": the same over prior_fill (needs cond_fill "prior")
    target_scale: float = 1.0  # multiplier of the residual (brings it to the scale of the data)

    @property
    def num_features(self) -> int:  # K
        return self.num_joints * self.coords

    @property
    def side_dim(self) -> int:  # time + feature embeddings + the mask channel
        return self.time_embedding_dim + self.feature_embedding_dim + 1

    def to_dict(self) -> dict:
        d = asdict(self)
        d["num_features"] = self.num_features
        d["side_dim"] = self.side_dim
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ModelConfig":
        names = {f.name for f in fields(cls)}
        cfg = cls(**{k: v for k, v in d.items() if k in names})
        for derived in ("num_features", "side_dim"):
            if derived in d and d[derived] != getattr(cfg, derived):
                raise ValueError(
                    f"model config: {derived}={d[derived]} disagrees with the sizes ({getattr(cfg, derived)})"
                )
        if cfg.cond_fill not in COND_FILLS:
            raise ValueError(f"model config: cond_fill must be one of {COND_FILLS}, got {cfg.cond_fill!r}")
        if cfg.target not in TARGETS:
            raise ValueError(f"model config: target must be one of {TARGETS}, got {cfg.target!r}")
        if (cfg.target == "prior_residual") != (cfg.cond_fill == "prior"):
            raise ValueError(
                "model config: target 'prior_residual' and cond_fill 'prior' go together "
                f"(got target {cfg.target!r}, cond_fill {cfg.cond_fill!r})"
            )
        if not (
            isinstance(cfg.target_scale, (int, float)) and math.isfinite(cfg.target_scale) and cfg.target_scale > 0
        ):
            raise ValueError(f"model config: target_scale must be a finite number > 0, got {cfg.target_scale!r}")
        if cfg.channels % cfg.num_heads:
            raise ValueError(f"model config: channels={cfg.channels} is not divisible by num_heads={cfg.num_heads}")
        return cfg


class Conv1x1(nn.Conv1d):
    """Kernel-size-1 Conv1d (same parameters and state_dict as nn.Conv1d) computed as a matrix product,
    which is several times faster than PyTorch's CPU convolution path for this shape."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, Cin, N) -> (B, Cout, N)
        return torch.matmul(self.weight.squeeze(-1), x) + self.bias.unsqueeze(-1)


def conv1x1(cin: int, cout: int) -> Conv1x1:
    """1x1 Conv1d with kaiming-normal weight (CSDI's Conv1d_with_init); bias keeps PyTorch's default."""
    layer = Conv1x1(cin, cout, 1)
    nn.init.kaiming_normal_(layer.weight)
    return layer


def step_embedding_table(num_steps: int, dim: int) -> torch.Tensor:
    """Fixed table (num_steps, dim): row t = [sin(t f_j)]_j ++ [cos(t f_j)]_j, f_j = 10^(4 j/(dim/2 - 1))."""
    half = dim // 2
    steps = torch.arange(num_steps, dtype=torch.float32).unsqueeze(1)
    freqs = 10.0 ** (torch.arange(half, dtype=torch.float32) / (half - 1) * 4.0).unsqueeze(0)
    table = steps * freqs
    return torch.cat([torch.sin(table), torch.cos(table)], dim=1)


def frame_embedding(length: int, dim: int, device=None) -> torch.Tensor:
    """Sinusoidal embedding of frame positions 0..length-1: (length, dim), even channels sin, odd cos."""
    pos = torch.arange(length, dtype=torch.float32, device=device).unsqueeze(1)
    div_term = torch.exp(torch.arange(0, dim, 2, dtype=torch.float32, device=device) * -(math.log(10000.0) / dim))
    pe = torch.zeros(length, dim, device=device)
    pe[:, 0::2] = torch.sin(pos * div_term)
    pe[:, 1::2] = torch.cos(pos * div_term)
    return pe


class DiffusionEmbedding(nn.Module):
    def __init__(self, num_steps: int, dim: int):
        super().__init__()
        # Not a learned weight: recomputed from the formula, kept out of the state_dict.
        self.register_buffer("embedding", step_embedding_table(num_steps, dim), persistent=False)
        self.projection1 = nn.Linear(dim, dim)
        self.projection2 = nn.Linear(dim, dim)

    def forward(self, step: torch.Tensor) -> torch.Tensor:
        x = self.embedding[step]
        x = F.silu(self.projection1(x))
        return F.silu(self.projection2(x))


def transformer(cfg: ModelConfig) -> nn.TransformerEncoder:
    layer = nn.TransformerEncoderLayer(
        d_model=cfg.channels,
        nhead=cfg.num_heads,
        dim_feedforward=cfg.ffn_dim,
        dropout=cfg.dropout,
        activation="gelu",
        layer_norm_eps=cfg.layer_norm_eps,
    )
    return nn.TransformerEncoder(layer, num_layers=1, enable_nested_tensor=False)


class ResidualBlock(nn.Module):
    def __init__(self, cfg: ModelConfig):
        super().__init__()
        C = cfg.channels
        self.diffusion_projection = nn.Linear(cfg.diffusion_embedding_dim, C)
        self.cond_projection = conv1x1(cfg.side_dim, 2 * C)
        self.mid_projection = conv1x1(C, 2 * C)
        self.output_projection = conv1x1(C, 2 * C)
        self.time_layer = transformer(cfg)
        self.feature_layer = transformer(cfg)

    def forward_time(self, y: torch.Tensor, B: int, C: int, K: int, L: int) -> torch.Tensor:
        if L == 1:
            return y
        y = y.reshape(B, C, K, L).permute(0, 2, 1, 3).reshape(B * K, C, L)  # one sequence per coordinate
        y = self.time_layer(y.permute(2, 0, 1)).permute(1, 2, 0)  # (L, B*K, C) sequence-first
        return y.reshape(B, K, C, L).permute(0, 2, 1, 3).reshape(B, C, K * L)

    def forward_feature(self, y: torch.Tensor, B: int, C: int, K: int, L: int) -> torch.Tensor:
        if K == 1:
            return y
        y = y.reshape(B, C, K, L).permute(0, 3, 1, 2).reshape(B * L, C, K)  # one sequence per frame
        y = self.feature_layer(y.permute(2, 0, 1)).permute(1, 2, 0)  # (K, B*L, C)
        return y.reshape(B, L, C, K).permute(0, 2, 3, 1).reshape(B, C, K * L)

    def forward(self, x: torch.Tensor, cond: torch.Tensor, emb: torch.Tensor):
        B, C, K, L = x.shape
        x = x.reshape(B, C, K * L)
        y = x + self.diffusion_projection(emb).unsqueeze(-1)  # (B, C, K*L)
        y = self.forward_time(y, B, C, K, L)
        y = self.forward_feature(y, B, C, K, L)
        y = self.mid_projection(y)  # (B, 2C, K*L)
        y = y + self.cond_projection(cond.reshape(B, cond.shape[1], K * L))
        gate, filt = torch.chunk(y, 2, dim=1)
        y = torch.sigmoid(gate) * torch.tanh(filt)
        y = self.output_projection(y)
        residual, skip = torch.chunk(y, 2, dim=1)
        out = (x + residual) / math.sqrt(2.0)
        return out.reshape(B, C, K, L), skip.reshape(B, C, K, L)


class DiffCSDI(nn.Module):
    def __init__(self, cfg: ModelConfig, num_steps: int):
        super().__init__()
        C = cfg.channels
        self.diffusion_embedding = DiffusionEmbedding(num_steps, cfg.diffusion_embedding_dim)
        self.input_projection = conv1x1(2, C)
        self.output_projection1 = conv1x1(C, C)
        self.output_projection2 = conv1x1(C, 1)
        nn.init.zeros_(self.output_projection2.weight)  # the reference zero-initialises the last conv
        self.residual_layers = nn.ModuleList([ResidualBlock(cfg) for _ in range(cfg.num_layers)])

    def forward(self, x: torch.Tensor, cond: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        B, _, K, L = x.shape
        h = F.relu(self.input_projection(x.reshape(B, 2, K * L))).reshape(B, -1, K, L)
        emb = self.diffusion_embedding(step)
        skip_sum = 0.0
        for layer in self.residual_layers:
            h, skip = layer(h, cond, emb)
            skip_sum = skip_sum + skip
        y = skip_sum.reshape(B, -1, K * L) / math.sqrt(len(self.residual_layers))
        y = F.relu(self.output_projection1(y))
        return self.output_projection2(y).reshape(B, K, L)


class TCDModel(nn.Module):
    """Side information + denoiser. ``forward(noisy, observed, mask, step) -> eps_hat``, all (B, K, L)."""

    def __init__(self, cfg: ModelConfig, num_train_timesteps: int = 50):
        super().__init__()
        self.cfg = cfg
        self.num_train_timesteps = num_train_timesteps
        self.embed_layer = nn.Embedding(cfg.num_features, cfg.feature_embedding_dim)
        self.diffmodel = DiffCSDI(cfg, num_train_timesteps)

    @property
    def prior(self):
        """The frozen prior forecaster of a ``cond_fill="prior"`` model (``attach_prior``), else None."""
        return self.__dict__.get("_prior")

    def attach_prior(self, prior: nn.Module) -> None:
        """Give a ``cond_fill="prior"`` model its prior forecaster (a ``training.prior_net.PriorNet``). It is
        kept out of the module tree on purpose: not in the state_dict (the weight file holds the denoiser;
        the prior ships as its own file), not trained (frozen, eval mode)."""
        prior.eval()
        for p in prior.parameters():
            p.requires_grad_(False)
        self.__dict__["_prior"] = prior

    def side_info(self, mask: torch.Tensor) -> torch.Tensor:
        """(B, K, L) mask -> (B, side_dim, K, L): [frame embedding | feature embedding | mask]."""
        B, K, L = mask.shape
        if K != self.cfg.num_features:
            raise ValueError(f"mask has K={K} features, the model expects {self.cfg.num_features}")
        temb = frame_embedding(L, self.cfg.time_embedding_dim, mask.device)  # (L, 128)
        temb = temb.t().unsqueeze(1).expand(-1, K, -1)  # (128, K, L)
        femb = self.embed_layer.weight.t().unsqueeze(2).expand(-1, -1, L)  # (16, K, L)
        side = torch.cat([temb, femb], dim=0).unsqueeze(0).expand(B, -1, -1, -1)
        return torch.cat([side, mask.unsqueeze(1)], dim=1)

    def forward(
        self, noisy: torch.Tensor, observed: torch.Tensor, mask: torch.Tensor, step: torch.Tensor | int
    ) -> torch.Tensor:
        if not torch.is_tensor(step):
            step = torch.tensor([step], device=noisy.device)
        step = step.reshape(-1).to(noisy.device).long()
        cond = condition(self.cfg, observed, mask, self.prior)
        inp = torch.stack([cond, (1 - mask) * noisy], dim=1)  # (B, 2, K, L)
        return self.diffmodel(inp, self.side_info(mask), step)


def linear_fill(observed: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(..., L) values and 0/1 mask -> observed entries kept, each masked entry linearly interpolated along
    the last axis between the nearest observed entries before and after it, held constant before the first
    and after the last, and 0 on a row with none. Masked entries of ``observed`` are never read (may be NaN).

    In float32 the value is ``a + (b - a) * w`` with ``w = float(l - p) / float(n - p)``, the same operation
    order as the Rust engine (tcd-core ``fill_linear``), so both give identical bits.
    """
    L = observed.shape[-1]
    obs = mask > 0.5
    x = torch.where(obs, observed, torch.zeros((), dtype=observed.dtype, device=observed.device))
    idx = torch.arange(L, device=observed.device).expand_as(x)
    prev = torch.where(obs, idx, torch.full_like(idx, -1)).cummax(-1).values
    nxt = torch.where(obs, idx, torch.full_like(idx, L)).flip(-1).cummin(-1).values.flip(-1)
    has_prev, has_next = prev >= 0, nxt < L
    a = torch.gather(x, -1, prev.clamp(min=0))
    b = torch.gather(x, -1, nxt.clamp(max=L - 1))
    span = (nxt - prev).clamp(min=1).to(x.dtype)
    w = (idx - prev).to(x.dtype) / span
    between = a + (b - a) * w
    out = torch.where(
        has_prev & has_next, between, torch.where(has_prev, a, torch.where(has_next, b, torch.zeros_like(x)))
    )
    return torch.where(obs, x, out)


def spline_fill(observed: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(..., L) values and 0/1 mask -> observed entries kept, each masked entry between two observed entries
    of its row filled by the natural cubic spline through the row's observed entries (knots at their frame
    indices); before the first and after the last observed entry, and on rows with fewer than 2, the rule of
    :func:`linear_fill` (held constant; 0 on a row with none). Masked entries of ``observed`` are never read.

    Computed in float64 and rounded to the input dtype: the second derivatives by the Thomas algorithm
    (``w = b - a * c'[i-1]``, ``c'[i] = c / w``, ``d'[i] = (d - a * d'[i-1]) / w``, then
    ``M[i] = d'[i] - c'[i] * M[i+1]``), the value on a segment of length h at distances a (to its right knot)
    and b (to its left knot) as ``M0*a*a*a/(6*h) + M1*b*b*b/(6*h) + (y0/h - M0*h/6)*a + (y1/h - M1*h/6)*b``:
    the operation order of the Rust engine (tcd-core ``fill_spline``), so both give identical bits.
    """
    L = observed.shape[-1]
    lin = linear_fill(observed, mask)
    if L < 3:
        return lin
    obs = (mask > 0.5).reshape(-1, L)
    x = torch.where(obs, observed.reshape(-1, L), torch.zeros((), dtype=observed.dtype, device=observed.device))
    x = x.to(torch.float64)
    dev = observed.device
    S = x.shape[0]
    n = obs.sum(-1)  # knots per row
    idx = torch.arange(L, device=dev).expand(S, L)
    order = torch.where(obs, idx, idx + L).argsort(-1)  # observed frames first, ascending
    kx = order.to(torch.float64)  # knot frames (valid below n)
    ky = x.gather(-1, order)  # knot values
    h = kx[:, 1:] - kx[:, :-1]
    zero = torch.zeros(S, dtype=torch.float64, device=dev)
    cp = [zero] * L
    dp = [zero] * L
    for i in range(1, L - 1):
        active = i < n - 1
        a, c = h[:, i - 1], h[:, i]
        b = 2.0 * (a + c)
        d = 6.0 * ((ky[:, i + 1] - ky[:, i]) / c - (ky[:, i] - ky[:, i - 1]) / a)
        w = b - a * cp[i - 1]
        cp[i] = torch.where(active, c / w, zero)
        dp[i] = torch.where(active, (d - a * dp[i - 1]) / w, zero)
    M = [zero] * L
    for i in range(L - 2, 0, -1):
        M[i] = torch.where(i < n - 1, dp[i] - cp[i] * M[i + 1], zero)
    M = torch.stack(M, -1)
    # segment of every frame: j = index of the last knot at or before it
    j = (obs.long().cumsum(-1) - 1).clamp(min=0, max=L - 2)
    j1 = j + 1
    x0, x1 = kx.gather(-1, j), kx.gather(-1, j1)
    y0, y1 = ky.gather(-1, j), ky.gather(-1, j1)
    m0, m1 = M.gather(-1, j), M.gather(-1, j1)
    t = idx.to(torch.float64)
    hh = x1 - x0
    a = x1 - t
    b = t - x0
    v = (
        m0 * a * a * a / (6.0 * hh)
        + m1 * b * b * b / (6.0 * hh)
        + (y0 / hh - m0 * hh / 6.0) * a
        + (y1 / hh - m1 * hh / 6.0) * b
    )
    between = ~obs & (obs.long().cumsum(-1) >= 1) & (j1 < n.unsqueeze(-1))
    v = torch.where(between, v, torch.zeros((), dtype=torch.float64, device=dev)).to(observed.dtype)
    return torch.where(between.reshape(observed.shape), v.reshape(observed.shape), lin)


FILLS = {"linear": linear_fill, "spline": spline_fill}


def prior_fill(prior: nn.Module, observed: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """(B, K, L) observation -> observed entries kept; the masked entries of the first ``obs_len`` frames
    (the prior's observation length) filled by :func:`spline_fill` over those frames; the masked entries
    after them by the prior's rollout from the filled frames (frame ``obs_len + i`` = the prior's i-th
    forecast frame). A long-term window's teacher-forced frames (mask 1 after ``obs_len``) stay as given;
    the prior still forecasts from the first ``obs_len`` frames, so the fill is the same function of the
    observation in the short and the long model. A repair fill (``prior.cfg.anchor == "window"``, L =
    ``obs_len``) fills the masked entries with its correction of the spline over the whole window instead, and
    one with ``gap_fill == "forecaster"`` then the window's whole-frame gaps from its forecaster (:func:`fill_gaps`),
    and one with an in-betweener (``inbetween_max_gap``) corrects them, one with a joint in-betweener
    (``joint_inbetween_max_gap``) the runs of a coordinate hidden in seen frames (``training.inbetween``)."""
    if prior is None:
        raise ValueError("a cond_fill='prior' model needs its prior forecaster (TCDModel.attach_prior)")
    obs_len = prior.cfg.obs_len
    L = observed.shape[-1]
    if prior.cfg.anchor == "window":  # a repair fill: its correction of the spline over the whole window
        if L != obs_len:
            raise ValueError(f"prior_fill: the repair fill corrects windows of {obs_len} frames, got {L}")
        spline = spline_fill(observed, mask)
        with torch.no_grad():
            fill = prior(spline.float().transpose(1, 2)).transpose(1, 2).to(observed.dtype)
        fill = torch.where(mask > 0.5, observed, fill)
        if prior.cfg.gap_fill == "forecaster":
            forecaster = getattr(prior, "gap_forecaster", None)
            if forecaster is None:
                raise ValueError(
                    "prior_fill: the repair fill fills whole-frame gaps with a forecaster (gap_fill "
                    '"forecaster"): training.prior_net.attach_gap_forecaster'
                )
            fill = fill_gaps(forecaster, fill, mask)
        if prior.cfg.inbetween_max_gap or prior.cfg.joint_inbetween_max_gap:  # training.inbetween
            from .inbetween import correct_window

            corrected = correct_window(
                prior, fill.transpose(1, 2).numpy(), mask.transpose(1, 2).numpy(), whole_frame_gaps(mask)
            )
            fill = torch.from_numpy(corrected).transpose(1, 2).to(fill.dtype)
        return fill
    if L <= obs_len:
        raise ValueError(f"prior_fill: the window has {L} frames, not more than the prior's {obs_len} observed ones")
    head = spline_fill(observed[..., :obs_len], mask[..., :obs_len])  # (B, K, O)
    with torch.no_grad():
        future = prior.rollout(head.float().transpose(1, 2), L - obs_len).transpose(1, 2).to(observed.dtype)
    fill = torch.cat([head, future], dim=-1)
    return torch.where(mask > 0.5, observed, fill)


def whole_frame_gaps(mask: torch.Tensor) -> list:
    """The runs of frames ``[start, end)`` of each sequence of a (B, K, L) mask with every entry 0, as
    (sequence, start, end), except a run over the whole window (nothing to fill it from)."""
    gaps = []
    for b, row in enumerate((mask <= 0.5).all(dim=1).tolist()):
        t, length = 0, len(row)
        while t < length:
            if not row[t]:
                t += 1
                continue
            start = t
            while t < length and row[t]:
                t += 1
            if start > 0 or t < length:
                gaps.append((b, start, t))
    return gaps


def fill_gaps(forecaster: nn.Module, fill: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """A filled (B, K, L) window with its whole-frame gaps (:func:`whole_frame_gaps`) filled from the prior
    ``forecaster`` (the engine's ``fill_gaps``, the same steps).
    For a gap of n frames [s, e) and w_i = (i + 1) / (n + 1): forward (s > 0), the forecaster's n + 1 frames
    from the frames before the gap (its last ``obs_len``, the first repeated before them where fewer), frame
    i plus w_i times its n-th frame's miss against frame e where the window goes on; backward (e < L), the
    same on the time-reversed frames after the gap, reversed back, meeting frame s - 1; blended as (1 - w_i)
    forward + w_i backward (one alone at a window's edge) and averaged with ``fill`` there. Every history
    is read from ``fill`` as given; all are rolled out in one call."""
    gaps = whole_frame_gaps(mask)
    if not gaps:
        return fill
    o, length = forecaster.cfg.obs_len, fill.shape[-1]
    x = fill.float().transpose(1, 2)  # (B, L, K)

    def history(b: int, frames: list) -> torch.Tensor:  # the last o of ``frames``, the first repeated before
        return x[b, [frames[max(0, len(frames) - o + j)] for j in range(o)]]

    hist, sides = [], []
    for b, s, e in gaps:
        fwd = bwd = None
        if s > 0:
            fwd = len(hist)
            hist.append(history(b, list(range(s))))
        if e < length:
            bwd = len(hist)
            hist.append(history(b, list(range(length - 1, e - 1, -1))))
        sides.append((fwd, bwd))
    horizon = max(e - s for _, s, e in gaps) + 1
    with torch.no_grad():
        pred = forecaster.rollout(torch.stack(hist), horizon)  # (N, horizon, K)
    out = x.clone()
    for (b, s, e), (fwd, bwd) in zip(gaps, sides):
        n = e - s
        w = ((torch.arange(n, dtype=torch.float32) + 1) / (n + 1))[:, None]
        forward = backward = None
        if fwd is not None:
            miss = x[b, e] - pred[fwd, n] if e < length else torch.zeros_like(pred[fwd, n])
            forward = pred[fwd, :n] + w * miss
        if bwd is not None:
            miss = x[b, s - 1] - pred[bwd, n] if s > 0 else torch.zeros_like(pred[bwd, n])
            backward = pred[bwd, :n].flip(0) + (1 - w) * miss  # backward frame i: its forecast's n - 1 - i
        if forward is None:
            both = backward
        elif backward is None:
            both = forward
        else:
            both = (1 - w) * forward + w * backward
        out[b, s:e] = 0.5 * (both + x[b, s:e])
    return out.transpose(1, 2).to(fill.dtype)


def condition(
    cfg: ModelConfig, observed: torch.Tensor, mask: torch.Tensor, prior: nn.Module | None = None
) -> torch.Tensor:
    """What the observed channel of the network holds (``cfg.cond_fill``): ``mask * observed`` (CSDI/TCD),
    or the observation with its masked entries filled (linear, spline, prior)."""
    if cfg.cond_fill == "zero":
        return mask * observed
    if cfg.cond_fill == "prior":
        return prior_fill(prior, observed, mask)
    return FILLS[cfg.cond_fill](observed, mask)


def residual_base(
    cfg: ModelConfig, observed: torch.Tensor, mask: torch.Tensor, prior: nn.Module | None = None
) -> torch.Tensor:
    """What a residual target is taken over: the fill its name says (``"spline_residual"``: spline_fill, ...)."""
    name = cfg.target.removesuffix("_residual")
    return prior_fill(prior, observed, mask) if name == "prior" else FILLS[name](observed, mask)


def to_target(
    cfg: ModelConfig, x0: torch.Tensor, observed: torch.Tensor, mask: torch.Tensor, prior: nn.Module | None = None
) -> torch.Tensor:
    """Clean windows -> the variable the diffusion runs on: x0 itself (``target="absolute"``) or
    ``target_scale * (x0 - base)`` with the base of the residual (:func:`residual_base`)."""
    if cfg.target == "absolute":
        return x0
    return (x0 - residual_base(cfg, observed, mask, prior)) * cfg.target_scale


def from_target(
    cfg: ModelConfig, x: torch.Tensor, observed: torch.Tensor, mask: torch.Tensor, prior: nn.Module | None = None
) -> torch.Tensor:
    """Inverse of :func:`to_target` on a sample: ``base + x * (1 / target_scale)`` in float32 (the
    Rust engine's operation order)."""
    if cfg.target == "absolute":
        return x
    return residual_base(cfg, observed, mask, prior) + x * (1.0 / cfg.target_scale)


def load_grown(model: TCDModel, state: dict) -> int:
    """Load ``state`` (a TCD model's weights) into ``model``, which may have more residual layers than it: the
    extra layers come last, each with its output projection zero (no residual, no skip), and the first output
    conv is scaled by sqrt(new / old layers) to undo the wider skip normalisation (``DiffCSDI.forward`` divides
    the skip sum by sqrt(layers)), so the deeper network starts as exactly the function ``state`` computes and
    training adds depth from there (as ``training.prior.load_grown`` does for the prior). Anything else that
    differs is an error. Returns the number of layers added."""
    prefix = "diffmodel.residual_layers."

    def layer_of(key: str) -> int:  # "diffmodel.residual_layers.3.mid_projection.weight" -> 3
        return int(key[len(prefix) :].split(".")[0])

    have = 1 + max((layer_of(k) for k in state if k.startswith(prefix)), default=-1)
    layers = model.diffmodel.residual_layers
    added = len(layers) - have
    if added < 0:
        raise ValueError(
            f"init_from has {have} residual layers, the config {len(layers)}: a model can grow, not shrink"
        )
    try:
        missing, unexpected = model.load_state_dict(state, strict=False)
    except RuntimeError as e:  # shapes differ: another channel count, joint count or embedding
        raise ValueError(f"init_from does not fit the config: {e}") from None
    new = {k for k in model.state_dict() if k.startswith(prefix) and layer_of(k) >= have}
    if unexpected or set(missing) != new:
        raise ValueError(
            f"init_from does not fit the config: missing {sorted(set(missing) - new)}, unexpected {sorted(unexpected)}"
        )
    if added:
        with torch.no_grad():
            for layer in layers[have:]:
                nn.init.zeros_(layer.output_projection.weight)
                nn.init.zeros_(layer.output_projection.bias)
            model.diffmodel.output_projection1.weight.mul_(math.sqrt(len(layers) / have))
    return added


def randomize_output_layer(model: TCDModel, seed: int = 0, std: float = 0.02) -> None:
    """Give the zero-initialised last conv a small seeded random weight (for fixtures: non-trivial outputs)."""
    g = torch.Generator().manual_seed(seed)
    w = model.diffmodel.output_projection2.weight
    with torch.no_grad():
        w.copy_(torch.randn(w.shape, generator=g) * std)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
