"""The high-level API: a model directory, forecasts and repairs of pose sequences.

Poses are ``(T, J, 3)`` or ``(B, T, J, 3)`` float arrays in the model's joint layout and order
(``TCD.joint_names``), root-relative, in metres by default (``units="mm"`` for millimetres). NaN marks
a missing value; an explicit ``mask`` (1 = observed) may be given instead or as well. Outputs come
back in the caller's units, with the caller's batch axis (present or not).

One length rule, with or without a ``capture`` (then counted in frames at the model's frame rate):
the model sees a window of :attr:`TCD.obs_len` frames ending at the last input frame. A longer observation
is forecast from its last ``obs_len`` frames (:meth:`TCD.repair` refuses it: :func:`tcd.repair_file`
repairs any length); a shorter one is padded at the start with missing frames, which the model in-paints
like any missing value. ``repaired`` always has the input's frames: those before the window as given.
"""

from __future__ import annotations

import hashlib
import inspect
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, List, Literal, Optional, Tuple, Union, get_args

import numpy as np
from numpy.typing import ArrayLike

from . import _checks, _directory
from ._cascade import Call, Cascade, Mode
from ._directory import (
    check_parts,
    default_mode,
    uses_prior,
    BUNDLED_MODELS,
    SAMPLING_TASKS,
    checksum_text,
    default_model_dir,
    humaneva_model_dir,
)
from ._mixture import Mixture
from ._predict import repair_then_predict
from ._poses import Units, Window, check_units, model_window
from ._progress import Progress
from ._sampler import SamplerOptions, checked as checked_sampler
from ._tempo import Tempo
from ._wild_calls import Capture, WildWindow
from .engine import Denoiser, Generator, Prior, repair_raw

__all__ = [
    "TCD",
    "Forecast",
    "Repair",
    "load",
    "forecast",
    "predict",
    "repair",
    "default_model_dir",
    "humaneva_model_dir",
    "BUNDLED_MODELS",
]

PathLike = Union[str, "os.PathLike[str]"]

#: the samples a repair averages when a call names none and the directory has no repair fill
#: (:attr:`TCD.repair_samples`); with one, 0: the fill alone
REPAIR_SAMPLES = 5

#: how :meth:`TCD.predict` fills missing observation entries before the prior forecasts
Fill = Literal["auto", "model", "spline", "linear"]
FILLS: Tuple[str, ...] = get_args(Fill)


@dataclass(frozen=True, eq=False)
class Forecast:
    """The result of :meth:`TCD.forecast` (arrays in the caller's units; ``B`` only if the input had it).

    * ``mean``: ``(B?, H, J, 3)``, the mean over samples of the H forecast frames (:meth:`TCD.predict`:
      the deterministic point forecast);
    * ``samples``: ``(S, B?, H, J, 3)``; ``None`` from :meth:`TCD.predict`, which draws no samples;
    * ``repaired``: the observation with its missing entries filled (same shape as the input; observed
      entries are returned unchanged, and frames before the model's window as given);
    * ``seed``: the seed used (drawn from ``os.urandom`` when none was given): pass it back to reproduce;
    * ``times``: ``(H,)`` seconds of each forecast frame after the last observed one (None when the model
      does not record its frame rate).
    """

    mean: np.ndarray
    samples: Optional[np.ndarray]
    repaired: np.ndarray
    seed: int
    #: seconds of each forecast frame after the last observed frame (at the caller's frame rate)
    times: Optional[np.ndarray] = None

    def __repr__(self) -> str:
        samples = "None" if self.samples is None else _checks.shape_str(self.samples.shape)
        return (
            f"Forecast(mean={_checks.shape_str(self.mean.shape)}, samples={samples}, "
            f"repaired={_checks.shape_str(self.repaired.shape)}, seed={self.seed})"
        )


@dataclass(frozen=True, eq=False)
class Repair:
    """The result of :meth:`TCD.repair` (in the caller's units, dtype and batch axis).

    * ``poses``: the observation with its missing entries filled, the shape of the input (observed entries
      are returned unchanged);
    * ``seed``: the seed used (drawn from ``os.urandom`` when none was given): pass it back to reproduce.
    """

    poses: np.ndarray
    seed: int

    def __repr__(self) -> str:
        return f"Repair(poses={_checks.shape_str(self.poses.shape)}, seed={self.seed})"


#: the modes :meth:`TCD.forecast` takes (:mod:`tcd._cascade`)
MODES = (Cascade, Mixture, Tempo)


def _check_mode(mode: Any) -> Mode:
    if not isinstance(mode, MODES):
        raise _checks.fail(
            "mode", "None, tcd.Cascade(), tcd.Mixture(share) or tcd.Tempo(lo, hi)", f"{mode!r} ({type(mode).__name__})"
        )
    return mode


def _seed(seed: Optional[int]) -> int:
    s = _checks.optional_machine_int("seed", seed, 128)  # its range (0..2**64 - 1) is the engine's to check
    return int.from_bytes(os.urandom(8), "little") if s is None else s


class TCD:
    """A Temporal Cascaded Diffusion model directory: short-term and long-term denoisers (and an
    optional repair model), or a generator directory without them (an MLP generator around its prior
    forecaster, :data:`tcd._directory.GENERATOR_ONLY`). Load with :func:`tcd.load`. Immutable and thread-safe."""

    def __init__(
        self,
        short: Optional[Denoiser],
        long: Optional[Denoiser],
        repair: Optional[Denoiser] = None,
        path: Optional[PathLike] = None,
        threads: Optional[int] = None,
        file_sha256: Optional[Dict[str, str]] = None,
        prior: Optional[Prior] = None,
        sampling: Optional[Dict[str, SamplerOptions]] = None,
        repair_fill: Optional[Prior] = None,
        generator: Optional[Generator] = None,
        mode: Optional[Mode] = None,
    ) -> None:
        self.short = short
        self.long = long
        self.repair_model = repair
        #: the deterministic prior forecaster of :meth:`predict` (``prior.safetensors``), or None
        self.prior = prior
        #: the repair model's fill (``repair_fill.safetensors``: a :class:`tcd.engine.Prior` with ``anchor``
        #: ``"window"``, its correction of the spline), for a repair model conditioned on it; else None
        self.repair_fill = repair_fill
        self.path = None if path is None else Path(path)
        self.threads = _checks.threads(threads)
        unknown = sorted(set(sampling or {}) - set(SAMPLING_TASKS))
        if unknown:
            raise ValueError(f"sampling: unknown task {unknown[0]!r} (tasks: {', '.join(SAMPLING_TASKS)})")
        #: the sampler each task uses when a call names none, by task (``"forecast"``, ``"repair"``): the model
        #: directory's ``sampling.json`` (chosen from measurements: docs/samplers.md), else
        #: :class:`SamplerOptions`' defaults. A call's ``sampler`` replaces it (see :meth:`sampler_options`).
        self.sampling: Dict[str, SamplerOptions] = {
            t: (sampling or {}).get(t) or SamplerOptions() for t in SAMPLING_TASKS
        }
        #: the MLP sample generator (``generator.safetensors``: :class:`tcd.engine.Generator`), or None
        self.generator = generator
        #: the mode of a :meth:`forecast` that names none (:mod:`tcd._cascade`): the model directory's
        #: ``sampling.json`` (``"forecast_generator_share"``: :class:`tcd.Mixture`, ``"forecast_tempo"``:
        #: :class:`tcd.Tempo`), else :class:`tcd.Cascade` (``Mixture(1)``, the generator alone, without a cascade)
        self.forecast_mode: Mode = default_mode(short) if mode is None else _check_mode(mode)
        #: SHA-256 (hex) of each weight file, by file name; empty when built from Denoisers directly.
        self.file_sha256: Dict[str, str] = dict(file_sha256 or {})
        #: SHA-256 (hex) identifying the model: the digest of its ``SHA256SUMS`` text (None without files).
        self.sha256: Optional[str] = (
            hashlib.sha256(checksum_text(self.file_sha256).encode()).hexdigest() if self.file_sha256 else None
        )
        check_parts(path, short, long, repair, prior, repair_fill, generator, self.forecast_mode)
        #: the roles whose model is conditioned on the prior forecaster (``cond_fill`` ``"prior"``)
        self._prior_roles = tuple(role for role, m in (("short", short), ("long", long)) if m and uses_prior(m))
        #: the network whose window the calls take: the short-term model, or the generator without a cascade
        self._front: Union[Denoiser, Generator] = short if short is not None else generator  # type: ignore[assignment]

    def _window(
        self,
        obs: ArrayLike,
        mask: Optional[ArrayLike],
        units: Units,
        capture: Optional[Capture],
        repair: bool = False,
    ) -> Union[Window, WildWindow]:
        """The call's poses in the model's window: as given (the model's layout) or, with a ``capture``,
        converted from the wild (:mod:`tcd._wild_calls`); either converts the model's outputs back."""
        if capture is None:
            w = model_window(obs, mask, self.num_joints, self.obs_len, units, repair=repair)
            w.times = None if self.fps is None else np.arange(1, self.horizon + 1) / float(self.fps)
            return w
        if not isinstance(capture, Capture):
            raise _checks.fail("capture", "None or a tcd.Capture", f"{capture!r} ({type(capture).__name__})")
        ww = WildWindow(self, obs, mask, capture=capture, units=units, frames=self.obs_len)
        if repair:
            ww.check_one_window(self)
        return ww

    def _repair_fills(self, den: Denoiser) -> Dict[str, Optional[Prior]]:
        """What a repair by ``den`` runs with, as :func:`tcd.engine.repair_raw`'s keywords: ``fill``, the
        directory's repair fill for its repair model (None for another denoiser: the short-term model
        in-painting), and ``forecaster``, the directory's prior forecaster beside that fill (the engine uses it
        where the fill's ``gap_fill`` is ``"forecaster"`` and ignores it otherwise)."""
        fill = self.repair_fill if den is self.repair_model else None
        return {"fill": fill, "forecaster": self.prior if fill is not None else None}

    def _repair_denoiser(self) -> Denoiser:
        """The denoiser a repair runs: the repair model, else the short-term model in-painting; a
        ``FileNotFoundError`` in a directory with neither (a generator directory)."""
        den = self.repair_model if self.repair_model is not None else self.short
        if den is None:
            raise FileNotFoundError(
                f"The model directory {self.path} has neither a repair model (repair.safetensors) nor the "
                "cascade's short-term model to in-paint with: it cannot repair. TCD.predict(obs, mask) fills "
                "the gaps with the spline instead (fill='spline')."
            )
        return den

    def _repairer(
        self,
        num_samples: Optional[int],
        seed: Optional[int],
        sampler: Optional[SamplerOptions],
        units: Units,
        threads: Optional[int],
        progress: Progress,
    ) -> Tuple[int, Units, Optional[int], Callable[[np.ndarray, np.ndarray], np.ndarray]]:
        """A repair's arguments checked (:meth:`repair`, :meth:`predict`'s model fill) and the repair itself:
        ``(seed, units, threads, run)``, ``run(observed, seen)`` the repair model's mean (B, K, T) in the engine's
        layout (the short-term model in-painting where the directory has no repair model)."""
        num_samples = self.repair_samples if num_samples is None else num_samples
        num_samples, sampling, units, threads = self._common("repair", num_samples, sampler, units, threads)
        seed = _seed(seed)

        def run(observed: np.ndarray, seen: np.ndarray) -> np.ndarray:
            den = self._repair_denoiser()
            return repair_raw(
                den,
                observed,
                seen,
                num_samples=num_samples,
                seed=seed,
                threads=threads,
                progress=progress,
                sampler=sampling,
                **self._repair_fills(den),
            )["mean"]

        return seed, units, threads, run

    # ------------------------------------------------------------------ description
    @property
    def repair_samples(self) -> int:
        """The ``num_samples`` of a repair (:meth:`repair`, :meth:`predict`'s model fill, :func:`tcd.repair_file`,
        ``tcd repair``) whose call names none: 0, the repair fill alone, where the directory has a repair fill
        (the bundled one does: on the repair benchmark its fill alone is below the mean of 5 samples around it
        on every pattern and on 231-254 of 256 windows each, docs/repair.md "The fill alone"), else
        :data:`REPAIR_SAMPLES` (5)."""
        return 0 if self.repair_fill is not None else REPAIR_SAMPLES

    @property
    def obs_len(self) -> int:
        """Observed frames a forecast conditions on (TCD: 50)."""
        return self._front.obs_len

    @property
    def horizon(self) -> int:
        """Forecast frames H (TCD: 25)."""
        if self.short is None or self.long is None:
            return self._front.pred_len  # type: ignore[union-attr]
        return self.long.seq_len - self.short.obs_len

    @property
    def num_joints(self) -> int:
        return self._front.num_features // 3

    @property
    def num_train_timesteps(self) -> Optional[int]:
        """The diffusion's training steps (None without a cascade)."""
        return None if self.short is None else self.short.num_train_timesteps

    @property
    def data(self) -> Dict[str, Any]:
        """The ``data`` section of the short-term model's config (the generator's without a cascade): dataset,
        fps, units, joint_names, ..."""
        return self._front._section("data")

    @property
    def joint_names(self) -> Optional[List[str]]:
        names = self.data.get("joint_names")
        return list(names) if names else None

    @property
    def fps(self) -> Optional[float]:
        return self.data.get("fps")

    @property
    def config(self) -> Dict[str, Dict[str, Any]]:
        """Each model's ``tcd_config``, by role."""
        roles = (("short", self.short), ("long", self.long), ("repair", self.repair_model))
        roles += (("prior", self.prior), ("generator", self.generator))
        return {role: m.config for role, m in roles if m is not None}

    def __repr__(self) -> str:
        return (
            f"TCD(path={str(self.path)!r}, obs_len={self.obs_len}, horizon={self.horizon}, "
            f"num_joints={self.num_joints}, repair_model={self.repair_model is not None}, "
            f"prior={self.prior is not None}, generator={self.generator is not None})"
        )

    # ------------------------------------------------------------------ inference
    def sampler_options(self, task: str, **changes: Any) -> SamplerOptions:
        """The model's sampler for ``task`` (``"forecast"`` or ``"repair"``, :attr:`sampling`) with the fields named
        in ``changes`` changed: ``m.forecast(obs, sampler=m.sampler_options("forecast", num_inference_steps=10))``.
        A different ``sampler`` drops the defaults' other fields (:meth:`SamplerOptions.build`)."""
        if task not in SAMPLING_TASKS:
            raise ValueError(f"task must be one of {', '.join(SAMPLING_TASKS)}, got {task!r}")
        return SamplerOptions.build(self.sampling[task], **changes)

    def _common(
        self, task: str, num_samples: int, sampler: Optional[SamplerOptions], units: Units, threads: Optional[int]
    ) -> Tuple[int, SamplerOptions, Units, Optional[int]]:
        """The arguments every call checks before any work; ``sampler`` comes back as the call's sampler (the
        model's default for ``task`` where it is None)."""
        num_samples = _checks.machine_int("num_samples", num_samples)  # ranges: the engine's
        sampling = self.sampling[task] if sampler is None else checked_sampler(sampler)
        units = check_units(units)
        threads = _checks.optional_machine_int("threads", threads)
        return num_samples, sampling, units, self.threads if threads is None else threads

    def forecast(
        self,
        obs: ArrayLike,
        mask: Optional[ArrayLike] = None,
        *,
        num_samples: int = 5,
        seed: Optional[int] = None,
        units: Units = "m",
        threads: Optional[int] = None,
        progress: Progress = False,
        capture: Optional[Capture] = None,
        mode: Optional[Mode] = None,
        sampler: Optional[SamplerOptions] = None,
    ) -> Forecast:
        """Forecasts the next :attr:`horizon` frames of ``obs``.

        Args:
            obs: ``(T, J, 3)`` or ``(B, T, J, 3)``, J = :attr:`num_joints`, in the model's joint order,
                root-relative; NaN marks a missing value. Any T >= 1: the forecast conditions on the last
                :attr:`obs_len` (50) frames, a shorter observation padded at the start with missing frames
                (the length rule of :mod:`tcd._model`; a forecast from fewer frames knows less).
            mask: optional, 1 = observed / 0 = missing, shape ``obs.shape`` or ``obs.shape[:-1]`` (per joint).
                Entries with mask 0 are ignored (NaN or not); NaN where mask is 1 is an error.
            num_samples: S, samples per sequence (and per cascade stage). TCD: 5.
            seed: the noise seed (an integer in [0, 2**64)); ``None`` draws one from ``os.urandom``
                (recorded in ``Forecast.seed``). Results do not depend on the thread count or the batch.
            units: ``"m"`` (default), ``"cm"`` or ``"mm"``: the units of ``obs`` and of every output.
            threads: worker threads (``None``: the value given to :func:`tcd.load`, else all cores).
            progress: ``True`` shows a tqdm bar on stderr; a callable ``f(done, total)`` gets the count of
                denoiser forwards, about ten times a second (raising in it stops the call). Ctrl-C stops the
                call (KeyboardInterrupt) within about 0.1 s plus one forward, whatever ``progress`` is.
            capture: poses from the wild, a :class:`tcd.Capture` (their layout, frame rate and up axis;
                :mod:`tcd.wild`); ``None``: the model's layout and frame rate. The forecast comes back in the
                capture's layout, coordinates and frame rate (``Forecast.times``).
            mode: where the samples come from (:mod:`tcd._cascade`): :class:`tcd.Cascade`, :class:`tcd.Mixture`
                (a share from the directory's MLP generator) or :class:`tcd.Tempo` (each sample at its own tempo);
                ``None`` the model's default (:attr:`forecast_mode`: ``Mixture(0.5)`` for the bundled HumanEva-I
                model, the cascade for the Human3.6M one).
            sampler: a :class:`tcd.SamplerOptions`; ``None`` the model's default (``sampling["forecast"]``: the
                bundled Human3.6M and HumanEva-I models one DDIM step, chosen from docs/samplers.md; a directory
                without ``sampling.json`` the paper's DDPM over every training step). To change one field of the
                default: :meth:`sampler_options`.
        """
        num_samples, sampling, units, threads = self._common("forecast", num_samples, sampler, units, threads)
        mode = self.forecast_mode if mode is None else _check_mode(mode)
        call = Call(
            short=self.short,
            long=self.long,
            conditioning=self.prior if self._prior_roles else None,
            prior=self.prior,
            generator=self.generator,
            num_samples=num_samples,
            seed=_seed(seed),
            threads=threads,
            progress=progress,
            sampler=sampling,
        )
        w = self._window(obs, mask, units, capture)
        mean, samples, repaired, times = w.forecast(mode.draw(call, w.observed, w.mask))
        return Forecast(mean=mean, samples=samples, repaired=repaired, seed=call.seed, times=times)

    def repair(
        self,
        obs: ArrayLike,
        mask: Optional[ArrayLike] = None,
        *,
        num_samples: Optional[int] = None,
        seed: Optional[int] = None,
        units: Units = "m",
        threads: Optional[int] = None,
        progress: Progress = False,
        capture: Optional[Capture] = None,
        sampler: Optional[SamplerOptions] = None,
    ) -> Repair:
        """Fills the missing entries of ``obs`` (same arguments as :meth:`forecast`) with the mean of
        ``num_samples`` samples of the repair model (the short-term model when the directory has no
        ``repair.safetensors``), sampled by ``sampler`` (``None``: the model's ``sampling["repair"]``, DDPM over 10
        steps for the bundled Human3.6M model). ``obs`` spans
        at most the model's window (:attr:`obs_len` frames, at the model's frame rate with a ``capture``; a
        shorter one is padded at the start with missing frames; longer ones: :func:`tcd.repair_file`).

        ``num_samples=0`` returns the repair fill alone (``repair_fill.safetensors``, which the repair model
        is conditioned on; an ``InvalidInputError`` naming ``num_samples`` for a directory without one): the
        window the chains would start from, deterministic (the seed and sampler unused) and one forward of the
        fill instead of the chains. On the repair benchmark the bundled fill alone is 5-7 % below the mean of
        5 samples around it on every pattern (docs/repair.md, "The fill alone"), so it is the default where a
        directory has a fill: ``num_samples=None`` is :attr:`repair_samples` (0 for the bundled model, else 5).

        Returns a :class:`Repair`: ``poses`` of the shape of ``obs`` (observed entries unchanged) and the
        ``seed`` used (drawn from ``os.urandom`` when ``seed`` is None): pass it back to reproduce."""
        seed_used, units, threads, run = self._repairer(num_samples, seed, sampler, units, threads, progress)
        w = self._window(obs, mask, units, capture, repair=True)
        return Repair(poses=w.repaired(run(w.observed, w.mask)), seed=seed_used)

    def predict(
        self,
        obs: ArrayLike,
        mask: Optional[ArrayLike] = None,
        *,
        fill: Fill = "auto",
        num_samples: Optional[int] = None,
        seed: Optional[int] = None,
        units: Units = "m",
        threads: Optional[int] = None,
        progress: Progress = False,
        capture: Optional[Capture] = None,
        sampler: Optional[SamplerOptions] = None,
    ) -> Forecast:
        """The deterministic point forecast of the next :attr:`horizon` frames by the prior
        (``prior.safetensors``: a siMLPe-class network, one forward per 10 frames, no sampling), with the
        inputs and conventions of :meth:`forecast` (mask/NaN, units, batches, the length rule, ``capture``).

        An observation with missing entries is repaired first, the paper's repair-then-predict pipeline:
        ``fill="auto"`` (default) uses the repair model where the directory has one (its sampler: the
        ``num_samples`` (default :attr:`repair_samples`: the bundled model's fill alone), ``seed`` and ``sampler``
        arguments, as in :meth:`repair`) and the natural
        cubic spline otherwise; ``"model"`` the repair model (the short-term model without one); ``"spline"`` or
        ``"linear"`` the fills of :func:`tcd.interpolate` (a joint never observed in the window cannot be
        filled that way: an error). A complete observation goes to the prior as given.

        Returns a :class:`Forecast` whose ``mean`` is the point forecast, ``samples`` ``None``,
        ``repaired`` the filled observation and ``seed`` the repair's seed. Raises ``FileNotFoundError`` when
        the model directory has no ``prior.safetensors``."""
        if self.prior is None:
            raise FileNotFoundError(
                f"The model directory {self.path} has no prior.safetensors: TCD.predict needs "
                "the prior forecaster (the bundled model has one; see MODEL_CARD.md)."
            )
        if _checks.text("fill", fill, FILLS) not in FILLS:
            raise _checks.fail("fill", "one of " + ", ".join(repr(f) for f in FILLS), repr(fill))
        seed_used, units, threads, run = self._repairer(num_samples, seed, sampler, units, threads, progress)
        if fill == "auto":
            fill = "model" if self.repair_model is not None else "spline"
        w = self._window(obs, mask, units, capture)
        prior, horizon = self.prior, self.horizon
        out = repair_then_predict(prior, horizon, w.observed, w.mask, fill=fill, repair=run, threads=threads)
        mean, _, repaired, times = w.forecast(out)
        return Forecast(mean=mean, samples=None, repaired=repaired, seed=seed_used, times=times)


def load(path: Optional[PathLike] = None, *, threads: Optional[int] = None) -> TCD:
    """Loads a model directory: ``short.safetensors`` + ``long.safetensors`` (+ ``repair.safetensors``), as
    written by ``python -m training.export``, or a generator directory (``generator.safetensors`` and the
    ``prior.safetensors`` it samples around, no cascade). ``path=None`` loads the bundled default model; a
    bundled model's name (:data:`BUNDLED_MODELS`: ``"h36m"``, the default; ``"humaneva"``, the HumanEva-I
    model; ``"h36m-stochastic"``, the Human3.6M Setting-A generator directory) loads that one: a string equal
    to a name is the bundled model, so pass a local directory of that name as ``"./humaneva"`` or a ``Path``.

    Raises ``FileNotFoundError`` when a file is missing (:class:`tcd.exceptions.ModelNotBundledError`, one,
    for a bundled model this installation does not hold), :class:`tcd.exceptions.WeightsError` when a file
    is invalid or the files do not fit together."""
    threads = _checks.threads(threads)
    f = _directory.read(path)
    return TCD(
        f.short,
        f.long,
        f.repair,
        path=f.path,
        threads=threads,
        file_sha256=f.file_sha256,
        prior=f.prior,
        sampling=f.sampling,
        repair_fill=f.repair_fill,
        generator=f.generator,
        mode=f.forecast_mode,
    )


_default: Optional[TCD] = None
_default_lock = threading.Lock()


def _default_model() -> TCD:
    global _default
    with _default_lock:
        if _default is None:
            _default = load(None)
        return _default


def _on_default_model(name: str) -> Callable[..., Any]:
    """:class:`TCD`'s method ``name`` on the bundled default model (:func:`load`, loaded at the first call), with
    that method's signature less ``self``: one signature, the method's, which checks every argument."""
    method = getattr(TCD, name)

    def call(*args: Any, **kwargs: Any) -> Any:
        return method(_default_model(), *args, **kwargs)

    signature = inspect.signature(method)
    call.__signature__ = signature.replace(parameters=list(signature.parameters.values())[1:])  # type: ignore[attr-defined]
    call.__annotations__ = dict(method.__annotations__)
    call.__name__ = call.__qualname__ = name
    call.__doc__ = f":meth:`TCD.{name}` with the bundled default model (see :func:`load`)."
    return call


forecast = _on_default_model("forecast")
predict = _on_default_model("predict")
repair = _on_default_model("repair")
