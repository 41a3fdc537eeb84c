"""Argument checks shared by the public API: each failure is an InvalidInputError naming the argument,
what was expected and what was received."""

from __future__ import annotations

import math
import numbers
from typing import Any, List, Optional, Sequence, Tuple

import numpy as np

from . import _native
from .exceptions import InvalidInputError


def fail(argument: str, expected: str, received: str) -> InvalidInputError:
    return InvalidInputError(f"Argument `{argument}` must be {expected}, but received {received}.", argument)


def _is_int(value: Any) -> bool:
    return isinstance(value, (numbers.Integral, np.integer)) and not isinstance(value, (bool, np.bool_))


def integer(argument: str, value: Any, minimum: int, maximum: Optional[int] = None) -> int:
    """An int (not bool) in [minimum, maximum]."""
    rng = f"at least {minimum}" if maximum is None else f"in {minimum}..{maximum}"
    if not _is_int(value):
        raise fail(argument, f"an integer {rng}", f"{value!r} ({type(value).__name__})")
    v = int(value)
    if v < minimum or (maximum is not None and v > maximum):
        raise fail(argument, f"an integer {rng}", str(v))
    return v


def choice(argument: str, value: Any, options: Sequence[str]) -> str:
    if not isinstance(value, str) or value not in options:
        listed = ", ".join(repr(o) for o in options)
        raise fail(argument, f"one of {listed}", repr(value))
    return value


def text(argument: str, value: Any, names: Sequence[str]) -> str:
    """A str (its value is the engine's to check against ``names``, listed in the message)."""
    if not isinstance(value, str):
        listed = ", ".join(repr(o) for o in names)
        raise fail(argument, f"one of {listed}", f"{value!r} ({type(value).__name__})")
    return value


def machine_int(argument: str, value: Any, bits: int = 64) -> int:
    """An int (not bool) that fits the binding's signed ``bits``-bit parameter (64, or 128 for seeds and stream
    ids, whose range is 0..2**64 - 1): the conversion is Python's to check, the range the engine's (a value
    out of range there is an InvalidInputError naming the argument, not an OverflowError)."""
    if not _is_int(value) or not -(2 ** (bits - 1)) <= int(value) < 2 ** (bits - 1):
        raise fail(argument, "an integer", f"{value!r} ({type(value).__name__})")
    return int(value)


def optional_machine_int(argument: str, value: Any, bits: int = 64) -> Optional[int]:
    return None if value is None else machine_int(argument, value, bits)


def real(argument: str, value: Any) -> float:
    """A real number (not bool), as a float (its range is the engine's to check)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        raise fail(argument, "a number", f"{value!r} ({type(value).__name__})")
    return float(value)


def frame_rate(value: Any) -> float:
    """A positive, finite frame rate (frames per second), as a float; an InvalidInputError naming ``fps``."""
    if (
        isinstance(value, (bool, np.bool_))
        or not isinstance(value, (numbers.Real, np.floating, np.integer))
        or not math.isfinite(float(value))
        or float(value) <= 0
    ):
        raise fail("fps", "a positive, finite frame rate (frames per second)", repr(value))
    return float(value)


def seed(value: Any) -> Optional[int]:
    """A seed kept for later calls, checked now with the engine's rule (0..2**64 - 1)."""
    v = optional_machine_int("seed", value, 128)
    _native.check_call_settings(seed=v)
    return v


def threads(value: Any) -> Optional[int]:
    """A thread count kept for later calls, checked now with the engine's rule."""
    v = optional_machine_int("threads", value)
    _native.check_call_settings(threads=v)
    return v


def num_samples(value: Any, window: Optional[Tuple[int, int]] = None, *, fill_alone: bool = False) -> int:
    """A sample count kept for later calls, checked now with the engine's rules: at least 1 (or 0 with
    ``fill_alone``: a repair's, the repair fill alone), and with ``window = (K, L)`` small enough for the
    samples of one sequence of that size to fit in memory."""
    v = machine_int("num_samples", value)
    if fill_alone and v == 0:
        return v
    _native.check_call_settings(num_samples=v, window=window)
    return v


def float32_array(argument: str, value: Any) -> np.ndarray:
    """A C-contiguous float32 array of any shape (the native layer checks the shape)."""
    try:
        a = np.asarray(value)
    except (ValueError, TypeError) as e:
        raise fail(argument, "an array of numbers", f"an object numpy cannot convert ({e})") from None
    if a.dtype.kind not in "biuf":
        raise fail(argument, "an array of numbers", f"an array of dtype {a.dtype}")
    return np.ascontiguousarray(a, dtype=np.float32)


def optional_float32_array(argument: str, value: Any) -> Optional[np.ndarray]:
    """None, or :func:`float32_array` (injected noise, which a seed may replace)."""
    return None if value is None else float32_array(argument, value)


def stream_ids(value: Any) -> Optional[List[int]]:
    """``sequences`` (None, or one seeded stream id per sequence) as Python ints; the engine checks their range and
    that there is one per sequence."""
    if value is None:
        return None
    a = np.asarray(value)
    if a.ndim != 1 or (a.size and a.dtype.kind not in "iu"):
        raise fail(
            "sequences",
            "a 1-D sequence of integer stream ids, one per sequence",
            f"an array of shape {shape_str(a.shape)} and dtype {a.dtype}",
        )
    return [int(v) for v in a]


def streams(seed: Any, first_sequence: Any, sequences: Any, threads: Any) -> _native._Streams:
    """The keywords every seeded engine call takes (``seed``, ``first_sequence``, ``sequences``, ``threads``),
    checked and converted for the binding; the engine checks their ranges against the call."""
    return {
        "seed": optional_machine_int("seed", seed, 128),
        "first_sequence": machine_int("first_sequence", first_sequence, 128),
        "sequences": stream_ids(sequences),
        "threads": optional_machine_int("threads", threads),
    }


def shape_str(shape: Sequence[int]) -> str:
    return "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
