"""The exceptions of ``tcd``.

Every error the package raises on purpose is one of these, or a ``FileNotFoundError`` for a missing
model file or directory:

* :class:`TcdError` — the base class; raised as itself only for failures that are not the caller's
  (e.g. a thread pool that cannot be built).
* :class:`InvalidInputError` — an argument has the wrong shape, value or content. Also a
  ``ValueError``. ``.argument`` names the offending argument.
* :class:`WeightsError` — a weight file is corrupt, truncated, lacks or has extra tensors, or its
  configuration disagrees with its tensors (or a model directory's files disagree with each other).
  Also a ``ValueError``. ``.path`` names the file.
"""
from __future__ import annotations

from typing import Optional

__all__ = ["TcdError", "InvalidInputError", "WeightsError"]


class TcdError(Exception):
    """Base class of every error raised by ``tcd``."""


class InvalidInputError(TcdError, ValueError):
    """An argument has the wrong shape, value or content; ``argument`` names it."""

    def __init__(self, message: str, argument: Optional[str] = None) -> None:
        super().__init__(message)
        self.argument = argument


class WeightsError(TcdError, ValueError):
    """A weight file (or model directory) is invalid; ``path`` names it."""

    def __init__(self, message: str, path: Optional[str] = None) -> None:
        super().__init__(message)
        self.path = path
