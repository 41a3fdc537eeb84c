"""Training the one-step sampler to cover the futures: implicit maximum likelihood estimation (IMLE; Li and
Malik, "Implicit Maximum Likelihood Estimation", 2018) on an x0-predicting denoiser.

DDIM over one step returns the network's estimate at the last training step from pure noise, ``net(x_T, observed,
mask, T - 1)``. The diffusion loss trains that estimate towards the conditional mean whatever x_T is (x_T carries
almost nothing of x0 there), so one-step samples hardly differ: on HumanEva-I the bundled model's 50 DDIM-1 samples
spread a third as far as its DDPM-10 samples. IMLE instead draws S candidate x_T per training window, computes
the S one-step samples without gradients, and trains only the one nearest to the window's own future towards it:
every future seen in training gets a draw of x_T that lands near it, so S samples cover the futures (the best of
S nearer the truth) instead of repeating their mean. The diffusion loss stays beside it (``imle_weight`` weighs the
two), so the other steps keep their meaning.

The candidates' forwards are most of the cost (S per window, against one forward and backward for the diffusion
loss); :class:`EngineSearch` runs them in the Rust engine (the weights serialised for it every step), several
times faster than PyTorch's CPU forward of this network. And a search can serve several optimizer steps
(``imle_echo``: :func:`imle_choose` apart from :func:`imle_loss`): the premise, which Li and Malik's IMLE (its
nearest samples refreshed only every few epochs) relies on, is that which candidate lands nearest changes slowly as
the weights move; its one run here made the model worse (docs/training.md, "Tried, not kept").
"""

from __future__ import annotations

import json
from typing import Callable, NamedTuple

import torch

from .diffusion import Schedule, _to_target, masked_eps_loss
from .fileformat import CONFIG_KEY
from .model import condition

#: ``search(noisy, observed, mask, rows, step) -> out``: the network's output without gradients for each of the N
#: sequences ``noisy`` (N, K, L), sequence n conditioned on window ``rows[n]`` of ``observed`` and ``mask`` (B, K, L;
#: ``observed`` as the training loss passes it), at the int ``step``
Search = Callable[[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, int], torch.Tensor]


def torch_search(model, chunk: int = 64) -> Search:
    """The candidates' forwards in PyTorch, ``chunk`` sequences at a time (the reference for :class:`EngineSearch`)."""

    def search(noisy, observed, mask, rows, step):
        outs = []
        with torch.no_grad():
            for r in range(0, noisy.shape[0], chunk):
                s, w = slice(r, r + chunk), rows[r : r + chunk]
                outs.append(
                    model(noisy[s], observed[w], mask[w], torch.full((len(w),), step, device=noisy.device)).float()
                )
        return torch.cat(outs)

    return search


class EngineSearch:
    """The candidates' forwards in the Rust engine (``tcd.engine.Denoiser.forward``): each call serialises the
    current weights of ``model`` (a ``training.model.TCDModel``; a few hundred kB) with ``config``, a weight
    file's configuration (what ``training.export.build_config`` writes, under ``training.fileformat.CONFIG_KEY``),
    loads them from the bytes, and writes the conditioning fill of a ``cond_fill="prior"`` model into
    ``observed``'s masked entries, where the engine's forward reads it (the engine's cascade does the same)."""

    def __init__(self, model, config: dict, threads: int | None = None):
        self.model, self.threads = model, threads
        self.metadata = {CONFIG_KEY: json.dumps(config)}

    def __call__(self, noisy, observed, mask, rows, step):
        from safetensors.torch import save
        from tcd.engine import Denoiser

        tensors = {k: v.detach().to("cpu", torch.float32).contiguous() for k, v in self.model.state_dict().items()}
        net = Denoiser.from_bytes(save(tensors, metadata=self.metadata), "imle candidates")
        with torch.no_grad():  # once per window, not per candidate: the fill depends on the window only
            cond = condition(self.model.cfg, observed, mask, self.model.prior)
        out = net.forward(
            noisy.cpu().numpy(), cond[rows].cpu().numpy(), mask[rows].cpu().numpy(), step, threads=self.threads
        )
        return torch.from_numpy(out).to(noisy.device)


class Choice(NamedTuple):
    """What :func:`imle_choose` picked for a batch: ``targets`` (M, B, K, L), the window's own future first and the
    further futures of ``imle_targets`` after it, in target units; ``nearest`` (M, B), the index of each target's
    nearest candidate; ``final`` (B,) or None, each window's candidate nearest on its last hidden frame, and
    ``final_weight`` the weight :func:`imle_loss` gives its term."""

    targets: torch.Tensor
    nearest: torch.Tensor
    final: torch.Tensor | None
    final_weight: float


def imle_choose(
    model,
    sched: Schedule,
    x0: torch.Tensor,
    mask: torch.Tensor,
    candidates: torch.Tensor,
    observed: torch.Tensor | None = None,
    search: Search | None = None,
    final_weight: float = 0.0,
    others: torch.Tensor | None = None,
) -> Choice:
    """The search of :func:`imle_loss`, without gradients: the S one-step samples from ``candidates`` (S, B, K, L)
    standard normals (``search`` computes them, default ``model`` itself, :func:`torch_search`) and each target's
    nearest among them (squared distance over the hidden entries, in target units). ``observed`` as in
    ``training.diffusion.training_loss``.

    ``others`` (M - 1, B, K, L): further futures of each window, laid out as x0 (its own observed frames, the
    future of one of its nearest training windows: ``imle_targets``). Each also pulls its nearest of the same S
    samples, and the loss is the mean over all M targets: the samples are taught to cover the futures of similar
    pasts, not only the one each window had (the nearest-training-futures baseline shows how near those lie).

    ``final_weight`` > 0 adds that weight x the same loss of each window's candidate nearest on its last hidden
    frame alone (the forecast's final pose). Why it was tried: the stochastic protocol scores the best sample
    twice, by ADE over the whole future and by FDE at its last frame, and the two bests are often different
    samples (HumanEva-I's FDE was 1.24 x its ADE, TCD's 1.08 x). Measured there (docs/training.md, "The
    final-frame term"): FDE within the margin, ADE worse and the samples narrower; off (0) by default.

    Apart from the loss so that one search can serve several optimizer steps (``imle_echo``): the search is most
    of a step's cost."""
    if sched.cfg.prediction_type != "sample":
        raise ValueError(
            "imle_loss trains the one-step sample of an x0-predicting model (prediction_type "
            f"'sample'); this one predicts {sched.cfg.prediction_type!r}"
        )
    if candidates.dim() != x0.dim() + 1 or tuple(candidates.shape[1:]) != tuple(x0.shape):
        raise ValueError(f"candidates must be (S, *x0.shape) = (S, {tuple(x0.shape)}), got {tuple(candidates.shape)}")
    if others is not None and (others.dim() != x0.dim() + 1 or tuple(others.shape[1:]) != tuple(x0.shape)):
        raise ValueError(f"others must be (M - 1, *x0.shape) = (M - 1, {tuple(x0.shape)}), got {tuple(others.shape)}")
    S, B = candidates.shape[:2]
    observed = x0 if observed is None else observed
    hidden = 1.0 - mask
    with torch.no_grad():
        target = _to_target(model, x0, observed, mask)
        targets = (
            target[None]
            if others is None
            else torch.cat([target[None], torch.stack([_to_target(model, o, observed, mask) for o in others])])
        )
        rows = torch.arange(S * B, device=x0.device) % B  # row s * B + b: window b
        out = (search or torch_search(model))(
            candidates.reshape(S * B, *x0.shape[1:]), observed, mask, rows, sched.T - 1
        )
        out = out.view(S, B, *x0.shape[1:])
        nearest = (((out[:, None] - targets[None]) * hidden) ** 2).sum((3, 4)).argmin(0)  # (M, B)
        final = None
        if final_weight > 0:
            sq = ((out - target) * hidden) ** 2  # (S, B, K, L)
            frames = torch.arange(x0.shape[-1], device=x0.device)
            last = (hidden.amax(1) * (frames + 1)).argmax(1)  # (B,): last hidden frame
            at_last = torch.gather(sq, 3, last.view(1, B, 1, 1).expand(S, B, sq.shape[2], 1))  # (S, B, K, 1)
            final = at_last.sum((2, 3)).argmin(0)
    return Choice(targets, nearest, final, final_weight)


def imle_loss(
    model,
    sched: Schedule,
    x0: torch.Tensor,
    mask: torch.Tensor,
    candidates: torch.Tensor,
    choice: Choice,
    observed: torch.Tensor | None = None,
) -> torch.Tensor:
    """The one-step sampler's IMLE loss for clean windows x0 (B, K, L) (module docstring): each target's nearest
    of the one-step samples from ``candidates`` (S, B, K, L), as ``choice`` (:func:`imle_choose` on the same
    arguments) found them, recomputed with gradients and scored by the masked mean square of the diffusion loss;
    the mean over the targets, plus ``choice.final_weight`` x the loss of each window's candidate nearest on its
    last hidden frame. ``observed``: the conditioning, as in the search (default ``x0``)."""
    observed = x0 if observed is None else observed
    B = x0.shape[0]
    windows = torch.arange(B, device=x0.device)
    t_last = torch.full((B,), sched.T - 1, device=x0.device)
    # each target's nearest sample, one forward of B per target (a CPU step costs more per window at 4 B than at
    # B: docs/training.md, "Tried, not kept"); the mean over targets, each term normalised by the same count of
    # hidden entries, is the pooled mean
    loss = sum(
        masked_eps_loss(tm, model(candidates[nm, windows], observed, mask, t_last), mask)
        for tm, nm in zip(choice.targets, choice.nearest)
    ) / len(choice.targets)
    if choice.final is not None:
        out = model(candidates[choice.final, windows], observed, mask, t_last)
        loss = loss + choice.final_weight * masked_eps_loss(choice.targets[0], out, mask)
    return loss
