"""Interpolation of missing pose values along time: the engine's linear and natural-cubic-spline fills,
the very ones a model with interpolated conditioning sees (``cond_fill`` in the weight file), offered as
a function so that baselines, the demo and the benchmarks use the same code instead of copies."""

from __future__ import annotations

from typing import Literal, Optional

import numpy as np
from numpy.typing import ArrayLike

from . import _checks, _native
from ._poses import validate_poses

__all__ = ["INTERPOLATIONS", "Interpolation", "interpolate"]

#: The methods :func:`interpolate` knows, the default first (the engine's list).
INTERPOLATIONS = tuple(_native.INTERPOLATIONS)
#: :data:`INTERPOLATIONS` as a type (``method``).
Interpolation = Literal["linear", "spline"]


def interpolate(poses: ArrayLike, mask: Optional[ArrayLike] = None, *, method: Interpolation = "linear") -> np.ndarray:
    """Fills the missing values of ``poses`` (T, J, 3) or (B, T, J, 3), NaN = missing (or ``mask``: 1 =
    observed, of ``poses``' shape or without its last axis), along time, per sequence, joint and coordinate.

    ``method="linear"``: straight lines between the nearest observed frames; ``"spline"``: the natural cubic
    spline through the observed frames (a line with two). Before the first and after the last observed
    frame the nearest observed value is held. A joint coordinate never observed in its sequence stays NaN:
    there is nothing to interpolate from. Observed values come back unchanged, in the input's float dtype
    (float64 for integer input); filled values are computed by the engine in float32.

    Raises :class:`tcd.exceptions.InvalidInputError` naming ``poses``, ``mask`` or ``method``."""
    name = _checks.text("method", method, INTERPOLATIONS)
    checked = validate_poses(poses, mask, num_joints=None, names=("poses", "mask"))
    values, observed = checked.values, checked.observed
    # the engine fills along the last axis: time last, (B, J, 3, T)
    rows = np.ascontiguousarray(np.where(observed, values, 0).transpose(0, 2, 3, 1), dtype=np.float32)
    seen = np.ascontiguousarray(observed.transpose(0, 2, 3, 1), dtype=np.float32)
    filled = _native.interpolate(rows, seen, name).transpose(0, 3, 1, 2)
    out = np.where(observed, values, filled.astype(values.dtype))
    out[~observed.any(axis=1, keepdims=True) & ~observed] = np.nan
    return out if checked.batched else out[0]
