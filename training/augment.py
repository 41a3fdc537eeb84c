"""Data augmentation shared by the prior's and the diffusion models' training batches.

``rotate_about``: each window turned by its own uniform random angle about the vertical axis. Motion is
the same motion whichever way the subject faces, but a small dataset shows few headings: HumanEva-I's
prior, trained without it, forecast its own training windows 35 % worse once they were turned (ADE 0.252
-> 0.340 m; issue 31), i.e. it had learned the room's headings along with the motion.

``mirror``: windows reflected through a vertical plane, the subject's left and right joints swapped: a left-handed
boxer's motion is as human as a right-handed one's, and a small dataset (HumanEva-I: three subjects) shows each
motion with one handedness.

``resample``: windows read at their own playback speed (linear interpolation between frames): the same motion
done faster or slower. HumanEva-I's prior forecasts its training windows far better than the protocol's (ADE
0.147 against 0.240 m after the rolled-out loss): it has learned these takes' timing along with the motion.

``future_neighbours`` and ``swap_futures``: a window's future replaced by the future of another training window that
arrives at the same pose with the same velocity, joined to the window's own last observed pose (the offset between
the two fades out over the future). A small dataset shows each past with one future, so a diffusion model trained
on it learns a narrow conditional distribution; the futures that similar pasts had elsewhere in the data are what a
person in that pose may do next (the protocol's "multimodal ground truth", DLow / GSPS, is the same idea at test
time). On HumanEva-I the bundled model's 50 samples spread about a third as far as those futures do (MODEL_CARD.md).
"""

from __future__ import annotations

import numpy as np

AXES = {"x": 0, "y": 1, "z": 2}


def check_axis(axis: str, where: str) -> None:
    if axis not in ("", *AXES):
        raise ValueError(f"{where}: rotate_axis must be '' (no rotation) or one of {sorted(AXES)}, got {axis!r}")


def rotate_about(wins: np.ndarray, axis: str, rng: np.random.Generator) -> np.ndarray:
    """(B, ..., 3) windows of root-relative (or world) coordinates, each turned about ``axis`` ("x", "y" or
    "z": the data's vertical) by an angle drawn uniformly from [0, 2 pi) with ``rng`` (B draws)."""
    a = AXES[axis]
    u, v = [i for i in range(3) if i != a]
    theta = rng.uniform(0.0, 2.0 * np.pi, len(wins)).astype(wins.dtype)
    shape = (len(wins),) + (1,) * (wins.ndim - 2)
    c, s = np.cos(theta).reshape(shape), np.sin(theta).reshape(shape)
    out = wins.copy()
    out[..., u] = c * wins[..., u] - s * wins[..., v]
    out[..., v] = s * wins[..., u] + c * wins[..., v]
    return out


def mirror_permutation(names) -> np.ndarray:
    """The joint order of a mirrored pose: each ``left_*`` joint takes its ``right_*`` twin's place and back;
    the others (pelvis, spine, head) keep theirs. A left joint without its twin is an error."""
    names = list(names)
    index = {n: i for i, n in enumerate(names)}
    perm = np.arange(len(names))
    for i, n in enumerate(names):
        for a, b in (("left_", "right_"), ("right_", "left_")):
            if n.startswith(a):
                twin = b + n[len(a) :]
                if twin not in index:
                    raise ValueError(f"mirror: joint {n!r} has no {twin!r}")
                perm[i] = index[twin]
    return perm


def mirror(wins: np.ndarray, vertical: str, perm: np.ndarray, which: np.ndarray) -> np.ndarray:
    """(B, T, J, 3) windows; those where ``which`` (B bools) is set are reflected through the vertical plane that
    holds ``vertical`` and the first other axis (the second other axis negated) and have their joints reordered by
    ``perm`` (:func:`mirror_permutation`): the same motion with the other handedness. The others are unchanged."""
    a = AXES[vertical]
    flip_axis = [i for i in range(3) if i != a][1]
    out = wins.copy()
    m = out[which][:, :, perm]
    m[..., flip_axis] *= -1
    out[which] = m
    return out


def sequence_ends(starts: np.ndarray, length: int) -> np.ndarray:
    """For each window start of :func:`training.prior.training_frames` (runs of consecutive rows, one run per
    sequence, every window of ``length`` frames inside its sequence), the row just past its sequence's end."""
    starts = np.asarray(starts, dtype=np.int64)
    run_last = np.r_[np.flatnonzero(np.diff(starts) != 1), len(starts) - 1]  # the last start of each run
    run_of = np.searchsorted(run_last, np.arange(len(starts)))
    return starts[run_last][run_of] + length


def resample(frames: np.ndarray, rows: np.ndarray, ends: np.ndarray, length: int, speeds: np.ndarray) -> np.ndarray:
    """(B, length, K) windows of ``frames`` (N, K) starting at ``rows``, frame t read at row ``rows + s t``
    (linear interpolation), s = ``speeds`` (B): above 1 faster, below 1 slower. A speed whose window would run
    past its sequence's end (``ends``, :func:`sequence_ends`) is lowered to the fastest that fits (at least 1:
    every start has ``length`` frames)."""
    rows, ends = np.asarray(rows, np.int64), np.asarray(ends, np.int64)
    fits = (ends - 1 - rows) / max(length - 1, 1)
    s = np.minimum(np.asarray(speeds, np.float64), fits)
    pos = rows[:, None] + s[:, None] * np.arange(length)  # (B, length), rows of frames
    i0 = np.minimum(np.floor(pos).astype(np.int64), ends[:, None] - 1)
    i1 = np.minimum(i0 + 1, ends[:, None] - 1)
    w = (pos - i0)[..., None].astype(frames.dtype)
    return frames[i0] * (1 - w) + frames[i1] * w


def arrival_keys(wins: np.ndarray, obs_len: int, velocity_weight: float = 5.0) -> np.ndarray:
    """(N, T, ...) windows -> (N, 2 D) keys: the last observed pose (frame ``obs_len - 1``) and ``velocity_weight``
    times its change over the two frames before it, flattened. Two windows whose keys are near arrive at the
    same pose moving the same way, so either's future continues the other's past."""
    flat = np.asarray(wins, np.float64).reshape(len(wins), wins.shape[1], -1)
    last = flat[:, obs_len - 1]
    return np.concatenate([last, velocity_weight * (last - flat[:, obs_len - 3])], axis=1)


def squared_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) squared Euclidean distances between the rows of two key arrays (for ranking neighbours)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return (a**2).sum(1)[:, None] + (b**2).sum(1)[None] - 2.0 * a @ b.T


def future_neighbours(
    keys: np.ndarray, seq_ids: np.ndarray, starts: np.ndarray, k: int, exclude_frames: int
) -> np.ndarray:
    """(N, k) indices: for each window, the ``k`` windows with the nearest :func:`arrival_keys` (Euclidean), leaving
    out the windows of the same sequence that start within ``exclude_frames`` of it (itself included: they are its
    own future shifted by a few frames, not another one). Brute force, in blocks of rows: fine for the tens of
    thousands of windows of a small dataset, which is where this augmentation is for."""
    keys = np.asarray(keys, np.float64)
    n = len(keys)
    seq_ids, starts = np.asarray(seq_ids), np.asarray(starts, np.int64)
    if not 1 <= k < n:
        raise ValueError(f"future_neighbours: k must be in [1, {n - 1}] for {n} windows, got {k}")
    out = np.empty((n, k), dtype=np.int64)
    for a in range(0, n, 512):
        b = min(a + 512, n)
        d = squared_distances(keys[a:b], keys)
        near_self = (seq_ids[a:b, None] == seq_ids[None]) & (np.abs(starts[a:b, None] - starts[None]) < exclude_frames)
        d[near_self] = np.inf
        part = np.argpartition(d, k - 1, axis=1)[:, :k]
        order = np.argsort(np.take_along_axis(d, part, 1), axis=1, kind="stable")
        out[a:b] = np.take_along_axis(part, order, 1)
        if not np.isfinite(np.take_along_axis(d, out[a:b], 1)).all():
            raise ValueError(f"future_neighbours: fewer than {k} windows outside {exclude_frames} frames of their own")
    return out


def swap_futures(wins: np.ndarray, donors: np.ndarray, obs_len: int) -> np.ndarray:
    """(B, T, ...) windows with frames ``obs_len:`` replaced by those of ``donors`` (B, T, ...), joined at the last
    observed frame: the donor's future plus the offset between the two last observed poses, fading linearly from
    1 (at frame ``obs_len - 1``) to 0 at the last frame. The observed frames are the window's own."""
    out = np.array(wins, copy=True)
    T = wins.shape[1]
    fade = (1.0 - np.arange(1, T - obs_len + 1) / (T - obs_len)).astype(wins.dtype)
    fade = fade.reshape((1, -1) + (1,) * (wins.ndim - 2))
    offset = (wins[:, obs_len - 1] - donors[:, obs_len - 1])[:, None]
    out[:, obs_len:] = donors[:, obs_len:] + fade * offset
    return out
