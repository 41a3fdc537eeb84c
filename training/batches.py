"""Where training batches come from. A batch is (x0, observed, mask, t, eps), each (B, K, L) but t (B,),
and is a pure function of (seed, epoch, batch index), so a resumed run continues with exactly the batches
it would have drawn.

:class:`BatchSource`: windows gathered with numpy (turned about the vertical when the config's ``rotate_axis``
says so, ``training.augment``), occlusion masks drawn per window by ``training.masks`` (the reference
patterns), t and eps by a CPU ``torch.Generator``; optionally in DataLoader worker processes (the same bits).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from .augment import rotate_about
from .masks import corrupt, mix_entry

if TYPE_CHECKING:
    from .train import TrainConfig


class Windows:
    """All windows of ``length`` frames with a stride, gathered on demand."""

    def __init__(self, seqs: list[np.ndarray], length: int, stride: int):
        self.seqs = seqs
        self.length = length
        self.index = np.asarray([(i, s) for i, q in enumerate(seqs) for s in range(0, len(q) - length + 1, stride)],
                                dtype=np.int64).reshape(-1, 2)

    def __len__(self) -> int:
        return len(self.index)

    def gather(self, rows: np.ndarray) -> np.ndarray:
        return np.stack([self.seqs[i][s:s + self.length] for i, s in self.index[rows]]).astype(np.float32)


def make_batch(cfg: "TrainConfig", wins: np.ndarray, rng: np.random.Generator):
    """Clean windows (B, L, J, 3) -> (x0, observed, mask) tensors (B, K, L).
    Each window draws one pattern of ``mask_mix``; occluded observation entries become targets."""
    B, L, J, _ = wins.shape
    observed = wins.copy()
    jmask = np.zeros((B, L, J), dtype=np.float32)
    jmask[:, :cfg.obs_len] = 1.0
    patterns, weights, rates = zip(*(mix_entry(entry) for entry in cfg.mask_mix))
    weights = np.asarray(weights, dtype=np.float64)
    choice = rng.choice(len(patterns), size=B, p=weights / weights.sum())
    for b in range(B):
        if patterns[choice[b]] != "none":
            observed[b], jmask[b] = corrupt(wins[b], patterns[choice[b]], cfg.obs_len, rng, rate=rates[choice[b]])
    observed[:, cfg.obs_len:] = 0.0
    def bkl(a):
        return torch.from_numpy(np.ascontiguousarray(a.reshape(B, L, J * 3).transpose(0, 2, 1)))
    return bkl(wins), bkl(observed), bkl(np.repeat(jmask[..., None], 3, axis=-1))


class BatchSource:
    """The training batches of an epoch, each a pure function of (seed, epoch, batch index): the window
    rows (a seeded permutation per epoch), the occlusion masks, the diffusion steps t and the noise eps.
    So the batches are the same whether drawn here or in DataLoader worker processes, and a resumed run
    continues with exactly the batches it would have drawn."""

    def __init__(self, cfg: "TrainConfig", windows: Windows, T: int, steps_per_epoch: int):
        self.cfg, self.windows, self.T, self.steps_per_epoch = cfg, windows, T, steps_per_epoch
        self._perm_epoch, self._perm = None, None

    def batch(self, epoch: int, batch_i: int):
        cfg = self.cfg
        if self._perm_epoch != epoch:
            self._perm = np.random.default_rng([cfg.seed, epoch]).permutation(len(self.windows))
            self._perm_epoch = epoch
        rows = self._perm[(np.arange(cfg.batch_size) + batch_i * cfg.batch_size) % len(self._perm)]
        wins = self.windows.gather(rows)
        if cfg.rotate_axis:     # its own stream: the masks, t and eps stay those of the same run without it
            wins = rotate_about(wins, cfg.rotate_axis, np.random.default_rng([cfg.seed, epoch, batch_i, 1]))
        x0, obs, mask = make_batch(cfg, wins, np.random.default_rng([cfg.seed, epoch, batch_i]))
        g = torch.Generator().manual_seed(((cfg.seed * 1_000_003 + epoch) * 1_000_003 + batch_i) % (1 << 62))
        t = torch.randint(0, self.T, (x0.shape[0],), generator=g)   # the draw order of training_loss
        eps = torch.randn(x0.shape, generator=g)
        return x0, obs, mask, t, eps

    def iterate(self, epoch: int, start: int, workers: int):
        """Batches start..steps_per_epoch-1 of an epoch, in order."""
        if workers <= 0:
            for i in range(start, self.steps_per_epoch):
                yield self.batch(epoch, i)
            return
        ds = _EpochBatches(self, epoch, start)
        loader = torch.utils.data.DataLoader(ds, batch_size=None, shuffle=False, num_workers=workers,
                                             pin_memory=torch.cuda.is_available(), prefetch_factor=4)
        yield from loader


class _EpochBatches(torch.utils.data.Dataset):
    def __init__(self, source: BatchSource, epoch: int, start: int):
        self.source, self.epoch, self.start = source, epoch, start

    def __len__(self) -> int:
        return self.source.steps_per_epoch - self.start

    def __getitem__(self, i: int):
        return self.source.batch(self.epoch, self.start + i)

