"""Poses from the wild into the model's convention and back: other joint layouts, world coordinates,
any frame rate and any length (issue 17). Used by :meth:`tcd.TCD.forecast` and :meth:`tcd.TCD.repair`
when ``layout``, ``fps`` or world coordinates are given.

The model's convention (Human3.6M, :mod:`tcd.layouts`): the root at the origin, the heading removed
(+x the subject's left, +y up, +z forward), the 22 joints on the Human3.6M skeleton's bone lengths, 25 fps.
The rules, in the order they are applied:

1. **Frame rate and length.** The observation is resampled to the model's frame rate on a grid that ends
   at its last frame (an entry is observed only when the source frames on both sides are: a gap never
   shrinks); a shorter one is padded with missing frames at the start, a longer one keeps its last
   ``obs_len`` frames.
2. **Root and heading.** Per frame, the root is the pelvis (or the mid-point of the hips), the heading the
   direction from the right to the left hip in the plane normal to ``up``; the pose is translated and
   turned so that the root is at the origin and the hips lie along +x. Frames without a pelvis and both
   hips get root and heading interpolated from the frames that have them.
3. **Skeleton.** Each model joint is placed along the caller's direction from its nearest observed
   ancestor (in the Human3.6M tree), at the model's distance for that pair (retargeting by bone
   direction); the root and hips are the model's fixed joints. A model joint the layout lacks is missing
   and in-painted by the model.
4. **Back.** Forecast and repaired poses are put back on the caller's bone lengths (each model bone scaled
   by the caller's length over the model's: per sequence the median over observed frames), joints of the layout the model lacks are carried rigidly (the median
   offset from their anchor joint in the root frame, :class:`tcd.layouts.Layout`), and each frame is put
   back in world coordinates; a joint never observed that the model cannot give stays NaN.
5. **Future root.** The forecast's root starts at the velocity and turn rate (about ``up``) of the last
   0.2 s of the observation, both decaying with a time constant of ``ROOT_DAMPING_S`` (0.4 s): a walker
   keeps walking, a turn or a stop is not carried on for a whole second. Future frames come at the
   caller's frame rate, with their times in seconds after the last observed frame.

Observed values are returned unchanged in ``repaired``.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Dict, List, Optional, Tuple

import numpy as np

from . import _checks, fk
from .exceptions import InvalidInputError
from .layouts import FIXED_IDS, MODEL_IDS, Layout
from .resample import resample_forward

__all__ = ["UP_AXES", "up_vector", "Scene", "to_model", "from_model", "future_frames", "resample_to_model"]

UP_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
#: How far back the root's velocity and turn rate are measured (model frames: 0.2 s at 25 fps).
EXTRAPOLATION_FRAMES = 5
#: Time constant (s) of the decay of the future root's velocity and turn rate (None: held constant, 0: the
#: root held). 0.4 s: the least summed root error at 1 s over Human3.6M's training subjects, CMU and the
#: AMASS samples of the rules benches/root_extrapolation.py compares (results/root_extrapolation.json).
ROOT_DAMPING_S: Optional[float] = 0.4


def up_vector(up: object) -> np.ndarray:
    """``"x"``, ``"y"``, ``"z"`` (optionally signed, ``"-z"``) or a 3-vector of unit length."""
    if isinstance(up, str):
        sign = -1.0 if up.startswith("-") else 1.0
        axis = up.lstrip("+-")
        if axis in UP_AXES:
            return sign * np.asarray(UP_AXES[axis])
        raise _checks.fail("up", "'x', 'y', 'z' (optionally signed) or a unit 3-vector", repr(up))
    try:
        v = np.asarray(up, dtype=np.float64)
    except (TypeError, ValueError):
        v = np.zeros(0)
    if v.shape != (3,) or not np.isfinite(v).all() or abs(np.linalg.norm(v) - 1.0) > 1e-6:
        raise _checks.fail("up", "'x', 'y', 'z' (optionally signed) or a unit 3-vector", repr(up))
    return v


# ---------------------------------------------------------------------------------------------- the skeleton
@lru_cache(maxsize=1)
def _rest() -> Tuple[np.ndarray, Tuple[int, ...]]:
    """Rest positions of the 32 joints in metres (zero rotations), and the 32-skeleton's parents."""
    sk = fk.skeleton()
    parents = tuple(int(p) for p in sk["parents"])
    off = np.asarray(sk["offsets_mm"], dtype=np.float64) / 1000.0
    pos = np.zeros((32, 3))
    for j in range(32):
        pos[j] = off[j] if parents[j] < 0 else pos[parents[j]] + off[j]
    return pos, parents


# Joints of the 32-skeleton that always sit where another joint is (the clavicle anchors on the neck, the
# wrist, hand and thumb ends on their parents: Human3.6M's evaluation copies them the same way): a bone from
# one of them is a bone from the joint it sits on, so every step of the tree below has a constant length.
_SAME_PLACE = {16: 13, 24: 13, 20: 19, 23: 22, 28: 27, 31: 30}


@lru_cache(maxsize=1)
def _tree() -> Tuple[Tuple[int, ...], Dict[int, Tuple[int, ...]]]:
    """The joints the conversion places (the fixed ones and the model's), parents first, and for each its
    ancestors among them, nearest first."""
    _, parents = _rest()
    placed = set(FIXED_IDS) | set(MODEL_IDS)
    ancestors = {}
    for j in placed:
        chain, p = [], parents[j]
        while p >= 0:
            p = _SAME_PLACE.get(p, p)
            if p in placed and p not in chain:
                chain.append(p)
            p = parents[p]
        ancestors[j] = tuple(chain)
    order = tuple(sorted(placed, key=lambda j: len(ancestors[j])))
    return order, ancestors


def _mean_of(x: np.ndarray, joints: Tuple[int, ...]) -> np.ndarray:
    """The mean position of ``joints`` (..., 3), NaN where any of them is missing."""
    if not joints:
        return np.full(x.shape[:-2] + (3,), np.nan)
    return x[..., list(joints), :].mean(axis=-2)


# ---------------------------------------------------------------------------------------------- root frames
def _frames(x: np.ndarray, layout: Layout, up: np.ndarray, arg: str) -> Tuple[np.ndarray, np.ndarray]:
    """Per frame of (B, T, J, 3) poses: the root (B, T, 3) and the rotation (B, T, 3, 3) whose columns are
    the root frame's axes (left, up, forward) in the caller's coordinates; interpolated where missing."""
    b, t = x.shape[:2]
    if layout.canonical:
        return np.zeros((b, t, 3)), np.broadcast_to(np.eye(3), (b, t, 3, 3)).copy()
    root = _mean_of(x, layout.source_of(0))
    across = _mean_of(x, layout.source_of(6)) - _mean_of(x, layout.source_of(1))
    across = across - (across @ up)[..., None] * up
    norm = np.linalg.norm(across, axis=-1)
    ok = np.isfinite(root).all(-1) & np.isfinite(norm) & (norm > 1e-6)
    for i in range(b):
        if not ok[i].any():
            which = f"sequence {i} of `{arg}`" if b > 1 else f"`{arg}`"
            raise InvalidInputError(
                f"Argument `{arg}` must show the root (pelvis or both hips) and both hips in at least one "
                f"frame, to place the body, but {which} has none such.", arg)
        known = np.flatnonzero(ok[i])
        frames = np.arange(t)
        for c in range(3):
            root[i, :, c] = np.interp(frames, known, root[i, known, c])
            across[i, :, c] = np.interp(frames, known, across[i, known, c])
    across = across - (across @ up)[..., None] * up
    left = across / np.linalg.norm(across, axis=-1, keepdims=True)
    forward = np.cross(left, up)
    rot = np.stack([left, np.broadcast_to(up, left.shape), forward], axis=-1)
    return root, rot


def _heading(rot: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The angle (radians, unwrapped over time) of the left axis about ``up``, (B, T)."""
    e1 = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = e1 - (e1 @ up) * up
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    left = rot[..., :, 0]
    return np.unwrap(np.arctan2(left @ e2, left @ e1), axis=-1)


def _turn(rot: np.ndarray, angle: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``rot`` (B, 3, 3) turned by ``angle`` (B, F) about ``up``: (B, F, 3, 3) (Rodrigues)."""
    k = np.array([[0, -up[2], up[1]], [up[2], 0, -up[0]], [-up[1], up[0], 0]])
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    turn = np.eye(3) + s * k + (1 - c) * (k @ k)
    return turn @ rot[:, None]


# ---------------------------------------------------------------------------------------------- scene
def _median(v: np.ndarray) -> np.ndarray:
    """Per sequence, the median over frames of (B, T, ...) values where finite (NaN where none is)."""
    out = np.full((v.shape[0],) + v.shape[2:], np.nan)
    for i, r in enumerate(v):
        ok = np.isfinite(r).reshape(r.shape[0], -1).all(-1)
        if ok.any():
            out[i] = np.median(r[ok], axis=0)
    return out


@dataclass
class Scene:
    """What :func:`to_model` learnt of the caller's poses, for :func:`from_model`. Per-frame values are
    (B, T, ...) over the model frames of the observation, NaN where unobserved."""

    layout: Layout
    up: np.ndarray
    root: np.ndarray                  # (B, T, 3) the root, caller coordinates
    rot: np.ndarray                   # (B, T, 3, 3) the root frame (columns: left, up, forward)
    lengths: Dict[int, np.ndarray]    # model 32-id -> (B, T) caller distance to its nearest layout ancestor
    fixed: Dict[int, np.ndarray]      # fixed 32-id -> (B, T, 3) caller position in the root frame
    carried: Dict[int, Tuple[int, np.ndarray]]   # layout joint -> (anchor 32-id, (B, T, 3) offset)

    def value(self, per_frame: np.ndarray, frames: bool) -> np.ndarray:
        """``per_frame`` on the observation's own frames where finite (``frames``), else (and for other
        frames) the sequence's median; (B, T, ...) or (B, 1, ...)."""
        med = _median(per_frame)[:, None]
        if not frames:
            return med
        return np.where(np.isfinite(per_frame), per_frame, med)


def _layout_has(layout: Layout, j: int) -> bool:
    return bool(layout.source_of(j)) or j == 0


def _static_ancestor(layout: Layout, j: int) -> int:
    """The nearest ancestor (among the placed joints) that the layout has; the root at worst."""
    return next((a for a in _tree()[1][j] if _layout_has(layout, a)), 0)


def _anchor32(layout: Layout, i: int) -> int:
    """The 32-id a carried layout joint hangs from: the layout's own choice (``Layout.anchors``: COCO's
    face points on the head), else its nearest layout ancestor that stands for a placed joint, else the root."""
    if i in layout.anchors:
        return layout.anchors[i]
    placed = set(FIXED_IDS) | set(MODEL_IDS)
    p = layout.parents[i]
    while p >= 0:
        t = layout.to32[p]
        if t is not None and t in placed:
            return t
        p = layout.parents[p]
    return 0


def to_model(x: np.ndarray, layout: Layout, up: np.ndarray, arg: str = "obs") -> Tuple[np.ndarray, Scene]:
    """(B, T, J, 3) caller poses (NaN = missing, metres) -> (B, T, 22, 3) model poses (NaN = missing)."""
    rest, _ = _rest()
    root, rot = _frames(x, layout, up, arg)
    canon = np.einsum("btjc,btck->btjk", x - root[:, :, None, :], rot)   # along the root frame's axes
    placed = set(FIXED_IDS) | set(MODEL_IDS)
    src = {j: _mean_of(canon, layout.source_of(j)) for j in placed}
    src[0] = np.zeros_like(src[0])                           # the root is the origin of its own frame
    order, ancestors = _tree()
    model: Dict[int, np.ndarray] = {j: np.broadcast_to(rest[j], canon.shape[:2] + (3,)).copy() for j in FIXED_IDS}
    for j in order:
        if j in FIXED_IDS:
            continue
        val = src[j]
        out = np.full(val.shape, np.nan)
        todo = np.isfinite(val).all(-1)
        for a in ancestors[j]:                               # per frame, the nearest observed ancestor
            use = todo & np.isfinite(src[a]).all(-1)
            if not use.any():
                continue
            d = val - src[a]
            n = np.linalg.norm(d, axis=-1, keepdims=True)
            step = np.where(n > 1e-12, d / np.where(n > 1e-12, n, 1.0) * np.linalg.norm(rest[j] - rest[a]),
                            rest[j] - rest[a])
            out[use] = (model[a] + step)[use]
            todo &= ~use
        model[j] = out
    lengths = {j: np.linalg.norm(src[j] - src[_static_ancestor(layout, j)], axis=-1) for j in MODEL_IDS}
    fixed = {j: src[j] for j in FIXED_IDS}
    carried = {}
    for i, t in enumerate(layout.to32):
        if t is None or t not in placed:
            a = _anchor32(layout, i)
            carried[i] = (a, canon[:, :, i] - src[a])
    scene = Scene(layout, up, root, rot, lengths, fixed, carried)
    return np.stack([model[j] for j in MODEL_IDS], axis=2), scene


def from_model(y: np.ndarray, scene: Scene, root: np.ndarray, rot: np.ndarray, own_frames: bool) -> np.ndarray:
    """(..., B, F, 22, 3) model poses -> (..., B, F, J, 3) caller poses in the root frames ``root`` (B, F, 3),
    ``rot`` (B, F, 3, 3). ``own_frames``: the F frames are the observation's (repair), so the caller's
    per-frame bone lengths and offsets are used where observed; otherwise (forecast) their medians."""
    rest, _ = _rest()
    layout = scene.layout
    lead = y.shape[:-2]
    model = {j: y[..., k, :] for k, j in enumerate(MODEL_IDS)}
    out: Dict[int, np.ndarray] = {}
    for j in FIXED_IDS:
        model[j] = np.broadcast_to(rest[j], lead + (3,))
        fixed = scene.value(scene.fixed[j], own_frames)
        out[j] = np.broadcast_to(np.where(np.isfinite(fixed), fixed, rest[j]), lead + (3,))
    order, ancestors = _tree()
    for j in order:
        if j in FIXED_IDS:
            continue
        a = _static_ancestor(layout, j)
        # the model's bone, scaled by the caller's length over the model's: the model's own output where the
        # two skeletons agree, and an exact round trip of the caller's frames through to_model
        ratio = 1.0                                          # a joint the caller lacks: the model's bone
        if _layout_has(layout, j):
            length = scene.value(scene.lengths[j], own_frames)[..., None]
            ratio = np.where(np.isfinite(length), length / np.linalg.norm(rest[j] - rest[a]), 1.0)
        out[j] = out[a] + (model[j] - model[a]) * ratio
    joints: List[np.ndarray] = []
    placed = set(FIXED_IDS) | set(MODEL_IDS)
    for i, t in enumerate(layout.to32):
        if t is not None and t in placed:
            joints.append(out[t])
        else:
            a, off = scene.carried[i]
            joints.append(out[a] + scene.value(off, own_frames))
    canon = np.stack(joints, axis=-2)
    return np.einsum("...btjk,btck->...btjc", canon, rot) + root[:, :, None, :]


def future_frames(scene: Scene, count: int, fps: float,
                  damping_s: Optional[float] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Root (B, count, 3) and root frames (B, count, 3, 3) of the ``count`` model frames (at ``fps``) after
    the last observed one: the velocity and turn rate of the last EXTRAPOLATION_FRAMES frames, held
    (``damping_s`` None) or decaying exponentially with that time constant in seconds (0 holds the root)."""
    root, rot, up = scene.root, scene.rot, scene.up
    t = root.shape[1]
    k = min(EXTRAPOLATION_FRAMES, t - 1)
    f = np.arange(1, count + 1, dtype=np.float64)
    if k == 0 or scene.layout.canonical or damping_s == 0:
        return (np.repeat(root[:, -1:], count, 1), np.repeat(rot[:, -1:], count, 1))
    # frames travelled at the last velocity: f itself, or tau (1 - exp(-f / tau)) as the velocity decays
    travel = f if damping_s is None else damping_s * fps * -np.expm1(-f / (damping_s * fps))
    velocity = (root[:, -1] - root[:, -1 - k]) / k
    heading = _heading(rot, up)
    rate = (heading[:, -1] - heading[:, -1 - k]) / k
    return (root[:, -1:, :] + velocity[:, None, :] * travel[None, :, None],
            _turn(rot[:, -1], rate[:, None] * travel, up))


# ---------------------------------------------------------------------------------------------- frame rates
def resample_to_model(x: np.ndarray, fps: float, model_fps: float, frames: int) -> Tuple[np.ndarray, np.ndarray]:
    """(B, T, J, 3) at ``fps`` (NaN = missing) -> the last ``frames`` model frames at ``model_fps`` on a grid
    ending at the last input frame, (B, frames, J, 3) NaN = missing, and each model frame's time in input
    frames (frames,) (negative for padding)."""
    b, t, j, _ = x.shape
    rev = x[:, ::-1].reshape(b, t, -1)
    outs = []
    for i in range(b):
        y, m = resample_forward(np.nan_to_num(rev[i]), ~np.isnan(rev[i]), fps, model_fps)
        outs.append(np.where(m, y, np.nan)[::-1])
    n = outs[0].shape[0]
    res = np.stack(outs).reshape(b, n, j, 3)
    times = (t - 1) - np.arange(n)[::-1] * (fps / model_fps)
    if n >= frames:
        return res[:, n - frames:], times[n - frames:]
    pad = np.full((b, frames - n, j, 3), np.nan)
    return np.concatenate([pad, res], axis=1), np.concatenate([times[0] - (np.arange(frames - n, 0, -1)) *
                                                                (fps / model_fps), times])
