"""Widening a trained denoiser: ``channels`` and ``ffn_dim`` times an integer ``factor``, the same function.

Why: on HumanEva-I the 5 x 32 long model stopped improving whatever the recipe, and it does not fit Box even on its
own training windows (docs/training.md, "Tried, not kept"). A wider network trained from
scratch would throw away the installments behind the bundled one; this starts it where they left off.

How (Net2Net, Chen et al. 2016, with exact preservation): every channel of the residual stream, of the skips, of
the gate and filter halves and of the feed-forward layers is copied ``factor`` times, so each hidden vector of the
wide network is the narrow one's repeated. A layer that reads copied channels splits each narrow weight among the
copies with random shares that sum to 1, so it computes exactly what it did (the copies are equal), yet the copies
of the layer before receive different gradients from then on, so they can part. LayerNorm over repeated copies has
the narrow mean and variance, so the norms keep their weights. Each attention head keeps its place and widens by
the factor (the head count stays): its queries are scaled by 1 / sqrt(factor), which undoes the wider head's
1 / sqrt(head dim) against the factor-times longer dot product of repeated queries and keys.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from .model import ModelConfig


def widened_config(cfg: ModelConfig, factor: int) -> ModelConfig:
    """``cfg`` with ``channels`` and ``ffn_dim`` times ``factor`` (the heads' count unchanged)."""
    if not isinstance(factor, int) or factor < 1:
        raise ValueError(f"factor must be an integer >= 1, got {factor!r}")
    return replace(cfg, channels=cfg.channels * factor, ffn_dim=cfg.ffn_dim * factor)


def _plain(n: int, f: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Channels laid out as f copies one after another: wide index j -> (narrow index, copy)."""
    j = torch.arange(n * f)
    return j % n, j // n


def _heads(n: int, heads: int, f: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Attention projections: head h of the wide layer is head h of the narrow one, its dims repeated f times."""
    d = n // heads
    j = torch.arange(n * f)
    h, within = j // (f * d), j % (f * d)
    return h * d + within % d, within // d


def _halves(n: int, f: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A 2n-channel output chunked in two halves (gate | filter, residual | skip), each half widened as _plain."""
    j = torch.arange(2 * n * f)
    half, within = j // (n * f), j % (n * f)
    return half * n + within % n, within // n


def _same(n: int) -> tuple[torch.Tensor, None]:
    """Inputs that are not widened (the side information, the step embedding, the two input channels)."""
    return torch.arange(n), None


class _Splitter:
    """Builds each wide weight from its narrow one and the row / column maps; seeded shares for copied inputs."""

    def __init__(self, factor: int, seed: int, spread: float):
        self.f, self.spread = factor, spread
        self.gen = torch.Generator().manual_seed(seed)

    def linear(self, w: torch.Tensor, rows, cols, row_scale: torch.Tensor | None = None) -> torch.Tensor:
        """w (out, in[, 1]) -> (len(rows), len(cols)[, 1]): W'[j, i] = W[row(j), col(i)] x share(j, i), the shares of
        the copies of one narrow input summing to 1 in each row (1 where the input is not copied)."""
        conv = w.dim() == 3
        w2 = w[..., 0] if conv else w
        (r_old, _), (c_old, c_copy) = rows, cols
        wide = w2[r_old][:, c_old].clone()
        if c_copy is not None:
            n_in = w2.shape[1]
            r = (torch.rand(len(r_old), n_in, self.f, generator=self.gen, dtype=torch.float64) - 0.5) * self.spread
            share = 1.0 / self.f + r - r.mean(-1, keepdim=True)  # sums to 1 over the copies
            wide = wide * share[:, c_old, c_copy].to(wide.device, wide.dtype)
        if row_scale is not None:
            wide = wide * row_scale[:, None].to(wide.device, wide.dtype)
        return wide[..., None] if conv else wide

    @staticmethod
    def vector(b: torch.Tensor, rows, row_scale: torch.Tensor | None = None) -> torch.Tensor:
        out = b[rows[0]].clone()
        return out if row_scale is None else out * row_scale.to(out.device, out.dtype)


def widen_state(state: dict, cfg: ModelConfig, factor: int, seed: int = 0, spread: float = 0.5) -> dict:
    """The weights of the model ``widened_config(cfg, factor)`` computing exactly what ``state`` (a
    ``training.model.TCDModel`` state_dict of config ``cfg``) computes (up to float rounding); ``seed`` draws the
    copies' shares: each copy's weight is the narrow weight x (1 / factor + u - the mean of the copies' u), u uniform
    of width ``spread`` about 0, so the shares of one weight sum to 1."""
    widened_config(cfg, factor)  # checks the factor
    C, F, H, f = cfg.channels, cfg.ffn_dim, cfg.num_heads, factor
    if C % H:
        raise ValueError(f"channels {C} is not a multiple of num_heads {H}")
    sp = _Splitter(f, seed, spread)
    plain_c, plain_f, heads_c, halves_c = _plain(C, f), _plain(F, f), _heads(C, H, f), _halves(C, f)
    q_scale = torch.cat([torch.full((C * f,), 1.0 / math.sqrt(f)), torch.ones(2 * C * f)])
    qkv_rows = torch.cat([heads_c[0] + k * C for k in range(3)]), None  # queries | keys | values, by head
    out = {}
    seen = set()

    def put(key: str, rows, cols, row_scale=None):
        w = state[key + ".weight"]
        out[key + ".weight"] = sp.linear(w, rows, cols, row_scale)
        if key + ".bias" in state:
            out[key + ".bias"] = sp.vector(state[key + ".bias"], rows, row_scale)
        seen.update({key + ".weight", key + ".bias"})

    def norm(key: str):
        out[key + ".weight"] = state[key + ".weight"][plain_c[0]].clone()
        out[key + ".bias"] = state[key + ".bias"][plain_c[0]].clone()
        seen.update({key + ".weight", key + ".bias"})

    d = "diffmodel."
    put(d + "input_projection", plain_c, _same(2))
    put(d + "output_projection1", plain_c, plain_c)
    put(d + "output_projection2", _same(1), plain_c)
    layers = sorted({int(k.split(".")[2]) for k in state if k.startswith(d + "residual_layers.")})
    for i in layers:
        p = f"{d}residual_layers.{i}."
        put(p + "diffusion_projection", plain_c, _same(cfg.diffusion_embedding_dim))
        put(p + "cond_projection", halves_c, _same(cfg.side_dim))
        put(p + "mid_projection", halves_c, plain_c)
        put(p + "output_projection", halves_c, plain_c)
        for t in ("time_layer", "feature_layer"):
            q = f"{p}{t}.layers.0."
            a = q + "self_attn."
            out[a + "in_proj_weight"] = sp.linear(state[a + "in_proj_weight"], qkv_rows, plain_c, q_scale)
            out[a + "in_proj_bias"] = sp.vector(state[a + "in_proj_bias"], qkv_rows, q_scale)
            seen.update({a + "in_proj_weight", a + "in_proj_bias"})
            put(a + "out_proj", plain_c, heads_c)
            put(q + "linear1", plain_f, plain_c)
            put(q + "linear2", plain_c, plain_f)
            norm(q + "norm1")
            norm(q + "norm2")
    for k, v in state.items():  # what does not depend on the width, as it was
        if k not in seen:
            if not (k.startswith("embed_layer.") or k.startswith(d + "diffusion_embedding.")):
                raise ValueError(f"widen_state does not know the tensor {k!r}")
            out[k] = v.clone()
    return out


def widen_to(cfg: ModelConfig, state: dict, seed: int = 0) -> tuple[dict, int]:
    """``state`` made as wide as ``cfg`` asks (``widen_state``) where its channels are a whole fraction of
    ``cfg.channels`` and its feed-forward width the same fraction of ``cfg.ffn_dim``; returns the weights and the
    factor (1: ``state`` unchanged, already as wide). Any other mismatch is left to the caller's load to report."""
    key = "diffmodel.input_projection.weight"
    if key not in state:
        return state, 1
    narrow = state[key].shape[0]
    if narrow == cfg.channels or cfg.channels % narrow:
        return state, 1
    f = cfg.channels // narrow
    ffn = state["diffmodel.residual_layers.0.time_layer.layers.0.linear1.weight"].shape[0]
    if ffn * f != cfg.ffn_dim:
        raise ValueError(
            f"init_from has {narrow} channels and a feed-forward width of {ffn}; the config asks "
            f"{cfg.channels} and {cfg.ffn_dim}: widening multiplies both by the same factor"
        )
    return widen_state(state, replace(cfg, channels=narrow, ffn_dim=ffn), f, seed), f
