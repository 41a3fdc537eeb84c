"""Argument checks shared by the public API: each failure is an InvalidInputError naming the argument,
what was expected and what was received."""
from __future__ import annotations

import math
import numbers
from typing import Any, Optional, Sequence, Tuple

import numpy as np

from .exceptions import InvalidInputError

UNITS = ("m", "mm")
MAX_SEED = 2**64 - 1


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


def optional_integer(argument: str, value: Any, minimum: int, maximum: Optional[int] = None) -> Optional[int]:
    return None if value is None else integer(argument, value, minimum, maximum)


def choice(argument: str, value: Any, options: Sequence[str]) -> str:
    if not isinstance(value, str) or value not in options:
        listed = ", ".join(repr(o) for o in options)
        raise fail(argument, f"one of {listed}", repr(value))
    return value


def eta(value: Any) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        raise fail("eta", "a number in [0, 1]", f"{value!r} ({type(value).__name__})")
    v = float(value)
    if not (math.isfinite(v) and 0.0 <= v <= 1.0):
        raise fail("eta", "a number in [0, 1]", repr(v))
    return v


def seed(value: Any) -> Optional[int]:
    return optional_integer("seed", value, 0, MAX_SEED)


MAX_THREADS = 1024


def threads(value: Any) -> Optional[int]:
    return optional_integer("threads", value, 1, MAX_THREADS)


def float32_array(argument: str, value: Any) -> np.ndarray:
    """A C-contiguous float32 array of any shape (the native layer checks the shape)."""
    try:
        a = np.asarray(value)
    except (ValueError, TypeError) as e:
        raise fail(argument, "an array of numbers", f"an object numpy cannot convert ({e})") from None
    if a.dtype.kind not in "biuf":
        raise fail(argument, "an array of numbers", f"an array of dtype {a.dtype}")
    return np.ascontiguousarray(a, dtype=np.float32)


def shape_str(shape: Sequence[int]) -> str:
    return "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
