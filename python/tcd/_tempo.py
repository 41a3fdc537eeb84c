"""Tempo sampling: each sample of a forecast from the observation replayed at its own tempo.

A stochastic forecaster is scored by how well its samples cover the futures a person may take (the best of 50 on
HumanEva-I). The bundled HumanEva-I model's samples spread about its prior's forecast without covering *when* a
movement happens: scaling the spread up or low-passing it changes nothing (MODEL_CARD.md), while forecasts from
the observation played faster or slower land closer. ``mode=tcd.Tempo(lo, hi)`` in :meth:`tcd.TCD.forecast`
(:mod:`tcd._cascade`) gives sample i of n the tempo ``s_i``, the n values spaced geometrically from ``lo`` to
``hi`` (both included; one sample gets 1). For each sample:

1. the observation is resampled on the clock of tempo ``s``, aligned at its last frame: warped frame ``tau``
   is the original frame ``last + s * (tau - last)``, linearly interpolated; an entry is observed only where
   both frames it reads are (an observed frame before the first one, for ``s > 1``, is missing: the model
   repairs it as any gap);
2. the cascade forecasts that observation (one sample);
3. the forecast is read back on the original clock: forecast frame ``t`` (1-based, the last observed frame is
   0) is warped frame ``t / s``, linearly interpolated. For ``s < 1`` the frames after ``s * horizon`` lie
   beyond the forecast: they hold its last pose (the sample's Zero-Velocity continuation).

The repaired observation is each sample's repair read back on the original clock, averaged over the samples
whose warped window covers the frame (every sample with ``s >= 1`` covers all of it, and ``hi >= 1``); its
observed entries are the observation's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Dict, List, Sequence, Tuple

import numpy as np

from . import _checks
from ._cascade import Call
from ._resample import _EPS, resample_backward, resample_forward


def check_tempo(tempo: object, name: str = "tempo") -> Tuple[float, float]:
    """A ``(lo, hi)`` pair with ``0 < lo <= 1 <= hi`` (the observed tempo inside the range) and ``hi / lo <= 4``;
    an :class:`InvalidInputError` naming ``name`` otherwise."""
    if isinstance(tempo, (str, bytes)) or not isinstance(tempo, Sequence) and not isinstance(tempo, np.ndarray):
        raise _checks.fail(name, "a (lo, hi) pair of tempi", repr(tempo))
    values = list(tempo)
    if len(values) != 2:
        raise _checks.fail(name, "a (lo, hi) pair of tempi", repr(tempo))
    lo, hi = (_checks.real(name, v) for v in values)
    if not (0.0 < lo <= 1.0 <= hi) or hi / lo > 4.0:
        raise _checks.fail(
            name,
            "a (lo, hi) pair with 0 < lo <= 1 <= hi and hi / lo <= 4 (the observed tempo inside the range)",
            repr((lo, hi)),
        )
    return (lo, hi)


@dataclass(frozen=True)
class Tempo:
    """Sample i of a forecast's n from the observation replayed at its own tempo, the n tempi spaced geometrically
    from ``lo`` to ``hi`` (``0 < lo <= 1 <= hi``, ``hi / lo <= 4``): samples that differ in when a movement happens
    (the module docstring of :mod:`tcd._tempo`). ``Tempo(1, 1)`` is every sample at the observed tempo, the
    cascade. The bundled models do not use it by default: their samples' mean gets worse with it (MODEL_CARD.md,
    "Tempo sampling")."""

    lo: float
    hi: float

    def __post_init__(self) -> None:
        lo, hi = check_tempo((self.lo, self.hi))
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    def draw(self, call: Call, observed: np.ndarray, seen: np.ndarray) -> Dict[str, np.ndarray]:
        if (self.lo, self.hi) == (1.0, 1.0):
            return call.cascade(observed, seen, call.num_samples)
        return tempo_forecast(
            lambda o, m, ids: call.cascade(o, m, 1, ids), observed, seen, call.num_samples, (self.lo, self.hi)
        )

    def describe(self) -> str:
        """One line for people (``tcd info``, ``tcd demo``)."""
        if (self.lo, self.hi) == (1.0, 1.0):
            return "the cascade (every sample at the observed tempo)"
        return f"the cascade at tempi {self.lo:g} to {self.hi:g}"


def tempi(tempo: Tuple[float, float], n: int) -> np.ndarray:
    """The n samples' tempi: geometrically spaced from ``lo`` to ``hi`` (both included); ``[1.0]`` for n = 1."""
    lo, hi = tempo
    return np.ones(1) if n == 1 else np.geomspace(lo, hi, n)


def _frames_last(x: np.ndarray) -> np.ndarray:
    """(B, K, T) -> (T, B * K) with the frames reversed: the layout :mod:`tcd._resample` reads, its frame 0 the
    last observed frame, which every tempo keeps in place."""
    return x.reshape(-1, x.shape[-1]).T[::-1]


def _batched(y: np.ndarray, shape: Tuple[int, ...]) -> np.ndarray:
    """The inverse of :func:`_frames_last`: (T, B * K) reversed frames -> (B, K, T) of ``shape``."""
    return np.ascontiguousarray(y[::-1].T).reshape(shape)


def warp(observed: np.ndarray, seen: np.ndarray, s: float) -> Tuple[np.ndarray, np.ndarray]:
    """The observation (B, K, T) and its mask played at tempo ``s``, aligned at the last frame (step 1 of the
    module docstring; :func:`tcd._resample.resample_forward`'s rule, counted back from the last frame: warped
    frame ``last - k`` reads original frame ``last - s k``). Unobserved entries hold 0."""
    T = observed.shape[-1]
    x, m = resample_forward(_frames_last(observed), _frames_last(seen > 0), 1.0, 1.0 / s)
    if len(x) < T:  # s > 1: the first warped frames lie before the observation's first frame: missing
        x = np.concatenate([x, np.zeros((T - len(x), x.shape[1]))])
        m = np.concatenate([m, np.zeros((T - len(m), m.shape[1]), bool)])
    return (_batched(x[:T], observed.shape).astype(observed.dtype), _batched(m[:T], observed.shape).astype(seen.dtype))


def unwarp_future(last: np.ndarray, future: np.ndarray, s: float) -> np.ndarray:
    """A forecast (..., K, H) made on the clock of tempo ``s`` read back on the original clock, ``last``
    (..., K, 1) the warped last observed frame (step 3 of the module docstring): original frame t is warped
    frame t / s, and :func:`tcd._resample.resample_backward` holds the last frame beyond the forecast."""
    full = np.concatenate([last, future], axis=-1)  # frame 0: the last observed one
    H = future.shape[-1]
    y = resample_backward(full.reshape(-1, H + 1).T, H + 1, 1.0, 1.0 / s)
    return np.ascontiguousarray(y[1:].T).reshape(future.shape)


def unwarp_history(history: np.ndarray, s: float) -> Tuple[np.ndarray, np.ndarray]:
    """A repaired observation (..., K, T) on the clock of tempo ``s`` read back on the original clock, and
    where that is defined (the original frames the warped window covers: all of them for ``s >= 1``)."""
    T = history.shape[-1]
    y = resample_backward(_frames_last(history), T, 1.0, 1.0 / s)  # original frame last - k: warped last - k / s
    covered = (np.arange(T) / s <= T - 1 + _EPS)[::-1]
    return _batched(y, history.shape), covered


def tempo_forecast(
    run_one: Callable[[np.ndarray, np.ndarray, List[int]], Dict[str, np.ndarray]],
    observed: np.ndarray,
    seen: np.ndarray,
    num_samples: int,
    tempo: Tuple[float, float],
) -> Dict[str, np.ndarray]:
    """The forecast of the module docstring in the engine's layout: ``observed``, ``seen`` (B, K, T);
    ``run_one(observed, seen, streams)`` forecasts one sample of each of its sequences, sequence j from the noise
    stream ``streams[j]`` (the cascade's ``sequences``). All samples run as one batch of n * B sequences, sample
    i's the i-th B; sample i of sequence b draws stream ``b * n + i``, so a sequence's samples do not depend on
    the others in the batch. Returns ``mean`` (B, K, H), ``samples`` (n, B, K, H) and ``repaired`` (B, K, T)."""
    B = observed.shape[0]
    ss = tempi(tempo, num_samples)
    n = len(ss)
    warped = [warp(observed, seen, float(s)) for s in ss]
    out = run_one(
        np.concatenate([w[0] for w in warped]),
        np.concatenate([w[1] for w in warped]),
        [b * n + i for i in range(n) for b in range(B)],
    )
    one = np.asarray(out["samples"])[0]
    one = one.reshape(n, B, *one.shape[1:])  # (n, B, K, H): sample i's sequences
    rep = np.asarray(out["repaired"])
    rep = rep.reshape(n, B, *rep.shape[1:])  # (n, B, K, T)
    samples = np.stack([unwarp_future(r[..., -1:], f, float(s)) for r, f, s in zip(rep, one, ss)])
    histories = [unwarp_history(r, float(s)) for r, s in zip(rep, ss)]
    total = sum(np.where(covered, h, 0.0) for h, covered in histories)
    count = sum(covered.astype(np.float64) for _, covered in histories)
    repaired = np.where(seen > 0, observed, total / count).astype(rep.dtype)  # observed entries as given
    return {"mean": samples.mean(axis=0).astype(one.dtype), "samples": samples.astype(one.dtype), "repaired": repaired}
