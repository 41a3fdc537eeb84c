"""The ``tcd`` command line.

    tcd demo [-o demo.npz] [--model DIR] [--samples N] [--steps S] [--sampler ddpm|ddim|dpmpp2m] [--seed S]
             [--threads N] [--plot demo.gif] [--overwrite] [--quiet]
    tcd info [--model DIR] [--json]
    tcd forecast IN.npz -o OUT.npz [--model DIR] [--samples N] [--steps S] [--sampler ddpm|ddim|dpmpp2m]
                 [--eta E] [--spacing trailing|leading|linspace] [--seed S] [--units m|mm]
                 [--threads N] [--overwrite]
    tcd repair INPUT... -o OUTDIR [--model DIR] [--units m|mm] [--fps F] [--steps N] [--sampler ddpm|ddim|dpmpp2m]
               [--samples N] [--seed S] [--overlap C] [--lookahead L] [--jobs N] [--overwrite] [--report FILE] [--quiet]

IN.npz holds ``poses``, (T, J, 3) or (B, T, J, 3) with NaN = missing, and optionally ``mask``
(1 = observed). OUT.npz receives ``mean``, ``samples``, ``repaired`` and ``seed``. An existing OUT is
never replaced without ``--overwrite``.

Exit codes: 0 success; 2 bad input (arguments, input file, model directory, existing output);
1 any other failure. ``tcd repair`` (see :mod:`tcd.batch_repair`): 1 when any input file failed (the
others are still repaired), 2 for bad arguments.
"""
from __future__ import annotations

import argparse
import json
import sys
import zipfile
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from . import __version__
from .denoiser import supported_kernels
from .exceptions import InvalidInputError, TcdError, WeightsError
from .model import TCD, load
from .options import SAMPLERS, SPACINGS, SamplerOptions

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_BAD_INPUT = 2


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


def add_sampler_flags(p: argparse.ArgumentParser, *, tuning: bool = True) -> None:
    """--steps and --sampler (and with ``tuning`` --eta and --spacing), defaults from SamplerOptions."""
    d = SamplerOptions()
    p.add_argument("--steps", dest="num_inference_steps", type=int, default=None, metavar="S",
                   help="inference steps (default: every training step, the paper's DDPM)")
    p.add_argument("--sampler", default=None, help=f"{', '.join(SAMPLERS)} (default {d.sampler}; dpmpp2m is "
                   "DPM-Solver++(2M))")
    if tuning:
        p.add_argument("--eta", type=float, default=None, help=f"DDIM eta in [0, 1] (default {d.eta:g})")
        p.add_argument("--spacing", dest="timestep_spacing", default=None,
                       help=f"timestep spacing: {', '.join(SPACINGS)} (default {d.timestep_spacing})")


def sampler_options(args: argparse.Namespace) -> SamplerOptions:
    """The SamplerOptions of the sampler flags given; a bad value is an error naming its flag."""
    given = {f: getattr(args, f) for f in SAMPLER_FLAGS if getattr(args, f, None) is not None}
    try:
        return SamplerOptions.build(**given)
    except InvalidInputError as e:
        raise _BadInput(flag_message(e)) from None


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="tcd", description="Temporal Cascaded Diffusion: 3D human motion forecasting.",
                                 epilog="Exit codes: 0 success, 2 bad input, 1 other failure.")
    ap.add_argument("--version", action="version", version=f"tcd {__version__}")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    info = sub.add_parser("info", help="describe a model directory")
    info.add_argument("--model", metavar="DIR", help="model directory (default: the bundled model)")
    info.add_argument("--json", action="store_true", help="print the full configuration as JSON")

    fc = sub.add_parser("forecast", help="forecast the poses of an .npz file",
                        description="Forecast the frames after the observed poses of IN.npz.")
    fc.add_argument("input", metavar="IN.npz", help="input: `poses` (T, J, 3) or (B, T, J, 3), NaN = missing; "
                    "optional `mask` (1 = observed)")
    fc.add_argument("-o", "--output", metavar="OUT.npz", required=True,
                    help="output: mean, samples, repaired, seed")
    fc.add_argument("--model", metavar="DIR", help="model directory (default: the bundled model)")
    fc.add_argument("--samples", type=int, default=5, metavar="N", help="samples per sequence (default 5)")
    add_sampler_flags(fc)
    fc.add_argument("--seed", type=int, default=None, help="noise seed (default: random, recorded in OUT)")
    fc.add_argument("--units", default="m", help="units of the poses: m (default) or mm")
    fc.add_argument("--threads", type=int, default=None, metavar="N", help="worker threads (default: all cores)")
    fc.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    dm = sub.add_parser("demo", help="forecast and repair the bundled demo clip (the README's main job)",
                        description="Forecast and repair the bundled CMU walking clip with the bundled model; "
                        "prints a summary with timings and writes demo.npz.")
    dm.add_argument("--model", metavar="DIR", help="model directory (default: the bundled model)")
    dm.add_argument("-o", "--output", metavar="OUT.npz", default="demo.npz", help="output file (default demo.npz)")
    dm.add_argument("--samples", type=int, default=None, metavar="N", help="samples (default 5)")
    add_sampler_flags(dm, tuning=False)
    dm.add_argument("--seed", type=int, default=0, help="noise and occlusion seed (default 0)")
    dm.add_argument("--threads", type=int, default=None, metavar="N", help="worker threads (default: all cores)")
    dm.add_argument("--plot", metavar="GIF", help="also render an animation (needs matplotlib: "
                    "pip install 'tcd-forecast[plot]')")
    dm.add_argument("--overwrite", action="store_true", help="replace OUT (and GIF) if they exist")
    dm.add_argument("--quiet", action="store_true", help="no progress lines")
    # --- tcd repair (issue 6): defined in tcd.batch_repair
    from . import batch_repair as _batch_repair
    _batch_repair.add_subparser(sub)
    return ap


def _demo(args: argparse.Namespace) -> int:
    from . import demo
    out = Path(args.output)
    targets = [out] + ([Path(args.plot)] if args.plot else [])
    for t in targets:
        if t.exists() and not args.overwrite:
            raise _BadInput(f"The output file {t} exists; pass --overwrite to replace it.")
        if not t.resolve().parent.is_dir():
            raise _BadInput(f"The output directory {t.parent} does not exist.")
    if args.plot:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise _BadInput("--plot needs matplotlib: pip install 'tcd-forecast[plot]'") from None
    model = _load(args.model)
    samples = demo.DEFAULT_SAMPLES if args.samples is None else args.samples
    try:
        res = demo.run(model, samples=samples, options=sampler_options(args), seed=args.seed, threads=args.threads,
                       quiet=args.quiet)
    except InvalidInputError as e:
        raise _BadInput(flag_message(e)) from None
    except ValueError as e:
        raise _BadInput(str(e)) from None
    demo.save(res, out, model)
    print(demo.summary(res, model))
    print(f"\nwrote {out}")
    if args.plot:
        demo.plot(res, Path(args.plot), res["fps"])
        print(f"wrote {args.plot}")
    return EXIT_OK


def _load(model: Optional[str]) -> TCD:
    try:
        return load(model)
    except (FileNotFoundError, NotADirectoryError, WeightsError, InvalidInputError) as e:
        raise _BadInput(str(e)) from None


def _info(args: argparse.Namespace) -> int:
    m = _load(args.model)
    if args.json:
        print(json.dumps({"path": str(m.path), "obs_len": m.obs_len, "horizon": m.horizon,
                          "num_joints": m.num_joints, "config": m.config}, indent=2))
        return EXIT_OK
    data = m.data
    lines: List[str] = [
        f"model directory: {m.path}",
        f"observed frames (obs_len): {m.obs_len}",
        f"forecast frames (horizon): {m.horizon}",
        f"joints: {m.num_joints}" + (f" ({', '.join(m.joint_names)})" if m.joint_names else ""),
        f"fps: {data.get('fps', 'unknown')}",
        f"units: {data.get('units', 'unknown')}, root-relative: {data.get('root_relative', 'unknown')}",
        f"dataset: {data.get('dataset', 'unknown')}; training data: {data.get('training_data', 'unknown')}",
    ]
    for role, d in (("short", m.short), ("long", m.long), ("repair", m.repair_model)):
        if d is None:
            lines.append(f"{role}: none")
            continue
        c = d.config
        mc, diff = c.get("model", {}), c.get("diffusion", {})
        lines.append(f"{role}: window {d.obs_len} + {d.pred_len} frames, channels {mc.get('channels')}, "
                     f"layers {mc.get('num_layers')}, heads {mc.get('num_heads')}, "
                     f"T = {d.num_train_timesteps} ({diff.get('beta_schedule')})"
                     + ("" if mc.get("cond_fill", "zero") == "zero" else f", conditioning {mc['cond_fill']}-filled")
                     + ("" if mc.get("target", "absolute") == "absolute"
                        else f", target {mc['target']} (scale {mc.get('target_scale', 1.0):g})"))
    lines.append(f"kernels: {m.short.kernel} (this CPU supports: {', '.join(supported_kernels())})")
    print("\n".join(lines))
    return EXIT_OK


def _read_npz(path: Path) -> Dict[str, np.ndarray]:
    if not path.is_file():
        raise _BadInput(f"The input file {path} does not exist.")
    try:
        with np.load(path, allow_pickle=False) as f:
            if not isinstance(f, np.lib.npyio.NpzFile):
                raise _BadInput(f"The input file {path} is a single .npy array; an .npz archive with `poses` is required.")
            return {k: f[k] for k in f.files}
    except _BadInput:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise _BadInput(f"The input file {path} is not a readable .npz archive: {e}") from None


def _forecast(args: argparse.Namespace) -> int:
    out = Path(args.output)
    if out.exists() and not args.overwrite:
        raise _BadInput(f"The output file {out} exists; pass --overwrite to replace it.")
    if out.exists() and out.is_dir():
        raise _BadInput(f"The output path {out} is a directory.")
    if not out.parent.is_dir():
        raise _BadInput(f"The output directory {out.parent} does not exist.")
    data = _read_npz(Path(args.input))
    if "poses" not in data:
        raise _BadInput(f"The input file {args.input} has no `poses` array (it has: {', '.join(sorted(data)) or 'nothing'}).")
    options = sampler_options(args)
    model = _load(args.model)
    try:
        f = model.forecast(data["poses"], data.get("mask"), num_samples=args.samples, options=options,
                           seed=args.seed, units=args.units, threads=args.threads)
    except InvalidInputError as e:
        raise _BadInput(flag_message(e, {**OPTION_FLAGS, "obs": "the `poses` array of the input file",
                                          "mask": "the `mask` array of the input file"})) from None
    try:
        with open(out, "wb" if args.overwrite else "xb") as fh:
            np.savez(fh, mean=f.mean, samples=f.samples, repaired=f.repaired, seed=np.uint64(f.seed))
    except FileExistsError:
        raise _BadInput(f"The output file {out} exists; pass --overwrite to replace it.") from None
    print(f"wrote {out}: mean {f.mean.shape}, samples {f.samples.shape}, repaired {f.repaired.shape}, seed {f.seed}")
    return EXIT_OK


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``tcd`` console script; returns the exit code."""
    args = _parser().parse_args(argv)  # exits with 2 on a usage error
    try:
        if args.command == "info":
            return _info(args)
        if args.command == "demo":
            return _demo(args)
        if args.command == "repair":  # tcd repair (issue 6): prints its own errors
            from . import batch_repair as _batch_repair
            return _batch_repair.cli(args)
        return _forecast(args)
    except _BadInput as e:
        print(f"tcd {args.command}: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except TcdError as e:
        print(f"tcd {args.command}: error: {e}", file=sys.stderr)
        return EXIT_FAILURE
    except OSError as e:
        print(f"tcd {args.command}: error: {e}", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
