"""The ``tcd`` command line.

    tcd demo [-o demo.npz] [--model DIR] [--samples N] [--steps S] [--sampler ddpm|ddim|dpmpp2m] [--seed S]
             [--threads N] [--plot demo.gif] [--overwrite] [--quiet]
    tcd info [--model DIR] [--json]
    tcd forecast IN.npz -o OUT.npz [--model DIR] [--samples N] [--steps S] [--sampler ddpm|ddim|dpmpp2m]
                 [--eta E] [--spacing trailing|leading|linspace] [--seed S] [--units m|cm|mm]
                 [--layout L] [--fps F] [--up AXIS] [--threads N] [--overwrite] [--quiet]
    tcd repair INPUT... -o OUTDIR [--model DIR] [--units m|cm|mm] [--fps F] [--layout L] [--up AXIS] [--steps N]
               [--sampler ddpm|ddim|dpmpp2m]
               [--samples N] [--seed S] [--overlap C] [--lookahead L] [--jobs N] [--overwrite] [--report FILE] [--quiet]

IN.npz holds ``poses``, (T, J, 3) or (B, T, J, 3) with NaN = missing, and optionally ``mask``
(1 = observed). OUT.npz receives ``mean``, ``samples``, ``repaired``, ``seed`` and ``times``. An existing OUT is
never replaced without ``--overwrite``; every output is written under a temporary name and renamed into
place (:mod:`tcd._files`), so it is complete or absent.

Exit codes: 0 success; 2 bad input (arguments, input file, model directory, existing output);
1 any other failure; 130 interrupted (Ctrl-C: one line, no traceback, nothing half-written); 143 terminated
(SIGTERM, stopped the same way). ``tcd repair`` (see :mod:`tcd._repair`): 1 when any input file failed
(the others are still repaired), 2 for bad arguments, 130 / 143 when stopped (re-run it to resume). A closed
pipe (``tcd info | head``) ends quietly.

Signals (:func:`.common.stop_signals`): SIGINT raises KeyboardInterrupt (Python's handler) and SIGTERM the
command line's own; either stops a running engine call within about 0.1 s plus one forward. A signal ignored
when ``tcd`` starts stays ignored, as in Python, GNU make and coreutils: a non-interactive shell (a script,
CI) starts ``tcd ... &`` with SIGINT ignored, so that the Ctrl-C meant for the foreground command does not
stop it; stop such a run with ``kill PID`` (SIGTERM).

One module per command (``info``, ``forecast``, ``demo``, ``repair``: ``add_parser`` and ``run``); what
they share (exit codes, the option-to-flag mapping, the sampler flags) is in ``common``.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Optional, Sequence

from .._native import __version__
from ..exceptions import TcdError
from . import demo, forecast, info, repair
from .common import (
    EXIT_BAD_INPUT,
    EXIT_FAILURE,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_TERMINATED,
    OPTION_FLAGS,
    SAMPLER_FLAGS,
    _BadInput,
    add_sampler_flags,
    flag_message,
    sampler_changes,
    stop_signals,
    stopped,
)

__all__ = [
    "main",
    "EXIT_OK",
    "EXIT_FAILURE",
    "EXIT_BAD_INPUT",
    "EXIT_INTERRUPTED",
    "EXIT_TERMINATED",
    "OPTION_FLAGS",
    "SAMPLER_FLAGS",
    "flag_message",
    "add_sampler_flags",
    "sampler_changes",
]

COMMANDS = {"info": info, "forecast": forecast, "demo": demo, "repair": repair}  # in the order of --help


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="tcd",
        description="Temporal Cascaded Diffusion: 3D human motion forecasting.",
        epilog="Exit codes: 0 success, 2 bad input, 1 other failure.",
    )
    ap.add_argument("--version", action="version", version=f"tcd {__version__}")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for command in COMMANDS.values():
        command.add_parser(sub)
    return ap


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``tcd`` console script; returns the exit code."""
    prog = "tcd"  # "tcd <command>" once the arguments are parsed
    try:
        with stop_signals():  # SIGTERM stops a command as Ctrl-C does, until it returns
            args = _parser().parse_args(argv)  # exits with 2 on a usage error
            prog = f"tcd {args.command}"
            return COMMANDS[args.command].run(args)
    except _BadInput as e:
        return _error(prog, e, EXIT_BAD_INPUT)
    except KeyboardInterrupt as e:
        # Ctrl-C or SIGTERM: the engine stopped its threads and no output was half-written (atomic writes)
        word, code = stopped(e)
        print(f"{prog}: {word}", file=sys.stderr)
        return code
    except BrokenPipeError:
        # the reader went away (`tcd info | head`): stop quietly, and let nothing flush into the closed pipe
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    except (TcdError, OSError) as e:
        return _error(prog, e, EXIT_FAILURE)


def _error(prog: str, e: Exception, code: int) -> int:
    print(f"{prog}: error: {e}", file=sys.stderr)
    return code
