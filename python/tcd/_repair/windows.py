"""One file through the model: resampling to the model's frame rate and back, the overlapping windows
with their lookahead (:class:`FileJob`), as described in :mod:`tcd._repair`."""

from __future__ import annotations

import math
from typing import List, Optional, Tuple

import numpy as np

from .inputs import Loaded
from .._poses import UNIT_SCALE
from .._resample import resample_backward, resample_forward


def window_starts(frames: int, window: int, overlap: int, lookahead: int = 0) -> List[int]:
    """Start frames of the windows covering ``frames`` (>= ``window``) frames; consecutive windows share
    at least ``overlap + lookahead`` frames and the last one ends at ``frames``."""
    if not 1 <= overlap + lookahead < window or overlap < 1 or lookahead < 0:
        raise ValueError(
            f"need overlap >= 1, lookahead >= 0 and overlap + lookahead < window ({window}), "
            f"got overlap {overlap}, lookahead {lookahead}"
        )
    starts = [0]
    while starts[-1] + window < frames:
        starts.append(min(starts[-1] + window - overlap - lookahead, frames - window))
    return starts


# ---------------------------------------------------------------------------------------------- one file
class FileJob:
    """One input's repair, window by window, in the model's units, layout (frames, K) and frame rate."""

    def __init__(
        self, loaded: Loaded, window: int, overlap: int, model_fps: Optional[float], units: str, lookahead: int = 0
    ) -> None:
        self.loaded = loaded
        self.scale = UNIT_SCALE[units]
        p = loaded.poses
        t, j, _ = p.shape
        k = j * 3
        x = np.where(loaded.full_mask, p, 0.0).reshape(t, k).astype(np.float64) / self.scale
        m = loaded.full_mask.reshape(t, k)
        self.resample = (
            model_fps is not None and math.isfinite(loaded.fps) and abs(loaded.fps - model_fps) > 1e-9 * model_fps
        )
        if self.resample:
            x, m = resample_forward(x, m, loaded.fps, float(model_fps))
        self.model_frames = x.shape[0]
        padded = max(self.model_frames, window)
        self.values = np.zeros((padded, k), np.float32)
        self.values[: self.model_frames] = np.where(m, x, 0.0)
        self.mask = np.zeros((padded, k), bool)
        self.mask[: self.model_frames] = m
        self.window = window
        self.starts = window_starts(padded, window, overlap, lookahead)
        self.lookahead = lookahead
        self.k = 0  # next window
        self.done = 0  # frames [0, done) repaired
        self.model_fps = model_fps

    @property
    def finished(self) -> bool:
        return self.k >= len(self.starts)

    @property
    def windows(self) -> int:
        return len(self.starts)

    def next_window(self) -> Tuple[np.ndarray, np.ndarray]:
        """(observed, mask) of the next window, each (K, W) float32: frames already repaired count as observed."""
        s = self.starts[self.k]
        w = self.window
        mask = self.mask[s : s + w].copy()
        if self.done > s:
            mask[: self.done - s] = True
        obs = np.where(mask, self.values[s : s + w], 0.0)
        return np.ascontiguousarray(obs.T, dtype=np.float32), np.ascontiguousarray(mask.T, dtype=np.float32)

    def accept(self, mean: np.ndarray) -> int:
        """Stores the repaired window (K, W); returns the model frames newly repaired (committed). Except in
        the last window, the trailing ``lookahead`` frames are not committed: the next window, which sees
        the frames after them, generates them again."""
        s = self.starts[self.k]
        w = self.window
        first = max(self.done - s, 0)
        self.values[s + first : s + w] = mean.T[first:]
        end = s + w if self.k == len(self.starts) - 1 else s + w - self.lookahead
        new = min(end, self.model_frames) - min(max(self.done, s), self.model_frames)
        self.done = max(self.done, end)
        self.k += 1
        return max(new, 0)

    def result(self) -> np.ndarray:
        """The repaired poses (T, J, 3) in the caller's units and dtype; observed entries bit-identical."""
        ld = self.loaded
        t, j, _ = ld.poses.shape
        y = self.values[: self.model_frames].astype(np.float64)
        if self.resample:
            y = resample_backward(y, t, ld.fps, float(self.model_fps))
        dtype = ld.poses.dtype
        rep = (y.reshape(t, j, 3) * self.scale).astype(dtype) if self.scale != 1.0 else y.reshape(t, j, 3).astype(dtype)
        return ld.back(np.where(ld.full_mask, ld.poses, rep), self.scale)
