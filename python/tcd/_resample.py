"""Resampling pose sequences between frame rates, the one rule dataset repair (:mod:`tcd._repair`), poses
from the wild (:mod:`tcd.wild`) and tempo sampling (:mod:`tcd._tempo`) share."""

from __future__ import annotations

import math
from typing import Tuple

import numpy as np

__all__ = ["resample_forward", "resample_backward"]

_EPS = 1e-9  # frame positions this close to a source frame are that frame


def resample_forward(x: np.ndarray, m: np.ndarray, src_fps: float, dst_fps: float) -> Tuple[np.ndarray, np.ndarray]:
    """(T, K) values and bool mask at ``src_fps`` -> (T', K) at ``dst_fps`` on the grid starting at frame 0:
    linear interpolation, an entry observed only when the source frames on both sides are (a gap never
    shrinks); unobserved entries are 0."""
    t = x.shape[0]
    n = int(math.ceil((t - 1) * dst_fps / src_fps - _EPS)) + 1
    pos = np.arange(n) * (src_fps / dst_fps)  # fractional source index of each model frame
    i0 = np.floor(pos + _EPS).astype(np.int64)
    frac = pos - i0
    exact = frac < _EPS
    frac = np.where(exact, 0.0, frac)
    inside = i0 < t
    i0c = np.minimum(i0, t - 1)
    i1 = np.where(exact, i0c, np.minimum(i0c + 1, t - 1))
    ok = inside & (exact | (i0 + 1 < t))
    xv = np.where(m, x, 0.0)
    out = (1.0 - frac)[:, None] * xv[i0c] + frac[:, None] * xv[i1]
    out_mask = m[i0c] & m[i1] & ok[:, None]
    return np.where(out_mask, out, 0.0), out_mask


def resample_backward(y: np.ndarray, frames: int, src_fps: float, dst_fps: float) -> np.ndarray:
    """(T', K) values at ``dst_fps`` -> (frames, K) at ``src_fps`` by linear interpolation."""
    n = y.shape[0]
    pos = np.arange(frames) * (dst_fps / src_fps)
    j0 = np.minimum(np.floor(pos + _EPS).astype(np.int64), n - 1)
    frac = np.clip(pos - j0, 0.0, 1.0)
    frac = np.where(frac < _EPS, 0.0, frac)
    j1 = np.minimum(j0 + 1, n - 1)
    return (1.0 - frac)[:, None] * y[j0] + frac[:, None] * y[j1]
