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


def _read_sampling(f: Path) -> Tuple[Dict[str, SamplerOptions], Mode]:
    """A model directory's ``sampling.json`` (:data:`SAMPLING_FILE`), read once and checked: its sampler settings by
    task and its forecast mode (``{}`` and the cascade when there is no file); a :class:`WeightsError` naming the
    file and the key for anything else."""
    if not f.is_file():
        return {}, Cascade()
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
        share = check_generator_share(doc.get(GENERATOR_SHARE_KEY, 0.0), GENERATOR_SHARE_KEY)
        return out, Mixture(share) if share else Cascade()
    except InvalidInputError as e:
        raise WeightsError(f"{f}: {e}", str(f)) from None


@dataclass(frozen=True)
class Files:
    """What a model directory holds, read and checked file by file (:func:`read`); :class:`tcd.TCD` checks that
    the parts fit together."""

    path: Path
    short: Denoiser
    long: Denoiser
    repair: Optional[Denoiser]
    prior: Optional[Prior]
    repair_fill: Optional[Prior]
    generator: Optional[Generator]
    file_sha256: Dict[str, str]
    sampling: Dict[str, SamplerOptions]
    forecast_mode: Mode


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


def check_parts(
    path: Optional[PathLike],
    short: Denoiser,
    long: Denoiser,
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


def uses_prior(model: Denoiser) -> bool:
    """Whether a denoiser is conditioned on the prior forecaster (``model.cond_fill`` ``"prior"``)."""
    return (model.config.get("model") or {}).get("cond_fill", "zero") == "prior"
