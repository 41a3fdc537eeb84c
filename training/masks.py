"""Imperfect-observation masks and input corruption (TCD reference, section 4).

A window has ``seq_len`` frames: the first ``obs_len`` are observed, the rest are to be predicted.
A mask is a ``(seq_len, J)`` float32 array of 0/1 per model joint: 1 = observed and visible,
0 = missing (to be generated). Every pattern only hides parts of the observation; all future rows
are 0.

Patterns are defined on joint ids of the 32-joint Human3.6M skeleton, as in the paper's code, and
mapped onto the model's joints through ``joints32``: model joint ``j`` is the 32-skeleton joint
``joints32[j]``. A 32-skeleton joint that is not in the layout has no effect (for the 22-joint layout
that is the case of the hips 1 and 6).

Patterns (``rate`` is a fraction in [0, 1], not a percentage):

* ``none``: every observed frame fully visible.
* ``random_leg_arm`` (paper "Random Leg, Arm Occlusions", default 0.4):
  ``floor(rate * obs_len)`` observed frames drawn without replacement; in them the 32-joints
  {1, 2, 3, 17, 18, 19} (right hip/knee/ankle, left shoulder/elbow/wrist) are hidden.
* ``structured_leg`` ("Structured Joint Occlusions", default 0.2): one block of
  ``round(rate * obs_len)`` consecutive frames (10 for obs_len 50), start uniform over all valid
  positions, in which the right-leg 32-joints {1, 2, 3} are hidden.
* ``consecutive_frames`` ("Missing Frames: 20% of the consecutive frames", default 0.2): one block
  of ``round(rate * obs_len)`` consecutive observed frames, all joints hidden, start uniform over
  all valid positions. (The official code hides 5 frames, i.e. 10%; this is the paper's 20%.)
* ``random_frames`` (default 0.2): ``floor(rate * obs_len)`` frames drawn without replacement,
  all joints hidden.
* ``noisy_25`` / ``noisy_50`` ("Gaussian noise", sigma 25 / 50 mm): in each observed frame 3 joints
  drawn without replacement from the leg 32-joints {1, 2, 3, 6, 7, 8} are hidden; :func:`corrupt`
  also adds N(0, sigma^2) noise to every visible observed coordinate. No rate.
  (The official code crashes in this mode; this is the intended behaviour.)
* ``random_joints`` (default 0.2): every (observed frame, model joint) hidden independently with
  probability ``rate``. ``rate`` may also be a ``(low, high)`` pair: the rate is then drawn
  uniformly in [low, high] once per window.
* ``random``: p ~ U(0, 1) drawn once per window, then every (observed frame, model joint) hidden
  independently with probability p. No rate.

Rounding: ``floor`` and ``round`` (half up) are applied to ``rate * obs_len`` with a 1e-9
tolerance, so that e.g. 0.29 * 100 gives 29 frames and not 28.

All randomness comes from the ``numpy.random.Generator`` passed in: the same generator state gives
the same mask (and noise).
"""

from __future__ import annotations

import math
import numbers

import numpy as np

__all__ = [
    "PATTERNS",
    "DEFAULT_RATES",
    "JOINTS32_H36M_22",
    "make_mask",
    "corrupt",
    "coord_mask",
    "mix_entry",
]

PATTERNS: tuple[str, ...] = (
    "none",
    "random_leg_arm",
    "structured_leg",
    "consecutive_frames",
    "random_frames",
    "noisy_25",
    "noisy_50",
    "random_joints",
    "random",
)

# Default rate of the patterns that take one. Patterns absent from this dict (none, noisy_25,
# noisy_50, random) take no rate.
DEFAULT_RATES: dict[str, float] = {
    "random_leg_arm": 0.4,
    "structured_leg": 0.2,
    "consecutive_frames": 0.2,
    "random_frames": 0.2,
    "random_joints": 0.2,
}

# 32-skeleton joint ids of the 22 joints the Human3.6M model uses, in model order
# (``joints_used_22`` of shared/data/h36m/skeleton32.json).
JOINTS32_H36M_22: tuple[int, ...] = (
    2,
    3,
    4,
    5,
    7,
    8,
    9,
    10,
    12,
    13,
    14,
    15,
    17,
    18,
    19,
    21,
    22,
    25,
    26,
    27,
    29,
    30,
)

N_JOINTS32 = 32

# 32-skeleton joint groups used by the patterns.
LEG_ARM_JOINTS32: tuple[int, ...] = (1, 2, 3, 17, 18, 19)  # right hip/knee/ankle, left shoulder/elbow/wrist
RIGHT_LEG_JOINTS32: tuple[int, ...] = (1, 2, 3)  # right hip, knee, ankle
LEGS_JOINTS32: tuple[int, ...] = (1, 2, 3, 6, 7, 8)  # both legs: hip, knee, ankle
NOISY_HIDDEN_PER_FRAME = 3
NOISE_SIGMA_MM: dict[str, float] = {"noisy_25": 25.0, "noisy_50": 50.0}

_NO_RATE = frozenset({"none", "noisy_25", "noisy_50", "random"})
_EPS = 1e-9


# ----------------------------------------------------------------------------------------------
# validation helpers


def _check_pattern(pattern) -> str:
    if not isinstance(pattern, str) or pattern not in PATTERNS:
        raise ValueError(f"pattern must be one of {', '.join(PATTERNS)}; got {pattern!r}")
    return pattern


def _check_int(name: str, value, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be an integer; got {value!r}")
    value = int(value)
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}; got {value}")
    return value


def _check_fraction(value, what: str = "rate") -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{what} must be a number in [0, 1]; got {value!r}")
    value = float(value)
    if not 0.0 <= value <= 1.0:  # also rejects NaN
        raise ValueError(f"{what} must be in [0, 1]; got {value!r}")
    return value


def _resolve_rate(pattern: str, rate):
    """Returns the pattern's rate: a float, a (low, high) pair (random_joints only), or None."""
    if pattern in _NO_RATE:
        if rate is not None:
            raise ValueError(f"rate is not used by pattern {pattern!r}; pass rate=None")
        return None
    if rate is None:
        return DEFAULT_RATES[pattern]
    if isinstance(rate, (tuple, list)):
        if pattern != "random_joints":
            raise ValueError(
                f"rate must be a single number for pattern {pattern!r}; "
                f"a (low, high) pair is only accepted by 'random_joints'; got {rate!r}"
            )
        if len(rate) != 2:
            raise ValueError(f"rate as a range must be a (low, high) pair; got {rate!r}")
        low = _check_fraction(rate[0], "rate (low)")
        high = _check_fraction(rate[1], "rate (high)")
        if low > high:
            raise ValueError(f"rate range must have low <= high; got {rate!r}")
        return (low, high)
    return _check_fraction(rate)


def _check_joints32(joints32) -> np.ndarray:
    try:
        arr = np.asarray(joints32)
    except Exception as exc:  # pragma: no cover - exotic inputs
        raise ValueError(f"joints32 must be a sequence of 32-skeleton joint ids; got {joints32!r}") from exc
    if arr.ndim != 1 or arr.size == 0 or not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"joints32 must be a non-empty 1-D sequence of integer joint ids; got {joints32!r}")
    if arr.min() < 0 or arr.max() >= N_JOINTS32:
        raise ValueError(f"joints32 ids must be in [0, {N_JOINTS32 - 1}]; got {joints32!r}")
    return arr.astype(np.int64)


def _check_lengths(obs_len, seq_len) -> tuple[int, int]:
    obs_len = _check_int("obs_len", obs_len, 0)
    seq_len = _check_int("seq_len", seq_len, 1)
    if obs_len > seq_len:
        raise ValueError(f"obs_len ({obs_len}) must be <= seq_len ({seq_len})")
    return obs_len, seq_len


def _check_rng(rng) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator; got {type(rng).__name__}")
    return rng


def _floor_count(rate: float, n: int) -> int:
    return min(n, int(math.floor(rate * n + _EPS)))


def _round_count(rate: float, n: int) -> int:
    return min(n, int(math.floor(rate * n + 0.5 + _EPS)))


def _model_columns(joints32: np.ndarray, group32) -> np.ndarray:
    """Model-joint indices whose 32-skeleton id is in ``group32``."""
    return np.flatnonzero(np.isin(joints32, np.asarray(group32)))


def _block_start(rng: np.random.Generator, obs_len: int, length: int, pattern: str) -> int:
    # Cannot trigger while rate <= 1 (the length follows the rate); kept as a guard.
    if length > obs_len:  # pragma: no cover
        raise ValueError(f"obs_len ({obs_len}) is shorter than the block length ({length}) of pattern {pattern!r}")
    return int(rng.integers(0, obs_len - length + 1))


# ----------------------------------------------------------------------------------------------
# public API


def make_mask(
    pattern: str,
    obs_len: int,
    seq_len: int,
    rng: np.random.Generator,
    *,
    rate: float | tuple[float, float] | None = None,
    joints32=JOINTS32_H36M_22,
) -> np.ndarray:
    """Draws a joint-level mask for one window.

    Returns a float32 array (seq_len, J), J = len(joints32): 1 = observed and visible, 0 = missing.
    Rows >= obs_len are always 0. ``rate`` defaults to ``DEFAULT_RATES[pattern]``; it must be None
    for the patterns that take no rate (none, noisy_25, noisy_50, random).
    """
    pattern = _check_pattern(pattern)
    obs_len, seq_len = _check_lengths(obs_len, seq_len)
    rng = _check_rng(rng)
    j32 = _check_joints32(joints32)
    rate = _resolve_rate(pattern, rate)
    n_joints = j32.size

    mask = np.zeros((seq_len, n_joints), dtype=np.float32)
    obs = mask[:obs_len]  # view: writing into it writes into mask
    obs[...] = 1.0

    if pattern == "none":
        pass
    elif pattern == "random_leg_arm":
        frames = rng.choice(obs_len, size=_floor_count(rate, obs_len), replace=False)
        cols = _model_columns(j32, LEG_ARM_JOINTS32)
        obs[np.ix_(frames, cols)] = 0.0
    elif pattern == "structured_leg":
        length = _round_count(rate, obs_len)
        start = _block_start(rng, obs_len, length, pattern)
        cols = _model_columns(j32, RIGHT_LEG_JOINTS32)
        obs[start : start + length, cols] = 0.0
    elif pattern == "consecutive_frames":
        length = _round_count(rate, obs_len)
        start = _block_start(rng, obs_len, length, pattern)
        obs[start : start + length, :] = 0.0
    elif pattern == "random_frames":
        frames = rng.choice(obs_len, size=_floor_count(rate, obs_len), replace=False)
        obs[frames, :] = 0.0
    elif pattern in NOISE_SIGMA_MM:
        legs = np.asarray(LEGS_JOINTS32)
        # A uniformly random 3-subset of the 6 leg joints per frame (argsort of i.i.d. uniforms is
        # a uniform random permutation).
        picks = np.argsort(rng.random((obs_len, legs.size)), axis=1)[:, :NOISY_HIDDEN_PER_FRAME]
        hidden32 = np.zeros((obs_len, N_JOINTS32), dtype=bool)
        np.put_along_axis(hidden32, legs[picks], True, axis=1)
        obs[hidden32[:, j32]] = 0.0
    elif pattern == "random_joints":
        p = rng.uniform(rate[0], rate[1]) if isinstance(rate, tuple) else rate
        obs[rng.random((obs_len, n_joints)) < p] = 0.0
    elif pattern == "random":
        p = rng.random()
        obs[rng.random((obs_len, n_joints)) < p] = 0.0
    else:  # pragma: no cover - PATTERNS and the branches above are kept in sync
        raise AssertionError(pattern)
    return mask


def corrupt(
    window: np.ndarray,
    pattern: str,
    obs_len: int,
    rng: np.random.Generator,
    *,
    rate: float | tuple[float, float] | None = None,
    joints32=JOINTS32_H36M_22,
    units_per_mm: float = 1e-3,
) -> tuple[np.ndarray, np.ndarray]:
    """Applies an imperfect-observation pattern to a clean window.

    window: (seq_len, J, 3) clean positions (metres by default; ``units_per_mm`` converts the noise
    sigma of the noisy_* patterns, given in mm, to the window's units).
    Returns ``(observed, mask)``: ``observed`` is a new array of the window's float dtype (float32
    for non-float input) holding the window plus, for noisy_*, N(0, sigma^2) noise on the visible
    observed coordinates, with every entry whose mask is 0 (hidden joints and all future frames) set
    to 0; ``mask`` is the (seq_len, J) float32 mask of :func:`make_mask`. The mask is drawn first,
    then the noise, both from ``rng``. ``window`` is never modified.
    """
    pattern = _check_pattern(pattern)
    j32 = _check_joints32(joints32)
    arr = np.asarray(window)
    if arr.ndim != 3 or arr.shape[1] != j32.size or arr.shape[2] != 3 or arr.shape[0] < 1:
        raise ValueError(f"window must have shape (seq_len, {j32.size}, 3) to match joints32; got {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"window must hold real numbers; got dtype {arr.dtype}")
    if (
        isinstance(units_per_mm, bool)
        or not isinstance(units_per_mm, numbers.Real)
        or not (math.isfinite(units_per_mm) and units_per_mm > 0)
    ):
        raise ValueError(f"units_per_mm must be a finite positive number; got {units_per_mm!r}")

    seq_len = arr.shape[0]
    mask = make_mask(pattern, obs_len, seq_len, rng, rate=rate, joints32=j32)
    obs_len = int(obs_len)

    dtype = arr.dtype if np.issubdtype(arr.dtype, np.floating) else np.dtype(np.float32)
    observed = np.array(arr, dtype=dtype, copy=True)
    if pattern in NOISE_SIGMA_MM:
        sigma = NOISE_SIGMA_MM[pattern] * float(units_per_mm)
        noise = rng.normal(0.0, sigma, size=observed[:obs_len].shape)
        observed[:obs_len] += noise.astype(dtype, copy=False)
    observed[mask == 0] = 0.0  # assignment, not multiplication: NaN/inf in hidden entries become 0 too
    return observed, mask


def mix_entry(entry) -> tuple[str, float, object]:
    """One entry of a training config's ``mask_mix``, ``[pattern, weight]`` or ``[pattern, weight, rate]``,
    checked -> (pattern, weight, resolved rate: a float, a (low, high) pair, or None). The one parser of
    the entries (``training.batches.make_batch``)."""
    if not isinstance(entry, (list, tuple)) or len(entry) not in (2, 3):
        raise ValueError(f"mask_mix entry {entry!r}: expected [pattern, weight] or [pattern, weight, rate]")
    rate = None if len(entry) == 2 else (tuple(entry[2]) if isinstance(entry[2], (list, tuple)) else entry[2])
    try:
        pattern = _check_pattern(entry[0])
        rate = _resolve_rate(pattern, rate)
    except ValueError as exc:
        raise ValueError(f"mask_mix entry {entry!r}: {exc}") from None
    weight = entry[1]
    if isinstance(weight, bool) or not isinstance(weight, (int, float)) or not weight >= 0:
        raise ValueError(f"mask_mix entry {entry!r}: the weight must be a number >= 0")
    return pattern, float(weight), rate


def coord_mask(joint_mask) -> np.ndarray:
    """(..., J) joint mask -> (..., J*3) coordinate mask, each joint repeated for x, y, z."""
    arr = np.asarray(joint_mask)
    if arr.ndim < 1:
        raise ValueError(f"joint_mask must have at least 1 dimension (..., J); got shape {arr.shape}")
    return np.repeat(arr, 3, axis=-1)
