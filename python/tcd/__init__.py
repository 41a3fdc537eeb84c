"""tcd — Temporal Cascaded Diffusion: forecast and repair 3D human motion on the CPU.

    >>> import tcd
    >>> model = tcd.load("models/h36m")          # short.safetensors + long.safetensors
    >>> tcd.load("humaneva")                     # the bundled HumanEva-I model, where installed
    >>> tcd.load("h36m-stochastic")              # Human3.6M Setting-A, 25 -> 100 frames at 50 Hz, where installed
    >>> f = model.forecast(obs, seed=0)          # obs: (50, 22, 3) metres, NaN = missing
    >>> f.mean.shape, f.samples.shape            # (25, 22, 3), (5, 25, 22, 3)

High level: :func:`load`, :class:`TCD` (``forecast``, ``predict``: the prior's point forecast, ``repair``),
:class:`Forecast`, :class:`Repair`, :func:`forecast`, :func:`predict`, :func:`repair`, :func:`repair_file`;
the sampler of every call: its ``sampler`` argument, a :class:`SamplerOptions` (its fields, defaults and
checks); where a forecast's samples come from: its ``mode``, :class:`Cascade`, :class:`Mixture` or :class:`Tempo`;
poses from the wild: a call's ``capture``, a :class:`Capture`; the engine's fills of missing
values along time (linear, natural cubic spline): :func:`interpolate`.
Engine level, in the engine's (B, K, L) layout: :mod:`tcd.engine` (``Denoiser``, ``cascade_raw``,
``repair_raw``, ``seeded_noise``, ``supported_kernels``, ``STAGE_SHORT``, ``STAGE_LONG``, and ``Prior``, the
deterministic prior forecaster on (B, T, K) frames). Poses from the wild: :mod:`tcd.wild`, :mod:`tcd.layouts`.
Errors: :mod:`tcd.exceptions`. Inference runs in a Rust engine (no torch). Modules whose name starts with an
underscore are internal.
"""

from __future__ import annotations

from . import engine, exceptions
from ._native import __version__
from .exceptions import InvalidInputError, ModelNotBundledError, TcdError, WeightsError
from ._interpolation import interpolate
from ._model import (
    BUNDLED_MODELS,
    TCD,
    Forecast,
    Repair,
    default_model_dir,
    forecast,
    humaneva_model_dir,
    load,
    predict,
    repair,
)
from ._cascade import Cascade
from ._mixture import Mixture
from ._sampler import SamplerOptions
from ._tempo import Tempo
from ._wild_calls import Capture
from ._repair import repair_file  # `tcd repair` / offline repair of files of any length (issue 6)

__all__ = [
    "__version__",
    "load",
    "forecast",
    "predict",
    "repair",
    "repair_file",
    "interpolate",
    "TCD",
    "Forecast",
    "Repair",
    "SamplerOptions",
    "Capture",
    "Cascade",
    "Mixture",
    "Tempo",
    "default_model_dir",
    "humaneva_model_dir",
    "BUNDLED_MODELS",
    "engine",
    "exceptions",
    "TcdError",
    "InvalidInputError",
    "WeightsError",
    "ModelNotBundledError",
]
