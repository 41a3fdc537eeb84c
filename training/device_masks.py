"""The occlusion patterns of ``training.masks`` drawn for a whole batch at once, on the batch's device.

``training.masks`` draws one window at a time with numpy: it is the reference, used by evaluation and
the benchmarks, whose seeded windows and masks are recorded in results. A GPU training step cannot wait
for that Python loop, so ``training.batches.DeviceBatchSource`` draws its masks here: the same patterns,
rates, rounding and joint groups (imported from ``training.masks``, never re-stated), as batched tensor
operations from one ``torch.Generator`` on the device, with no host round trip. The two draw different
bits from different generators; tests/test_device_masks.py checks that they draw the same distributions.
"""
from __future__ import annotations

import torch

from . import masks as M


class MaskMix:
    """A training config's ``mask_mix`` for windows of ``seq_len`` frames whose first ``obs_len`` are
    observed: each window draws one entry with probability proportional to its weight, then that entry's
    pattern at its rate."""

    def __init__(self, mask_mix: list, obs_len: int, seq_len: int, joints32=M.JOINTS32_H36M_22):
        self.obs_len, self.seq_len = M._check_lengths(obs_len, seq_len)
        self.j32 = M._check_joints32(joints32)
        if not mask_mix:
            raise ValueError("mask_mix is empty")
        self.entries = [M.mix_entry(e) for e in mask_mix]
        total = sum(w for _, w, _ in self.entries)
        if not total > 0:
            raise ValueError(f"mask_mix {mask_mix!r}: the weights sum to 0")
        cols = {}
        for group in (M.LEG_ARM_JOINTS32, M.RIGHT_LEG_JOINTS32):
            c = torch.zeros(self.j32.size, dtype=torch.bool)
            c[torch.as_tensor(M._model_columns(self.j32, group), dtype=torch.long)] = True
            cols[group] = c
        self._host = {"weights": torch.tensor([w / total for _, w, _ in self.entries], dtype=torch.float64),
                      "legs": torch.as_tensor(M.LEGS_JOINTS32), "j32": torch.as_tensor(self.j32), **cols}
        self._on = {}

    def _consts(self, dev: torch.device) -> dict:
        """The constant tensors on ``dev``, copied there once: a host-to-device copy in every batch would
        make the host wait for the GPU."""
        key = str(dev)
        if key not in self._on:
            self._on[key] = {k: v.to(dev) for k, v in self._host.items()}
        return self._on[key]

    def _hidden(self, pattern: str, rate, B: int, g: torch.Generator) -> torch.Tensor:
        """(B, obs_len, J) bool: the observed entries the pattern hides, for every window."""
        O, J, dev = self.obs_len, self.j32.size, g.device
        frames = torch.arange(O, device=dev)
        const = self._consts(dev)

        def n_random_frames(n):          # n distinct frames per window, uniformly: ranks of i.i.d. uniforms
            ranks = torch.rand(B, O, generator=g, device=dev).argsort(dim=1).argsort(dim=1)
            return ranks < n

        def block(n):                     # n consecutive frames, start uniform in [0, O - n]
            start = torch.randint(0, O - n + 1, (B, 1), generator=g, device=dev)
            return (frames >= start) & (frames < start + n)

        if pattern == "none":
            return torch.zeros(B, O, J, dtype=torch.bool, device=dev)
        if pattern == "random_leg_arm":
            return n_random_frames(M._floor_count(rate, O))[:, :, None] & const[M.LEG_ARM_JOINTS32]
        if pattern == "structured_leg":
            return block(M._round_count(rate, O))[:, :, None] & const[M.RIGHT_LEG_JOINTS32]
        if pattern == "consecutive_frames":
            return block(M._round_count(rate, O))[:, :, None].expand(B, O, J)
        if pattern == "random_frames":
            return n_random_frames(M._floor_count(rate, O))[:, :, None].expand(B, O, J)
        if pattern in M.NOISE_SIGMA_MM:
            legs = const["legs"]
            pick = torch.rand(B, O, legs.numel(), generator=g, device=dev).argsort(dim=2)[..., :M.NOISY_HIDDEN_PER_FRAME]
            hidden32 = torch.zeros(B, O, M.N_JOINTS32, dtype=torch.bool, device=dev)
            hidden32.scatter_(2, legs[pick], True)
            return hidden32[..., const["j32"]]
        if pattern in ("random_joints", "random"):
            if pattern == "random":
                p = torch.rand(B, 1, 1, generator=g, device=dev)
            elif isinstance(rate, tuple):
                p = rate[0] + (rate[1] - rate[0]) * torch.rand(B, 1, 1, generator=g, device=dev)
            else:
                p = torch.full((B, 1, 1), float(rate), device=dev)
            return torch.rand(B, O, J, generator=g, device=dev) < p
        raise AssertionError(pattern)  # pragma: no cover - masks.PATTERNS and the branches are kept in sync

    def draw(self, batch: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """-> (mask (batch, seq_len, J) float32, 1 = observed and visible, rows >= obs_len 0;
        noise_sigma_mm (batch,) float32, the noisy patterns' sigma, 0 elsewhere), on the generator's device."""
        g, dev = generator, generator.device
        choice = torch.multinomial(self._consts(dev)["weights"], batch, replacement=True, generator=g)
        hidden = torch.zeros(batch, self.obs_len, self.j32.size, dtype=torch.bool, device=dev)
        sigma = torch.zeros(batch, device=dev)
        # every entry is drawn for the whole batch (cheap on a GPU, no data-dependent shapes), then selected
        for i, (pattern, _, rate) in enumerate(self.entries):
            mine = choice == i
            hidden = torch.where(mine[:, None, None], self._hidden(pattern, rate, batch, g), hidden)
            if pattern in M.NOISE_SIGMA_MM:
                sigma = torch.where(mine, M.NOISE_SIGMA_MM[pattern], sigma)
        mask = torch.zeros(batch, self.seq_len, self.j32.size, device=dev)
        mask[:, :self.obs_len] = (~hidden).float()
        return mask, sigma


def corrupt_batch(windows: torch.Tensor, mix: MaskMix, generator: torch.Generator,
                  units_per_mm: float = 1e-3) -> tuple[torch.Tensor, torch.Tensor]:
    """Clean windows (B, seq_len, J, 3) -> (observed, mask (B, seq_len, J)), ``masks.corrupt`` per window:
    N(0, sigma^2) noise on the visible observed coordinates of the noisy windows, every entry whose mask
    is 0 (hidden joints and all future frames) exactly 0."""
    mask, sigma_mm = mix.draw(windows.shape[0], generator)
    observed = windows
    if any(pattern in M.NOISE_SIGMA_MM for pattern, _, _ in mix.entries):
        noise = torch.randn(windows.shape, generator=generator, device=windows.device, dtype=windows.dtype)
        observed = windows + noise * (sigma_mm * units_per_mm).view(-1, 1, 1, 1).to(windows.dtype)
    return torch.where(mask[..., None] > 0, observed, torch.zeros((), dtype=windows.dtype, device=windows.device)), mask
