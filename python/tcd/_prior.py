"""The deterministic prior forecaster (issue 28): one ``prior.safetensors`` file, run by the Rust engine.

A siMLPe-class network (``training/prior.py``, ``PriorNet``): the last ``obs_len`` frames of K = joints x 3
coordinates (root-relative, model units) -> DCT over time -> spatial FC -> temporal FC + layer-norm blocks ->
spatial FC -> inverse DCT -> the next ``chunk`` frames, added to the last observed pose. Longer horizons are
rolled out chunk by chunk, each prediction appended to the history. No sampling: the same input gives the
same output.

A prior whose ``anchor`` is ``"window"`` is a **repair fill** instead: the same network over a whole window
(``chunk`` = ``obs_len``), its output added to the input window frame by frame. Its input is the natural cubic
spline through a masked window's observed entries; a repair model conditioned on it (``cond_fill`` ``"prior"``)
sees its correction (``repair_fill.safetensors`` in a model directory).

Arrays are float32 **(B, T, K)**, frame-major (unlike :class:`tcd.engine.Denoiser`'s (B, K, L)): B
sequences, T frames, K coordinates (index ``joint * 3 + axis``). Its public home is :mod:`tcd.engine`
(``tcd.engine.Prior``).
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from numpy.typing import ArrayLike

from . import _checks, _native
from ._attributes import NativeAttribute, NativeModel

__all__ = ["Prior"]


class Prior(NativeModel[_native.Prior]):
    """A loaded prior forecaster (one ``.safetensors`` file with ``role: "prior"``). Immutable and
    thread-safe."""

    __slots__ = ()
    _NATIVE = _native.Prior

    # The file's settings beyond NativeModel's, read from the engine's model (each read-only).
    obs_len = NativeAttribute(int, "Frames one forward reads: the last ``obs_len`` frames of the input.")
    chunk = NativeAttribute(int, "Frames one forward predicts; :meth:`predict` rolls out longer horizons.")
    blocks = NativeAttribute(int, "Temporal FC + layer-norm blocks.")
    anchor = NativeAttribute(
        str,
        'What a forward\'s output is added to: ``"last"``, the last observed pose (a '
        'forecaster, rolled out by :meth:`predict`), or ``"window"``, its input window (a '
        "repair fill: ``chunk`` = ``obs_len``, :meth:`predict` only with ``horizon`` = "
        "``obs_len``; :func:`tcd.engine.repair_raw`'s ``fill``).",
    )
    gap_fill = NativeAttribute(
        str,
        "How a repair fill fills a window's whole-frame gaps (runs of frames with every "
        'entry hidden): ``"none"``, like every other hidden entry, or ``"forecaster"``, '
        "with the prior forecaster run forward and backward into the gap and averaged with "
        "its own fill (:func:`tcd.engine.repair_raw` then needs ``forecaster``). "
        '``"none"`` for a forecaster.',
    )
    dct_matrix = NativeAttribute(
        np.ndarray,
        "The (obs_len, obs_len) float32 DCT-II matrix the engine computes "
        "(row f the f-th cosine); it equals ``training.prior_net.dct_matrix(obs_len)`` rounded "
        "to float32.",
    )

    # ------------------------------------------------------------------ compute
    def predict(self, obs: ArrayLike, horizon: int, *, threads: Optional[int] = None) -> np.ndarray:
        """The next ``horizon`` frames of each sequence: ``obs`` (B, T, K) float32 with T >= ``obs_len`` (the
        last ``obs_len`` frames are read and must be finite) -> (B, horizon, K) float32. ``threads`` (default:
        all cores) share the batch; results do not depend on it. Ctrl-C stops the call within about 0.1 s."""
        return self._native.predict(
            _checks.float32_array("obs", obs),
            _checks.machine_int("horizon", horizon),
            threads=_checks.optional_machine_int("threads", threads),
        )

    def fill(
        self,
        observed: ArrayLike,
        mask: ArrayLike,
        *,
        forecaster: Optional["Prior"] = None,
        threads: Optional[int] = None,
    ) -> np.ndarray:
        """What a model conditioned on this prior sees (``training.model.prior_fill``): ``observed`` (B, T, K)
        float32 with its ``mask``-0 entries filled, (B, T, K) float32; ``mask`` of the same shape, 1 = given (the
        given entries must be finite and come back bit for bit; the others are never read). A forecaster
        (``anchor`` ``"last"``, T > ``obs_len``) fills the first ``obs_len`` frames with the natural cubic spline
        and rolls out after them; a repair fill (T = ``obs_len``) returns its correction of the spline, and one
        with ``gap_fill`` ``"forecaster"`` then fills the whole-frame gaps from ``forecaster`` (required for it).
        ``threads`` (default: all cores); Ctrl-C stops the call."""
        if forecaster is not None and not isinstance(forecaster, Prior):
            raise _checks.fail("forecaster", "a tcd.engine.Prior or None", type(forecaster).__name__)
        return self._native.fill(
            _checks.float32_array("observed", observed),
            _checks.float32_array("mask", mask),
            forecaster=None if forecaster is None else forecaster._native,
            threads=_checks.optional_machine_int("threads", threads),
        )
