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
   A sequence whose bent knees point backward in that frame, as swapped left and right make them, gets a
   :class:`tcd.exceptions.MirroredPosesWarning` (:func:`mirrored`).
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
from typing import Dict, List, Optional, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike

from . import _checks
from ._body_frame import _frames, _heading, _turn
from ._resample import resample_forward
from ._skeleton import _anchor32, _carry_ends, _mean_of, _median, _place, _rest, _shown_ancestor, _tree
from .exceptions import MirroredPosesWarning
from .layouts import FIXED_IDS, MODEL_IDS, Layout

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


# ---------------------------------------------------------------------------------------------- scene
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


def _canonical(x: np.ndarray, layout: Layout, up: np.ndarray, arg: str) -> Tuple[np.ndarray, ...]:
    """(B, T, J, 3) caller poses -> (root, rot, the poses along their root frame's axes, root subtracted)."""
    root, rot = _frames(x, layout, up, arg, BODY_FRAME_SIGMA)
    return root, rot, np.einsum("btjc,btck->btjk", x - root[:, :, None, :], rot)


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
    lengths = {}  # each model bone's caller length per frame, from the joint's nearest shown ancestor
    for j in MODEL_IDS:
        lengths[j] = np.full(src[j].shape[:-1], np.nan)
        for a in np.unique(ancestor[j]):
            use = ancestor[j] == a
            lengths[j][use] = np.linalg.norm(src[j][use] - src[a][use], axis=-1)
    model = _place(src, ancestor, lengths)
    if CARRY_ENDS:
        _carry_ends(model, shown)
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
    heading = _heading(rot[..., :, 0], up)
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
