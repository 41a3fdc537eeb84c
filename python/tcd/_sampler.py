"""How each chain is sampled: the one home of the sampler settings, their defaults and their checks.

Every layer that samples (``TCD.forecast`` / ``TCD.repair`` / ``TCD.predict``, :class:`tcd.engine.Denoiser`,
:func:`tcd.engine.cascade_raw`, :func:`tcd.engine.repair_raw`, :func:`tcd.repair_file`, the command line) takes
the settings as keyword arguments (``sampler``, ``num_inference_steps``, ``eta``, ``timestep_spacing``) and reads
them with :meth:`SamplerOptions.build`; the binding converts the resulting :class:`SamplerOptions` into the engine's
``SamplerConfig`` in one place (``SamplerOptions`` in crates/tcd-py/src/convert.rs, a ``FromPyObject``).
The values are checked by the engine's rules (``SamplerConfig::from_names``), when an options object is
made and again when it is used; Python checks only that each field has the Python type the binding reads.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, Optional

from . import _checks, _native

#: The samplers and the timestep spacings the engine knows, its default first.
SAMPLERS = tuple(_native.SAMPLERS)
SPACINGS = tuple(_native.SPACINGS)
COUPLINGS = tuple(_native.COUPLINGS)


@dataclass(frozen=True)
class SamplerOptions:
    """The sampler of every chain. Checked when made (each bad value an
    :class:`~tcd.exceptions.InvalidInputError` naming the field); the number of steps is checked against a
    model's training steps when the model samples. Calls take these fields as keyword arguments, never the
    object; it is the record of a run's settings (``tcd._repair.RepairOptions.sampling``) and what the
    binding reads.

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
        _native.check_sampler_options(self)  # the values, by the engine's rules

    @classmethod
    def build(cls, defaults: Optional["SamplerOptions"] = None, **sampler: Any) -> "SamplerOptions":
        """The settings named in ``sampler`` (the sampler keywords of a call), ``defaults`` for the rest (a
        model's own defaults, :attr:`tcd.TCD.sampling`; ``None``: this class's). Naming a ``sampler`` other
        than the default's drops the default's other fields too (its step count and ``eta`` belong to it):
        ``sampler="ddpm"`` alone is the paper's DDPM over every step whatever the model's default. An unknown
        name is a ``TypeError`` naming the valid ones; a bad value an
        :class:`~tcd.exceptions.InvalidInputError` naming its field."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(sampler) - names)
        if unknown:
            raise TypeError(
                f"unexpected keyword argument {unknown[0]!r} (sampler settings: {', '.join(sorted(names))})"
            )
        if defaults is None or sampler.get("sampler", defaults.sampler) != defaults.sampler:
            return cls(**sampler)
        return cls(**{**asdict(defaults), **sampler})

    def describe(self, num_train_timesteps: int) -> str:
        """One line for people: ``"ddim, 1 step (eta 0, trailing spacing)"`` (``None`` steps: every training step),
        ``", centred noise"`` added where the chains' noise is coupled."""
        n = num_train_timesteps if self.num_inference_steps is None else self.num_inference_steps
        extra = f"eta {self.eta:g}, " if self.sampler == "ddim" else ""
        coupled = ", centred noise" if self.noise_coupling == "centered" else ""
        return f"{self.sampler}, {n} step{'' if n == 1 else 's'} ({extra}{self.timestep_spacing} spacing{coupled})"
