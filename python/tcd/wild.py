"""Poses from the wild into the model's convention and back: other joint layouts, world coordinates,
any frame rate and any length. Used by :meth:`tcd.TCD.forecast`, :meth:`~tcd.TCD.predict` and
:meth:`~tcd.TCD.repair` when a call names a ``capture`` (:class:`tcd.Capture`), and by :func:`tcd.repair_file` with a
``layout`` or ``fps``.

The model's convention (Human3.6M, :mod:`tcd.layouts`): the root at the origin, the heading removed
(+x the subject's left, +y up, +z forward), the 22 joints on the Human3.6M skeleton's bone lengths, 25 fps.
The rules, in the order they are applied:

1. **Frame rate and length.** The observation is resampled to the model's frame rate on a grid that ends
   at its last frame (an entry is observed only when the source frames on both sides are: a gap never
   shrinks); a shorter one is padded with missing frames at the start, a longer one keeps its last
   ``obs_len`` frames.
2. **Root and heading.** Per frame, the heading is the direction from the right to the left hip in the
   plane normal to ``up``, and the root is the pelvis; where the pelvis is missing (3DPW's 13 SoMoF joints,
   COCO-style lifters: every layout), the root is the mid-point of the hips moved by the pelvis's offset
   from it along the root frame's axes: the sequence's own (the median over the frames that show the
   pelvis and both hips), else the model skeleton's, which is 0 (Human3.6M's pelvis is the mid-point of
   its hips). The pose is translated and turned so that the root is at the origin and the hips lie along
   +x. Frames without the hips get the heading, and frames without a pelvis and the hips the root,
   interpolated from the frames that have them; a sequence needs both hips in at least one frame. The root
   and the heading (as an angle about ``up``) are then smoothed over the window by local linear regression
   with Gaussian weights of :data:`BODY_FRAME_SIGMA` frames: detector noise on three joints no longer turns and
   moves the whole body frame by frame, while a constant velocity or turn rate passes unchanged. A pelvis
   placed by the hips only places the body: where the caller never showed one, the outputs' pelvis stays NaN.
3. **Skeleton.** Each model joint is placed along the caller's direction from its nearest ancestor that
   the sequence shows (in the Human3.6M tree), at the model's distance for that pair (retargeting by bone
   direction). In a frame that hides that ancestor, the joint is placed from the nearest ancestor the frame
   shows, by the caller's offset from it times the sequence's size ratio (the model's bones over the
   caller's, median); a fixed joint (the root, the hips, the spine) is rigid in the root frame, so its median
   stands in where a frame hides it. Every joint a frame shows is placed; the root and hips are the model's
   fixed joints. A model joint the layout lacks is carried rigidly on its parent's bone where it is an end the
   layout stops short of (hands, toes, sites: the rest pose's offset, turned with the bone), and missing and
   in-painted by the model otherwise (coco17's thorax).
4. **Back.** Forecast and repaired poses are put back on the caller's bone lengths: each model bone, from
   the joint's nearest ancestor that the sequence shows in some frame, scaled by the caller's length over
   the model's (per sequence the median over observed frames; a joint the caller never showed keeps the
   model's bone, and is no anchor for the bones below it). Joints of the layout the model lacks are carried
   rigidly (the median offset from their anchor joint in the root frame, :class:`tcd.layouts.Layout`), and
   each frame is put back in world coordinates; a joint never observed that the model cannot give stays
   NaN. The observation's own frames go through the conversion and back unchanged; a forecast on the
   medians would not start at the last observed pose where the caller's hips tilt or its bones vary from
   frame to frame (``last_pose_conversion_mm`` in benches/in_the_wild.py), which rule 6 takes care of.
5. **Future root.** The forecast's root starts at the velocity and turn rate (about ``up``) of the last
   0.2 s of the observation, the speed less ``ROOT_DEAD_ZONE_MPS`` (0.2 m/s, never below 0), both decaying
   with a time constant of ``ROOT_DAMPING_S`` (0.4 s): a walker keeps walking, a person shifting in place or
   a jittering root is held, a turn or a stop is not carried on for a whole second. Future frames come at the
   caller's frame rate, with their times in seconds after the last observed frame.
6. **Joining the observation.** In the root frame, forecast frame ``f`` (1, 2, ... model frames after the
   last observed one) is the last observed pose moved ``min(f / JOIN_FRAMES, 1)`` of the way to the
   model's forecast (5 frames, 0.2 s): the forecast starts where the person is and is the model's own from
   0.2 s on. A joint the last frame lacks starts where it was last seen (Zero-Velocity's choice; one never
   seen is the model's throughout). (A call without a
   ``capture`` does not come here: it returns the model's frames as they are.)

Observed values are returned unchanged in ``repaired``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import lru_cache
from typing import Dict, List, Optional, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike

from . import _checks, _fk as fk
from .exceptions import InvalidInputError, MirroredPosesWarning
from .layouts import FIXED_IDS, MODEL_IDS, Layout
from ._resample import resample_forward

__all__ = [
    "UP_AXES",
    "Up",
    "up_vector",
    "Scene",
    "to_model",
    "from_model",
    "join",
    "future_frames",
    "resample_to_model",
    "mirrored",
]

UP_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
#: The ``up`` argument: an axis of :data:`UP_AXES`, optionally signed (``"-z"``), or a unit 3-vector.
Up = Union[str, ArrayLike]
#: How far back the root's velocity and turn rate are measured (model frames: 0.2 s at 25 fps).
EXTRAPOLATION_FRAMES = 5
#: Time constant (s) of the decay of the future root's velocity and turn rate (None: held constant, 0: the
#: root held). 0.4 s: the least summed root error at 1 s over Human3.6M's training subjects, CMU and the
#: AMASS samples of the rules benches/root_extrapolation.py compares (results/root_extrapolation.json).
ROOT_DAMPING_S: Optional[float] = 0.4
#: Root speed (m/s) taken off the measured velocity before it is carried on (a soft threshold): a person
#: shifting in place, or the jitter of a noisy root, is held; a walker keeps walking at a little less. 0.2:
#: the least summed root error at 1 s over the same sources, clean and with 10 mm of noise on every observed
#: coordinate, of 0 / 0.05 / 0.1 / 0.2 / 0.3 (benches/root_extrapolation.py; 0 m/s carried 10 mm of noise into
#: 55 mm of root error at 1 s on Human3.6M, where holding the root gives 17.5).
ROOT_DEAD_ZONE_MPS = 0.2
#: Model frames (0.2 s at 25 fps) over which a forecast passes from the last observed pose to the model's
#: (0: the model's frames unchanged). The bundled model's first frame does not start where the person is
#: (DDIM-10, one sample, Human3.6M S5 windows 8-15 as h36m32: 25.8 mm from the truth at 40 ms against
#: Zero-Velocity's 14.7). 5: on those windows the 80 ms error is least at 4 and 5 frames (25.1 mm;
#: Zero-Velocity 28.1), the first frame no worse than Zero-Velocity's from 3 on; longer joins only lean
#: longer on the held pose (docs/wild.md; benches/in_the_wild.py --first-window 8 --join-frames N).
JOIN_FRAMES = 5
#: Frames (model frames, 25 fps: 160 ms) of the Gaussian weights with which the body frame (the root and the
#: heading, rule 2) is smoothed over the window (:func:`_smooth`), so that detector noise on the pelvis and hips
#: does not turn and move the whole body frame by frame; 0: per frame, as measured. Against 0, with 25 / 50 mm of
#: jitter on every coordinate, S5 as h36m17 at 50 fps, 1 s root-relative: 129.8 -> 109.8 / 204.2 -> 140.7 mm
#: (Zero-Velocity 137.6 / 177.5), the same on clean input (94.4 -> 94.6); on clean CMU at 120 fps the root's first
#: frame 3.7 -> 5.5 mm (Zero-Velocity 7.9) (benches/in_the_wild.py --variants as-given --noise 25 50 --samples 5
#: --steps 1 --body-frame-sigma 0 | 4). 4 frames was chosen over 2, 6 and 8 on 25-frame S5 windows with half the
#: leg entries hidden: most of the gain, the shortest reach for real turns.
BODY_FRAME_SIGMA = 4.0
#: Whether a model joint the caller's layout stops short of (a hand, a toe, a site) is carried on its parent's
#: bone (rule 3, :func:`_carry_ends`) instead of reaching the model with nothing observed (False). Human3.6M S5 as
#: h36m17 in world coordinates, DDIM-1, mean of 5 at 1 s root-relative: 105.9 -> 94.6 mm (Zero-Velocity 117.0;
#: the native input on the same joints 94.8) (benches/in_the_wild.py --variants as-given --samples 5 --steps 1).
CARRY_ENDS = True


def up_vector(up: Up) -> np.ndarray:
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


def _smooth(v: np.ndarray, ok: np.ndarray, sigma: Optional[float] = None) -> np.ndarray:
    """(T, C) values over the frames ``ok`` (T,) smoothed along time by local linear regression with Gaussian
    weights of ``sigma`` frames (:data:`BODY_FRAME_SIGMA`): a constant velocity passes unchanged, up to the
    window's last frame, where a plain average would lag; (T, C) at the ``ok`` frames (others: NaN)."""
    sigma = BODY_FRAME_SIGMA if sigma is None else sigma
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


def _frames(x: np.ndarray, layout: Layout, up: np.ndarray, arg: str) -> Tuple[np.ndarray, np.ndarray]:
    """Per frame of (B, T, J, 3) poses: the root (B, T, 3) and the rotation (B, T, 3, 3) whose columns are
    the root frame's axes (left, up, forward) in the caller's coordinates, smoothed over the window and
    interpolated where missing. The root is the pelvis, or where the pelvis is missing, the mid-point of the
    hips moved by the pelvis's offset from it (:func:`_hip_root_offset`)."""
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
        a = np.unwrap(np.arctan2(across[i, seen] @ e2, across[i, seen] @ e1))
        angle[i] = np.interp(frames, seen, _smooth(a[:, None], np.ones(len(seen), bool))[:, 0])
        smooth_root = _smooth(root[i], has_root[i])
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


def _heading(rot: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The angle (radians, unwrapped over time) of the left axis about ``up``, (B, T)."""
    e1, e2 = _plane(up)
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
    root: np.ndarray  # (B, T, 3) the root, caller coordinates
    rot: np.ndarray  # (B, T, 3, 3) the root frame (columns: left, up, forward)
    lengths: Dict[int, np.ndarray]  # model 32-id -> (B, T) caller distance to ``ancestor``
    ancestor: Dict[int, np.ndarray]  # model 32-id -> (B,) its nearest placed ancestor the sequence shows
    fixed: Dict[int, np.ndarray]  # fixed 32-id -> (B, T, 3) caller position in the root frame
    carried: Dict[int, Tuple[int, np.ndarray]]  # layout joint -> (anchor 32-id, (B, T, 3) offset)
    last: np.ndarray  # (B, J, 3) each joint where last seen, in that frame's root frame (last_seen)
    start: np.ndarray  # (B, J, 3) each joint where last seen, caller coordinates: a forecast's time 0

    def value(self, per_frame: np.ndarray, frames: bool) -> np.ndarray:
        """``per_frame`` on the observation's own frames where finite (``frames``), else (and for other
        frames) the sequence's median; (B, T, ...) or (B, 1, ...)."""
        med = _median(per_frame)[:, None]
        if not frames:
            return med
        return np.where(np.isfinite(per_frame), per_frame, med)


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


def _canonical(x: np.ndarray, layout: Layout, up: np.ndarray, arg: str) -> Tuple[np.ndarray, ...]:
    """(B, T, J, 3) caller poses -> (root, rot, the poses along their root frame's axes, root subtracted)."""
    root, rot = _frames(x, layout, up, arg)
    return root, rot, np.einsum("btjc,btck->btjk", x - root[:, :, None, :], rot)


def _scale(src: Dict[int, np.ndarray], ancestor: Dict[int, np.ndarray]) -> np.ndarray:
    """Per sequence (B,), the model's size over the caller's: the median over the model's bones (each from
    its nearest shown ancestor) of the model's length over the caller's (its median over the frames that show
    both ends); 1 where no bone is measured."""
    rest, _ = _rest()
    ratios = []
    for j, anc in ancestor.items():
        r = np.full(len(anc), np.nan)
        for a in np.unique(anc):
            use = anc == a
            caller = _median(np.linalg.norm(src[j][use] - src[a][use], axis=-1)[..., None])[:, 0]
            r[use] = np.linalg.norm(rest[j] - rest[a]) / np.where(caller > 1e-6, caller, np.nan)
        ratios.append(r)
    r = np.stack(ratios, axis=-1)
    ok = np.isfinite(r)
    return np.array([np.median(row[m]) if m.any() else 1.0 for row, m in zip(r, ok)])


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The least rotation taking direction ``a`` (3,) onto the directions ``b`` (..., 3): (..., 3, 3)."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    v, c = np.cross(a, b), b @ a
    k = np.zeros(b.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k = k - np.swapaxes(k, -1, -2)
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
        for p in chains[j][:1]:
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


def _place(src: Dict[int, np.ndarray], ancestor: Dict[int, np.ndarray]) -> Dict[int, np.ndarray]:
    """The model's joints (32-id -> (B, T, 3)) from the caller's in the root frame (``src``, NaN = missing), parents
    first: the fixed joints at the model's rest pose; each other joint, in a frame that shows it,

    1. along the caller's direction from its nearest ancestor that the sequence shows (``ancestor``), at the
       model's distance for that pair: retargeting by bone direction, where that ancestor is in the frame too;
    2. else from the nearest ancestor the frame does show, by the caller's offset from it times the sequence's
       size ratio (:func:`_scale`): a knee seen while its hip is hidden, an ankle while its knee is. Placing it at
       the rest pose's distance instead put a hand seen without its arm 37 mm further from the truth than
       Zero-Velocity at the forecast's start; leaving it missing left a knee hidden in turn with its hip with
       nothing observed in the window, which the repair fill put at the root, 447 mm off (issue 73).

    A fixed ancestor (the root, a hip, the spine) is rigid in the root frame: in a frame that hides it, its
    sequence median stands in. Every joint a frame shows is placed; one it hides is missing (in-painted)."""
    rest, _ = _rest()
    order, chains = _tree()
    shape = src[0].shape
    at = {a: np.where(np.isfinite(src[a]), src[a], _median(src[a])[:, None]) for a in FIXED_IDS}
    model: Dict[int, np.ndarray] = {j: np.broadcast_to(rest[j], shape).copy() for j in FIXED_IDS}
    scale = _scale(src, ancestor)[:, None, None]
    for j in order:
        if j in FIXED_IDS:
            continue
        val = src[j]
        seen = np.isfinite(val).all(-1)
        out = np.full(shape, np.nan)
        for a in np.unique(ancestor[j]):
            from_a = at.get(a, src[a])
            use = (ancestor[j] == a)[:, None] & seen & np.isfinite(from_a).all(-1)
            d = val - from_a
            n = np.linalg.norm(d, axis=-1, keepdims=True)
            step = np.where(
                n > 1e-12, d / np.where(n > 1e-12, n, 1.0) * np.linalg.norm(rest[j] - rest[a]), rest[j] - rest[a]
            )
            out[use] = (model[a] + step)[use]
        for a in chains[j]:  # nearest first; the root, last, is always there
            from_a = at.get(a, src[a])
            use = seen & ~np.isfinite(out).all(-1) & np.isfinite(from_a).all(-1) & np.isfinite(model[a]).all(-1)
            out[use] = (model[a] + (val - from_a) * scale)[use]
        model[j] = out
    return model


#: (hip, knee, ankle) 32-ids of the two legs: a knee bends forward, the chirality cue of :func:`mirrored`
_LEGS = ((1, 2, 3), (6, 7, 8))
#: A knee counts as bent where it stands this far (m) off its hip-ankle line along the root frame's forward axis.
BENT_KNEE_M = 0.03


def mirrored(src: Dict[int, np.ndarray]) -> np.ndarray:
    """Per sequence (B,), whether its left and right look swapped: the caller's hips, knees and ankles in the root
    frame (``src``: 32-id -> (B, T, 3), NaN = missing; forward is +z) show at least 5 bent knees (frames x legs, off
    the hip-ankle line by :data:`BENT_KNEE_M`) and 80 % of them bend backward. A knee bends forward only; the root
    frame is built from the hips, so swapped labels turn the person round and mirror them, and every bent knee
    then points backward. A straight-legged sequence cannot tell (False)."""
    bent, backward = 0, 0
    for hip, knee, ankle in _LEGS:
        h, k, a = src[hip], src[knee], src[ankle]
        u = a - h
        n2 = np.einsum("btc,btc->bt", u, u)
        off = (k - h) - (np.einsum("btc,btc->bt", k - h, u) / np.where(n2 > 1e-12, n2, np.nan))[..., None] * u
        fwd = np.nan_to_num(off[..., 2])  # a leg a frame does not show is not bent
        bent = bent + (np.abs(fwd) > BENT_KNEE_M).sum(-1)
        backward = backward + (fwd < -BENT_KNEE_M).sum(-1)
    return (bent >= 5) & (backward >= 0.8 * bent)


def to_model(
    x: np.ndarray, layout: Layout, up: np.ndarray, arg: str = "obs", sightings: Optional[np.ndarray] = None
) -> Tuple[np.ndarray, Scene]:
    """(B, T, J, 3) caller poses (NaN = missing, metres) -> (B, T, 22, 3) model poses (NaN = missing).
    ``sightings``: the caller's poses at their own frame rate, ending at ``x``'s last frame (``x`` resampled
    from them), from which ``Scene.last`` takes where each joint was last seen (default: ``x``). At the
    model's rate a frame shows a joint only where both input frames around it do, so at 120 fps a joint hidden
    for a few input frames is missing for a whole model frame or two."""
    rest, _ = _rest()
    root, rot, canon = _canonical(x, layout, up, arg)
    placed = set(FIXED_IDS) | set(MODEL_IDS)
    src = {j: _mean_of(canon, layout.source_of(j)) for j in placed}
    pelvis_seen = np.isfinite(src[0]).all(-1, keepdims=True)
    src[0] = np.zeros_like(src[0])  # the root is the origin of its own frame
    shown = {j: np.isfinite(src[j]).all(-1).any(-1) for j in placed}
    shown[0] = np.ones_like(shown[0])
    flipped = np.flatnonzero(mirrored(src))
    if len(flipped):
        which = f"sequences {flipped.tolist()} of `{arg}`" if len(src[0]) > 1 else f"`{arg}`"
        warnings.warn(
            f"{which} in layout {layout.name!r}: the knees bend backward in the body frame built from the hips, "
            "as they do when left and right are swapped. Check that the joints are in the layout's order "
            "(tcd.layouts; docs/wild.md, 'Left and right').",
            MirroredPosesWarning,
            stacklevel=4,
        )
    ancestor = {j: _shown_ancestor(shown, j) for j in MODEL_IDS}
    model = _place(src, ancestor)
    if CARRY_ENDS:
        _carry_ends(model, shown)
    lengths = {}
    for j in MODEL_IDS:
        lengths[j] = np.full(src[j].shape[:-1], np.nan)
        for a in np.unique(ancestor[j]):
            use = ancestor[j] == a
            lengths[j][use] = np.linalg.norm(src[j][use] - src[a][use], axis=-1)
    fixed = {j: src[j] for j in FIXED_IDS}
    fixed[0] = np.where(pelvis_seen, src[0], np.nan)  # where the caller showed a pelvis (else: the hips')
    carried = {}
    for i, t in enumerate(layout.to32):
        if t is None or t not in placed:
            a = _anchor32(layout, i)
            carried[i] = (a, canon[:, :, i] - src[a])
    last = last_seen(canon if sightings is None else _canonical(sightings, layout, up, arg)[2])
    if sightings is not None:
        # the joints the last frame shows in the root frame the forecast continues from (the model's last frame:
        # the same instant), not in the sightings' own, which their rate smooths differently
        final = np.einsum("bjc,bck->bjk", sightings[:, -1] - root[:, -1, None, :], rot[:, -1])
        last = np.where(np.isfinite(final), final, last)
    start = last_seen(x if sightings is None else sightings)
    scene = Scene(layout, up, root, rot, lengths, ancestor, fixed, carried, last, start)
    return np.stack([model[j] for j in MODEL_IDS], axis=2), scene


def from_model(y: np.ndarray, scene: Scene, root: np.ndarray, rot: np.ndarray, own_frames: bool) -> np.ndarray:
    """(..., B, F, 22, 3) model poses -> (..., B, F, J, 3) caller poses in the root frames ``root`` (B, F, 3),
    ``rot`` (B, F, 3, 3). ``own_frames``: the F frames are the observation's (repair), so the caller's
    per-frame bone lengths and offsets are used where observed; otherwise they are the F model frames after
    the last observed one (forecast): the sequence's medians, and each joint the last frame shows passes
    from where it was to the model's forecast over the first JOIN_FRAMES frames (:func:`join`)."""
    rest, _ = _rest()
    layout = scene.layout
    lead = y.shape[:-2]
    model = {j: y[..., k, :] for k, j in enumerate(MODEL_IDS)}
    out: Dict[int, np.ndarray] = {}
    for j in FIXED_IDS:
        model[j] = np.broadcast_to(rest[j], lead + (3,))
        fixed = scene.value(scene.fixed[j], own_frames)
        out[j] = np.broadcast_to(np.where(np.isfinite(fixed), fixed, rest[j]), lead + (3,))
    order, _ = _tree()
    for j in order:
        if j in FIXED_IDS:
            continue
        # the model's bone from the joint's nearest ancestor the sequence shows, scaled by the caller's length
        # over the model's: the model's own output where the two skeletons agree, and an exact round trip of
        # the caller's frames through to_model; a joint the caller never showed: the model's bone
        anc = scene.ancestor[j]
        base = np.zeros(lead + (3,))
        bone = np.zeros(lead + (3,))
        model_length = np.ones(len(anc))
        for a in np.unique(anc):
            use = (anc == a)[:, None, None]
            base = np.where(use, out[a], base)
            bone = np.where(use, model[j] - model[a], bone)
            model_length[anc == a] = np.linalg.norm(rest[j] - rest[a])
        length = scene.value(scene.lengths[j], own_frames)[..., None]
        ratio = np.where(np.isfinite(length), length / model_length[:, None, None], 1.0)
        out[j] = base + bone * ratio
    joints: List[np.ndarray] = []
    placed = set(FIXED_IDS) | set(MODEL_IDS)
    # a pelvis the caller never showed is not made up: the root placed from the hips stays inside
    pelvis = np.isfinite(scene.value(scene.fixed[0], own_frames)).all(-1, keepdims=True)
    for i, t in enumerate(layout.to32):
        if t == 0:
            joints.append(np.where(pelvis, out[0], np.nan))
        elif t is not None and t in placed:
            joints.append(out[t])
        else:
            a, off = scene.carried[i]
            joints.append(out[a] + scene.value(off, own_frames))
    canon = np.stack(joints, axis=-2)
    if not own_frames:
        canon = join(canon, scene.last)
    return np.einsum("...btjk,btck->...btjc", canon, rot) + root[:, :, None, :]


def last_seen(canon: np.ndarray) -> np.ndarray:
    """(B, T, J, 3) caller poses in their root frames (NaN = unobserved) -> (B, J, 3): each joint where the
    last frame that shows it put it (NaN: never shown). Where the last frame lacks a joint (an occlusion), the
    forecast starts from there, as Zero-Velocity does: on the in-the-wild benchmark's occluded rows the model's
    in-painting of such a joint started the forecast 1.1 to 2.9 x further from the truth than the joint's last
    sighting (benches/in_the_wild.py, issue 27)."""
    seen = np.isfinite(canon).all(-1)  # (B, T, J)
    idx = canon.shape[1] - 1 - np.argmax(seen[:, ::-1], axis=1)  # the last frame showing each joint
    out = np.take_along_axis(canon, idx[:, None, :, None], axis=1)[:, 0]
    return np.where(seen.any(axis=1)[..., None], out, np.nan)


def join(canon: np.ndarray, last: np.ndarray, frames: Optional[int] = None) -> np.ndarray:
    """The forecast (..., B, F, J, 3) in the root frame, frame f (1, 2, ...) moved from the last observed
    pose ``last`` (B, J, 3; :func:`last_seen`) to the model's: ``last + (forecast - last) * min(f / frames, 1)``
    with ``frames`` JOIN_FRAMES (0: the model's unchanged); joints never shown are the model's."""
    frames = JOIN_FRAMES if frames is None else frames
    if frames <= 0:
        return canon
    f = canon.shape[-3]
    w = np.minimum(np.arange(1, f + 1, dtype=np.float64) / frames, 1.0)[:, None, None]
    start = last[:, None]
    return np.where(np.isfinite(start), start + (canon - start) * w, canon)


def future_frames(
    scene: Scene, count: int, fps: float, damping_s: Optional[float] = None
) -> Tuple[np.ndarray, np.ndarray]:
    """Root (B, count, 3) and root frames (B, count, 3, 3) of the ``count`` model frames (at ``fps``) after
    the last observed one: the velocity (its speed less ROOT_DEAD_ZONE_MPS) and turn rate of the last
    EXTRAPOLATION_FRAMES frames of the smoothed body frame, held (``damping_s`` None) or decaying exponentially
    with that time constant in seconds (0 holds the root)."""
    root, rot, up = scene.root, scene.rot, scene.up
    t = root.shape[1]
    k = min(EXTRAPOLATION_FRAMES, t - 1)
    f = np.arange(1, count + 1, dtype=np.float64)
    start = root[:, -1:, :]
    if k == 0 or scene.layout.canonical or damping_s == 0:
        return np.repeat(start, count, 1), np.repeat(rot[:, -1:], count, 1)
    # frames travelled at the last velocity: f itself, or tau (1 - exp(-f / tau)) as the velocity decays
    travel = f if damping_s is None else damping_s * fps * -np.expm1(-f / (damping_s * fps))
    velocity = (root[:, -1] - root[:, -1 - k]) / k
    if ROOT_DEAD_ZONE_MPS > 0:  # soft threshold: the speed less the dead zone, never below 0
        speed = np.linalg.norm(velocity, axis=-1, keepdims=True) * fps
        velocity = velocity * np.clip(1.0 - ROOT_DEAD_ZONE_MPS / np.maximum(speed, 1e-12), 0.0, None)
    heading = _heading(rot, up)
    rate = (heading[:, -1] - heading[:, -1 - k]) / k
    return start + velocity[:, None, :] * travel[None, :, None], _turn(rot[:, -1], rate[:, None] * travel, up)


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
        return res[:, n - frames :], times[n - frames :]
    pad = np.full((b, frames - n, j, 3), np.nan)
    return np.concatenate([pad, res], axis=1), np.concatenate(
        [times[0] - (np.arange(frames - n, 0, -1)) * (fps / model_fps), times]
    )
