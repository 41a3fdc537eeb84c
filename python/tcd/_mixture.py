"""The mixture mode of :meth:`tcd.TCD.forecast` (:mod:`tcd._cascade`): a share of the samples from the MLP sample
generator (``generator.safetensors``), one forward each around the prior's forecast, the rest from the cascade."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Dict, Optional

import numpy as np

from . import _checks
from ._cascade import Call
from .engine import Generator, Prior
from .exceptions import InvalidInputError

#: the file of a model directory's generator (:attr:`tcd.TCD.generator`), optional
GENERATOR_FILE = "generator.safetensors"


def check_generator_share(value: Any, name: str = "share") -> float:
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


@dataclass(frozen=True)
class Mixture:
    """``floor(num_samples * share)`` of a forecast's samples from the model directory's MLP generator
    (:attr:`tcd.TCD.generator`: one forward each, around the prior's forecast of the observation filled as the
    cascade's prior fill fills it), after the cascade's; the cascade's stages run with the remaining samples.
    ``mean`` is the mean of all of them, and ``repaired`` the cascade's (the prior's fill where every sample is the
    generator's). ``share`` is in [0, 1]; the bundled HumanEva-I model's default is ``Mixture(0.5)``, whose best of
    50 samples is best half and half (MODEL_CARD.md)."""

    share: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "share", check_generator_share(self.share))

    def draw(self, call: Call, observed: np.ndarray, seen: np.ndarray) -> Dict[str, np.ndarray]:
        drawn = generator_samples(self, call.num_samples)  # the generator's samples; the cascade's are the rest
        if self.share and (call.generator is None or call.prior is None):
            raise InvalidInputError(
                f"Argument `mode` is {self}, but the model has no generator ({GENERATOR_FILE}): pass "
                "tcd.Cascade() or Mixture(0).",
                "mode",
            )
        if not drawn:
            return call.cascade(observed, seen, call.num_samples)
        return mixture(
            call.prior,
            call.generator,
            observed,
            seen,
            call.num_samples - drawn,
            drawn,
            call.seed,
            call.threads,
            call.cascade,
        )

    def describe(self) -> str:
        """One line for people (``tcd info``, ``tcd demo``)."""
        if self.share == 1.0:
            return "every sample from the generator"
        return f"the cascade with a share of {self.share:g} of the samples from the generator"


def generator_samples(mode: object, num_samples: int) -> int:
    """How many of a forecast's ``num_samples`` samples ``mode`` draws from the generator (0 but for a mixture)."""
    return int(num_samples * mode.share) if isinstance(mode, Mixture) else 0


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
