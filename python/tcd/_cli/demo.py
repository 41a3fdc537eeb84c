"""``tcd demo``: the command line of :mod:`tcd._demo` (which does the work)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .. import _demo as demo
from ..exceptions import InvalidInputError
from .common import (
    EXIT_OK,
    _BadInput,
    add_model_flag,
    add_sampler_flags,
    flag_message,
    load_model,
    output_exists,
    sampler_changes,
    writing,
)


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "demo",
        help="forecast and repair the bundled demo clip (the README's main job)",
        description="Forecast and repair the bundled CMU walking clip with the bundled model; "
        "prints a summary with timings and writes demo.npz.",
    )
    add_model_flag(p)
    p.add_argument("-o", "--output", metavar="OUT.npz", default="demo.npz", help="output file (default demo.npz)")
    p.add_argument("--samples", type=int, default=None, metavar="N", help="samples (default 5)")
    add_sampler_flags(p, tuning=False)
    p.add_argument("--seed", type=int, default=0, help="noise and occlusion seed (default 0)")
    p.add_argument("--threads", type=int, default=None, metavar="N", help="worker threads (default: all cores)")
    p.add_argument(
        "--plot", metavar="GIF", help="also render an animation (needs matplotlib: pip install 'tcd-forecast[plot]')"
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace OUT (and GIF) even if they are not this command's earlier outputs",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    return p


def run(args: argparse.Namespace) -> int:
    out = Path(args.output)
    # a re-run replaces the demo's own previous outputs (the .npz it wrote, the GIF whose SHA-256 that .npz
    # records), never another file, unless --overwrite
    targets = [out] + ([Path(args.plot)] if args.plot else [])
    for t in targets:
        if t.exists() and not (args.overwrite or demo.is_own_output(t, out)):
            raise output_exists(t)
        if not t.resolve().parent.is_dir():
            raise _BadInput(f"The output directory {t.parent} does not exist.")
    if args.plot:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise _BadInput("--plot needs matplotlib: pip install 'tcd-forecast[plot]'") from None
    model = load_model(args.model)
    samples = demo.DEFAULT_SAMPLES if args.samples is None else args.samples
    changes = sampler_changes(args)
    try:
        res = demo.run(
            model,
            samples=samples,
            seed=args.seed,
            threads=args.threads,
            quiet=args.quiet,
            sampling={t: model.sampler_options(t, **changes) for t in model.sampling},
        )
    except InvalidInputError as e:
        raise _BadInput(flag_message(e)) from None
    except ValueError as e:
        raise _BadInput(str(e)) from None
    plot_sha256 = None
    if args.plot:
        gif = Path(args.plot)
        with writing(gif):
            demo.plot(res, gif, res["fps"], overwrite=args.overwrite or demo.is_own_output(gif, out))
        plot_sha256 = demo.sha256_of(gif)
    with writing(out):
        demo.save(res, out, model, overwrite=args.overwrite or demo.is_own_output(out, out), plot_sha256=plot_sha256)
    print(demo.summary(res, model))
    print(f"\nwrote {out}" + (f" and {args.plot}" if args.plot else ""))
    return EXIT_OK
