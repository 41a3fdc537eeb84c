"""The model's skeleton and the placing of the caller's joints on it (:mod:`tcd.wild`, rule 3): the Human3.6M
32-joint rest pose and tree, the joints' nearest shown ancestors, retargeting by bone direction, and the ends a layout
stops short of carried on their parents' bones."""

from __future__ import annotations

from functools import lru_cache
from typing import Dict, Tuple

import numpy as np

from . import _fk as fk
from .layouts import FIXED_IDS, MODEL_IDS, Layout


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


def _median(v: np.ndarray) -> np.ndarray:
    """Per sequence, the median over frames of (B, T, ...) values where finite (NaN where none is)."""
    out = np.full((v.shape[0],) + v.shape[2:], np.nan)
    for i, r in enumerate(v):
        ok = np.isfinite(r).reshape(r.shape[0], -1).all(-1)
        if ok.any():
            out[i] = np.median(r[ok], axis=0)
    return out


def _shown_ancestor(shown: Dict[int, np.ndarray], j: int) -> np.ndarray:
    """Per sequence (B,), the nearest ancestor of ``j`` among the placed joints that the sequence shows in
    some frame (``shown``: 32-id -> (B,) bool); the root at worst. A joint the caller's layout has but never
    showed (3DPW's 13 joints as smpl24: no spine) is skipped, so the bone is measured from a joint that
    was seen."""
    out = np.zeros(len(shown[0]), dtype=np.int64)
    for a in reversed(_tree()[1][j]):
        out = np.where(shown[a], a, out)
    return out


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


def _scale(lengths: Dict[int, np.ndarray], ancestor: Dict[int, np.ndarray]) -> np.ndarray:
    """Per sequence (B,), the model's size over the caller's: the median over the model's bones (each from
    its nearest shown ancestor) of the model's length over the caller's (``lengths``: 32-id -> (B, T), its median
    over the frames that show both ends); 1 where no bone is measured."""
    rest, _ = _rest()
    ratios = []
    for j, anc in ancestor.items():
        caller = _median(lengths[j][..., None])[:, 0]
        model = np.linalg.norm(rest[j] - rest[anc], axis=-1)
        ratios.append(model / np.where(caller > 1e-6, caller, np.nan))
    r = np.stack(ratios, axis=-1)
    ok = np.isfinite(r)
    return np.array([np.median(row[m]) if m.any() else 1.0 for row, m in zip(r, ok)])


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrices (..., 3, 3) of vectors ``v`` (..., 3): ``skew(v) @ w == cross(v, w)``."""
    k = np.zeros(v.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return k - np.swapaxes(k, -1, -2)


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The least rotation taking direction ``a`` (3,) onto the directions ``b`` (..., 3): (..., 3, 3)."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    k, c = skew(np.cross(a, b)), b @ a
    scale = (1.0 / np.maximum(1.0 + c, 1e-9))[..., None, None]  # c = -1 (opposite) does not occur for a bone
    return np.eye(3) + k + k @ k * scale


def _carry_ends(model: Dict[int, np.ndarray], shown: Dict[int, np.ndarray]) -> None:
    """Places, in ``model``, each end the caller's layout stops short of (a hand, a toe: a model joint the
    sequence never shows, below a joint it does show, with nothing shown below it) rigidly on its parent's bone:
    the rest pose's offset from the parent, turned by the least rotation that takes the rest bone into the
    current one. Without it these rows reached the model with nothing observed, and its in-painting of them
    cost the forecast of the joints the layout does give (issue 73)."""
    rest, _ = _rest()
    order, chains = _tree()
    below: Dict[int, np.ndarray] = {j: np.zeros_like(shown[j]) for j in order}
    for j in reversed(order):  # children first: whether anything below j is shown
        if chains[j]:
            p = chains[j][0]
            below[p] = below[p] | shown[j] | below[j]
    have = dict(shown)  # shown, or carried here (a toe, then its site)
    for j in order:
        if j in FIXED_IDS or len(chains[j]) < 2:
            continue
        p, g = chains[j][0], chains[j][1]
        end = ~shown[j] & ~below[j] & have[p]
        if not end.any():
            continue
        turn = _rotation_between(rest[p] - rest[g], model[p] - model[g])
        placed = model[p] + turn @ (rest[j] - rest[p])
        model[j] = np.where(end[:, None, None], placed, model[j])
        have[j] = shown[j] | end


def _place(
    src: Dict[int, np.ndarray], ancestor: Dict[int, np.ndarray], lengths: Dict[int, np.ndarray]
) -> Dict[int, np.ndarray]:
    """The model's joints (32-id -> (B, T, 3)) from the caller's in the root frame (``src``, NaN = missing), parents
    first: the fixed joints at the model's rest pose; each other joint, in a frame that shows it,

    1. along the caller's direction from its nearest ancestor that the sequence shows (``ancestor``), at the
       model's distance for that pair: retargeting by bone direction, where that ancestor is in the frame too;
    2. else from the nearest ancestor the frame does show, by the caller's offset from it times the sequence's
       size ratio (:func:`_scale` of the caller's bone ``lengths``): a knee seen while its hip is hidden, an
       ankle while its knee is. Placing it at the rest pose's distance instead put a hand seen without its arm
       37 mm further from the truth than Zero-Velocity at the forecast's start; leaving it missing left a knee
       hidden in turn with its hip with nothing observed in the window, which the repair fill put at the root,
       447 mm off (issue 73).

    A fixed ancestor (the root, a hip, the spine) is rigid in the root frame: in a frame that hides it, its
    sequence median stands in. Every joint a frame shows is placed; one it hides is missing (in-painted)."""
    rest, _ = _rest()
    order, chains = _tree()
    shape = src[0].shape
    # where each ancestor is in each frame: the caller's joint, a fixed one's median where the frame hides it
    at = {**src, **{a: np.where(np.isfinite(src[a]), src[a], _median(src[a])[:, None]) for a in FIXED_IDS}}
    model: Dict[int, np.ndarray] = {j: np.broadcast_to(rest[j], shape).copy() for j in FIXED_IDS}
    scale = _scale(lengths, ancestor)[:, None, None]
    for j in order:
        if j in FIXED_IDS:
            continue
        val = src[j]
        seen = np.isfinite(val).all(-1)
        out = np.full(shape, np.nan)
        for a in np.unique(ancestor[j]):
            use = (ancestor[j] == a)[:, None] & seen & np.isfinite(at[a]).all(-1)
            d = val - at[a]
            n = np.linalg.norm(d, axis=-1, keepdims=True)
            step = np.where(
                n > 1e-12, d / np.where(n > 1e-12, n, 1.0) * np.linalg.norm(rest[j] - rest[a]), rest[j] - rest[a]
            )
            out[use] = (model[a] + step)[use]
        for a in chains[j]:  # nearest first; the root, last, is always there
            use = seen & ~np.isfinite(out).all(-1) & np.isfinite(at[a]).all(-1) & np.isfinite(model[a]).all(-1)
            out[use] = (model[a] + (val - at[a]) * scale)[use]
        model[j] = out
    return model
