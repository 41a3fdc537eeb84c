"""The mixture mode of :meth:`tcd.TCD.forecast`: a share of the samples from the MLP sample generator
(``generator.safetensors``), one forward each around the prior's forecast, the rest from the cascade."""

from __future__ import annotations

from typing import Any, Callable, Dict, Optional

import numpy as np

from . import _checks
from .engine import Generator, Prior


def check_generator_share(value: Any, name: str = "generator_share") -> float:
    """``value`` as a share of samples in [0, 1]; an :class:`InvalidInputError` naming ``name`` otherwise."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not 0.0 <= float(value) <= 1.0
    ):
        raise _checks.fail(
            name, "a number in [0, 1] (the share of a forecast's samples the generator draws)", repr(value)
        )
    return float(value)


def mixture(
    prior: Prior,
    generator: Generator,
    observed: np.ndarray,
    seen: np.ndarray,
    cascaded: int,
    drawn: int,
    seed: int,
    threads: Optional[int],
    cascade: Callable[[np.ndarray, np.ndarray, int], Dict[str, np.ndarray]],
) -> Dict[str, np.ndarray]:
    """``cascaded`` samples from ``cascade(observed, seen, n)`` and then ``drawn`` from the generator (its seeded
    streams, stage :data:`tcd.engine.STAGE_GENERATOR`), in the engine's layout (B, K, O) in, the cascade's dict
    out. The generator reads the observation as the cascade's prior fill fills it (the spline through each
    coordinate's observed frames) and the prior's forecast from that: one :meth:`tcd.engine.Prior.fill` over the
    window and the horizon (the generator's ``pred_len`` frames)."""
    b, k, o = observed.shape
    h = generator.pred_len
    window = np.concatenate([observed, np.zeros((b, k, h), np.float32)], axis=2).transpose(0, 2, 1)
    given = np.concatenate([seen, np.zeros((b, k, h), np.float32)], axis=2).transpose(0, 2, 1)
    filled = prior.fill(np.ascontiguousarray(window), np.ascontiguousarray(given), threads=threads)
    drawn_samples = generator.sample(filled[:, :o], filled[:, o:], drawn, seed=seed, threads=threads)
    drawn_samples = np.ascontiguousarray(drawn_samples.transpose(0, 1, 3, 2))  # (S', B, K, H)
    if not cascaded:
        return {
            "samples": drawn_samples,
            "mean": drawn_samples.mean(axis=0, dtype=np.float32),
            "repaired": np.ascontiguousarray(filled[:, :o].transpose(0, 2, 1)),
        }
    out = cascade(observed, seen, cascaded)
    samples = np.concatenate([out["samples"], drawn_samples])
    return {**out, "samples": samples, "mean": samples.mean(axis=0, dtype=np.float32)}
