"""The pipeline of :meth:`tcd.TCD.predict`: repair the observation, then the prior's deterministic point forecast."""

from __future__ import annotations

from typing import Any, Callable, Dict, Optional

import numpy as np

from . import _native
from .engine import Prior
from .exceptions import InvalidInputError


def repair_then_predict(
    prior: Prior,
    horizon: int,
    observed: np.ndarray,
    seen: np.ndarray,
    *,
    fill: str,
    repair: Callable[[np.ndarray, np.ndarray], np.ndarray],
    threads: Optional[int],
) -> Dict[str, Any]:
    """Repair-then-predict in the engine's layout: observed, seen (B, K, T) float32 (0 where missing) ->
    {"mean": (B, K, H) point forecast, "repaired": (B, K, T), "samples": None}. Missing entries are filled by
    ``repair(observed, seen)`` (the repair model's mean, (B, K, T)) where ``fill`` is ``"model"``, else by the
    engine's ``"spline"`` or ``"linear"`` fill along time; a complete observation goes to the prior as given."""
    repaired = observed
    missing = seen < 0.5
    if missing.any():
        if fill == "model":
            repaired = np.where(missing, repair(observed, seen), observed).astype(np.float32)
        else:
            never = missing.all(axis=-1)
            if never.any():
                b, k = np.argwhere(never)[0]
                raise InvalidInputError(
                    f"Argument `obs` has coordinate {k} of joint {k // 3} never observed in sequence {b}: "
                    f"fill={fill!r} interpolates along time and has nothing to start from; use fill='model'.",
                    "obs",
                )
            repaired = np.ascontiguousarray(_native.interpolate(observed, seen, fill), dtype=np.float32)
            repaired = np.where(missing, repaired, observed)
    hist = np.ascontiguousarray(repaired[..., -prior.obs_len :].transpose(0, 2, 1))  # (B, T, K)
    mean = prior.predict(hist, horizon, threads=threads)  # (B, H, K)
    return {"mean": np.ascontiguousarray(mean.transpose(0, 2, 1)), "repaired": repaired, "samples": None}
