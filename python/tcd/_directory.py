"""A model directory on disk: its files, their checksums and its sampler defaults (``sampling.json``), read once and
checked; the bundled directories. :func:`tcd.load` builds a :class:`tcd.TCD` from what :func:`read` returns."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional, Tuple, Union

from . import _checks
from ._cascade import Cascade, Mode
from ._mixture import GENERATOR_FILE, Mixture, check_generator_share
from ._sampler import SamplerOptions
from ._tempo import Tempo, check_tempo
from .engine import Denoiser, Generator, Prior
from .exceptions import InvalidInputError, ModelNotBundledError, WeightsError

PathLike = Union[str, "os.PathLike[str]"]

#: the prior forecaster's file in a model directory (:attr:`TCD.prior`)
PRIOR_FILE = "prior.safetensors"
#: the repair model's fill in a model directory (:attr:`TCD.repair_fill`), for a repair model conditioned on it
REPAIR_FILL_FILE = "repair_fill.safetensors"
#: the MLP sample generator in a model directory (:attr:`TCD.generator`), optional: ``GENERATOR_FILE``, named
#: beside the mode that draws from it (:class:`tcd.Mixture`, ``sampling.json`` ``"forecast_generator_share"``)

#: what a model directory without the cascade holds (a generator directory, such as the bundled Setting-A
#: model): its samples come from the generator alone (``tcd.Mixture(1)``), around the prior's forecast
GENERATOR_ONLY = f"a generator directory: {GENERATOR_FILE} and the {PRIOR_FILE} it samples around"

#: a model directory's own sampler defaults (:attr:`TCD.sampling`), optional: ``{"forecast": {...}, "repair":
#: {...}, "why": "...", "forecast_tempo": [lo, hi]}``, each task's object holding :class:`SamplerOptions` fields; a
#: task or field left out takes :class:`SamplerOptions`' defaults (the paper's DDPM over every training step);
#: ``"forecast_tempo"`` or ``"forecast_generator_share"``, optional (one at most), the default
#: :attr:`TCD.forecast_mode`: ``tcd.Tempo(lo, hi)`` or ``tcd.Mixture(share)`` (``tcd.Cascade()`` without either)
SAMPLING_FILE = "sampling.json"
#: the key of ``sampling.json`` holding the range of a default ``tcd.Tempo``
TEMPO_KEY = "forecast_tempo"
#: the key of ``sampling.json`` holding the share of a default ``tcd.Mixture``
GENERATOR_SHARE_KEY = "forecast_generator_share"
#: the tasks a model directory may set sampler defaults for: ``"forecast"`` the cascade (:meth:`TCD.forecast`),
#: ``"repair"`` the repair model (:meth:`TCD.repair`, the model fill of :meth:`TCD.predict`, :func:`tcd.repair_file`)
SAMPLING_TASKS = ("forecast", "repair")


#: the bundled model directories by name (:func:`tcd.load` takes the name), each a folder of the package:
#: ``"h36m"`` the default (Human3.6M Setting-B, 50 -> 25 frames at 25 fps: the cascade, its prior, the repair
#: model), ``"humaneva"`` the HumanEva-I model (15 -> 60 frames at 60 Hz), ``"h36m-stochastic"`` the Human3.6M
#: Setting-A model (25 -> 100 frames at 50 Hz: a prior and the MLP generator around it, no cascade)
BUNDLED_DIRS: Dict[str, str] = {
    "h36m": "weights",
    "humaneva": "weights_humaneva",
    "h36m-stochastic": "weights_h36m_stochastic",
}
#: the names :func:`load` takes for the bundled model directories (:data:`BUNDLED_DIRS`), when the installation
#: holds them
BUNDLED_MODELS = tuple(BUNDLED_DIRS)


def bundled_model_dir(name: str) -> Path:
    """Where the bundled model ``name`` (:data:`BUNDLED_MODELS`) lives in the package, installed or not."""
    if name not in BUNDLED_DIRS:
        raise _checks.fail("name", "one of " + ", ".join(repr(n) for n in BUNDLED_MODELS), repr(name))
    return Path(__file__).resolve().parent / BUNDLED_DIRS[name]


def default_model_dir() -> Path:
    """Where the bundled default model lives (``tcd/weights/``)."""
    return bundled_model_dir("h36m")


def humaneva_model_dir() -> Path:
    """Where the bundled HumanEva-I model lives (``tcd/weights_humaneva/``): ``tcd.load("humaneva")``."""
    return bundled_model_dir("humaneva")


def _bundled_dir(name: str) -> Path:
    """The directory of the bundled model ``name``; :class:`ModelNotBundledError` when it is not installed."""
    d = bundled_model_dir(name)
    if not any((d / f).is_file() for f in ("short.safetensors", GENERATOR_FILE)):
        raise ModelNotBundledError(
            f"The model {name!r} is not bundled with this installation of tcd ({d} holds no model files): "
            "pass a model directory instead, e.g. tcd.load('path/to/model') or `--model DIR` on the command "
            "line, as written by `python -m training.export` (docs/training.md).",
            name,
            str(d),
        )
    return d


#: the checksums of a model directory's weight files (``sha256sum`` format)
CHECKSUM_FILE = "SHA256SUMS"
#: the weight files of a model directory, by role, in checksum order
ROLES = ("short", "long", "repair", "prior", "repair_fill", "generator")


def checksum_text(digests: Dict[str, str]) -> str:
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
    out.write_text(checksum_text(digests))
    return out


def _read_sampling(f: Path) -> Tuple[Dict[str, SamplerOptions], Optional[Mode]]:
    """A model directory's ``sampling.json`` (:data:`SAMPLING_FILE`), read once and checked: its sampler settings by
    task and its forecast mode (``{}`` and None, the directory's own default (:func:`default_mode`), when there is
    no file or it names no mode); a :class:`WeightsError` naming the file and the key for anything else."""
    if not f.is_file():
        return {}, None
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
    if TEMPO_KEY in doc and GENERATOR_SHARE_KEY in doc:
        raise WeightsError(
            f'{f}: "{TEMPO_KEY}" and "{GENERATOR_SHARE_KEY}" name two forecast modes; a directory has one.', str(f)
        )
    try:
        if doc.get(TEMPO_KEY) is not None:
            return out, Tempo(*check_tempo(doc[TEMPO_KEY], TEMPO_KEY))
        if doc.get(GENERATOR_SHARE_KEY) is None:
            return out, None
        share = check_generator_share(doc[GENERATOR_SHARE_KEY], GENERATOR_SHARE_KEY)
        return out, Mixture(share) if share else Cascade()
    except InvalidInputError as e:
        raise WeightsError(f"{f}: {e}", str(f)) from None


@dataclass(frozen=True)
class Files:
    """What a model directory holds, read and checked file by file (:func:`read`); :class:`tcd.TCD` checks that
    the parts fit together."""

    path: Path
    #: the cascade's two stages; both None in a generator directory (:data:`GENERATOR_ONLY`)
    short: Optional[Denoiser]
    long: Optional[Denoiser]
    repair: Optional[Denoiser]
    prior: Optional[Prior]
    repair_fill: Optional[Prior]
    generator: Optional[Generator]
    file_sha256: Dict[str, str]
    sampling: Dict[str, SamplerOptions]
    #: the mode ``sampling.json`` names, None where it names none (:func:`default_mode`)
    forecast_mode: Optional[Mode]


def read(path: Optional[PathLike]) -> Files:
    """The model directory ``path`` (``None`` or a bundled model's name: that bundled directory), its weight files
    checked against ``SHA256SUMS`` (required for a bundled model). Errors: as :func:`tcd.load`."""
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
    cascade = any((d / f"{role}.safetensors").is_file() for role in ("short", "long"))
    for role in ("short", "long") if cascade or not (d / GENERATOR_FILE).is_file() else ():
        if not (d / f"{role}.safetensors").is_file():
            raise FileNotFoundError(
                f"The model directory {d} has no {role}.safetensors: a model directory holds the cascade, "
                f"short.safetensors and long.safetensors (and optionally repair.safetensors), or {GENERATOR_ONLY}."
            )
    names = [f"{r}.safetensors" for r in ROLES if (d / f"{r}.safetensors").is_file()]
    blobs = {n: (d / n).read_bytes() for n in names}
    digests = {n: hashlib.sha256(b).hexdigest() for n, b in blobs.items()}
    _verify_checksums(d, digests, bundled=bundled)
    short, long = (
        Denoiser.from_bytes(blobs[n], str(d / n)) if n in blobs else None
        for n in ("short.safetensors", "long.safetensors")
    )
    rp = "repair.safetensors"
    repair_model = Denoiser.from_bytes(blobs[rp], str(d / rp)) if rp in blobs else None
    priors = {n: Prior.from_bytes(blobs[n], str(d / n)) if n in blobs else None for n in (PRIOR_FILE, REPAIR_FILL_FILE)}
    generator = (
        Generator.from_bytes(blobs[GENERATOR_FILE], str(d / GENERATOR_FILE)) if GENERATOR_FILE in blobs else None
    )
    sampling, mode = _read_sampling(d / SAMPLING_FILE)
    return Files(
        path=d,
        short=short,
        long=long,
        repair=repair_model,
        prior=priors[PRIOR_FILE],
        repair_fill=priors[REPAIR_FILL_FILE],
        generator=generator,
        file_sha256=digests,
        sampling=sampling,
        forecast_mode=mode,
    )


def default_mode(short: Optional[Denoiser]) -> Mode:
    """The forecast mode of a model directory whose ``sampling.json`` names none: the cascade, or the generator
    alone (``Mixture(1)``) in a directory without one (:data:`GENERATOR_ONLY`)."""
    return Cascade() if short is not None else Mixture(1.0)


def check_parts(
    path: Optional[PathLike],
    short: Optional[Denoiser],
    long: Optional[Denoiser],
    repair: Optional[Denoiser],
    prior: Optional[Prior],
    repair_fill: Optional[Prior],
    generator: Optional[Generator],
    mode: Mode,
) -> None:
    """That the parts of a model directory fit together (each checked alone when read): the cascade's two
    stages, the prior each model conditioned on it needs, the repair model and its fill, the generator around the
    prior's forecast. A :class:`WeightsError` naming the file that does not fit."""
    where = str(path) if path is not None else "the model"
    if short is None or long is None:
        _check_generator_only(where, path, short or long, repair or repair_fill, prior, generator, mode)
        return
    k = short.num_features
    if short.num_features % 3:
        raise WeightsError(f"{where}: the short-term model has num_features = {k}, not joints x 3.", short.path)
    if long.num_features != k:
        raise WeightsError(
            f"{where}: the long-term model has num_features = {long.num_features}, but the short-term model has {k}.",
            long.path,
        )
    if long.obs_len != short.seq_len or long.seq_len <= short.obs_len:
        raise WeightsError(
            f"{where}: the long-term model's obs_len ({long.obs_len}) must equal the short-term "
            f"model's seq_len ({short.seq_len}).",
            long.path,
        )
    prior_roles = tuple(role for role, m in (("short", short), ("long", long)) if uses_prior(m))
    if prior_roles and prior is None:
        missing = str(Path(path) / PRIOR_FILE) if path is not None else PRIOR_FILE
        roles = " and ".join(f"{r}-term" for r in prior_roles)
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
    if repair is not None and uses_prior(repair) and repair_fill is None:
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
    if isinstance(mode, Mixture) and mode.share and generator is None:
        raise WeightsError(
            f"{where}: the forecast mode is {mode}, but there is no generator ({GENERATOR_FILE}).",
            str(Path(path) / GENERATOR_FILE) if path is not None else GENERATOR_FILE,
        )
    if repair_fill is not None and repair_fill.gap_fill == "forecaster" and prior is None:
        missing = str(Path(path) / PRIOR_FILE) if path is not None else PRIOR_FILE
        raise WeightsError(
            f"{where}: the repair fill fills whole-frame gaps with the prior forecaster (gap_fill "
            f'"forecaster"), but {missing} is missing: the model directory must hold it.',
            missing,
        )


def _check_generator_only(
    where: str,
    path: Optional[PathLike],
    stage: Optional[Denoiser],
    extra: Union[Denoiser, Prior, None],
    prior: Optional[Prior],
    generator: Optional[Generator],
    mode: Mode,
) -> None:
    """:func:`check_parts` for a directory without the cascade (at most one ``stage`` of it, refused):
    :data:`GENERATOR_ONLY`, nothing ``extra`` (a repair model or fill, refused)."""

    def file(name: str) -> str:
        return str(Path(path) / name) if path is not None else name

    if stage is not None:
        raise WeightsError(
            f"{where}: the cascade needs both its stages, short and long; only {stage.path} is given.", stage.path
        )
    if generator is None or prior is None:
        missing = file(GENERATOR_FILE if generator is None else PRIOR_FILE)
        raise WeightsError(
            f"{where}: without the cascade a model directory is {GENERATOR_ONLY}; {missing} is missing.", missing
        )
    if extra is not None:
        raise WeightsError(
            f"{where}: {extra.path} is a repair model or fill, which repairs with the cascade's short-term model's "
            "window; this directory has no cascade.",
            extra.path,
        )
    if prior.anchor != "last" or prior.num_features != generator.num_features or prior.obs_len != generator.obs_len:
        raise WeightsError(
            f"{where}: the generator (num_features = {generator.num_features}, obs_len = {generator.obs_len}) samples "
            f'around the prior\'s forecast, so the prior must be a forecaster (anchor "last", not '
            f'"{prior.anchor}") of the same num_features and obs_len (it has {prior.num_features} and '
            f"{prior.obs_len}).",
            prior.path,
        )
    if mode != Mixture(1.0):
        raise WeightsError(
            f"{where}: the forecast mode is {mode}, but the directory has no cascade: its mode is the generator "
            "alone, tcd.Mixture(1).",
            file(SAMPLING_FILE),
        )


def uses_prior(model: Denoiser) -> bool:
    """Whether a denoiser is conditioned on the prior forecaster (``model.cond_fill`` ``"prior"``)."""
    return (model.config.get("model") or {}).get("cond_fill", "zero") == "prior"
