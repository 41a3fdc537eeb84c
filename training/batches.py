"""Where training batches come from. A batch is (x0, observed, mask, t, eps), each (B, K, L) but t (B,), with
the config's ``imle_samples`` S also the one-step sampler's candidate noise (S, B, K, L) (training.imle.imle_loss),
and with ``imle_targets`` M > 1 then the M - 1 further futures of each window (M - 1, B, K, L): the window with the
future of one of its ``future_swap_k`` nearest windows. A batch is a pure function of (seed, epoch, batch index),
so a resumed run continues with exactly the batches it would have drawn.

:class:`BatchSource`: windows gathered with numpy (turned about the vertical when the config's ``rotate_axis``
says so, ``training.augment``), occlusion masks drawn per window by ``training.masks`` (the reference
patterns), t and eps by a CPU ``torch.Generator``; optionally in DataLoader worker processes (the same bits).
With the config's ``future_swap`` a share of the windows take another training window's future
(``training.augment.swap_futures``) before they are turned.
"""

from __future__ import annotations

import numpy as np
import torch

from .augment import arrival_keys, future_neighbours, rotate_about, swap_futures
from .masks import corrupt, mix_entry
from .train_config import TrainConfig


class Windows:
    """All windows of ``length`` frames with a stride, gathered on demand."""

    def __init__(self, seqs: list[np.ndarray], length: int, stride: int):
        self.seqs = seqs
        self.length = length
        self.index = np.asarray(
            [(i, s) for i, q in enumerate(seqs) for s in range(0, len(q) - length + 1, stride)], dtype=np.int64
        ).reshape(-1, 2)

    def __len__(self) -> int:
        return len(self.index)

    def gather(self, rows: np.ndarray, frames: slice = slice(None)) -> np.ndarray:
        """(len(rows), length, J, 3) windows, or only their ``frames`` (a slice of the window's frames)."""
        return np.stack([self.seqs[i][s : s + self.length][frames] for i, s in self.index[rows]]).astype(np.float32)

    def future_neighbours(self, obs_len: int, k: int, exclude_frames: int) -> np.ndarray:
        """(N, k): each window's ``k`` nearest windows by :func:`training.augment.arrival_keys` at ``obs_len``,
        none of its own sequence within ``exclude_frames`` frames of it (:func:`training.augment.future_neighbours`)."""
        ends = self.gather(np.arange(len(self)), slice(obs_len - 3, obs_len))
        return future_neighbours(arrival_keys(ends, 3), self.index[:, 0], self.index[:, 1], k, exclude_frames)


def make_batch(cfg: TrainConfig, wins: np.ndarray, rng: np.random.Generator):
    """Clean windows (B, L, J, 3) -> (x0, observed, mask) tensors (B, K, L).
    Each window draws one pattern of ``mask_mix``; occluded observation entries become targets."""
    B, L, J, _ = wins.shape
    observed = wins.copy()
    jmask = np.zeros((B, L, J), dtype=np.float32)
    jmask[:, : cfg.obs_len] = 1.0
    patterns, weights, rates = zip(*(mix_entry(entry) for entry in cfg.mask_mix))
    weights = np.asarray(weights, dtype=np.float64)
    choice = rng.choice(len(patterns), size=B, p=weights / weights.sum())
    for b in range(B):
        if patterns[choice[b]] != "none":
            observed[b], jmask[b] = corrupt(wins[b], patterns[choice[b]], cfg.obs_len, rng, rate=rates[choice[b]])
    observed[:, cfg.obs_len :] = 0.0

    def bkl(a):
        return torch.from_numpy(np.ascontiguousarray(a.reshape(B, L, J * 3).transpose(0, 2, 1)))

    return bkl(wins), bkl(observed), bkl(np.repeat(jmask[..., None], 3, axis=-1))


#: ``future_swap``: a window's donors are never windows of its own sequence starting within this many frames of it
#: (those are its own future shifted by a few frames)
SWAP_EXCLUDE_FRAMES = 30


def action_weights(actions: np.ndarray, balance: float) -> np.ndarray:
    """Each window's probability of being drawn, from its action (one label per window): proportional to
    n ** -balance, n the number of windows of that action (0: every window alike; 1: every action alike)."""
    _, group, counts = np.unique(actions, return_inverse=True, return_counts=True)
    w = counts[group].astype(np.float64) ** -float(balance)
    return w / w.sum()


class BatchSource:
    """The training batches of an epoch, each a pure function of (seed, epoch, batch index): the window
    rows (a seeded permutation per epoch, or with ``weights`` as many rows drawn with replacement by them), the
    swapped futures, the occlusion masks, the diffusion steps t and the noise eps. So the batches are the same
    whether drawn here or in DataLoader worker processes, and a resumed run continues with exactly the batches it
    would have drawn."""

    def __init__(
        self, cfg: TrainConfig, windows: Windows, T: int, steps_per_epoch: int, weights: np.ndarray | None = None
    ):
        self.cfg, self.windows, self.T, self.steps_per_epoch = cfg, windows, T, steps_per_epoch
        if weights is not None and np.shape(weights) != (len(windows),):
            raise ValueError(f"weights: one per window ({len(windows)}), got shape {np.shape(weights)}")
        self.weights = weights
        self._perm_epoch, self._perm = None, None
        self.neighbours = (
            windows.future_neighbours(cfg.obs_len, cfg.future_swap_k, SWAP_EXCLUDE_FRAMES)
            if cfg.future_swap > 0 or cfg.imle_targets > 1
            else None
        )

    def batch(self, epoch: int, batch_i: int):
        cfg = self.cfg
        if self._perm_epoch != epoch:
            rng = np.random.default_rng([cfg.seed, epoch])
            n = len(self.windows)
            self._perm = rng.permutation(n) if self.weights is None else rng.choice(n, size=n, p=self.weights)
            self._perm_epoch = epoch
        rows = self._perm[(np.arange(cfg.batch_size) + batch_i * cfg.batch_size) % len(self._perm)]
        wins = self.windows.gather(rows)
        if cfg.future_swap > 0:  # its own stream, like the rotation's
            rng = np.random.default_rng([cfg.seed, epoch, batch_i, 2])
            swap = rng.random(len(rows)) < cfg.future_swap
            donor = self.neighbours[rows, rng.integers(0, cfg.future_swap_k, len(rows))]
            if swap.any():
                wins[swap] = swap_futures(wins[swap], self.windows.gather(donor[swap]), cfg.obs_len)
        others = None
        if cfg.imle_targets > 1:  # the further IMLE targets: the window with a neighbour's future (own stream)
            rng = np.random.default_rng([cfg.seed, epoch, batch_i, 3])
            pick = rng.integers(0, cfg.future_swap_k, (len(rows), cfg.imle_targets - 1))
            donors = self.neighbours[rows[:, None], pick]
            others = np.stack(
                [
                    swap_futures(wins, self.windows.gather(donors[:, m]), cfg.obs_len)
                    for m in range(cfg.imle_targets - 1)
                ],
                axis=1,
            )  # (B, M - 1, L, J, 3)
        if cfg.rotate_axis:  # its own stream: the masks, t and eps stay those of the same run without it
            rng = np.random.default_rng([cfg.seed, epoch, batch_i, 1])
            if others is None:
                wins = rotate_about(wins, cfg.rotate_axis, rng)
            else:  # one angle per window for it and its further targets: the same B draws
                both = rotate_about(np.concatenate([wins[:, None], others], axis=1), cfg.rotate_axis, rng)
                wins, others = both[:, 0], both[:, 1:]
        x0, obs, mask = make_batch(cfg, wins, np.random.default_rng([cfg.seed, epoch, batch_i]))
        g = torch.Generator().manual_seed(((cfg.seed * 1_000_003 + epoch) * 1_000_003 + batch_i) % (1 << 62))
        t = torch.randint(0, self.T, (x0.shape[0],), generator=g)  # the draw order of training_loss
        eps = torch.randn(x0.shape, generator=g)
        if cfg.imle_samples:  # drawn after eps from the same stream: the batches before them are unchanged
            candidates = torch.randn((cfg.imle_samples, *x0.shape), generator=g)
            if others is None:
                return x0, obs, mask, t, eps, candidates
            B, M1, L = others.shape[:3]  # (M - 1, B, K, L), laid out as x0
            o = np.ascontiguousarray(others.reshape(B, M1, L, -1).transpose(1, 0, 3, 2))
            return x0, obs, mask, t, eps, candidates, torch.from_numpy(o)
        return x0, obs, mask, t, eps

    def iterate(self, epoch: int, start: int, workers: int):
        """Batches start..steps_per_epoch-1 of an epoch, in order."""
        if workers <= 0:
            for i in range(start, self.steps_per_epoch):
                yield self.batch(epoch, i)
            return
        ds = _EpochBatches(self, epoch, start)
        loader = torch.utils.data.DataLoader(
            ds,
            batch_size=None,
            shuffle=False,
            num_workers=workers,
            pin_memory=torch.cuda.is_available(),
            prefetch_factor=4,
        )
        yield from loader


class _EpochBatches(torch.utils.data.Dataset):
    def __init__(self, source: BatchSource, epoch: int, start: int):
        self.source, self.epoch, self.start = source, epoch, start

    def __len__(self) -> int:
        return self.source.steps_per_epoch - self.start

    def __getitem__(self, i: int):
        return self.source.batch(self.epoch, self.start + i)
