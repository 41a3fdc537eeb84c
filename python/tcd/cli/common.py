"""What the commands share: exit codes, the user's-error exception, the option-to-flag mapping, the
sampler flags and loading the model."""
from __future__ import annotations

import argparse
from contextlib import contextmanager
from pathlib import Path
from typing import Dict, Iterator, Optional

from ..exceptions import InvalidInputError, WeightsError
from ..model import TCD, load
from ..options import SAMPLERS, SPACINGS, SamplerOptions

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130  # tcd repair: re-run the command to resume


class _BadInput(Exception):
    """A problem the user can fix: reported on stderr with exit code 2."""


# The sampler flags of every command that samples: one mapping from SamplerOptions field to flag. A flag
# not given is left out, so the defaults are SamplerOptions' own.
SAMPLER_FLAGS = {"sampler": "--sampler", "num_inference_steps": "--steps", "eta": "--eta",
                 "timestep_spacing": "--spacing"}
# The API argument each flag sets, for the commands' error messages; a command adds or overrides its own.
OPTION_FLAGS = {"num_samples": "--samples", "seed": "--seed", "units": "--units", "threads": "--threads",
                **SAMPLER_FLAGS}


def flag_message(e: InvalidInputError, flags: Dict[str, str] = OPTION_FLAGS) -> str:
    """The error's message, saying which flag (or input) set the argument it names."""
    flag = flags.get(e.argument or "")
    return f"{e} (`{e.argument}` is {flag}.)" if flag else str(e)


def add_model_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", metavar="DIR", help="model directory (default: the bundled model)")


def add_sampler_flags(p: argparse.ArgumentParser, *, tuning: bool = True) -> None:
    """--steps and --sampler (and with ``tuning`` --eta and --spacing). Each defaults to None, so that a
    flag not given leaves SamplerOptions' default; argparse refuses a choice not in SAMPLERS or SPACINGS."""
    d = SamplerOptions()
    p.add_argument("--steps", dest="num_inference_steps", type=int, default=None, metavar="S",
                   help="inference steps (default: every training step, the paper's DDPM)")
    p.add_argument("--sampler", default=None, choices=SAMPLERS,
                   help=f"sampler (default {d.sampler}; dpmpp2m is DPM-Solver++(2M))")
    if tuning:
        p.add_argument("--eta", type=float, default=None, help=f"DDIM eta in [0, 1] (default {d.eta:g})")
        p.add_argument("--spacing", dest="timestep_spacing", default=None, choices=SPACINGS,
                       help=f"timestep spacing (default {d.timestep_spacing})")


def sampler_options(args: argparse.Namespace) -> SamplerOptions:
    """The SamplerOptions of the sampler flags given; a bad value is an error naming its flag."""
    given = {f: getattr(args, f) for f in SAMPLER_FLAGS if getattr(args, f, None) is not None}
    try:
        return SamplerOptions.build(**given)
    except InvalidInputError as e:
        raise _BadInput(flag_message(e)) from None


def load_model(model: Optional[str]) -> TCD:
    """The model of ``--model``; a missing or broken model directory is the user's to fix."""
    try:
        return load(model)
    except (FileNotFoundError, NotADirectoryError, WeightsError, InvalidInputError) as e:
        raise _BadInput(str(e)) from None


def output_exists(path: Path) -> _BadInput:
    return _BadInput(f"The output file {path} exists; pass --overwrite to replace it.")


@contextmanager
def writing(path: Path) -> Iterator[None]:
    """Around the write of an output checked beforehand: one that appeared since (``FileExistsError`` from
    :mod:`tcd.files` without overwrite) is the same error as one there from the start."""
    try:
        yield
    except FileExistsError:
        raise output_exists(path) from None
