"""The MLP sample generator (issue 31): one ``generator.safetensors`` file, run by the Rust engine.

The network of ``training/generator.py`` (``Generator``): forecast samples around the prior forecaster's
forecast, one MLP forward each. With ``last`` the last observed pose, D_n the orthonormal DCT-II matrix of n
frames (the prior's) and z ~ N(0, I) of ``z_dim`` values per sample::

    h   = [D_O (obs - last), D_P[:C] (prior - last), z]    (O = obs_len, P = pred_len, C = coefs)
    h   = GELU(W_i h + b_i) for each of the ``layers`` hidden layers
    out = prior + D_P[:C]^T (W_head h + b_head)             (P, K)

where ``prior`` is the prior forecaster's P-frame forecast of the observation (:meth:`tcd.engine.Prior.predict`;
the caller passes it: the generator runs no prior of its own).

Arrays are float32 **(B, T, K)**, frame-major like :class:`tcd.engine.Prior`'s; the samples (S, B, pred_len, K).
Its public home is :mod:`tcd.engine` (``tcd.engine.Generator``).
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from . import _checks, _native
from ._attributes import NativeAttribute, NativeModel

__all__ = ["Generator"]


class Generator(NativeModel[_native.Generator]):
    """A loaded MLP sample generator (one ``.safetensors`` file with ``role: "generator"``). Immutable and
    thread-safe."""

    __slots__ = ()
    _NATIVE = _native.Generator

    # The file's settings beyond NativeModel's, read from the engine's model (each read-only).
    obs_len = NativeAttribute(int, "O: observed frames it reads, the last ``obs_len`` of ``obs``.")
    pred_len = NativeAttribute(int, "P: frames of the prior's forecast it takes and of each sample.")
    hidden = NativeAttribute(int, "Width of the hidden layers.")
    layers = NativeAttribute(int, "Hidden layers (each a Linear and the exact GELU).")
    z_dim = NativeAttribute(int, "Noise values one sample reads: the last axis of injected ``noise``.")
    coefs = NativeAttribute(
        int, "C <= pred_len: the DCT coefficients of the forecast it reads and of the residual it adds to it."
    )

    # ------------------------------------------------------------------ compute
    def sample(
        self,
        obs: ArrayLike,
        prior: ArrayLike,
        num_samples: int = 1,
        *,
        noise: Optional[ArrayLike] = None,
        seed: Optional[int] = None,
        first_sequence: int = 0,
        sequences: Optional[Sequence[int]] = None,
        threads: Optional[int] = None,
    ) -> np.ndarray:
        """``num_samples`` forecasts of each sequence: ``obs`` (B, T, K) float32 with T >= ``obs_len`` (the last
        ``obs_len`` frames are read and must be finite) and ``prior`` (B, ``pred_len``, K), the prior forecaster's
        forecast of each (finite) -> (S, B, ``pred_len``, K) float32.

        Exactly one of ``noise`` (S, B, ``z_dim``) standard normals and ``seed`` must be given; seeded sample s of
        sequence b draws stream ``first_sequence + b``, or ``sequences[b]`` (one id per sequence), of stage
        :data:`tcd.engine.STAGE_GENERATOR`: ``seeded_noise(seed, STAGE_GENERATOR, S, 1, B, z_dim, 1)`` reshaped to
        (S, B, z_dim) is the noise it reads. ``threads`` (default: all cores) share the samples; results depend
        neither on it nor on the other sequences of the batch. Ctrl-C stops the call within about 0.1 s."""
        return self._native.sample(
            _checks.float32_array("obs", obs),
            _checks.float32_array("prior", prior),
            _checks.machine_int("num_samples", num_samples),
            noise=_checks.optional_float32_array("noise", noise),
            streams=_checks.streams(seed, first_sequence, sequences, threads),
        )
