"""Stubs of the private native module ``tcd._native`` (crates/tcd-py). Use the ``tcd`` package.

Arrays are float32 in the engine's layout: sequences (B, K, L), samples (S, B, K, L), injected
noise (S, n + 1, B, K, L) ((S, 1, B, K, L) for ``sampler="dpmpp2m"``). The sampler of a call is a
``tcd.SamplerOptions``, read through the :class:`Sampler` it holds (``_engine``), checked once when it was made.
Errors: ``tcd.exceptions.InvalidInputError`` (bad argument),
``tcd.exceptions.WeightsError`` (bad weight file), ``FileNotFoundError`` (missing file),
``OSError`` (unreadable file), ``tcd.exceptions.TcdError`` (anything else).
"""

import os
from typing import Any, Callable, Dict, List, Optional, Tuple, Type, TypedDict, TypeVar, Union, final

import numpy as np
import numpy.typing as npt

from ._sampler import SamplerOptions

# The module's __all__ (PyO3 fills it with every name crates/tcd-py/src/lib.rs adds), checked by
# `python -m mypy.stubtest tcd._native` (tests/test_api.py).
__all__ = [
    "__version__",
    "TcdError",
    "InvalidInputError",
    "WeightsError",
    "STAGE_SHORT",
    "STAGE_LONG",
    "STAGE_GENERATOR",
    "Denoiser",
    "Prior",
    "Generator",
    "Sampler",
    "cascade",
    "repair",
    "seeded_noise",
    "interpolate",
    "supported_kernels",
    "check_call_settings",
    "SAMPLERS",
    "SPACINGS",
    "COUPLINGS",
    "INTERPOLATIONS",
]

__version__: str
STAGE_SHORT: int
STAGE_LONG: int
STAGE_GENERATOR: int
SAMPLERS: List[str]
SPACINGS: List[str]
COUPLINGS: List[str]
INTERPOLATIONS: List[str]

_F32 = npt.NDArray[np.float32]

# The exceptions (re-exported by tcd.exceptions): constructed as (message,), (message, argument) and
# (message, path); str() is the message.
class TcdError(Exception): ...

class InvalidInputError(TcdError, ValueError):
    @property
    def argument(self) -> Optional[str]: ...

class WeightsError(TcdError, ValueError):
    @property
    def path(self) -> Optional[str]: ...

class _Streams(TypedDict):
    """How a seeded call numbers its noise streams, and its threads (``tcd._checks.streams`` builds it)."""

    seed: Optional[int]
    first_sequence: int
    sequences: Optional[List[int]]
    threads: Optional[int]

class _Call(TypedDict):
    """The arguments a sampling call (``Denoiser.sample``, ``cascade``, ``repair``) has beside its models and their
    injected noise (``tcd.engine._chains`` builds it)."""

    observed: _F32
    mask: _F32
    num_samples: int
    options: SamplerOptions
    streams: _Streams
    progress: Optional[Callable[[int, int], Any]]

_W = TypeVar("_W", bound="_WeightFile")

# The loaders and getters every class of a loaded weight file has (the binding's `model_methods!`): typing only,
# no runtime base class.
class _WeightFile:
    @classmethod
    def load(cls: Type[_W], path: Union[str, os.PathLike[str]]) -> _W: ...
    @classmethod
    def from_bytes(cls: Type[_W], data: bytes, name: Union[str, os.PathLike[str]]) -> _W: ...
    @property
    def path(self) -> str: ...
    @property
    def config_json(self) -> str: ...
    @property
    def kernel(self) -> str: ...
    @property
    def num_features(self) -> int: ...
    @property
    def num_joints(self) -> int: ...
    @property
    def coords(self) -> int: ...
    @property
    def obs_len(self) -> int: ...

# PyO3 classes cannot be subclassed (no #[pyclass(subclass)]).
@final
class Denoiser(_WeightFile):
    @property
    def role(self) -> str: ...
    @property
    def pred_len(self) -> int: ...
    @property
    def seq_len(self) -> int: ...
    @property
    def num_train_timesteps(self) -> int: ...
    def timesteps(self, options: SamplerOptions) -> List[int]: ...
    def num_noise_blocks(self, options: SamplerOptions) -> int: ...
    def forward(self, noisy: _F32, observed: _F32, mask: _F32, step: int, *, threads: Optional[int] = None) -> _F32: ...
    def sample(self, call: _Call, *, noise: Optional[_F32] = None) -> _F32: ...

@final
class Prior(_WeightFile):
    """The deterministic prior forecaster; arrays (B, T, K) float32, frame-major."""
    @property
    def chunk(self) -> int: ...
    @property
    def blocks(self) -> int: ...
    @property
    def anchor(self) -> str: ...
    @property
    def gap_fill(self) -> str: ...
    @property
    def dct_matrix(self) -> _F32: ...
    def predict(self, obs: _F32, horizon: int, *, threads: Optional[int] = None) -> _F32: ...
    def fill(
        self, observed: _F32, mask: _F32, *, forecaster: Optional[Prior] = None, threads: Optional[int] = None
    ) -> _F32: ...

@final
class Generator(_WeightFile):
    """The MLP sample generator; arrays (B, T, K) float32, frame-major; samples (S, B, pred_len, K)."""
    @property
    def pred_len(self) -> int: ...
    @property
    def hidden(self) -> int: ...
    @property
    def layers(self) -> int: ...
    @property
    def z_dim(self) -> int: ...
    @property
    def coefs(self) -> int: ...
    def sample(
        self,
        obs: _F32,
        prior: _F32,
        num_samples: int,
        *,
        noise: Optional[_F32] = None,
        streams: _Streams,
    ) -> _F32: ...

def cascade(
    short: Denoiser,
    long: Denoiser,
    call: _Call,
    *,
    noise_short: Optional[_F32] = None,
    noise_long: Optional[_F32] = None,
    prior: Optional[Prior] = None,
) -> Dict[str, _F32]: ...
def repair(
    model: Denoiser,
    call: _Call,
    *,
    noise: Optional[_F32] = None,
    fill: Optional[Prior] = None,
    forecaster: Optional[Prior] = None,
) -> Dict[str, _F32]: ...
def seeded_noise(seed: int, stage: int, shape: Tuple[int, int, int, int, int], first_sequence: int = 0) -> _F32: ...
def interpolate(observed: _F32, mask: _F32, method: str) -> _F32: ...

@final
class Sampler:
    """The engine's sampler, checked when made (``InvalidInputError`` naming the bad field)."""

    def __new__(
        cls,
        sampler: str,
        num_inference_steps: Optional[int],
        eta: float,
        timestep_spacing: str,
        noise_coupling: str,
    ) -> "Sampler": ...

def check_call_settings(
    *,
    num_samples: Optional[int] = None,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    window: Optional[Tuple[int, int]] = None,
) -> None: ...
def supported_kernels() -> List[str]: ...
