"""The one check of a pose array and its mask, used by the API (:meth:`tcd.TCD.forecast`,
:meth:`tcd.TCD.repair`) and by dataset repair (``tcd repair``) alike.

What it checks is what only Python can see: that the input converts to numbers, its rank and layout
(J joints × 3 coordinates), infinities, the mask's values and its two accepted shapes, NaN where the
mask says observed, and that every sequence has something observed. Units, the engine's layout and the
engine's own checks (sizes against the model, sampler settings) are the callers'.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Dict, Literal, Optional, Tuple, cast

import numpy as np
from numpy.typing import ArrayLike

from . import _checks
from .exceptions import InvalidInputError

__all__ = [
    "PLAUSIBLE_SPREAD_M",
    "Poses",
    "UNIT_SCALE",
    "Units",
    "check_units",
    "check_window",
    "spread_m",
    "validate_poses",
]

#: The units a pose array may be in (the ``units`` argument of every call that takes poses).
Units = Literal["m", "cm", "mm"]

#: Each of :data:`Units` with what divides it into metres (the models' unit).
UNIT_SCALE: Dict[str, float] = {"m": 1.0, "cm": 100.0, "mm": 1000.0}


def check_units(value: Any) -> Units:
    """``value`` if it names one of :data:`UNIT_SCALE`'s units, else an InvalidInputError naming ``units``."""
    return cast(Units, _checks.choice("units", value, tuple(UNIT_SCALE)))


@dataclass(frozen=True)
class Poses:
    """A checked pose input, always with a batch axis."""

    values: np.ndarray  # (B, T, J, 3) the caller's values in a float dtype (float64 for integer input)
    observed: np.ndarray  # (B, T, J, 3) bool, True = observed (the mask, or ~isnan(values) without one)
    batched: bool  # whether the caller gave the batch axis

    @property
    def dtype(self) -> np.dtype:
        return self.values.dtype


#: The plausible size of a person, in metres: the median distance of the observed joints from their frame's
#: centroid. A person measures about 0.15-0.5 m on this statistic; outside [0.01, 3] m the values are not
#: in the declared units (or are not poses). It is translation-invariant, so world coordinates pass too.
PLAUSIBLE_SPREAD_M = (0.01, 3.0)


def spread_m(values: np.ndarray, observed: np.ndarray, units: str) -> Optional[float]:
    """The median distance (metres) of the observed joints from their frame's centroid, over the frames with
    at least two fully observed joints; None when no frame has two (nothing to measure)."""
    joint_seen = observed.all(axis=-1)  # (B, T, J)
    frames = joint_seen.sum(axis=-1) >= 2  # (B, T)
    if not frames.any():
        return None
    v = np.where(joint_seen[..., None], values, 0.0)[frames].astype(np.float64)  # (N, J, 3)
    seen = joint_seen[frames]
    centroid = v.sum(axis=1, keepdims=True) / seen.sum(axis=1)[:, None, None]
    dist = np.linalg.norm(v - centroid, axis=-1)[seen]
    return float(np.median(dist)) / UNIT_SCALE[units]


def _check_plausible(values: np.ndarray, observed: np.ndarray, units: str, name: str, owner: str) -> None:
    spread = spread_m(values, observed, units)
    low, high = PLAUSIBLE_SPREAD_M
    if spread is None or spread == 0.0 or low <= spread <= high:  # 0: every joint at one point, no scale
        return
    # the unit in which the person measures closest to a typical 0.3 m
    fits = {u: spread * UNIT_SCALE[units] / UNIT_SCALE[u] for u in UNIT_SCALE}
    fits = {u: v for u, v in fits.items() if low <= v <= high}
    likely = min(fits, key=lambda u: abs(math.log(fits[u] / 0.3))) if fits else None
    words = {"m": "metres", "cm": "centimetres", "mm": "millimetres"}
    hint = (
        f"the values look like {words[likely]}: pass units={likely!r}"
        if likely
        else "no supported unit fits: are these poses?"
    )
    subject = (
        f"Argument `units` must be the unit of `{name}` ({units!r}), but"
        if owner == "Argument"
        else f"{owner} `{name}` is not in the declared units ({units!r}):"
    )
    raise InvalidInputError(
        f"{subject} its observed joints lie a median {spread:.4g} m from their frame's centroid (a person "
        f"measures about 0.15-0.5 m; accepted {low}-{high} m): {hint}.",
        "units",
    )


def _fail(names: Tuple[str, str], which: int, expected: str, received: str, owner: str) -> InvalidInputError:
    e = _checks.fail(names[which], expected, received)
    if owner == "Argument":
        return e
    return InvalidInputError(str(e).replace("Argument ", f"{owner} ", 1), names[which])


def validate_poses(
    obs: ArrayLike,
    mask: Optional[ArrayLike] = None,
    *,
    num_joints: Optional[int],
    batched_ok: bool = True,
    names: Tuple[str, str] = ("obs", "mask"),
    owner: str = "Argument",
    units: Optional[str] = None,
) -> Poses:
    """Checks poses (T, J, 3) (or (B, T, J, 3) when ``batched_ok``) with NaN = missing, and an optional
    ``mask`` of the same shape or without the last axis (1 = observed).

    ``num_joints``: the exact J required (None: any J >= 1); any T >= 1 (the callers apply their own length
    rule to the checked poses). ``names``: what the two arrays are called in the messages (and
    :attr:`InvalidInputError.argument`); ``owner`` how a message introduces them ("Argument" for function
    arguments, e.g. "The file's" for arrays read from a file). ``units``: when
    given, the values must be plausible poses in that unit (:data:`PLAUSIBLE_SPREAD_M`), else an
    InvalidInputError naming ``units`` and the unit that fits.
    Raises :class:`tcd.exceptions.InvalidInputError` naming the array at fault."""

    def fail(which: int, expected: str, received: str) -> InvalidInputError:
        return _fail(names, which, expected, received, owner)

    layouts = "(T, J, 3) or (B, T, J, 3)" if batched_ok else "(T, J, 3)"
    try:
        a = np.asarray(obs)
    except (ValueError, TypeError) as e:
        raise fail(0, f"an array of shape {layouts}", f"an object numpy cannot convert ({e})") from None
    if a.dtype.kind not in "iuf":  # booleans are not coordinates
        raise fail(0, f"a float array of shape {layouts}", f"an array of dtype {a.dtype}")
    t_rule = "T >= 1 frames"
    j_rule = f"J = {num_joints} joints" if num_joints is not None else "J >= 1 joints"
    want = f"{layouts} with {t_rule} and {j_rule}"
    shape = _checks.shape_str(a.shape)
    if a.ndim not in ((3, 4) if batched_ok else (3,)):
        raise fail(0, f"an array of shape {want}", f"an array of shape {shape} ({a.ndim} dimensions)")
    batched = a.ndim == 4
    a4 = a if batched else a[None]
    b, t, j, c = a4.shape
    if c != 3:
        raise fail(
            0, f"an array of shape {want} (3 coordinates per joint)", f"shape {shape} with {c} coordinates per joint"
        )
    if j != num_joints and num_joints is not None:
        raise fail(0, f"an array of shape {want} (the model's joint layout)", f"shape {shape} with {j} joints")
    if j < 1:
        raise fail(0, f"an array of shape {want}", f"shape {shape} with no joints")
    if t < 1:
        raise fail(0, f"an array of shape {want}", f"shape {shape} with no frames")
    if b < 1:
        raise fail(0, f"an array of shape {want} with at least one sequence", f"shape {shape}")
    dtype = np.result_type(a.dtype, np.float32) if a.dtype.kind == "f" else np.dtype(np.float64)
    a4 = a4.astype(dtype, copy=False)
    nan = np.isnan(a4)
    inf = np.isinf(a4)
    if inf.any():
        raise fail(
            0,
            "finite, with NaN marking missing values",
            f"{a4[inf][0]} at index {_index(np.argwhere(inf)[0], batched)}",
        )

    if mask is None:
        full = ~nan
    else:
        try:
            m = np.asarray(mask)
        except (ValueError, TypeError) as e:
            raise fail(1, "an array of 0/1", f"an object numpy cannot convert ({e})") from None
        if m.dtype.kind not in "biuf":
            raise fail(1, "an array of 0 (missing) and 1 (observed)", f"an array of dtype {m.dtype}")
        if m.shape not in (a.shape, a.shape[:-1]):
            raise fail(
                1,
                f"an array of shape {shape} or {_checks.shape_str(a.shape[:-1])} (the shape of "
                f"`{names[0]}`, optionally without its last axis)",
                f"shape {_checks.shape_str(m.shape)}",
            )
        bad = ~((m == 0) | (m == 1))
        if bad.any():
            raise fail(
                1,
                "0 (missing) or 1 (observed) everywhere",
                f"{m[bad][0]!r} at index {tuple(int(i) for i in np.argwhere(bad)[0])}",
            )
        m = m.astype(bool)
        if m.shape == a.shape[:-1]:
            m = np.repeat(m[..., None], 3, axis=-1)
        full = m if batched else m[None]
        clash = full & nan
        if clash.any():
            raise fail(
                0,
                f"a number wherever `{names[1]}` is 1 (observed)",
                f"NaN at index {_index(np.argwhere(clash)[0], batched)}, where {names[1]} is 1",
            )
    empty = ~full.reshape(b, -1).any(axis=1)
    if empty.any():
        which = f"sequence {int(np.argmax(empty))} of `{names[0]}`" if batched else f"`{names[0]}`"
        raise fail(
            0 if mask is None else 1,
            "an observation with at least one observed value per sequence",
            f"{which} in which every value is missing",
        )
    if units is not None:
        _check_plausible(a4, full, units, names[0], owner)
    return Poses(values=a4, observed=full, batched=batched)


def check_window(seen: np.ndarray, window: int, batched: bool) -> None:
    """The length rule's one requirement on content (:mod:`tcd._model`): ``seen`` (B, ...) bool, the observed
    entries of the model's window of each sequence, has one per sequence, else an InvalidInputError naming
    ``obs`` (a longer observation whose last ``window`` frames are all missing)."""
    empty = ~seen.reshape(seen.shape[0], -1).any(axis=1)
    if empty.any():
        which = f"sequence {int(np.argmax(empty))} of `obs`" if batched else "`obs`"
        raise _checks.fail(
            "obs",
            f"an observation with at least one observed value per sequence in the model's "
            f"window (its last {window} frames, at the model's frame rate)",
            f"{which} with every value missing there",
        )


def _index(idx: np.ndarray, batched: bool) -> Tuple[int, ...]:
    """An index into the caller's array (without the batch axis the caller did not give)."""
    i = tuple(int(v) for v in idx)
    return i if batched else i[1:]


class Window:
    """A validated pose input in the model's layout and the model's window of it, in the engine's layout; the
    model's outputs converted back (the interface :class:`tcd._wild_calls.WildWindow` shares)."""

    def __init__(
        self,
        observed: np.ndarray,
        mask: np.ndarray,
        original: np.ndarray,
        full_mask: np.ndarray,
        batched: bool,
        scale: float,
        dtype: np.dtype,
        start: int,
    ) -> None:
        self.observed = observed  # (B, K, W) float32, model units, 0 where missing: the window
        self.mask = mask  # (B, K, W) float32 0/1
        self.original = original  # (B, T, J, 3) the caller's values
        self.full_mask = full_mask  # (B, T, J, 3) bool
        self.batched = batched
        self.scale = scale
        self.dtype = dtype
        self.start = start  # the caller's frame at the window's first frame (< 0: padded)
        self.times: Optional[np.ndarray] = None  # seconds of each forecast frame (set where the model has a rate)

    def poses(self, bkl: np.ndarray) -> np.ndarray:
        """(..., B, K, L) float32 model units -> (..., B?, L, J, 3) in the caller's units and dtype."""
        *lead, b, k, length = bkl.shape
        j = k // 3
        out = np.swapaxes(bkl, -1, -2).reshape(*lead, b, length, j, 3).astype(self.dtype)
        if self.scale != 1.0:
            out = out * self.dtype.type(self.scale)
        return out if self.batched else out[..., 0, :, :, :]

    def repaired(self, bkt: np.ndarray) -> np.ndarray:
        """The window's repair (B, K, W) -> the caller's observation filled (its shape, units and dtype)."""
        out = self.poses(bkt)
        original = self.original if self.batched else self.original[0]
        full_mask = self.full_mask if self.batched else self.full_mask[0]
        if self.start < 0:  # the padded frames dropped
            out = out[..., -self.start :, :, :]
        elif self.start > 0:  # the frames before the window as given
            out = np.concatenate([original[..., : self.start, :, :].astype(self.dtype, copy=False), out], axis=-3)
        # Observed entries bit for bit as given (also when units or dtype needed a conversion).
        return np.where(full_mask, original.astype(self.dtype, copy=False), out)

    def forecast(self, out: Dict[str, Any]) -> Tuple[Any, ...]:
        """(mean, samples, repaired, times) from the model's ``out`` (``mean`` (B, K, H), ``samples``
        (S, B, K, H) or None, ``repaired`` (B, K, W)), in the caller's units, dtype and batch axis."""
        samples = None if out["samples"] is None else self.poses(out["samples"])
        return self.poses(out["mean"]), samples, self.repaired(out["repaired"]), self.times


def model_window(
    obs: ArrayLike, mask: Optional[ArrayLike], num_joints: int, window: int, units: Units, *, repair: bool = False
) -> Window:
    """Checks ``obs`` / ``mask`` (see :meth:`TCD.forecast`) and converts the model's window of them (the
    module docstring's length rule: its last ``window`` frames, padded at the start with missing frames when
    shorter) to (B, K, window) float32. ``repair``: more than ``window`` frames is an error."""
    p = validate_poses(obs, mask, num_joints=num_joints, units=units)
    a4, full, dtype = p.values, p.observed, p.dtype
    b, t = a4.shape[:2]
    if repair and t > window:
        raise InvalidInputError(
            f"Argument `obs` must span at most the model's window ({window} frames) to be repaired in one call, "
            f"but received {t} frames: repair longer sequences with tcd.repair_file (overlapping windows).",
            "obs",
        )
    start = t - window
    if start < 0:
        pad = (b, -start) + a4.shape[2:]
        a4w = np.concatenate([np.zeros(pad, a4.dtype), a4], axis=1)
        full_w = np.concatenate([np.zeros(pad, bool), full], axis=1)
    else:
        a4w, full_w = a4[:, start:], full[:, start:]
    check_window(full_w, window, p.batched)
    scale = UNIT_SCALE[units]
    x = np.where(full_w, a4w, 0.0)
    if scale != 1.0:
        x = x / scale
    k = num_joints * 3
    observed = np.ascontiguousarray(x.astype(np.float32).reshape(b, window, k).transpose(0, 2, 1))
    mask_bkt = np.ascontiguousarray(full_w.astype(np.float32).reshape(b, window, k).transpose(0, 2, 1))
    return Window(observed, mask_bkt, a4, full, p.batched, scale, dtype, start)
