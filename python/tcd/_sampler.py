"""How each chain is sampled: :class:`SamplerOptions`, the one carrier of the sampler settings from the caller to
the engine.

It is made once, from keywords (``SamplerOptions(sampler="ddim", num_inference_steps=10)``), from keywords over a
model's defaults (:meth:`tcd.TCD.sampler_options`, :meth:`SamplerOptions.build`), from a model directory's
``sampling.json`` or from the command line's sampler flags, and every call that samples takes it as its
``sampler`` argument (``None`` where a model's default applies). The engine checks its values once, when it is
made: the object holds the engine's checked sampler (``_engine``, a ``tcd._native.Sampler``), which the binding
reads on every call without checking again.
"""

from __future__ import annotations

from dataclasses import asdict, astuple, dataclass, fields
from typing import Any, Optional, Tuple

from . import _checks, _native

#: The samplers and the timestep spacings the engine knows, its default first.
SAMPLERS = tuple(_native.SAMPLERS)
SPACINGS = tuple(_native.SPACINGS)
COUPLINGS = tuple(_native.COUPLINGS)


@dataclass(frozen=True)
class SamplerOptions:
    """The sampler of every chain, and the one place its fields are listed. Checked when made (each bad value
    an :class:`~tcd.exceptions.InvalidInputError` naming the field); the number of steps is checked against a
    model's training steps when the model samples. Every call that samples takes one as ``sampler``; it is
    also the record of a run's settings (``RepairOptions.sampling``, a results file's ``sampling``).

    Attributes:
        sampler: ``"ddpm"`` (ancestral, the paper's), ``"ddim"`` (``eta``) or ``"dpmpp2m"``
            (DPM-Solver++(2M), deterministic given the initial noise; meant for 10-25 steps).
        num_inference_steps: ``None`` = every training step (50: the paper's DDPM sampler); fewer run
            respaced DDPM, DDIM or DPM-Solver++(2M).
        eta: DDIM stochasticity in [0, 1] (0 = deterministic given the initial noise); ignored by the
            other samplers.
        timestep_spacing: ``"trailing"``, ``"leading"`` or ``"linspace"``: which training steps a
            shortened sampler visits.
        noise_coupling: ``"independent"`` (the paper's) or ``"centered"``: the S chains of each sequence start
            from x_T centred on their mean and rescaled by sqrt(S / (S - 1)), so each chain's x_T is still a
            standard normal but the S sum to zero: samples that spread further apart and a mean that is less
            noisy (docs/samplers.md, "Centred noise"). The per-step noise is left as drawn; one chain per
            sequence is not coupled. Applied to seeded and injected noise alike.
    """

    sampler: str = "ddpm"
    num_inference_steps: Optional[int] = None
    eta: float = 0.0
    timestep_spacing: str = "trailing"
    noise_coupling: str = "independent"

    def __post_init__(self) -> None:
        set_ = object.__setattr__  # frozen: normalise the types once (numpy ints to int, eta to float)
        set_(self, "sampler", _checks.text("sampler", self.sampler, SAMPLERS))
        if self.num_inference_steps is not None:
            set_(self, "num_inference_steps", _checks.machine_int("num_inference_steps", self.num_inference_steps))
        set_(self, "eta", _checks.real("eta", self.eta))
        set_(self, "timestep_spacing", _checks.text("timestep_spacing", self.timestep_spacing, SPACINGS))
        set_(self, "noise_coupling", _checks.text("noise_coupling", self.noise_coupling, COUPLINGS))
        # The values, by the engine's rules, once: every call hands this checked sampler to the engine.
        set_(self, "_engine", _native.Sampler(*astuple(self)))

    def __reduce__(self) -> Tuple[Any, ...]:
        """Pickled as its fields (``tcd repair --ray`` sends its options to the workers); made and checked
        again where it is unpickled."""
        return (type(self), astuple(self))

    @classmethod
    def build(cls, defaults: Optional["SamplerOptions"] = None, **changes: Any) -> "SamplerOptions":
        """The fields named in ``changes`` (a dict's, a ``sampling.json`` task's or the command line's sampler
        flags), ``defaults`` for the rest (a model's own defaults, :attr:`tcd.TCD.sampling`; ``None``: this
        class's). Naming a ``sampler`` other
        than the default's drops the default's other fields too (its step count and ``eta`` belong to it):
        ``sampler="ddpm"`` alone is the paper's DDPM over every step whatever the model's default. An unknown
        name is a ``TypeError`` naming the valid ones; a bad value an
        :class:`~tcd.exceptions.InvalidInputError` naming its field."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise TypeError(
                f"unexpected keyword argument {unknown[0]!r} (sampler settings: {', '.join(sorted(names))})"
            )
        if defaults is None or changes.get("sampler", defaults.sampler) != defaults.sampler:
            return cls(**changes)
        return cls(**{**asdict(defaults), **changes})

    def describe(self, num_train_timesteps: int) -> str:
        """One line for people: ``"ddim, 1 step (eta 0, trailing spacing)"`` (``None`` steps: every training step),
        ``", centred noise"`` added where the chains' noise is coupled."""
        n = num_train_timesteps if self.num_inference_steps is None else self.num_inference_steps
        extra = f"eta {self.eta:g}, " if self.sampler == "ddim" else ""
        coupled = ", centred noise" if self.noise_coupling == "centered" else ""
        return f"{self.sampler}, {n} step{'' if n == 1 else 's'} ({extra}{self.timestep_spacing} spacing{coupled})"


def checked(value: Any, name: str = "sampler") -> SamplerOptions:
    """``value`` as a call's sampler: a :class:`SamplerOptions`; an :class:`~tcd.exceptions.InvalidInputError`
    naming ``name`` for anything else (sampler keywords are not taken: make the object from them)."""
    if not isinstance(value, SamplerOptions):
        hint = f"tcd.SamplerOptions(sampler={value!r})" if isinstance(value, str) else "tcd.SamplerOptions(...)"
        raise _checks.fail(name, f"a tcd.SamplerOptions (e.g. {hint})", repr(value))
    return value
