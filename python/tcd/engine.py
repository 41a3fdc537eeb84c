"""The engine-level API, ``tcd.engine``: one denoiser, the samplers and the cascade in the engine's layout,
the deterministic prior forecaster, and the MLP sample generator.

:class:`Denoiser` (one weight file), :func:`cascade_raw` (short-term -> long-term), :func:`repair_raw`
(observation-only inference), :func:`seeded_noise` (the seeded streams, :data:`STAGE_SHORT` /
:data:`STAGE_LONG` / :data:`STAGE_GENERATOR`), :func:`supported_kernels`, :class:`Prior` (the prior forecaster,
frame-major (B, T, K): see its docstring) and :class:`Generator` (forecast samples around the prior's forecast,
one MLP forward each, frame-major too; its injected noise (S, B, z_dim): see its docstring). :mod:`tcd` itself
holds the high-level API (:func:`tcd.load`, :class:`tcd.TCD`) built on these.

Arrays here are float32 **(B, K, L)**: B sequences, K = joints x 3 coordinates (index
``joint * 3 + axis``), L frames (frame axis last). Masks are 1 (observed) / 0 (to generate).
Injected noise is **(S, n + 1, B, K, L)**: for each of the S chains, block 0 is x_T and block i + 1
the z of step i — with S = 1 the ``(num_steps + 1, B, K, L)`` array of ``training.diffusion.sample``.
The deterministic ``sampler="dpmpp2m"`` (DPM-Solver++(2M)) draws no per-step noise: its noise is
(S, 1, B, K, L), x_T only (:meth:`Denoiser.num_noise_blocks`).
Pass ``noise`` for bit-exact parity tests, or a ``seed`` for the engine's seeded ChaCha8 streams
(:func:`seeded_noise` materialises them). The sampler of every call: its ``sampler`` argument, a
:class:`tcd.SamplerOptions` (default: the paper's DDPM over every training step).
"""

from __future__ import annotations

import functools
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
from numpy.typing import ArrayLike

from . import _checks, _native
from ._attributes import NativeAttribute, NativeModel
from ._sampler import SamplerOptions, checked
from ._generator import Generator
from ._prior import Prior
from ._progress import Progress, reporter

__all__ = [
    "Denoiser",
    "Prior",
    "Generator",
    "cascade_raw",
    "repair_raw",
    "seeded_noise",
    "supported_kernels",
    "STAGE_SHORT",
    "STAGE_LONG",
    "STAGE_GENERATOR",
]

#: Stream stage of :meth:`Denoiser.sample`, :func:`repair_raw` and the cascade's short-term stage.
STAGE_SHORT: int = _native.STAGE_SHORT
#: Stream stage of the cascade's long-term stage.
STAGE_LONG: int = _native.STAGE_LONG
#: Stream stage of :meth:`Generator.sample` (its noise z, ``num_blocks`` 1, ``length`` 1 in :func:`seeded_noise`).
STAGE_GENERATOR: int = _native.STAGE_GENERATOR
#: The sampler of an engine call that names none: the paper's DDPM over every training step.
DEFAULT_SAMPLER = SamplerOptions()


class Denoiser(NativeModel[_native.Denoiser]):
    """A loaded TCD denoiser (one ``.safetensors`` file). Immutable and thread-safe."""

    __slots__ = ()
    _NATIVE = _native.Denoiser

    # The file's settings beyond NativeModel's, read from the engine's model (each read-only).
    role = NativeAttribute(str, "``short``, ``long`` or ``repair``.")
    obs_len = NativeAttribute(int, "Observed (conditioning) frames of the training window.")
    pred_len = NativeAttribute(int, "Predicted frames of the training window.")
    seq_len = NativeAttribute(int, "L = obs_len + pred_len.")
    num_train_timesteps = NativeAttribute(int, "Diffusion steps the model was trained with.")

    # ------------------------------------------------------------------ compute
    def timesteps(self, sampler: SamplerOptions = DEFAULT_SAMPLER) -> List[int]:
        """The descending training steps ``sampler`` visits, e.g. ``timesteps(tcd.SamplerOptions(sampler="ddim",
        num_inference_steps=10))``; ``num_inference_steps=None`` (the default) visits all of them."""
        return list(self._native.timesteps(checked(sampler)))

    def num_noise_blocks(self, sampler: SamplerOptions = DEFAULT_SAMPLER) -> int:
        """The second axis of injected noise: n + 1 (x_T, then one z per step) for ddpm / ddim, 1 (x_T
        only) for the deterministic dpmpp2m."""
        return int(self._native.num_noise_blocks(checked(sampler)))

    def forward(
        self, noisy: ArrayLike, observed: ArrayLike, mask: ArrayLike, step: int, *, threads: Optional[int] = None
    ) -> np.ndarray:
        """ε̂ = net(noisy, observed, mask, step) (x̂₀ for a model whose ``diffusion.prediction_type`` is
        ``"sample"``): arrays (B, K, L) float32, ``step`` in 0..num_train_timesteps-1. Returns (B, K, L)
        float32. ``threads`` (default: all cores) split each sequence's forward across that many threads.
        A model with ``cond_fill`` ``"prior"`` reads the prior forecaster's fill from the mask-0 entries of
        ``observed`` (the caller puts it there; :func:`cascade_raw` does, given the prior)."""
        step = _checks.machine_int("step", step)
        return self._native.forward(
            _checks.float32_array("noisy", noisy),
            _checks.float32_array("observed", observed),
            _checks.float32_array("mask", mask),
            step,
            threads=_checks.optional_machine_int("threads", threads),
        )

    def sample(
        self,
        observed: ArrayLike,
        mask: ArrayLike,
        num_samples: int = 1,
        *,
        noise: Optional[ArrayLike] = None,
        seed: Optional[int] = None,
        first_sequence: int = 0,
        sequences: Optional[Sequence[int]] = None,
        threads: Optional[int] = None,
        progress: Progress = None,
        sampler: SamplerOptions = DEFAULT_SAMPLER,
    ) -> np.ndarray:
        """``num_samples`` merged samples per sequence: observed, mask (B, K, L) -> (S, B, K, L).

        Exactly one of ``noise`` (S, n + 1, B, K, L) — (S, 1, B, K, L) for ``sampler="dpmpp2m"`` — and
        ``seed`` must be given; seeded sequence b draws stream ``first_sequence + b``, or ``sequences[b]``
        (one id per sequence). ``sampler``: a :class:`tcd.SamplerOptions`. ``progress``: ``True`` a tqdm bar on
        stderr, a callable ``f(done, total)`` the count of denoiser forwards about ten times a second (raising in it
        stops the call). Ctrl-C stops the call within about 0.1 s plus one forward (KeyboardInterrupt)."""
        return _chains(
            self._native.sample,
            "tcd sample",
            (observed, mask, num_samples, sampler),
            progress,
            _checks.streams(seed, first_sequence, sequences, threads),
            noise=_checks.optional_float32_array("noise", noise),
        )


def cascade_raw(
    short: Denoiser,
    long: Denoiser,
    observed: ArrayLike,
    mask: ArrayLike,
    *,
    num_samples: int = 5,
    noise_short: Optional[ArrayLike] = None,
    noise_long: Optional[ArrayLike] = None,
    seed: Optional[int] = None,
    first_sequence: int = 0,
    sequences: Optional[Sequence[int]] = None,
    threads: Optional[int] = None,
    progress: Progress = None,
    prior: Optional[Prior] = None,
    sampler: SamplerOptions = DEFAULT_SAMPLER,
) -> Dict[str, np.ndarray]:
    """The short-term -> long-term cascade in the engine's layout (``training.diffusion.cascade``).

    observed, mask: (B, K, O) with O = ``short.obs_len``. Noise: ``noise_short`` (S, n + 1, B, K, L_s)
    and ``noise_long`` (S, n + 1, B, K, L_l) (one block instead of n + 1 for ``sampler="dpmpp2m"``), or a
    ``seed`` (streams numbered as in :meth:`Denoiser.sample`). ``sampler``: a :class:`tcd.SamplerOptions`, both
    stages'. Returns
    ``mean`` (B, K, P), ``samples`` (S, B, K, P) (P = L_l - O forecast frames), ``repaired`` (B, K, O) and
    ``short_mean`` (B, K, L_s).

    ``prior``: the prior forecaster (:class:`Prior`), required where a model is conditioned on it
    (``cond_fill`` ``"prior"``): before each such stage the engine fills the stage's masked entries once
    with ``training.model.prior_fill`` (the spline over the prior's observed frames, its rollout after
    them). Models with other fills ignore it.
    """
    for name, m in (("short", short), ("long", long)):
        if not isinstance(m, Denoiser):
            raise _checks.fail(name, "a tcd.engine.Denoiser", type(m).__name__)
    if prior is not None and not isinstance(prior, Prior):
        raise _checks.fail("prior", "a tcd.engine.Prior or None", type(prior).__name__)
    return _chains(
        functools.partial(_native.cascade, short._native, long._native),
        "tcd forecast",
        (observed, mask, num_samples, sampler),
        progress,
        _checks.streams(seed, first_sequence, sequences, threads),
        noise_short=_checks.optional_float32_array("noise_short", noise_short),
        noise_long=_checks.optional_float32_array("noise_long", noise_long),
        prior=None if prior is None else prior._native,
    )


def repair_raw(
    model: Denoiser,
    observed: ArrayLike,
    mask: ArrayLike,
    *,
    num_samples: int = 5,
    noise: Optional[ArrayLike] = None,
    seed: Optional[int] = None,
    first_sequence: int = 0,
    sequences: Optional[Sequence[int]] = None,
    threads: Optional[int] = None,
    progress: Progress = None,
    fill: Optional[Prior] = None,
    forecaster: Optional[Prior] = None,
    sampler: SamplerOptions = DEFAULT_SAMPLER,
) -> Dict[str, np.ndarray]:
    """Fills the mask-0 entries of an observation (B, K, O), O = ``model.obs_len``
    (``training.diffusion.repair``). Returns ``mean`` (B, K, O; observed entries exact) and ``samples``
    (S, B, K, O); ``num_samples`` 0 returns the repair ``fill`` alone as ``mean`` (a model conditioned on it
    only; no chain runs, ``samples`` (0, B, K, O)). Noise: ``noise`` (S, n + 1, B, K, model.seq_len)
    ((S, 1, ...) for ``sampler="dpmpp2m"``) or a ``seed`` (streams numbered as in :meth:`Denoiser.sample`).
    ``sampler``: a :class:`tcd.SamplerOptions`.

    ``fill``: the repair fill (a :class:`Prior` with ``anchor`` ``"window"`` over the model's window),
    required where the model is conditioned on it (``cond_fill`` ``"prior"``): before the chains the engine
    fills the masked entries once with its correction of the natural cubic spline (``training.model.prior_fill``).
    Models with other fills ignore it. ``forecaster``: the prior forecaster (a :class:`Prior` with ``anchor``
    ``"last"``), required where that fill has ``gap_fill`` ``"forecaster"``: the whole-frame gaps of the window
    are then filled from its forecasts into the gap from both sides (``training.model.fill_gaps``); unused
    otherwise."""
    if not isinstance(model, Denoiser):
        raise _checks.fail("model", "a tcd.engine.Denoiser", type(model).__name__)
    for name, p in (("fill", fill), ("forecaster", forecaster)):
        if p is not None and not isinstance(p, Prior):
            raise _checks.fail(name, "a tcd.engine.Prior or None", type(p).__name__)
    return _chains(
        functools.partial(_native.repair, model._native),
        "tcd repair",
        (observed, mask, num_samples, sampler),
        progress,
        _checks.streams(seed, first_sequence, sequences, threads),
        noise=_checks.optional_float32_array("noise", noise),
        fill=None if fill is None else fill._native,
        forecaster=None if forecaster is None else forecaster._native,
    )


def _chains(
    run: Callable[..., Any],
    desc: str,
    call: Tuple[Any, Any, Any, Any],
    progress: Progress,
    streams: _native._Streams,
    **rest: Any,
) -> Any:
    """Runs one of the binding's sampling calls (``run``: ``Denoiser.sample``, ``cascade`` or ``repair``, its
    models bound) with the checks the three share: ``call`` is its (observed, mask, num_samples, sampler) as the
    caller got them, ``progress`` shown as ``desc``; ``rest`` the call's own noise and models, already checked."""
    observed, mask, num_samples, sampler = call
    num_samples = _checks.machine_int("num_samples", num_samples)
    options = checked(sampler)
    with reporter(progress, desc) as callback:
        args: _native._Call = {
            "observed": _checks.float32_array("observed", observed),
            "mask": _checks.float32_array("mask", mask),
            "num_samples": num_samples,
            "options": options,
            "streams": streams,
            "progress": callback,
        }
        out = run(args, **rest)
    return dict(out) if isinstance(out, dict) else out


def supported_kernels() -> List[str]:
    """The kernel paths this CPU can run (``"portable"`` always; ``"avx2"``, ``"avx512"`` where the CPU has
    them), the best last. ``TCD_KERNEL`` (read when a model is loaded) accepts these and ``"auto"``."""
    return list(_native.supported_kernels())


def seeded_noise(
    seed: int,
    stage: int,
    num_samples: int,
    num_blocks: int,
    batch: int,
    num_features: int,
    length: int,
    first_sequence: int = 0,
) -> np.ndarray:
    """The engine's seeded noise streams in the injected layout (S, num_blocks, B, K, L): feeding
    this array as ``noise`` reproduces the seeded call exactly (``stage``: :data:`STAGE_SHORT` for
    :meth:`Denoiser.sample` / :func:`repair_raw` / the cascade's first stage, :data:`STAGE_LONG` for
    its second; :data:`STAGE_GENERATOR` with ``num_blocks`` 1, ``num_features`` z_dim and ``length`` 1 for
    :meth:`Generator.sample`, reshaped to (S, B, z_dim))."""
    shape = (
        _checks.machine_int("num_samples", num_samples),
        _checks.machine_int("num_blocks", num_blocks),
        _checks.machine_int("batch", batch),
        _checks.machine_int("num_features", num_features),
        _checks.machine_int("length", length),
    )
    seed, stage = _checks.machine_int("seed", seed, 128), _checks.machine_int("stage", stage, 128)
    return _native.seeded_noise(seed, stage, shape, _checks.machine_int("first_sequence", first_sequence, 128))
