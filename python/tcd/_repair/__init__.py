"""Offline repair of pose sequences of any length, file by file: ``tcd repair`` and :func:`repair_file`.

Inputs
    * ``.npz`` with ``poses`` ``(T, J, 3)`` (NaN = missing; J = the model's joints, in its order,
      root-relative) and optionally ``mask`` ``(T, J, 3)`` or ``(T, J)`` (1 = observed; entries with
      mask 0 are repaired whatever their value);
    * Human3.6M exp-map ``.txt`` files (99 comma-separated values per row, 50 Hz), converted through
      forward kinematics (:mod:`tcd._fk`) to the 22 model joints; NaN in a joint's exp-map marks the
      joint's descendants missing.

Windows
    The repair model sees W = ``TCD.obs_len`` (50) frames at a time. A sequence of T > W frames is cut
    into overlapping windows starting at 0, S, 2 S, ... and a last one ending at T, with the stride
    S = W - C - L (C = ``overlap``, 5 by default; L = ``lookahead``, 10 by default). They are repaired in
    order. A window commits its frames except its L trailing ones (the last window commits all): those
    were generated without seeing what follows them (a gap running past the window's end is extrapolated),
    so the next window generates them again. In each window after the first, the committed frames (at
    least C) count as observed in the in-painting mask, so the new frames are generated conditioned on them
    and there are no seams. A sequence of T < W frames is padded to W with masked frames (discarded
    afterwards). ``benches/repair_dataset.py`` measured the lookahead: on 8 occluded S5 recordings at
    25 fps (DDPM-10 x 5), ADE 12.6 mm with C = 10, L = 0 against 8.0 mm with C = 5, L = 10.

Frame rates
    Inputs at another rate F than the model's (``TCD.fps``, 25) are resampled to it and back. Forward:
    model frame j (time j / 25) takes the linear interpolation of the two source frames around it; an
    entry counts as observed only when both of them are observed (conservative: a gap never shrinks),
    and model frames past the last source frame are missing. Backward: every source frame takes the
    linear interpolation of the two repaired model frames around it. Either way, the observed entries
    of the output are the input's, bit for bit; only missing entries come from the model.

Noise and determinism
    Window k of a file draws the engine's seeded noise stream k of ``seed`` (0 by default; the engine
    takes one stream id per batched window), so a file's result depends only on the file, the model and the
    settings: not on the
    other files, the batching, the thread count, nor on whether an earlier run was interrupted. Windows
    of several files are batched into one engine call (``files_per_batch`` files in lock step).

Outputs
    ``poses`` (repaired, the input's units and dtype), ``mask`` (the input's ``mask`` as given, else
    the observation mask ``~isnan(poses)`` as bool ``(T, J, 3)``) and ``provenance`` (a JSON string:
    package version, model SHA-256, sampler, steps, samples, seed, ...). Files are written to a
    temporary file in the destination directory and renamed into place, so an output either is
    complete or does not exist.
"""

from __future__ import annotations

# The package's modules, in the order of the work: options (settings, provenance), inputs (reading one
# file), windows (resampling and the windows of one file), runner (the engine loop, repair_file, planning),
# distributed (tcd repair --ray). The command line is tcd._cli.repair, the atomic writes tcd._files. Only the
# names of __all__ are imported here; everything else from the module that defines it.
from .options import DEFAULT_OVERLAP, DEFAULT_SEED, INPUT_SUFFIXES, RepairOptions
from .runner import repair_file

__all__ = ["repair_file", "RepairOptions", "DEFAULT_OVERLAP", "DEFAULT_SEED", "INPUT_SUFFIXES"]
