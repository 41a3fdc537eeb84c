"""The high-level API: a model directory, forecasts and repairs of pose sequences.

Poses are ``(T, J, 3)`` or ``(B, T, J, 3)`` float arrays in the model's joint layout and order
(``TCD.joint_names``), root-relative, in metres by default (``units="mm"`` for millimetres). NaN marks
a missing value; an explicit ``mask`` (1 = observed) may be given instead or as well. Outputs come
back in the caller's units, with the caller's batch axis (present or not).

One length rule, with or without ``layout`` / ``fps`` (then counted in frames at the model's frame rate):
the model sees a window of :attr:`TCD.obs_len` frames ending at the last input frame. A longer observation
is forecast from its last ``obs_len`` frames (:meth:`TCD.repair` refuses it: :func:`tcd.repair_file`
repairs any length); a shorter one is padded at the start with missing frames, which the model in-paints
like any missing value. ``repaired`` always has the input's frames: those before the window as given.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Literal, Optional, Tuple, Union, get_args

import numpy as np
from numpy.typing import ArrayLike

from . import _checks, _wild_calls
from ._poses import UNIT_SCALE, Units, check_units, check_window, validate_poses
from ._progress import Progress
from .engine import Denoiser, Generator, Prior, cascade_raw, repair_raw
from . import _native
from .exceptions import InvalidInputError, ModelNotBundledError, WeightsError
from ._sampler import SamplerOptions
from ._tempo import Tempo, check_tempo, tempo_forecast
from .wild import Up

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

#: the prior forecaster's file in a model directory (:attr:`TCD.prior`)
PRIOR_FILE = "prior.safetensors"
#: the repair model's fill in a model directory (:attr:`TCD.repair_fill`), for a repair model conditioned on it
REPAIR_FILL_FILE = "repair_fill.safetensors"
#: the MLP sample generator in a model directory (:attr:`TCD.generator`), optional: a share of the forecast's
#: samples drawn around the prior's forecast (``sampling.json`` ``"forecast_generator_share"``)
GENERATOR_FILE = "generator.safetensors"

#: a model directory's own sampler defaults (:attr:`TCD.sampling`), optional: ``{"forecast": {...}, "repair":
#: {...}, "why": "...", "forecast_tempo": [lo, hi]}``, each task's object holding :class:`SamplerOptions` fields; a
#: task or field left out takes :class:`SamplerOptions`' defaults (the paper's DDPM over every training step);
#: ``"forecast_tempo"`` is :attr:`TCD.forecast_tempo` (:mod:`tcd._tempo`), optional; ``"forecast_generator_share"``
#: is :attr:`TCD.generator_share`, optional (0 when absent)
SAMPLING_FILE = "sampling.json"
#: the key of ``sampling.json`` holding :attr:`TCD.forecast_tempo`
TEMPO_KEY = "forecast_tempo"
#: the key of ``sampling.json`` holding :attr:`TCD.generator_share`
GENERATOR_SHARE_KEY = "forecast_generator_share"
#: the tasks a model directory may set sampler defaults for: ``"forecast"`` the cascade (:meth:`TCD.forecast`),
#: ``"repair"`` the repair model (:meth:`TCD.repair`, the model fill of :meth:`TCD.predict`, :func:`tcd.repair_file`)
SAMPLING_TASKS = ("forecast", "repair")

#: the samples a repair averages when a call names none and the directory has no repair fill
#: (:attr:`TCD.repair_samples`); with one, 0: the fill alone
REPAIR_SAMPLES = 5

#: how :meth:`TCD.predict` fills missing observation entries before the prior forecasts
Fill = Literal["auto", "model", "spline", "linear"]
FILLS: Tuple[str, ...] = get_args(Fill)


def default_model_dir() -> Path:
    """Where the bundled default model lives (``tcd/weights/``)."""
    return Path(__file__).resolve().parent / "weights"


def humaneva_model_dir() -> Path:
    """Where the bundled HumanEva-I model lives (``tcd/weights_humaneva/``), once one is trained and bundled
    (docs/training.md, "HumanEva-I"): ``tcd.load("humaneva")``."""
    return Path(__file__).resolve().parent / "weights_humaneva"


#: the names :func:`load` takes for the bundled model directories: ``"h36m"`` the default (Human3.6M, 50 -> 25
#: frames at 25 fps), ``"humaneva"`` the HumanEva-I model (15 -> 60 frames at 60 Hz), when the installation has it
BUNDLED_MODELS = ("h36m", "humaneva")


def _bundled_dir(name: str) -> Path:
    """The directory of the bundled model ``name``; :class:`ModelNotBundledError` when it is not installed."""
    if name == "h36m":
        d = default_model_dir()
        if not (d / "short.safetensors").is_file():
            raise ModelNotBundledError(
                "No default model is bundled with tcd yet: pass a model directory, e.g. "
                "tcd.load('path/to/model') or `--model DIR` on the command line (a directory holding "
                "short.safetensors and long.safetensors, as written by `python -m training.export`).",
                name,
                str(d),
            )
        return d
    d = humaneva_model_dir()
    if not (d / "short.safetensors").is_file():
        raise ModelNotBundledError(
            f"The HumanEva-I model is not bundled with this installation of tcd yet ({d} holds no "
            'short.safetensors). Train and export it as docs/training.md (section "HumanEva-I") says, then '
            "pass its directory, e.g. tcd.load('models/humaneva') or `--model models/humaneva`; a release that "
            "bundles it opens it with tcd.load('humaneva').",
            name,
            str(d),
        )
    return d


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


class _Poses:
    """A validated pose input and the model's window of it, in the engine's layout."""

    def __init__(
        self,
        observed: np.ndarray,
        mask: np.ndarray,
        original: np.ndarray,
        full_mask: np.ndarray,
        batched: bool,
        scale: float,
        dtype: np.dtype,
        start: int,
    ) -> None:
        self.observed = observed  # (B, K, W) float32, model units, 0 where missing: the window
        self.mask = mask  # (B, K, W) float32 0/1
        self.original = original  # (B, T, J, 3) the caller's values
        self.full_mask = full_mask  # (B, T, J, 3) bool
        self.batched = batched
        self.scale = scale
        self.dtype = dtype
        self.start = start  # the caller's frame at the window's first frame (< 0: padded)

    def poses(self, bkl: np.ndarray) -> np.ndarray:
        """(..., B, K, L) float32 model units -> (..., B?, L, J, 3) in the caller's units and dtype."""
        *lead, b, k, length = bkl.shape
        j = k // 3
        out = np.swapaxes(bkl, -1, -2).reshape(*lead, b, length, j, 3).astype(self.dtype)
        if self.scale != 1.0:
            out = out * self.dtype.type(self.scale)
        return out if self.batched else out[..., 0, :, :, :]

    def repaired(self, bkt: np.ndarray) -> np.ndarray:
        """The window's repair (B, K, W) -> the caller's observation filled (its shape, units and dtype)."""
        out = self.poses(bkt)
        original = self.original if self.batched else self.original[0]
        full_mask = self.full_mask if self.batched else self.full_mask[0]
        if self.start < 0:  # the padded frames dropped
            out = out[..., -self.start :, :, :]
        elif self.start > 0:  # the frames before the window as given
            out = np.concatenate([original[..., : self.start, :, :].astype(self.dtype, copy=False), out], axis=-3)
        # Observed entries bit for bit as given (also when units or dtype needed a conversion).
        return np.where(full_mask, original.astype(self.dtype, copy=False), out)


def _poses(
    obs: ArrayLike, mask: Optional[ArrayLike], num_joints: int, window: int, units: Units, *, repair: bool = False
) -> _Poses:
    """Checks ``obs`` / ``mask`` (see :meth:`TCD.forecast`) and converts the model's window of them (the
    module docstring's length rule: its last ``window`` frames, padded at the start with missing frames when
    shorter) to (B, K, window) float32. ``repair``: more than ``window`` frames is an error."""
    p = validate_poses(obs, mask, num_joints=num_joints, units=units)
    a4, full, dtype = p.values, p.observed, p.dtype
    b, t = a4.shape[:2]
    if repair and t > window:
        raise InvalidInputError(
            f"Argument `obs` must span at most the model's window ({window} frames) to be repaired in one call, "
            f"but received {t} frames: repair longer sequences with tcd.repair_file (overlapping windows).",
            "obs",
        )
    start = t - window
    if start < 0:
        pad = (b, -start) + a4.shape[2:]
        a4w = np.concatenate([np.zeros(pad, a4.dtype), a4], axis=1)
        full_w = np.concatenate([np.zeros(pad, bool), full], axis=1)
    else:
        a4w, full_w = a4[:, start:], full[:, start:]
    check_window(full_w, window, p.batched)
    scale = UNIT_SCALE[units]
    x = np.where(full_w, a4w, 0.0)
    if scale != 1.0:
        x = x / scale
    k = num_joints * 3
    observed = np.ascontiguousarray(x.astype(np.float32).reshape(b, window, k).transpose(0, 2, 1))
    mask_bkt = np.ascontiguousarray(full_w.astype(np.float32).reshape(b, window, k).transpose(0, 2, 1))
    return _Poses(observed, mask_bkt, a4, full, p.batched, scale, dtype, start)


def _seed(seed: Optional[int]) -> int:
    s = _checks.optional_machine_int("seed", seed, 128)  # its range (0..2**64 - 1) is the engine's to check
    return int.from_bytes(os.urandom(8), "little") if s is None else s


class TCD:
    """A Temporal Cascaded Diffusion model directory: short-term and long-term denoisers (and an
    optional repair model). Load with :func:`tcd.load`. Immutable and thread-safe."""

    def __init__(
        self,
        short: Denoiser,
        long: Denoiser,
        repair: Optional[Denoiser] = None,
        path: Optional[PathLike] = None,
        threads: Optional[int] = None,
        file_sha256: Optional[Dict[str, str]] = None,
        prior: Optional[Prior] = None,
        sampling: Optional[Dict[str, SamplerOptions]] = None,
        forecast_tempo: Tempo = None,
        repair_fill: Optional[Prior] = None,
        generator: Optional[Generator] = None,
        generator_share: float = 0.0,
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
        #: :class:`SamplerOptions`' defaults. A call's sampler keywords override it (see :meth:`sampler_options`).
        self.sampling: Dict[str, SamplerOptions] = {
            t: (sampling or {}).get(t) or SamplerOptions() for t in SAMPLING_TASKS
        }
        #: the tempo range :meth:`forecast` samples when a call names none (:mod:`tcd._tempo`): the model
        #: directory's ``sampling.json`` ``"forecast_tempo"``, else None (every sample at the observed tempo)
        self.forecast_tempo: Tempo = check_tempo(forecast_tempo, "forecast_tempo")
        #: the MLP sample generator (``generator.safetensors``: :class:`tcd.engine.Generator`), or None
        self.generator = generator
        #: the share of :meth:`forecast`'s samples the generator draws when a call names none: the model
        #: directory's ``sampling.json`` ``"forecast_generator_share"``, else 0 (every sample from the cascade)
        self.generator_share: float = check_generator_share(generator_share, "generator_share")
        #: SHA-256 (hex) of each weight file, by file name; empty when built from Denoisers directly.
        self.file_sha256: Dict[str, str] = dict(file_sha256 or {})
        #: SHA-256 (hex) identifying the model: the digest of its ``SHA256SUMS`` text (None without files).
        self.sha256: Optional[str] = (
            hashlib.sha256(_checksum_text(self.file_sha256).encode()).hexdigest() if self.file_sha256 else None
        )
        where = str(path) if path is not None else "the model"
        k = short.num_features
        if short.num_features % 3:
            raise WeightsError(f"{where}: the short-term model has num_features = {k}, not joints x 3.", short.path)
        if long.num_features != k:
            raise WeightsError(
                f"{where}: the long-term model has num_features = {long.num_features}, "
                f"but the short-term model has {k}.",
                long.path,
            )
        if long.obs_len != short.seq_len or long.seq_len <= short.obs_len:
            raise WeightsError(
                f"{where}: the long-term model's obs_len ({long.obs_len}) must equal the short-term "
                f"model's seq_len ({short.seq_len}).",
                long.path,
            )
        #: the roles whose model is conditioned on the prior forecaster (``cond_fill`` ``"prior"``)
        self._prior_roles = tuple(role for role, m in (("short", short), ("long", long)) if _uses_prior(m))
        if self._prior_roles and prior is None:
            missing = str(Path(path) / PRIOR_FILE) if path is not None else PRIOR_FILE
            roles = " and ".join(f"{r}-term" for r in self._prior_roles)
            raise WeightsError(
                f"{where}: the {roles} model is conditioned on the prior forecaster (cond_fill "
                f'"prior"), but {missing} is missing: the model directory must hold the prior '
                f"it was trained with.",
                missing,
            )
        if prior is not None and (prior.num_features != k or prior.obs_len > short.obs_len):
            raise WeightsError(
                f"{where}: the prior (num_features = {prior.num_features}, obs_len = {prior.obs_len}) "
                f"must match the short-term model (num_features = {k}) and read at most its "
                f"{short.obs_len} observed frames.",
                prior.path,
            )
        if prior is not None and prior.anchor != "last":
            raise WeightsError(
                f'{where}: {PRIOR_FILE} is a repair fill (anchor "{prior.anchor}"), not a forecaster (anchor "last").',
                prior.path,
            )
        if repair is not None and (repair.num_features != k or repair.obs_len != short.obs_len):
            raise WeightsError(
                f"{where}: the repair model (num_features = {repair.num_features}, obs_len = "
                f"{repair.obs_len}) must match the short-term model (num_features = {k}, obs_len = "
                f"{short.obs_len}).",
                repair.path,
            )
        if repair is not None and _uses_prior(repair) and repair_fill is None:
            missing = str(Path(path) / REPAIR_FILL_FILE) if path is not None else REPAIR_FILL_FILE
            raise WeightsError(
                f'{where}: the repair model is conditioned on its fill (cond_fill "prior"), but '
                f"{missing} is missing: the model directory must hold the fill it was trained with.",
                missing,
            )
        if repair_fill is not None and (
            repair is None
            or repair_fill.anchor != "window"
            or repair_fill.num_features != k
            or repair_fill.obs_len != repair.seq_len
        ):
            raise WeightsError(
                f'{where}: the repair fill (anchor "{repair_fill.anchor}", num_features = '
                f"{repair_fill.num_features}, obs_len = {repair_fill.obs_len}) must be a repair fill "
                f'(anchor "window") over the repair model\'s window (num_features = {k}, '
                f"{'no repair model' if repair is None else f'seq_len = {repair.seq_len}'}).",
                repair_fill.path,
            )
        if generator is not None and (
            prior is None
            or generator.num_features != k
            or prior.obs_len != short.obs_len
            or generator.obs_len != short.obs_len
            or generator.pred_len != long.seq_len - short.obs_len
        ):
            raise WeightsError(
                f"{where}: the generator (num_features = {generator.num_features}, obs_len = "
                f"{generator.obs_len}, pred_len = {generator.pred_len}) samples around the prior's "
                f"forecast, so the directory must hold a prior forecaster ({PRIOR_FILE}) reading the "
                f"short-term model's {short.obs_len} observed frames, and the generator must match "
                f"them (num_features = {k}, obs_len = {short.obs_len}, pred_len = the horizon, "
                f"{long.seq_len - short.obs_len}).",
                generator.path,
            )
        if self.generator_share and generator is None:
            raise WeightsError(
                f"{where}: generator_share = {self.generator_share}, but there is no generator ({GENERATOR_FILE}).",
                str(Path(path) / GENERATOR_FILE) if path is not None else GENERATOR_FILE,
            )
        if repair_fill is not None and repair_fill.gap_fill == "forecaster" and prior is None:
            missing = str(Path(path) / PRIOR_FILE) if path is not None else PRIOR_FILE
            raise WeightsError(
                f"{where}: the repair fill fills whole-frame gaps with the prior forecaster (gap_fill "
                f'"forecaster"), but {missing} is missing: the model directory must hold it.',
                missing,
            )

    def _repair_fills(self, den: Denoiser) -> Dict[str, Optional[Prior]]:
        """What a repair by ``den`` runs with, as :func:`tcd.engine.repair_raw`'s keywords: ``fill``, the
        directory's repair fill for its repair model (None for another denoiser: the short-term model
        in-painting), and ``forecaster``, the directory's prior forecaster beside that fill (the engine uses it
        where the fill's ``gap_fill`` is ``"forecaster"`` and ignores it otherwise)."""
        fill = self.repair_fill if den is self.repair_model else None
        return {"fill": fill, "forecaster": self.prior if fill is not None else None}

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
        return self.short.obs_len

    @property
    def horizon(self) -> int:
        """Forecast frames H (TCD: 25)."""
        return self.long.seq_len - self.short.obs_len

    @property
    def num_joints(self) -> int:
        return self.short.num_features // 3

    @property
    def num_train_timesteps(self) -> int:
        return self.short.num_train_timesteps

    @property
    def data(self) -> Dict[str, Any]:
        """The ``data`` section of the short-term model's config (dataset, fps, units, joint_names, ...)."""
        return dict(self.short.config.get("data") or {})

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
        out = {"short": self.short.config, "long": self.long.config}
        if self.repair_model is not None:
            out["repair"] = self.repair_model.config
        if self.prior is not None:
            out["prior"] = self.prior.config
        if self.generator is not None:
            out["generator"] = self.generator.config
        return out

    def __repr__(self) -> str:
        return (
            f"TCD(path={str(self.path)!r}, obs_len={self.obs_len}, horizon={self.horizon}, "
            f"num_joints={self.num_joints}, repair_model={self.repair_model is not None}, "
            f"prior={self.prior is not None}, generator={self.generator is not None})"
        )

    # ------------------------------------------------------------------ inference
    def sampler_options(self, task: str, **sampler: Any) -> SamplerOptions:
        """The sampler a call of ``task`` (``"forecast"`` or ``"repair"``) runs: the keywords it names over the
        model's defaults for the task (:attr:`sampling`; a different ``sampler`` drops the defaults' other
        fields, :meth:`SamplerOptions.build`)."""
        if task not in SAMPLING_TASKS:
            raise ValueError(f"task must be one of {', '.join(SAMPLING_TASKS)}, got {task!r}")
        return SamplerOptions.build(self.sampling[task], **sampler)

    def _common(
        self, task: str, num_samples: int, sampler: Dict[str, Any], units: Units, threads: Optional[int]
    ) -> Tuple[int, Dict[str, Any], Units, Optional[int]]:
        """The arguments every call checks before any work; the sampler keywords come back checked, all four
        given (the model's defaults for ``task`` filled in), for the low-level calls."""
        num_samples = _checks.machine_int("num_samples", num_samples)  # ranges: the engine's
        sampling = dataclasses.asdict(self.sampler_options(task, **sampler))
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
        layout: Optional[str] = None,
        fps: Optional[float] = None,
        up: Up = "y",
        tempo: Tempo = None,
        generator_share: Optional[float] = None,
        **sampler: Any,
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
            layout, fps, up: poses from the wild (:mod:`tcd.wild`): ``layout`` one of
                :data:`tcd.layouts.LAYOUTS` (``"h36m32"``, ``"h36m17"``, ``"smpl24"``, ``"coco17"``; J its
                joints) in world or camera coordinates with ``up`` the vertical axis (``"y"``, ``"z"``, ...
                or a unit vector), at ``fps`` frames per second, of any length, the same rule counted at the
                model's frame rate (and at least 2 observed frames, to measure the root's motion). The
                forecast comes back in the same layout, coordinates and frame rate (``Forecast.times``).
            **sampler: the sampler: ``sampler`` (``"ddpm"``, ``"ddim"``, ``"dpmpp2m"``),
                ``num_inference_steps``, ``eta``, ``timestep_spacing``, as :class:`tcd.SamplerOptions` defines
                and checks them; those not given are the model's defaults (``sampling["forecast"]``: the bundled
                Human3.6M and HumanEva-I models one DDIM step, chosen from docs/samplers.md; a directory
                without ``sampling.json`` the paper's DDPM over every training step).
                Any other keyword is a ``TypeError``.
            tempo: ``(lo, hi)`` with ``0 < lo <= 1 <= hi``: sample i of ``num_samples`` forecast from the
                observation replayed at its own tempo, spaced geometrically from ``lo`` to ``hi``
                (:mod:`tcd._tempo`: samples that differ in when a movement happens); ``(1, 1)`` every sample at
                the observed tempo; ``None`` the model's default (:attr:`forecast_tempo`; the bundled models set
                none: their samples' mean gets worse with it, MODEL_CARD.md "Tempo sampling").
            generator_share: in [0, 1]: ``floor(num_samples * generator_share)`` of the samples come from the
                directory's MLP generator (:attr:`generator`, one forward each, around the prior's forecast of the
                observation filled as the cascade's prior fill fills it), after the cascade's; ``None`` the
                model's default (:attr:`generator_share`: 0.5 for the bundled HumanEva-I model, whose best of 50
                samples is best half and half, MODEL_CARD.md; 0 for a directory without a generator). The
                cascade's stages run with the remaining samples; ``mean`` is the mean of all of them, and
                ``repaired`` the cascade's (the prior's fill where every sample is the generator's). Not with
                ``tempo``.
        """
        num_samples, sampling, units, threads = self._common("forecast", num_samples, sampler, units, threads)
        tempo = self.forecast_tempo if tempo is None else check_tempo(tempo)
        share = self.generator_share if generator_share is None else check_generator_share(generator_share)
        drawn = int(num_samples * share)  # the generator's samples; the cascade's are the rest
        if drawn and self.generator is None:
            raise InvalidInputError(
                f"Argument `generator_share` is {share}, but the model has no generator "
                f"({GENERATOR_FILE}): pass 0 or None.",
                "generator_share",
            )
        if drawn and tempo not in (None, (1.0, 1.0)):
            raise InvalidInputError(
                f"Argument `tempo` is {tempo}, but the generator draws {drawn} of the "
                f"{num_samples} samples at the observed tempo: pass generator_share=0 with a "
                "tempo.",
                "tempo",
            )
        seed = _seed(seed)
        prior = self.prior if self._prior_roles else None

        def cascade(observed: np.ndarray, seen: np.ndarray, n: int, streams=None) -> Dict[str, np.ndarray]:
            return cascade_raw(
                self.short,
                self.long,
                observed,
                seen,
                num_samples=n,
                seed=seed,
                threads=threads,
                progress=progress,
                prior=prior,
                sequences=streams,
                **sampling,
            )

        if drawn:
            run = lambda observed, seen: self._mixture(  # noqa: E731
                observed, seen, num_samples - drawn, drawn, seed, threads, cascade
            )
        elif tempo is None or tempo == (1.0, 1.0):
            run = lambda observed, seen: cascade(observed, seen, num_samples)  # noqa: E731
        else:
            run = lambda observed, seen: tempo_forecast(  # noqa: E731
                lambda o, m, ids: cascade(o, m, 1, ids),
                observed,
                seen,
                num_samples,
                tempo,
            )
        if layout is not None or fps is not None:
            mean, samples, repaired, times = _wild_calls.forecast(
                self, obs, mask, layout="h36m22" if layout is None else layout, fps=fps, up=up, units=units, run=run
            )
            return Forecast(mean=mean, samples=samples, repaired=repaired, seed=seed, times=times)
        p = _poses(obs, mask, self.num_joints, self.obs_len, units)
        out = run(p.observed, p.mask)
        return Forecast(
            mean=p.poses(out["mean"]),
            samples=p.poses(out["samples"]),
            repaired=p.repaired(out["repaired"]),
            seed=seed,
            times=None if self.fps is None else np.arange(1, self.horizon + 1) / float(self.fps),
        )

    def _mixture(
        self,
        observed: np.ndarray,
        seen: np.ndarray,
        cascaded: int,
        drawn: int,
        seed: int,
        threads: Optional[int],
        cascade,
    ) -> Dict[str, np.ndarray]:
        """:meth:`forecast`'s run with the generator: ``cascaded`` samples from ``cascade(observed, seen, n)`` and
        then ``drawn`` from the generator (its seeded streams, stage :data:`tcd.engine.STAGE_GENERATOR`), in the
        engine's layout (B, K, O) in, the cascade's dict out. The generator reads the observation as the
        cascade's prior fill fills it (the spline through each coordinate's observed frames) and the prior's
        forecast from that: one :meth:`tcd.engine.Prior.fill` over the window and the horizon."""
        b, k, o = observed.shape
        h = self.horizon
        window = np.concatenate([observed, np.zeros((b, k, h), np.float32)], axis=2).transpose(0, 2, 1)
        given = np.concatenate([seen, np.zeros((b, k, h), np.float32)], axis=2).transpose(0, 2, 1)
        filled = self.prior.fill(np.ascontiguousarray(window), np.ascontiguousarray(given), threads=threads)
        drawn_samples = self.generator.sample(filled[:, :o], filled[:, o:], drawn, seed=seed, threads=threads)
        drawn_samples = np.ascontiguousarray(drawn_samples.transpose(0, 1, 3, 2))  # (S', B, K, H)
        if not cascaded:
            return {
                "samples": drawn_samples,
                "mean": drawn_samples.mean(axis=0, dtype=np.float32),
                "repaired": np.ascontiguousarray(filled[:, :o].transpose(0, 2, 1)),
            }
        out = cascade(observed, seen, cascaded)
        samples = np.concatenate([out["samples"], drawn_samples])
        return {**out, "samples": samples, "mean": samples.mean(axis=0, dtype=np.float32)}

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
        layout: Optional[str] = None,
        fps: Optional[float] = None,
        up: Up = "y",
        **sampler: Any,
    ) -> Repair:
        """Fills the missing entries of ``obs`` (same arguments as :meth:`forecast`) with the mean of
        ``num_samples`` samples of the repair model (the short-term model when the directory has no
        ``repair.safetensors``), sampled as the sampler keywords say (those not given: the model's
        ``sampling["repair"]``: DDPM over 10 steps for the bundled Human3.6M model). ``obs`` spans
        at most the model's window (:attr:`obs_len` frames, at the model's frame rate with ``layout`` / ``fps``; a
        shorter one is padded at the start with missing frames; longer ones: :func:`tcd.repair_file`).

        ``num_samples=0`` returns the repair fill alone (``repair_fill.safetensors``, which the repair model
        is conditioned on; an ``InvalidInputError`` naming ``num_samples`` for a directory without one): the
        window the chains would start from, deterministic (the seed and sampler unused) and one forward of the
        fill instead of the chains. On the repair benchmark the bundled fill alone is 5-7 % below the mean of
        5 samples around it on every pattern (docs/repair.md, "The fill alone"), so it is the default where a
        directory has a fill: ``num_samples=None`` is :attr:`repair_samples` (0 for the bundled model, else 5).

        Returns a :class:`Repair`: ``poses`` of the shape of ``obs`` (observed entries unchanged) and the
        ``seed`` used (drawn from ``os.urandom`` when ``seed`` is None): pass it back to reproduce."""
        num_samples = self.repair_samples if num_samples is None else num_samples
        num_samples, sampling, units, threads = self._common("repair", num_samples, sampler, units, threads)
        seed = _seed(seed)
        model = self.repair_model if self.repair_model is not None else self.short
        if layout is not None or fps is not None:
            poses = _wild_calls.repair(
                self,
                model,
                obs,
                mask,
                layout="h36m22" if layout is None else layout,
                fps=fps,
                up=up,
                num_samples=num_samples,
                sampling=sampling,
                seed=seed,
                units=units,
                threads=threads,
                progress=progress,
            )
            return Repair(poses=poses, seed=seed)
        p = _poses(obs, mask, self.num_joints, self.obs_len, units, repair=True)
        out = repair_raw(
            model,
            p.observed,
            p.mask,
            num_samples=num_samples,
            seed=seed,
            threads=threads,
            progress=progress,
            **self._repair_fills(model),
            **sampling,
        )
        return Repair(poses=p.repaired(out["mean"]), seed=seed)

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
        layout: Optional[str] = None,
        fps: Optional[float] = None,
        up: Up = "y",
        **sampler: Any,
    ) -> Forecast:
        """The deterministic point forecast of the next :attr:`horizon` frames by the prior
        (``prior.safetensors``: a siMLPe-class network, one forward per 10 frames, no sampling), with the
        inputs and conventions of :meth:`forecast` (mask/NaN, units, batches, the length rule,
        ``layout``/``fps``/``up``).

        An observation with missing entries is repaired first, the paper's repair-then-predict pipeline:
        ``fill="auto"`` (default) uses the repair model where the directory has one (its sampler: the
        ``num_samples`` (default :attr:`repair_samples`: the bundled model's fill alone) and ``seed`` arguments
        and the sampler keywords, as in :meth:`repair`) and the natural
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
        num_samples = self.repair_samples if num_samples is None else num_samples
        num_samples, sampling, units, threads = self._common("repair", num_samples, sampler, units, threads)
        seed = _seed(seed)
        run = lambda observed, seen: self._predict_raw(  # noqa: E731
            observed,
            seen,
            fill=fill,
            num_samples=num_samples,
            sampling=sampling,
            seed=seed,
            threads=threads,
            progress=progress,
        )
        if layout is not None or fps is not None:
            mean, _, repaired, times = _wild_calls.forecast(
                self, obs, mask, layout="h36m22" if layout is None else layout, fps=fps, up=up, units=units, run=run
            )
            return Forecast(mean=mean, samples=None, repaired=repaired, seed=seed, times=times)
        p = _poses(obs, mask, self.num_joints, self.obs_len, units)
        out = run(p.observed, p.mask)
        return Forecast(
            mean=p.poses(out["mean"]),
            samples=None,
            repaired=p.repaired(out["repaired"]),
            seed=seed,
            times=None if self.fps is None else np.arange(1, self.horizon + 1) / float(self.fps),
        )

    def _predict_raw(
        self,
        observed: np.ndarray,
        seen: np.ndarray,
        *,
        fill: str,
        num_samples: int,
        sampling: Dict[str, Any],
        seed: int,
        threads: Optional[int],
        progress: Progress,
    ) -> Dict[str, Any]:
        """Repair-then-predict in the engine's layout: observed, seen (B, K, T) float32 (0 where missing) ->
        {"mean": (B, K, H) point forecast, "repaired": (B, K, T), "samples": None}."""
        repaired = observed
        missing = seen < 0.5
        if missing.any():
            if fill == "auto":
                fill = "model" if self.repair_model is not None else "spline"
            if fill == "model":
                den = self.repair_model if self.repair_model is not None else self.short
                out = repair_raw(
                    den,
                    observed,
                    seen,
                    num_samples=num_samples,
                    seed=seed,
                    threads=threads,
                    progress=progress,
                    **self._repair_fills(den),
                    **sampling,
                )
                repaired = np.where(missing, out["mean"], observed).astype(np.float32)
            else:
                never = missing.all(axis=-1)
                if never.any():
                    b, k = np.argwhere(never)[0]
                    raise InvalidInputError(
                        f"Argument `obs` has coordinate {k} of joint {k // 3} never observed in sequence {b}: "
                        f"fill={fill!r} interpolates along time and has nothing to start from; use fill='model'.",
                        "obs",
                    )
                repaired = np.ascontiguousarray(_native.interpolate(observed, seen, fill), dtype=np.float32)
                repaired = np.where(missing, repaired, observed)
        hist = np.ascontiguousarray(repaired[..., -self.prior.obs_len :].transpose(0, 2, 1))  # (B, T, K)
        mean = self.prior.predict(hist, self.horizon, threads=threads)  # (B, H, K)
        return {"mean": np.ascontiguousarray(mean.transpose(0, 2, 1)), "repaired": repaired, "samples": None}


def load(path: Optional[PathLike] = None, *, threads: Optional[int] = None) -> TCD:
    """Loads a model directory: ``short.safetensors`` + ``long.safetensors`` (+ ``repair.safetensors``), as
    written by ``python -m training.export``. ``path=None`` loads the bundled default model; a bundled
    model's name (:data:`BUNDLED_MODELS`: ``"h36m"``, the default, or ``"humaneva"``, the HumanEva-I model)
    loads that one: a string equal to a name is the bundled model, so pass a local directory of that name
    as ``"./humaneva"`` or a ``Path``.

    Raises ``FileNotFoundError`` when a file is missing (:class:`tcd.exceptions.ModelNotBundledError`, one,
    for a bundled model this installation does not hold), :class:`tcd.exceptions.WeightsError` when a file
    is invalid or the files do not fit together."""
    threads = _checks.threads(threads)
    bundled = path is None or (isinstance(path, str) and path in BUNDLED_MODELS)
    if bundled:
        d = _bundled_dir("h36m" if path is None else str(path))
    else:
        if not isinstance(path, (str, os.PathLike)):
            raise _checks.fail("path", "a model directory (str or os.PathLike) or None", repr(path))
        d = Path(path)
        if not d.exists():
            raise FileNotFoundError(f"The model directory {d} does not exist.")
        if not d.is_dir():
            raise NotADirectoryError(
                f"{d} is not a directory: pass the model directory that holds short.safetensors and long.safetensors."
            )
    for role in ("short", "long"):
        if not (d / f"{role}.safetensors").is_file():
            raise FileNotFoundError(
                f"The model directory {d} has no {role}.safetensors: a model directory holds "
                "short.safetensors and long.safetensors (and optionally repair.safetensors)."
            )
    names = [f"{r}.safetensors" for r in ROLES if (d / f"{r}.safetensors").is_file()]
    blobs = {n: (d / n).read_bytes() for n in names}
    digests = {n: hashlib.sha256(b).hexdigest() for n, b in blobs.items()}
    _verify_checksums(d, digests, bundled=bundled)
    short = Denoiser.from_bytes(blobs["short.safetensors"], str(d / "short.safetensors"))
    long = Denoiser.from_bytes(blobs["long.safetensors"], str(d / "long.safetensors"))
    rp = "repair.safetensors"
    repair_model = Denoiser.from_bytes(blobs[rp], str(d / rp)) if rp in blobs else None
    priors = {n: Prior.from_bytes(blobs[n], str(d / n)) if n in blobs else None for n in (PRIOR_FILE, REPAIR_FILL_FILE)}
    generator = (
        Generator.from_bytes(blobs[GENERATOR_FILE], str(d / GENERATOR_FILE)) if GENERATOR_FILE in blobs else None
    )
    sampling, forecast_tempo, share = _read_sampling(d / SAMPLING_FILE)
    return TCD(
        short,
        long,
        repair_model,
        path=d,
        threads=threads,
        file_sha256=digests,
        prior=priors[PRIOR_FILE],
        sampling=sampling,
        forecast_tempo=forecast_tempo,
        repair_fill=priors[REPAIR_FILL_FILE],
        generator=generator,
        generator_share=share,
    )


def check_generator_share(value: Any, name: str = "generator_share") -> float:
    """``value`` as a share of samples in [0, 1]; an :class:`InvalidInputError` naming ``name`` otherwise."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float, np.integer, np.floating))
        or not 0.0 <= float(value) <= 1.0
    ):
        raise _checks.fail(
            name, "a number in [0, 1] (the share of a forecast's samples the generator draws)", repr(value)
        )
    return float(value)


def _read_sampling(f: Path) -> Tuple[Dict[str, SamplerOptions], Tempo, float]:
    """A model directory's ``sampling.json`` (:data:`SAMPLING_FILE`), read once and checked: its sampler settings by
    task, its ``"forecast_tempo"`` and its ``"forecast_generator_share"`` (``{}``, None and 0 when there is no
    file); a :class:`WeightsError` naming the file and the key for anything else."""
    if not f.is_file():
        return {}, None, 0.0
    try:
        doc = json.loads(f.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise WeightsError(f"{f}: not a readable JSON file ({e}).", str(f)) from None
    if not isinstance(doc, dict):
        raise WeightsError(f"{f}: expected an object of tasks ({', '.join(SAMPLING_TASKS)}), got {doc!r}.", str(f))
    out: Dict[str, SamplerOptions] = {}
    for key, value in doc.items():
        if key in ("why", TEMPO_KEY, GENERATOR_SHARE_KEY):  # the reason, for the reader; the others checked below
            continue
        if key not in SAMPLING_TASKS:
            raise WeightsError(
                f'{f}: unknown key {key!r} (the tasks: {", ".join(SAMPLING_TASKS)}; and "why", '
                f'"{TEMPO_KEY}", "{GENERATOR_SHARE_KEY}").',
                str(f),
            )
        if not isinstance(value, dict):
            raise WeightsError(f"{f}, {key!r}: expected an object of sampler settings, got {value!r}", str(f))
        try:
            out[key] = SamplerOptions.build(**value)  # the fields it leaves out: SamplerOptions' defaults
        except (TypeError, InvalidInputError) as e:
            raise WeightsError(f"{f}, {key!r}: {e}", str(f)) from None
    try:
        tempo = check_tempo(doc.get(TEMPO_KEY), TEMPO_KEY)
        share = check_generator_share(doc.get(GENERATOR_SHARE_KEY, 0.0), GENERATOR_SHARE_KEY)
    except InvalidInputError as e:
        raise WeightsError(f"{f}: {e}", str(f)) from None
    return out, tempo, share


def _uses_prior(model: Denoiser) -> bool:
    """Whether a denoiser is conditioned on the prior forecaster (``model.cond_fill`` ``"prior"``)."""
    return (model.config.get("model") or {}).get("cond_fill", "zero") == "prior"


CHECKSUM_FILE = "SHA256SUMS"
#: the weight files of a model directory, by role, in checksum order
ROLES = ("short", "long", "repair", "prior", "repair_fill", "generator")


def _checksum_text(digests: Dict[str, str]) -> str:
    """``sha256sum`` format: one ``<hex>  <name>`` line per weight file, in role order."""
    return "".join(f"{h}  {n}\n" for n, h in digests.items())


def _verify_checksums(d: Path, digests: Dict[str, str], bundled: bool) -> None:
    """Checks the weight files against ``d/SHA256SUMS`` (required for the bundled model, optional for others)."""
    f = d / CHECKSUM_FILE
    if not f.is_file():
        if bundled:
            raise WeightsError(
                f"The bundled model in {d} has no {CHECKSUM_FILE}: the installation is incomplete; "
                "reinstall tcd-forecast.",
                str(f),
            )
        return
    expected: Dict[str, str] = {}
    for i, line in enumerate(f.read_text().splitlines(), 1):
        if not line.strip():
            continue
        parts = line.split()
        if len(parts) != 2 or len(parts[0]) != 64:
            raise WeightsError(f"{f}, line {i}: expected '<sha256 hex>  <file name>', got {line!r}.", str(f))
        expected[parts[1].lstrip("*")] = parts[0].lower()
    for n, h in digests.items():
        if n not in expected:
            raise WeightsError(f"{d / n} is not listed in {f}.", str(d / n))
        if expected[n] != h:
            hint = " The bundled weights are corrupt: reinstall tcd-forecast." if bundled else ""
            raise WeightsError(f"{d / n}: SHA-256 {h} does not match {expected[n]} recorded in {f}.{hint}", str(d / n))
    missing = sorted(set(expected) - set(digests))
    if missing:
        raise WeightsError(f"{f} lists {', '.join(missing)}, which {d} does not hold.", str(f))


def write_checksums(d: PathLike) -> Path:
    """Writes ``d/SHA256SUMS`` for the weight files of the model directory ``d`` (used when bundling)."""
    d = Path(d)
    names = [f"{r}.safetensors" for r in ROLES if (d / f"{r}.safetensors").is_file()]
    digests = {n: hashlib.sha256((d / n).read_bytes()).hexdigest() for n in names}
    out = d / CHECKSUM_FILE
    out.write_text(_checksum_text(digests))
    return out


_default: Optional[TCD] = None
_default_lock = threading.Lock()


def _default_model() -> TCD:
    global _default
    with _default_lock:
        if _default is None:
            _default = load(None)
        return _default


def forecast(obs: ArrayLike, mask: Optional[ArrayLike] = None, **kwargs: Any) -> Forecast:
    """:meth:`TCD.forecast` with the bundled default model (see :func:`load`)."""
    return _default_model().forecast(obs, mask, **kwargs)


def predict(obs: ArrayLike, mask: Optional[ArrayLike] = None, **kwargs: Any) -> Forecast:
    """:meth:`TCD.predict` with the bundled default model (see :func:`load`)."""
    return _default_model().predict(obs, mask, **kwargs)


def repair(obs: ArrayLike, mask: Optional[ArrayLike] = None, **kwargs: Any) -> Repair:
    """:meth:`TCD.repair` with the bundled default model (see :func:`load`)."""
    return _default_model().repair(obs, mask, **kwargs)
