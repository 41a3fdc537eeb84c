"""What the commands share: exit codes, the user's-error exception, the option-to-flag mapping, the
sampler flags and loading the model."""

from __future__ import annotations

import argparse
import dataclasses
import signal
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Dict, Iterator, Optional, Tuple

from ..exceptions import InvalidInputError, WeightsError
from .._model import TCD, load
from ..layouts import LAYOUTS
from .._sampler import COUPLINGS, SAMPLERS, SPACINGS, SamplerOptions
from .._wild_calls import Capture

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130  # tcd repair: re-run the command to resume
EXIT_TERMINATED = 143  # 128 + SIGTERM


class _BadInput(Exception):
    """A problem the user can fix: reported on stderr with exit code 2."""


class _Terminated(KeyboardInterrupt):
    """SIGTERM while a command runs: raised by :func:`stop_signals`' handler so that it stops as Ctrl-C does
    (the engine's call is cancelled, temporary files are removed, nothing half-written); a KeyboardInterrupt
    so that every path that cleans up after Ctrl-C cleans up after it too."""


def stopped(e: KeyboardInterrupt) -> Tuple[str, int]:
    """The word and exit code of a stop: ``("interrupted", 130)`` for Ctrl-C, ``("terminated", 143)`` for SIGTERM."""
    return ("terminated", EXIT_TERMINATED) if isinstance(e, _Terminated) else ("interrupted", EXIT_INTERRUPTED)


def _raise_terminated(signum: int, frame: Any) -> None:
    raise _Terminated()


@contextmanager
def stop_signals() -> Iterator[None]:
    """Around a command: SIGTERM stops it as Ctrl-C does (:class:`_Terminated`, exit 143).

    A signal ignored when the command starts stays ignored, as Python itself does for SIGINT and as GNU make,
    coreutils and the shells do: a non-interactive shell starts ``tcd ... &`` with SIGINT (and SIGQUIT)
    ignored so that the Ctrl-C meant for the foreground command, which reaches the whole process group, does
    not stop it; ``kill PID`` (SIGTERM) does. A handler the embedding program installed is kept too (only
    the default disposition is replaced), and so is everything when called from a thread other than the main
    one (Python runs handlers there only). The disposition found is restored on the way out."""
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGTERM) != signal.SIG_DFL:
        yield
        return
    try:
        signal.signal(signal.SIGTERM, _raise_terminated)
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


# The sampler flags of every command that samples: one mapping from SamplerOptions field to flag. A flag
# not given is left out, so the defaults are SamplerOptions' own.
SAMPLER_FLAGS = {
    "sampler": "--sampler",
    "num_inference_steps": "--steps",
    "eta": "--eta",
    "timestep_spacing": "--spacing",
    "noise_coupling": "--noise-coupling",
}
# The API argument each flag sets, for the commands' error messages; a command adds or overrides its own.
OPTION_FLAGS = {
    "num_samples": "--samples",
    "seed": "--seed",
    "units": "--units",
    "threads": "--threads",
    **SAMPLER_FLAGS,
}


def flag_message(e: InvalidInputError, flags: Dict[str, str] = OPTION_FLAGS) -> str:
    """The error's message, saying which flag (or input) set the argument it names."""
    flag = flags.get(e.argument or "")
    return f"{e} (`{e.argument}` is {flag}.)" if flag else str(e)


def add_model_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--model",
        metavar="DIR",
        help="model directory, or a bundled model's name: h36m (the default) "
        "or humaneva (the HumanEva-I model, where this installation bundles it)",
    )


def add_sampler_flags(p: argparse.ArgumentParser, *, tuning: bool = True) -> None:
    """--steps and --sampler (and with ``tuning`` --eta, --spacing and --noise-coupling). Each defaults to None,
    so that a flag not given leaves the model's default (its ``sampling.json``, else SamplerOptions'); argparse
    refuses a choice not in SAMPLERS, SPACINGS or COUPLINGS."""
    d = SamplerOptions()
    p.add_argument(
        "--steps",
        dest="num_inference_steps",
        type=int,
        default=None,
        metavar="S",
        help="inference steps (default: the model's; `tcd info` shows them)",
    )
    p.add_argument(
        "--sampler",
        default=None,
        choices=SAMPLERS,
        help="sampler (default: the model's, `tcd info`; dpmpp2m is DPM-Solver++(2M))",
    )
    if tuning:
        p.add_argument(
            "--eta", type=float, default=None, help=f"DDIM eta in [0, 1] (default: the model's, else {d.eta:g})"
        )
        p.add_argument(
            "--spacing",
            dest="timestep_spacing",
            default=None,
            choices=SPACINGS,
            help=f"timestep spacing (default: the model's, else {d.timestep_spacing})",
        )
        p.add_argument(
            "--noise-coupling",
            dest="noise_coupling",
            default=None,
            choices=COUPLINGS,
            help="how the samples of a sequence share their starting noise: centered (they sum to "
            f"zero) or independent (default: the model's, else {d.noise_coupling})",
        )


def add_capture_flags(p: argparse.ArgumentParser, what: str, fps_help: str) -> None:
    """--layout, --fps and --up: how ``what`` (the poses, the inputs) were captured (:func:`capture_of`)."""
    p.add_argument(
        "--layout",
        default=None,
        choices=tuple(LAYOUTS),
        help=f"joint layout of {what} (default: the model's own, root-relative); with another "
        "layout, world or camera coordinates are accepted (see --up)",
    )
    p.add_argument("--fps", type=float, default=None, metavar="F", help=fps_help)
    p.add_argument(
        "--up",
        default="y",
        choices=("x", "y", "z", "-x", "-y", "-z"),
        help=f"the vertical axis of {what}' coordinates (default y)",
    )


def capture_of(layout: Optional[str], fps: Optional[float], up: str) -> Optional[Capture]:
    """The ``tcd.Capture`` of the --layout, --fps and --up flags: None (the model's own layout and rate) where
    neither --layout nor --fps is given."""
    return None if layout is None and fps is None else Capture(layout or "h36m22", fps=fps, up=up)


def sampler_changes(args: argparse.Namespace) -> Dict[str, Any]:
    """The sampler fields the flags given set (only those: :meth:`tcd.TCD.sampler_options` puts them over the
    model's own defaults), checked before any file is read; a bad value is an error naming its flag."""
    given = {f: getattr(args, f) for f in SAMPLER_FLAGS if getattr(args, f, None) is not None}
    try:
        checked = dataclasses.asdict(SamplerOptions.build(**given))
    except InvalidInputError as e:
        raise _BadInput(flag_message(e)) from None
    return {f: checked[f] for f in given}


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
    :mod:`tcd._files` without overwrite) is the same error as one there from the start."""
    try:
        yield
    except FileExistsError:
        raise output_exists(path) from None
