"""The body frame of poses from the wild (:mod:`tcd.wild`, rule 2): per frame the root (the pelvis, or the hips'
mid-point moved by the pelvis's offset) and the heading (the hips' direction about ``up``), smoothed over the window;
and the turns of a root frame about ``up``."""

from __future__ import annotations

from typing import Tuple

import numpy as np

from .exceptions import InvalidInputError
from .layouts import Layout
from ._skeleton import _mean_of, _median, _rest, skew


def _hip_root_offset(
    layout: Layout, x: np.ndarray, mid: np.ndarray, rot: np.ndarray, width: np.ndarray, hips: np.ndarray
) -> np.ndarray:
    """Per sequence, the pelvis's offset from the mid-point of the hips along the root frame's axes (B, 3):
    the median over the frames that show the pelvis and both hips; for a sequence that never shows its
    pelvis, the model skeleton's offset scaled by the caller's hip width over the model's (on the Human3.6M
    skeleton the pelvis is the mid-point of the hips: the offset is 0 to 1e-7 m)."""
    rest, _ = _rest()
    pelvis = _mean_of(x, layout.source_of(0))
    both = np.isfinite(pelvis).all(-1) & hips
    own = np.einsum("btc,btck->btk", np.where(both[..., None], pelvis - mid, np.nan), rot)
    model_width = np.linalg.norm(rest[6] - rest[1])
    model_off = rest[0] - 0.5 * (rest[1] + rest[6])
    out = _median(own)
    caller_width = _median(np.where(hips, width, np.nan))
    none = ~np.isfinite(out).all(-1)
    out[none] = model_off * (caller_width[none, None] / model_width)
    return out


def _smooth(v: np.ndarray, ok: np.ndarray, sigma: float) -> np.ndarray:
    """(T, C) values over the frames ``ok`` (T,) smoothed along time by local linear regression with Gaussian
    weights of ``sigma`` frames (``tcd.wild.BODY_FRAME_SIGMA``): a constant velocity passes unchanged, up to the
    window's last frame, where a plain average would lag; (T, C) at the ``ok`` frames (others: NaN)."""
    out = np.full(v.shape, np.nan)
    idx = np.flatnonzero(ok)
    if sigma <= 0 or len(idx) < 2:
        out[idx] = v[idx]
        return out
    d = (idx[None, :] - idx[:, None]).astype(np.float64)  # (at, from)
    w = np.exp(-0.5 * (d / sigma) ** 2)
    s0, s1, s2 = w.sum(1), (w * d).sum(1), (w * d * d).sum(1)
    t0, t1 = w @ v[idx], (w * d) @ v[idx]
    det = s0 * s2 - s1 * s1
    flat = det <= 1e-9 * s0 * s0  # a frame with no neighbour in reach: its weighted mean (itself)
    det = np.where(flat, 1.0, det)
    line = (s2[:, None] * t0 - s1[:, None] * t1) / det[:, None]
    out[idx] = np.where(flat[:, None], t0 / s0[:, None], line)
    return out


def _frames(x: np.ndarray, layout: Layout, up: np.ndarray, arg: str, sigma: float) -> Tuple[np.ndarray, np.ndarray]:
    """Per frame of (B, T, J, 3) poses: the root (B, T, 3) and the rotation (B, T, 3, 3) whose columns are
    the root frame's axes (left, up, forward) in the caller's coordinates, smoothed over the window (``sigma``
    frames, :func:`_smooth`) and interpolated where missing. The root is the pelvis, or where the pelvis is
    missing, the mid-point of the hips moved by the pelvis's offset from it (:func:`_hip_root_offset`)."""
    b, t = x.shape[:2]
    if layout.canonical:
        return np.zeros((b, t, 3)), np.broadcast_to(np.eye(3), (b, t, 3, 3)).copy()
    left_hip, right_hip = _mean_of(x, layout.source_of(6)), _mean_of(x, layout.source_of(1))
    across = left_hip - right_hip
    across = across - (across @ up)[..., None] * up
    norm = np.linalg.norm(across, axis=-1)
    hips = np.isfinite(norm) & (norm > 1e-6)
    for i in range(b):
        if not hips[i].any():
            which = f"sequence {i} of `{arg}`" if b > 1 else f"`{arg}`"
            raise InvalidInputError(
                f"Argument `{arg}` must show both hips in at least one frame, to place the body (the root is "
                f"the pelvis, or the mid-point of the hips where the pelvis is missing), but {which} has no "
                "frame with both hips.",
                arg,
            )
    left = across / np.where(hips, norm, 1.0)[..., None]
    rot = np.stack([left, np.broadcast_to(up, left.shape), np.cross(left, up)], axis=-1)
    mid = 0.5 * (left_hip + right_hip)
    offset = _hip_root_offset(layout, x, mid, rot, np.linalg.norm(left_hip - right_hip, axis=-1), hips)
    root = _mean_of(x, layout.source_of(0))
    from_hips = np.where(hips[..., None], mid + np.einsum("btck,bk->btc", rot, offset), np.nan)
    root = np.where(np.isfinite(root).all(-1, keepdims=True), root, from_hips)
    has_root = np.isfinite(root).all(-1)  # every frame with both hips, and more
    frames = np.arange(t)
    e1, e2 = _plane(up)
    angle = np.zeros((b, t))
    for i in range(b):
        # the heading as an angle about up (unwrapped), so that a constant turn rate is smoothed unchanged
        seen = np.flatnonzero(hips[i])
        a = _heading(across[i, seen], up)
        angle[i] = np.interp(frames, seen, _smooth(a[:, None], np.ones(len(seen), bool), sigma)[:, 0])
        smooth_root = _smooth(root[i], has_root[i], sigma)
        for c in range(3):
            root[i, :, c] = np.interp(frames, np.flatnonzero(has_root[i]), smooth_root[has_root[i], c])
    left = np.cos(angle)[..., None] * e1 + np.sin(angle)[..., None] * e2
    forward = np.cross(left, up)
    rot = np.stack([left, np.broadcast_to(up, left.shape), forward], axis=-1)
    return root, rot


def _plane(up: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """An orthonormal basis (e1, e2) of the plane normal to ``up``, e2 = up x e1: headings are angles in it."""
    e1 = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = e1 - (e1 @ up) * up
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1)


def _heading(left: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The angle (radians, unwrapped over time, the last axis) of directions ``left`` (..., T, 3) about ``up`` in
    :func:`_plane`'s basis, (..., T)."""
    e1, e2 = _plane(up)
    return np.unwrap(np.arctan2(left @ e2, left @ e1), axis=-1)


def _turn(rot: np.ndarray, angle: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``rot`` (B, 3, 3) turned by ``angle`` (B, F) about ``up``: (B, F, 3, 3) (Rodrigues)."""
    k = skew(up)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    turn = np.eye(3) + s * k + (1 - c) * (k @ k)
    return turn @ rot[:, None]
