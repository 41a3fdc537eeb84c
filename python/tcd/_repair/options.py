"""Settings of a repair run: the defaults, their checks (:class:`RepairOptions`), the denoiser used and
the provenance recorded in every output."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Dict, Optional, Union


from .. import _checks
from .._poses import check_units
from .._native import __version__
from ..engine import Denoiser
from .._sampler import SamplerOptions, checked as checked_sampler
from .._wild_calls import Capture

PathLike = Union[str, "os.PathLike[str]"]

DEFAULT_OVERLAP = 5
DEFAULT_LOOKAHEAD = 10
DEFAULT_SEED = 0
DEFAULT_FILES_PER_BATCH = 4
INPUT_SUFFIXES = (".npz", ".txt", ".bvh")


#: the keywords of :meth:`RepairOptions.make` besides ``sampler`` (those of :func:`repair_file` it reads)
_MAKE_KEYWORDS = frozenset({"num_samples", "seed", "units", "capture", "overlap", "lookahead", "threads"})


class BadFile(Exception):
    """An input that cannot be repaired; ``str(e)`` is the reason."""


# ---------------------------------------------------------------------------------------------- options
@dataclass(frozen=True)
class RepairOptions:
    """Validated settings of a repair run (see :func:`repair_file`)."""

    num_samples: int  # the model's TCD.repair_samples when a call names none (make resolves it)
    sampling: SamplerOptions = SamplerOptions()
    seed: int = DEFAULT_SEED
    units: str = "m"
    overlap: int = DEFAULT_OVERLAP
    lookahead: int = DEFAULT_LOOKAHEAD
    threads: Optional[int] = None
    #: how the inputs were captured (``None``: the model's layout, at their own or the model's rate); layouts other
    #: than the model's are converted (tcd.wild), other rates resampled
    capture: Optional[Capture] = None

    @property
    def fps(self) -> Optional[float]:
        """The inputs' frame rate where the capture gives one (None: each file's own, else the model's)."""
        return None if self.capture is None else self.capture.fps

    @property
    def layout(self) -> str:
        """The inputs' joint layout (tcd.layouts)."""
        return "h36m22" if self.capture is None else self.capture.layout

    @property
    def up(self) -> str:
        """The inputs' vertical axis (a name: :meth:`make` refuses a vector)."""
        return "y" if self.capture is None else str(self.capture.up)

    @staticmethod
    def make(model: Any, *, sampler: Optional[SamplerOptions] = None, **kw: Any) -> "RepairOptions":
        """Checked settings: ``sampler``, the call's :class:`SamplerOptions` (``None``: the model's
        ``sampling["repair"]``); the rest as the other keywords of :func:`repair_file`."""
        unknown = sorted(set(kw) - _MAKE_KEYWORDS)
        if unknown:
            raise TypeError(
                f"unexpected keyword argument {unknown[0]!r} (settings: sampler, {', '.join(sorted(_MAKE_KEYWORDS))})"
            )
        sampling = model.sampling["repair"] if sampler is None else checked_sampler(sampler)
        den = _denoiser(model)
        den.timesteps(sampling)  # the step count against the model, before any file is read
        seed = kw.get("seed", DEFAULT_SEED)
        capture = kw.get("capture")
        if capture is not None:
            if not isinstance(capture, Capture):
                raise _checks.fail("capture", "a tcd.Capture or None", type(capture).__name__)
            if not isinstance(capture.up, str):
                raise _checks.fail("up", "'x', 'y' or 'z' (optionally signed) for tcd repair", repr(capture.up))
            if capture.fps is not None and model.fps is None:
                raise _checks.fail(
                    "fps",
                    "None: the model does not record its frame rate, so inputs cannot be resampled",
                    repr(capture.fps),
                )
        overlap = _checks.integer("overlap", kw.get("overlap", DEFAULT_OVERLAP), 1, model.obs_len - 1)
        lookahead = _checks.integer("lookahead", kw.get("lookahead", DEFAULT_LOOKAHEAD), 0, model.obs_len - 1 - overlap)
        n = kw.get("num_samples")
        num_samples = _checks.num_samples(
            model.repair_samples if n is None else n, window=(den.num_features, den.seq_len), fill_alone=True
        )
        if num_samples == 0 and model._repair_fills(den)["fill"] is None:
            # the engine would refuse it at the first window; refused here, before any file is read
            raise _checks.fail(
                "num_samples",
                "at least 1: 0 (the repair fill alone) needs a repair model conditioned "
                "on a repair fill (repair_fill.safetensors)",
                "0",
            )
        return RepairOptions(
            num_samples=num_samples,
            sampling=sampling,
            seed=_checks.seed(DEFAULT_SEED if seed is None else seed),
            units=check_units(kw.get("units", "m")),
            overlap=overlap,
            lookahead=lookahead,
            threads=_checks.threads(kw.get("threads")),
            capture=capture,
        )


def _denoiser(model: Any) -> Denoiser:
    """The denoiser :meth:`TCD.repair` uses: the repair model, else the short-term model (a
    ``FileNotFoundError`` in a directory with neither)."""
    return model._repair_denoiser()


def provenance(model: Any, opts: RepairOptions, fps: float) -> Dict[str, Any]:
    den = _denoiser(model)
    steps = len(den.timesteps(opts.sampling))
    return {
        "tool": "tcd repair",
        "tcd_version": __version__,
        "model_sha256": model.sha256,
        "model_path": None if model.path is None else str(model.path),
        "repair_model": "repair" if model.repair_model is not None else "short",
        "sampler": opts.sampling.sampler,
        "steps": steps,
        "num_samples": opts.num_samples,
        "eta": opts.sampling.eta,
        "timestep_spacing": opts.sampling.timestep_spacing,
        "noise_coupling": opts.sampling.noise_coupling,
        "seed": opts.seed,
        "units": opts.units,
        "fps": fps,
        "model_fps": model.fps,
        "window": model.obs_len,
        "overlap": opts.overlap,
        "lookahead": opts.lookahead,
        "layout": opts.layout,
        "up": opts.up,
    }
