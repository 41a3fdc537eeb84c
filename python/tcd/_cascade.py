"""The forecast modes of :meth:`tcd.TCD.forecast` and what they draw with.

A mode decides where a forecast's samples come from; :meth:`tcd.TCD.forecast` converts the poses into the model's
window, asks its mode to ``draw`` the samples there, and converts them back. The modes, each in its module:

* :class:`Cascade` (here): every sample from the two-stage diffusion cascade, the paper's TCD;
* :class:`tcd.Mixture` (:mod:`tcd._mixture`): a share of the samples from the MLP generator, the rest from the
  cascade;
* :class:`tcd.Tempo` (:mod:`tcd._tempo`): each sample from the observation replayed at its own tempo.

Each is a frozen dataclass whose constructor checks its fields and whose ``draw(call, observed, seen)`` returns the
engine's dict (``mean`` (B, K, H), ``samples`` (S, B, K, H), ``repaired`` (B, K, O)) for the engine's window
``observed``, ``seen`` (B, K, O). A :class:`Call` carries the model's networks and the call's settings.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Dict, Optional, Protocol, Sequence

import numpy as np

from ._progress import Progress
from .exceptions import InvalidInputError
from ._sampler import SamplerOptions
from .engine import Denoiser, Generator, Prior, cascade_raw


@dataclass(frozen=True)
class Call:
    """One forecast: the model's networks and the call's settings, what a mode draws with."""

    #: the cascade's stages (None in a generator directory, whose only mode is the generator alone)
    short: Optional[Denoiser]
    long: Optional[Denoiser]
    #: the prior forecaster the cascade's stages are conditioned on (None where no stage is)
    conditioning: Optional[Prior]
    #: the directory's prior forecaster (``prior.safetensors``), or None
    prior: Optional[Prior]
    #: the directory's MLP sample generator (``generator.safetensors``), or None
    generator: Optional[Generator]
    num_samples: int
    seed: int
    threads: Optional[int]
    progress: Progress
    sampler: SamplerOptions

    def cascade(
        self, observed: np.ndarray, seen: np.ndarray, n: int, streams: Optional[Sequence[int]] = None
    ) -> Dict[str, np.ndarray]:
        """``n`` cascade samples of each sequence (sequence j from noise stream ``streams[j]`` where given)."""
        if self.short is None or self.long is None:
            raise InvalidInputError(
                "Argument `mode` draws samples from the cascade, but this model has none (a generator directory: "
                "generator.safetensors around its prior): its only mode is the generator alone, tcd.Mixture(1), "
                "its default.",
                "mode",
            )
        return cascade_raw(
            self.short,
            self.long,
            observed,
            seen,
            num_samples=n,
            seed=self.seed,
            threads=self.threads,
            progress=self.progress,
            prior=self.conditioning,
            sequences=streams,
            sampler=self.sampler,
        )


class Mode(Protocol):
    """What :meth:`tcd.TCD.forecast`'s ``mode`` is: :class:`Cascade`, :class:`tcd.Mixture` or :class:`tcd.Tempo`."""

    def draw(self, call: Call, observed: np.ndarray, seen: np.ndarray) -> Dict[str, np.ndarray]: ...

    def describe(self) -> str: ...


@dataclass(frozen=True)
class Cascade:
    """Every sample of a forecast from the two-stage cascade (short-term model, then long-term model): the
    paper's TCD, and the mode of a model directory whose ``sampling.json`` names no other."""

    def draw(self, call: Call, observed: np.ndarray, seen: np.ndarray) -> Dict[str, np.ndarray]:
        return call.cascade(observed, seen, call.num_samples)

    def describe(self) -> str:
        """One line for people (``tcd info``, ``tcd demo``)."""
        return "the cascade"


def as_dict(mode: Mode) -> Dict[str, object]:
    """A mode as JSON for ``tcd info --json`` and the demo's summary: ``{"mode": "tempo", "lo": 0.8, "hi": 1.25}``."""
    return {"mode": type(mode).__name__.lower(), **dataclasses.asdict(mode)}  # type: ignore[call-overload]
