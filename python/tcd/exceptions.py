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
* :class:`ModelNotBundledError` — :func:`tcd.load` was given the name of a bundled model (``"humaneva"``)
  that this installation does not hold yet. Also a ``FileNotFoundError``. ``.model`` is the name, ``.path``
  the directory where it would be.

And one warning: :class:`MirroredPosesWarning` (a ``UserWarning``), for poses from the wild whose left and
right look swapped.
"""

from typing import Optional

from ._native import InvalidInputError, TcdError, WeightsError

# The classes are created in the native module (crates/tcd-py/src/error.rs), so the engine raises them
# without importing this module; they are defined there once and re-exported here. Construct them as
# ``InvalidInputError(message, argument)`` and ``WeightsError(message, path)``.

__all__ = ["TcdError", "InvalidInputError", "WeightsError", "ModelNotBundledError", "MirroredPosesWarning"]


class ModelNotBundledError(TcdError, FileNotFoundError):
    """A bundled model that this installation does not hold (see :func:`tcd.load`): its message says how to
    get it. A ``FileNotFoundError`` too, so code that handles a missing model directory handles this."""

    def __init__(self, message: str, model: Optional[str] = None, path: Optional[str] = None) -> None:
        super().__init__(message)
        #: the bundled model's name (``"humaneva"``, ``"h36m"``)
        self.model = model
        #: the directory where the model would be
        self.path = path


class MirroredPosesWarning(UserWarning):
    """Poses from the wild (a call with a ``capture``) whose knees bend forward only if left and right are swapped:
    the layout's joint order may not be the one named (lifters and toolkits order the 17 joints differently). The
    body frame is built from the hips, so swapped labels turn the person round and mirror them (docs/wild.md,
    "Left and right")."""
