"""Argument checks shared by the public API: each failure is an InvalidInputError naming the argument,
what was expected and what was received."""
from __future__ import annotations

import numbers
from typing import Any, Optional, Sequence

import numpy as np

from .exceptions import InvalidInputError

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


def text(argument: str, value: Any, names: Sequence[str]) -> str:
    """A str (its value is the engine's to check against ``names``, listed in the message)."""
    if not isinstance(value, str):
        listed = ", ".join(repr(o) for o in names)
        raise fail(argument, f"one of {listed}", f"{value!r} ({type(value).__name__})")
    return value


def machine_int(argument: str, value: Any) -> int:
    """An int (not bool) that fits the engine's 64-bit integers (its range is the engine's to check)."""
    if not _is_int(value) or not -2**63 <= int(value) < 2**63:
        raise fail(argument, "an integer", f"{value!r} ({type(value).__name__})")
    return int(value)


def real(argument: str, value: Any) -> float:
    """A real number (not bool), as a float (its range is the engine's to check)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        raise fail(argument, "a number", f"{value!r} ({type(value).__name__})")
    return float(value)


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
