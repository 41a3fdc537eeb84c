"""The training forward of :class:`training.model.TCDModel`: the same function and the same parameters,
computed in a channels-last layout that a GPU runs without strided copies.

``TCDModel.forward`` mirrors the reference (spec section 1) operation for operation: activations are
(B, C, K, L), and each transformer permutes them into a sequence-first (L, B*K, C) or (K, B*L, C) tensor
and back, four strided copies of the whole activation per block. The Rust engine and the parity tests
are checked against that forward, so it stays as it is. This module computes the same network on
(B, K, L, C) activations:

* the 1x1 convolutions are matrix products on the last dimension (``F.linear``);
* the time transformer's sequences (one per coordinate, along L) are contiguous rows of (B*K, L, C);
  the feature transformer (one sequence per frame, along K) needs the only transpose of the block,
  to (B, L, K, C); the rest of the block (mid and cond projections, gate, output projection) is
  pointwise in the channels and runs in that layout, and the residual is added back in (B, K, L, C)
  as a strided read inside the addition;
* attention is ``F.scaled_dot_product_attention`` on a GPU (flash / memory-efficient kernels) and the explicit
  softmax(q k^T / sqrt(d)) v on the CPU: the reduced models' heads have 8 channels, which PyTorch's CPU
  flash kernel handles poorly (54 % of a HumanEva-I long model's step); the explicit form trains 1.00 to 1.12 x
  the windows/s (batch 8 and 32, one Zen 4 core; docs/training.md, "Tried, not kept");
* the conditioning projection of the 145 side channels is split by linearity: frame embedding (L, 128)
  and feature embedding (K, 16) are projected once per block (an (L, 2C) and a (K, 2C) table), and the
  mask channel is one column, so the (B, 145, K, L) side tensor is never built.

Only the order of floating-point operations differs from the reference: ``tests/test_channels_last.py``
checks that both forwards agree within 1e-5 at every size preset, in eval mode and with every
``cond_fill``. ``ChannelsLast`` holds the model as ``.model``: checkpoints and exports take
``wrapper.model.state_dict()``, which loads strictly into today's classes.
"""

from __future__ import annotations

import math

import torch
from torch import nn
import torch.nn.functional as F

from .model import TCDModel, condition, frame_embedding


#: the CPU's attention: explicit (True) or PyTorch's fused kernel (False; benches/train_speed.py's ``sdpa`` variant)
EXPLICIT_CPU_ATTENTION = True


def attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, dropout_p: float) -> torch.Tensor:
    """Scaled dot-product attention of (N, H, S, d) heads: PyTorch's fused kernels on a GPU, the explicit
    product on the CPU (faster there for heads this small: the module docstring)."""
    if q.device.type != "cpu" or not EXPLICIT_CPU_ATTENTION:
        return F.scaled_dot_product_attention(q, k, v, dropout_p=dropout_p)
    w = torch.softmax((q * q.shape[-1] ** -0.5) @ k.transpose(-2, -1), dim=-1)
    return F.dropout(w, dropout_p) @ v if dropout_p > 0.0 else w @ v


def encoder_layer(layer: nn.TransformerEncoderLayer, x: torch.Tensor) -> torch.Tensor:
    """``nn.TransformerEncoderLayer`` (post-norm, GELU, the layer's own dropouts) on batch-first
    sequences x (N, S, C), with the layer's parameters."""
    attn = layer.self_attn
    N, S, C = x.shape
    H = attn.num_heads
    qkv = F.linear(x, attn.in_proj_weight, attn.in_proj_bias).view(N, S, 3, H, C // H)
    q, k, v = qkv.permute(2, 0, 3, 1, 4).unbind(0)  # each (N, H, S, d)
    o = attention(q, k, v, attn.dropout if layer.training else 0.0)
    o = F.linear(o.transpose(1, 2).reshape(N, S, C), attn.out_proj.weight, attn.out_proj.bias)
    x = layer.norm1(x + layer.dropout1(o))
    f = layer.linear2(layer.dropout(F.gelu(layer.linear1(x))))
    return layer.norm2(x + layer.dropout2(f))


def _w(conv: nn.Conv1d) -> torch.Tensor:
    return conv.weight.squeeze(-1)  # (Cout, Cin, 1) -> (Cout, Cin)


class ChannelsLast(nn.Module):
    """``forward(noisy, observed, mask, step) -> eps_hat``, all (B, K, L): ``model.forward`` in the
    channels-last layout (see the module docstring). Compile it with ``torch.compile`` for training."""

    def __init__(self, model: TCDModel):
        super().__init__()
        self.model = model
        self.cfg = model.cfg  # read by the losses and samplers (training.diffusion)

    @property
    def prior(self):  # read by the losses and samplers, as cfg
        return self.model.prior

    def forward(
        self, noisy: torch.Tensor, observed: torch.Tensor, mask: torch.Tensor, step: torch.Tensor | int
    ) -> torch.Tensor:
        m = self.model
        cfg, net = m.cfg, m.diffmodel
        B, K, L = noisy.shape
        if K != cfg.num_features:
            raise ValueError(f"noisy has K={K} features, the model expects {cfg.num_features}")
        if not torch.is_tensor(step):
            step = torch.tensor([step], device=noisy.device)
        step = step.reshape(-1).to(noisy.device).long()
        cond = condition(cfg, observed, mask, m.prior)
        x = torch.stack([cond, (1 - mask) * noisy], dim=-1)  # (B, K, L, 2)
        h = F.relu(F.linear(x, _w(net.input_projection), net.input_projection.bias))  # (B, K, L, C)
        emb = net.diffusion_embedding(step)  # (B or 1, 128)

        # Side information by linearity: cond_projection(side) = W_t temb + W_f femb + w_m mask + b.
        temb = frame_embedding(L, cfg.time_embedding_dim, noisy.device).to(h.dtype)  # (L, 128)
        femb = m.embed_layer.weight  # (K, 16)
        nt, nf = cfg.time_embedding_dim, cfg.feature_embedding_dim
        mask_lk = mask.transpose(1, 2).unsqueeze(-1)  # (B, L, K, 1) view

        skip_sum = None
        for block in net.residual_layers:
            C = h.shape[-1]
            y = h + block.diffusion_projection(emb).view(-1, 1, 1, C)
            if L > 1:  # the reference skips a length-1 axis
                y = encoder_layer(block.time_layer.layers[0], y.reshape(B * K, L, C)).view(B, K, L, C)
            y = y.transpose(1, 2).reshape(B * L, K, C)  # the block's one transpose
            if K > 1:
                y = encoder_layer(block.feature_layer.layers[0], y)
            y = y.view(B, L, K, C)
            wc = _w(block.cond_projection)  # (2C, 145)
            side = (
                F.linear(temb, wc[:, :nt]).unsqueeze(1)
                + F.linear(femb, wc[:, nt : nt + nf]).unsqueeze(0)
                + block.cond_projection.bias
            )  # (L, K, 2C)
            y = F.linear(y, _w(block.mid_projection), block.mid_projection.bias) + side + mask_lk * wc[:, nt + nf]
            gate, filt = y.chunk(2, dim=-1)
            y = F.linear(
                torch.sigmoid(gate) * torch.tanh(filt), _w(block.output_projection), block.output_projection.bias
            )
            residual, skip = y.chunk(2, dim=-1)  # (B, L, K, C) each
            h = (h + residual.transpose(1, 2)) / math.sqrt(2.0)  # back in (B, K, L, C)
            skip_sum = skip if skip_sum is None else skip_sum + skip
        y = skip_sum / math.sqrt(len(net.residual_layers))
        y = F.relu(F.linear(y, _w(net.output_projection1), net.output_projection1.bias))
        out = F.linear(y, _w(net.output_projection2), net.output_projection2.bias)  # (B, L, K, 1)
        return out.squeeze(-1).transpose(1, 2)  # (B, K, L)
