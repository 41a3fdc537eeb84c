"""The deterministic prior forecaster (issue 28): one ``prior.safetensors`` file, run by the Rust engine.

A siMLPe-class network (``training/prior.py``, ``PriorNet``): the last ``obs_len`` frames of K = joints x 3
coordinates (root-relative, model units) -> DCT over time -> spatial FC -> temporal FC + layer-norm blocks ->
spatial FC -> inverse DCT -> the next ``chunk`` frames, added to the last observed pose. Longer horizons are
rolled out chunk by chunk, each prediction appended to the history. No sampling: the same input gives the
same output.

Arrays are float32 **(B, T, K)**, frame-major (unlike :class:`tcd.engine.Denoiser`'s (B, K, L)): B
sequences, T frames, K coordinates (index ``joint * 3 + axis``). Its public home is :mod:`tcd.engine`
(``tcd.engine.Prior``).
"""
from __future__ import annotations

import json
import os
from typing import Any, Dict, Optional, Union

import numpy as np
from numpy.typing import ArrayLike

from . import _checks, _native
from ._attributes import NativeAttribute

__all__ = ["Prior"]

PathLike = Union[str, "os.PathLike[str]"]


class Prior:
    """A loaded prior forecaster (one ``.safetensors`` file with ``role: "prior"``). Immutable and
    thread-safe."""

    __slots__ = ("_native", "_config")

    def __init__(self, native: _native.Prior) -> None:
        if not isinstance(native, _native.Prior):
            raise TypeError("use Prior.load(path) or Prior.from_bytes(data)")
        self._native = native
        self._config: Dict[str, Any] = json.loads(native.config_json)

    @classmethod
    def load(cls, path: PathLike) -> "Prior":
        """Loads and validates a prior weight file. Missing file: ``FileNotFoundError``; invalid content
        (a denoiser's file included): :class:`tcd.exceptions.WeightsError`."""
        return cls(_native.Prior.load(os.fspath(path)))

    @classmethod
    def from_bytes(cls, data: bytes, name: str = "<bytes>") -> "Prior":
        """Like :meth:`load`, from the bytes of a weight file; ``name`` appears in error messages."""
        return cls(_native.Prior.from_bytes(bytes(data), name))

    # ------------------------------------------------------------------ configuration
    @property
    def config(self) -> Dict[str, Any]:
        """The ``tcd_config`` JSON of the file, parsed (a fresh copy)."""
        return json.loads(json.dumps(self._config))

    # The file's settings, read from the engine's model (each read-only).
    path = NativeAttribute(str, "The weight file's path (or the name given to :meth:`from_bytes`).")
    num_features = NativeAttribute(int, "K = num_joints * 3.")
    num_joints = NativeAttribute(int, "Joints of the model (its config's ``model.num_joints``).")
    obs_len = NativeAttribute(int, "Frames one forward reads: the last ``obs_len`` frames of the input.")
    chunk = NativeAttribute(int, "Frames one forward predicts; :meth:`predict` rolls out longer horizons.")
    blocks = NativeAttribute(int, "Temporal FC + layer-norm blocks.")
    kernel = NativeAttribute(str, 'The compute kernels in use: ``"portable"``, ``"avx2"`` or ``"avx512"`` (chosen '
                             "when the file is loaded: ``$TCD_KERNEL``, default the best this CPU supports, see "
                             ":func:`tcd.engine.supported_kernels`).")
    dct_matrix = NativeAttribute(np.ndarray, "The (obs_len, obs_len) float32 DCT-II matrix the engine computes "
                                 "(row f the f-th cosine); it equals ``training.prior.dct_matrix(obs_len)`` rounded "
                                 "to float32.")

    def __repr__(self) -> str:
        return repr(self._native)

    # ------------------------------------------------------------------ compute
    def predict(self, obs: ArrayLike, horizon: int, *, threads: Optional[int] = None) -> np.ndarray:
        """The next ``horizon`` frames of each sequence: ``obs`` (B, T, K) float32 with T >= ``obs_len`` (the
        last ``obs_len`` frames are read and must be finite) -> (B, horizon, K) float32. ``threads`` (default:
        all cores) share the batch; results do not depend on it. Ctrl-C stops the call within about 0.1 s."""
        return self._native.predict(_checks.float32_array("obs", obs), _checks.machine_int("horizon", horizon),
                                    threads=_checks.optional_machine_int("threads", threads))
