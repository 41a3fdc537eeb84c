"""tcd — Temporal Cascaded Diffusion: forecast and repair 3D human motion on the CPU.

    >>> import tcd
    >>> model = tcd.load("models/h36m")          # short.safetensors + long.safetensors
    >>> tcd.load("humaneva")                     # the bundled HumanEva-I model, where installed
    >>> f = model.forecast(obs, seed=0)          # obs: (50, 22, 3) metres, NaN = missing
    >>> f.mean.shape, f.samples.shape            # (25, 22, 3), (5, 25, 22, 3)

High level: :func:`load`, :class:`TCD` (``forecast``, ``predict``: the prior's point forecast, ``repair``),
:class:`Forecast`, :func:`forecast`, :func:`predict`;
the sampler of every call: the keyword arguments ``sampler``, ``num_inference_steps``, ``eta`` and
``timestep_spacing`` (their defaults and checks: :class:`SamplerOptions`); the engine's fills of missing
values along time (linear, natural cubic spline): :func:`interpolate`.
Low level, in the engine's (B, K, L) layout: :class:`Denoiser`, :func:`cascade_raw`, :func:`repair_raw`,
:func:`seeded_noise`. The deterministic prior forecaster on (B, T, K) frames: :class:`Prior`.
Errors: :mod:`tcd.exceptions`. Inference runs in a Rust engine (no torch).
"""
from __future__ import annotations

from . import exceptions
from ._native import __version__
from .denoiser import STAGE_LONG, STAGE_SHORT, Denoiser, cascade_raw, repair_raw, seeded_noise, supported_kernels
from .exceptions import InvalidInputError, ModelNotBundledError, TcdError, WeightsError
from .interpolation import interpolate
from .model import BUNDLED_MODELS, TCD, Forecast, default_model_dir, forecast, humaneva_model_dir, load, predict, repair
from .options import SamplerOptions
from .prior import Prior
from .batch_repair import repair_file  # `tcd repair` / offline repair of files of any length (issue 6)

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
    "SamplerOptions",
    "default_model_dir",
    "humaneva_model_dir",
    "BUNDLED_MODELS",
    "Denoiser",
    "Prior",
    "cascade_raw",
    "repair_raw",
    "seeded_noise",
    "supported_kernels",
    "STAGE_SHORT",
    "STAGE_LONG",
    "exceptions",
    "TcdError",
    "InvalidInputError",
    "WeightsError",
    "ModelNotBundledError",
]
