""":meth:`tcd.TCD.forecast`, :meth:`~tcd.TCD.predict` and :meth:`~tcd.TCD.repair` on poses from the wild
(``capture=tcd.Capture(layout, fps, up)``: another skeleton, world coordinates, another frame rate): the checks,
the conversions of :mod:`tcd.wild` around the engine, and the frame-rate interpolation of the outputs.

A model trained in another layout than Human3.6M's names it in its data block (``data.layout``, with
``data.root_joint`` and ``data.up``: the HumanEva-I model, ``"humaneva15"``, root ``"pelvis"``, +z up). It
takes poses of that layout only, converted without :mod:`tcd.wild`'s retargeting (the model's skeleton is
the caller's): the observation is rotated so that ``up`` is the model's up axis (the model keeps the global
rotation, as its protocol does: the poses are not turned to a heading), resampled to the model's frame rate,
and made relative to the root joint of each frame (a frame without it: the root interpolated in time from
the frames that have it; one is needed). The forecast's root continues the velocity of the last 0.2 s,
decaying with ``tcd.wild.ROOT_DAMPING_S``, and everything comes back in the caller's axes, units and rate.

Length, either way: the length rule of :mod:`tcd._model` counted in model frames (``wild.resample_to_model``:
the last ``obs_len`` of them, a shorter observation padded at the start with missing frames), and at least
2 observed frames per sequence (the root's motion is measured on them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Dict, Optional, Tuple, cast

import numpy as np
from numpy.typing import ArrayLike

from . import _checks, wild
from ._poses import UNIT_SCALE, Units, check_window, validate_poses
from .exceptions import InvalidInputError
from .layouts import get_layout
from .wild import Up

if TYPE_CHECKING:
    from ._model import TCD

__all__ = ["Capture", "WildWindow", "own_layout"]


@dataclass(frozen=True)
class Capture:
    """How poses from the wild were captured, for a call's ``capture`` argument (:mod:`tcd.wild`): without one,
    poses are in the model's own layout, joint order and frame rate, root-relative.

    * ``layout``: one of :data:`tcd.layouts.LAYOUTS` (``"h36m32"``, ``"h36m17"``, ``"smpl24"``, ``"coco17"``,
      ``"h36m22"``, ...; the poses' J its joints), in world or camera coordinates; a model trained in its own
      layout (``data.layout``: the HumanEva-I model's ``"humaneva15"``) takes that one only;
    * ``fps``: the poses' frame rate (``None``: the model's);
    * ``up``: the vertical axis, ``"y"`` (default), ``"z"``, ``"-y"``, ... or a unit 3-vector.

    The observation may have any length (the length rule of :mod:`tcd._model` counted at the model's frame rate,
    and at least 2 observed frames, to measure the root's motion); the outputs come back in the same layout,
    coordinates and frame rate (``Forecast.times``)."""

    layout: str
    fps: Optional[float] = None
    up: Up = "y"

    def __post_init__(self) -> None:
        object.__setattr__(self, "layout", get_layout(self.layout).name)
        if self.fps is not None:
            object.__setattr__(self, "fps", _checks.frame_rate(self.fps))
        v = wild.up_vector(self.up)  # checks it
        if not isinstance(self.up, str):  # a vector: kept as a tuple, so that the capture stays hashable
            object.__setattr__(self, "up", tuple(float(c) for c in v))


def _model_fps(model: Any, fps: Optional[float]) -> float:
    """The capture's frame rate (None: the model's); the model must record its own, to resample to it."""
    if model.fps is None:
        raise _checks.fail(
            "fps", "None: the model does not record its frame rate, so poses cannot be resampled", repr(fps)
        )
    return float(model.fps) if fps is None else fps


def _poses_with_motion(obs: Any, mask: Any, num_joints: int, units: str) -> Any:
    """The call's poses checked (:func:`tcd._poses.validate_poses`), with at least 2 observed frames per sequence:
    the root's motion is measured on them."""
    p = validate_poses(obs, mask, num_joints=num_joints, units=units)
    seen_frames = p.observed.reshape(p.observed.shape[0], p.observed.shape[1], -1).any(-1).sum(-1)
    if (seen_frames < 2).any():
        raise _checks.fail(
            "obs",
            "an observation with at least 2 observed frames per sequence (to measure motion)",
            f"{int(seen_frames.min())} observed frame(s)",
        )
    return p


def _prepare(model: Any, obs: Any, mask: Any, capture: Capture, units: str, frames: int):
    """Checks the call's poses; returns what the engine needs and how to come back."""
    lay = get_layout(capture.layout)
    src_fps = _model_fps(model, capture.fps)
    up_v = wild.up_vector(capture.up)
    p = _poses_with_motion(obs, mask, lay.num_joints, units)
    joint_seen = p.observed.all(-1, keepdims=True)  # a joint is observed when all 3 coordinates are
    x = np.where(joint_seen, p.values, np.nan).astype(np.float64) / UNIT_SCALE[units]
    xm, times = wild.resample_to_model(x, src_fps, float(model.fps), frames)
    y, scene = wild.to_model(xm, lay, up_v, sightings=x)
    b, t = y.shape[:2]
    seen = np.isfinite(y).all(-1, keepdims=True)
    check_window(seen, frames, p.batched)
    flat = lambda a: np.ascontiguousarray(a.reshape(b, t, -1).transpose(0, 2, 1), dtype=np.float32)  # noqa: E731
    return p, src_fps, scene, times, flat(np.where(seen, y, 0.0)), flat(np.broadcast_to(seen, y.shape))


def _model_poses(bkl: np.ndarray) -> np.ndarray:
    """(..., B, K, L) engine output -> (..., B, L, 22, 3) float64."""
    *lead, b, k, length = bkl.shape
    return np.swapaxes(bkl, -1, -2).reshape(*lead, b, length, k // 3, 3).astype(np.float64)


def _at_times(values: np.ndarray, times: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Linear interpolation along the frame axis (-3) of (..., F, J, 3) values given at ``times`` onto ``at``."""
    idx = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 2)
    w = ((at - times[idx]) / (times[idx + 1] - times[idx]))[:, None, None]
    return values[..., idx, :, :] * (1 - w) + values[..., idx + 1, :, :] * w


def _repaired(p: Any, rep_w: np.ndarray, times: np.ndarray, scale: float) -> np.ndarray:
    """The caller's observation with its missing entries filled inside the model's window (world poses at
    model frames ``times``, in input frames), observed entries bit for bit, earlier frames as given."""
    t_in = p.values.shape[1]
    frames = np.arange(t_in, dtype=np.float64)
    inside = frames >= times[0] - 1e-9
    filled = p.values.astype(np.float64).copy()
    if inside.any():
        filled[:, inside] = _at_times(rep_w, times, frames[inside]) * scale
    out = np.where(p.observed, p.values, filled.astype(p.dtype))
    return out if p.batched else out[0]


def own_layout(model: Any) -> Optional[str]:
    """The layout a model was trained in when it is not Human3.6M's (``data.layout``: the HumanEva-I model's
    ``"humaneva15"``), else None (the conversions of :mod:`tcd.wild`)."""
    name = model.data.get("layout")
    return None if name in (None, "h36m22") else str(name)


def _rotation_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) that turns unit vector ``a`` onto unit vector ``b`` by the smallest angle."""
    v, c = np.cross(a, b), float(np.dot(a, b))
    if c > 1.0 - 1e-12:
        return np.eye(3)
    if c < -1.0 + 1e-12:  # opposite: half a turn about an axis normal to a
        axis = np.cross(a, np.eye(3)[int(np.argmin(np.abs(a)))])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def _own_prepare(model: Any, own: str, obs: Any, mask: Any, capture: Capture, units: str, frames: int):
    """:func:`_prepare` for a model in its own layout (see the module docstring)."""
    lay = get_layout(capture.layout)
    if lay.name != own:
        raise _checks.fail(
            "layout",
            f"'{own}' (the layout this model was trained in; its poses without a layout "
            f"are {own}'s joints but the root, relative to it)",
            repr(capture.layout),
        )
    src_fps = _model_fps(model, capture.fps)
    rot = _rotation_onto(wild.up_vector(capture.up), wild.up_vector(model.data.get("up", "y")))  # caller -> model axes
    root_j = lay.joint_names.index(model.data.get("root_joint", lay.joint_names[0]))
    p = _poses_with_motion(obs, mask, lay.num_joints, units)
    joint_seen = p.observed.all(-1, keepdims=True)
    x = np.where(joint_seen, p.values, np.nan).astype(np.float64) / UNIT_SCALE[units] @ rot.T
    xm, times = wild.resample_to_model(x, src_fps, float(model.fps), frames)  # (B, O, J, 3)
    b, t = xm.shape[:2]
    root = xm[:, :, root_j]
    have = np.isfinite(root).all(-1)
    if not have.any(-1).all():
        raise InvalidInputError(
            f"Argument `obs` never shows the {lay.joint_names[root_j]} (joint {root_j} of {own}) "
            "inside the model's window: the model's poses are relative to it.",
            "obs",
        )
    f = np.arange(t, dtype=np.float64)
    root = np.stack(
        [np.stack([np.interp(f, f[have[i]], root[i, have[i], c]) for c in range(3)], -1) for i in range(b)]
    )  # (B, O, 3), held at the ends
    others = [j for j in range(lay.num_joints) if j != root_j]
    y = xm[:, :, others] - root[:, :, None]
    seen = np.isfinite(y).all(-1, keepdims=True)
    check_window(seen, frames, p.batched)
    flat = lambda a: np.ascontiguousarray(a.reshape(b, t, -1).transpose(0, 2, 1), dtype=np.float32)  # noqa: E731

    def world(bkl: np.ndarray, roots: np.ndarray) -> np.ndarray:
        """(..., B, K, L) model output and roots (B, L, 3) -> (..., B, L, J, 3) in the caller's axes (metres)."""
        rel = _model_poses(bkl)
        out = np.zeros(rel.shape[:-2] + (lay.num_joints, 3))
        out[..., others, :] = rel
        return (out + roots[:, :, None, :]) @ rot

    return p, src_fps, times, root, world, flat(np.where(seen, y, 0.0)), flat(np.broadcast_to(seen, y.shape))


def _own_future_root(root: np.ndarray, count: int, fps: float) -> np.ndarray:
    """(B, count, 3): the root's velocity over the last 0.2 s (``tcd.wild``'s rule 5, no turn: the poses carry
    the rotation), decaying with ``wild.ROOT_DAMPING_S``."""
    k = min(max(1, int(round(wild.EXTRAPOLATION_FRAMES / 25.0 * fps))), root.shape[1] - 1)
    f = np.arange(1, count + 1, dtype=np.float64)
    tau = wild.ROOT_DAMPING_S
    if k < 1 or tau == 0:
        return np.repeat(root[:, -1:], count, 1)
    travel = f if tau is None else tau * fps * -np.expm1(-f / (tau * fps))
    velocity = (root[:, -1] - root[:, -1 - k]) / k
    return root[:, -1:] + velocity[:, None, :] * travel[None, :, None]


def _to_caller(
    p: Any, future_w: np.ndarray, last: np.ndarray, h: int, model_fps: float, src_fps: float, scale: float
) -> Tuple[np.ndarray, np.ndarray]:
    """Forecast frames (..., B, h, J, 3) at the model's rate, after the frame ``last`` at time 0
    (B, 1, J, 3), at the caller's rate, units and dtype (and batch axis); with the times of its frames."""
    model_t = np.arange(h + 1) / model_fps
    n = int(math.floor(h / model_fps * src_fps + 1e-9))
    at = np.arange(1, n + 1) / src_fps
    last = np.broadcast_to(last, future_w.shape[:-3] + (1,) + future_w.shape[-2:])
    y = (_at_times(np.concatenate([last, future_w], axis=-3), model_t, at) * scale).astype(p.dtype)
    return (y if p.batched else y[..., 0, :, :, :]), at


class WildWindow:
    """Poses from the wild converted into the model's window, and the model's outputs converted back: what
    :meth:`tcd.TCD.forecast`, :meth:`~tcd.TCD.predict` and :meth:`~tcd.TCD.repair` wrap around a model-layout call
    (convert in, call, convert out). ``observed`` and ``mask`` are the engine's (B, K, ``frames``) window; a model in
    its own layout (:func:`own_layout`) converts as the module docstring says."""

    def __init__(
        self,
        model: "TCD",
        obs: ArrayLike,
        mask: Optional[ArrayLike],
        *,
        capture: Capture,
        units: Units,
        frames: int,
    ) -> None:
        self.own = own_layout(model)
        self.units, self.horizon = units, model.horizon
        self.model_fps = float(cast(float, model.fps)) if model.fps is not None else None
        if self.own is not None:
            p, src_fps, times, root, world, observed, seen = _own_prepare(
                model, self.own, obs, mask, capture, units, frames
            )
            self.root, self.world = root, world
        else:
            p, src_fps, scene, times, observed, seen = _prepare(model, obs, mask, capture, units, frames)
            self.scene = scene
        self.p, self.src_fps, self.times = p, src_fps, times
        self.observed, self.mask = observed, seen

    def forecast(self, out: Dict[str, Any]) -> Tuple[Any, ...]:
        """(mean, samples, repaired, times) from the model's ``out`` (``mean`` (B, K, H), ``samples``
        (S, B, K, H) or None, ``repaired`` (B, K, T)): the forecast in the caller's layout, coordinates, units and
        frame rate, ``times`` the seconds of each forecast frame after the last observed one."""
        p, h, scale = self.p, self.horizon, UNIT_SCALE[self.units]
        model_fps, src_fps = cast(float, self.model_fps), self.src_fps  # not None: _prepare checked it
        if self.own is not None:
            root_f = _own_future_root(self.root, h, model_fps)
            rep_w = self.world(out["repaired"], self.root)
            mean, at = _to_caller(p, self.world(out["mean"], root_f), rep_w[:, -1:], h, model_fps, src_fps, scale)
            samples = (
                None
                if out["samples"] is None
                else _to_caller(p, self.world(out["samples"], root_f), rep_w[:, -1:], h, model_fps, src_fps, scale)[0]
            )
            return mean, samples, _repaired(p, rep_w, self.times, scale), at
        scene = self.scene
        root_f, rot_f = wild.future_frames(scene, h, model_fps, wild.ROOT_DAMPING_S)
        mean_w = wild.from_model(_model_poses(out["mean"]), scene, root_f, rot_f, own_frames=False)
        samples_w = (
            None
            if out["samples"] is None
            else wild.from_model(_model_poses(out["samples"]), scene, root_f, rot_f, own_frames=False)
        )
        rep_w = wild.from_model(_model_poses(out["repaired"]), scene, scene.root, scene.rot, own_frames=True)
        # time 0, where the caller frames before the first model frame are interpolated from: each joint where it
        # was last seen, in the caller's coordinates (Zero-Velocity's start; where the last frame hides a joint or
        # a hip, neither the model's repair nor a root estimated without the hips is as close), the repaired last
        # frame for a joint never seen
        start = np.where(np.isfinite(scene.start[:, None]), scene.start[:, None], rep_w[:, -1:])
        mean, at = _to_caller(p, mean_w, start, h, model_fps, src_fps, scale)
        samples = None if samples_w is None else _to_caller(p, samples_w, start, h, model_fps, src_fps, scale)[0]
        return mean, samples, _repaired(p, rep_w, self.times, scale), at

    def check_one_window(self, model: "TCD") -> None:
        """A repair takes at most the model's window (longer files: :func:`tcd.repair_file`)."""
        if self.times[0] > 1e-9:
            raise InvalidInputError(
                f"Argument `obs` must span at most the model's window ({model.obs_len} frames at {model.fps:g} fps) "
                f"to be repaired in one call, but received {self.p.values.shape[1]} frames at {self.src_fps:g} fps: "
                "repair longer sequences with tcd.repair_file (overlapping windows).",
                "obs",
            )

    def repaired(self, mean: np.ndarray) -> np.ndarray:
        """The observation with its missing entries filled from the model's repair ``mean`` (B, K, T), in the
        caller's layout, coordinates, units and frame rate."""
        scale = UNIT_SCALE[self.units]
        if self.own is not None:
            return _repaired(self.p, self.world(mean, self.root), self.times, scale)
        scene = self.scene
        rep_w = wild.from_model(_model_poses(mean), scene, scene.root, scene.rot, own_frames=True)
        return _repaired(self.p, rep_w, self.times, scale)
