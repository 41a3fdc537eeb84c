"""``tcd forecast IN.npz -o OUT.npz``: forecast the frames after the observed poses of a file."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Dict

import numpy as np

from ..exceptions import InvalidInputError
from ..files import UnreadableFile, read_pose_npz, write_npz_atomic
from ..layouts import LAYOUTS
from ..poses import UNIT_SCALE
from .common import (EXIT_OK, OPTION_FLAGS, _BadInput, add_model_flag, add_sampler_flags, flag_message, load_model,
                     output_exists, sampler_options, writing)

# The arguments the input file sets, for the error messages.
FLAGS = {**OPTION_FLAGS, "obs": "the `poses` array of the input file", "mask": "the `mask` array of the input file",
         "fps": "--fps", "layout": "--layout", "up": "--up"}


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser("forecast", help="forecast the poses of an .npz file",
                       description="Forecast the frames after the observed poses of IN.npz.")
    p.add_argument("input", metavar="IN.npz", help="input: `poses` (T, J, 3) or (B, T, J, 3), NaN = missing; "
                   "optional `mask` (1 = observed); or a .bvh file (read as h36m32 joints, at its frame rate)")
    p.add_argument("-o", "--output", metavar="OUT.npz", required=True,
                   help="output: mean, samples, repaired, seed, times (s after the last observed frame)")
    add_model_flag(p)
    p.add_argument("--samples", type=int, default=5, metavar="N", help="samples per sequence (default 5)")
    add_sampler_flags(p)
    p.add_argument("--seed", type=int, default=None, help="noise seed (default: random, recorded in OUT)")
    p.add_argument("--units", default="m", choices=tuple(UNIT_SCALE), help="units of the poses: m (default), cm or mm")
    p.add_argument("--layout", default=None, choices=tuple(LAYOUTS),
                   help="joint layout of the poses (default: the model's own, root-relative); with another "
                   "layout, world or camera coordinates are accepted (see --up)")
    p.add_argument("--fps", type=float, default=None, metavar="F",
                   help="frame rate of the poses (default: the model's); any length is accepted")
    p.add_argument("--up", default="y", choices=("x", "y", "z", "-x", "-y", "-z"),
                   help="the vertical axis of the poses' coordinates (default y)")
    p.add_argument("--threads", type=int, default=None, metavar="N", help="worker threads (default: all cores)")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--quiet", action="store_true", help="no progress bar (shown on a terminal otherwise)")
    return p


def _read_npz(path: Path) -> Dict[str, np.ndarray]:
    try:
        return read_pose_npz(path)
    except FileNotFoundError:
        raise _BadInput(f"The input file {path} does not exist.") from None
    except UnreadableFile as e:
        raise _BadInput(f"The input file {path} cannot be read: it is {e}.") from None


def _read_bvh(path: Path):
    from ..bvh import read_bvh_h36m32
    if not path.is_file():
        raise _BadInput(f"The input file {path} does not exist.")
    try:
        poses, rate = read_bvh_h36m32(path)
    except (UnreadableFile, ImportError) as e:
        raise _BadInput(f"The input file {path} cannot be read: {e}.") from None
    return {"poses": poses}, rate


def run(args: argparse.Namespace) -> int:
    out = Path(args.output)
    if out.exists() and not args.overwrite:
        raise output_exists(out)
    if out.exists() and out.is_dir():
        raise _BadInput(f"The output path {out} is a directory.")
    if not out.parent.is_dir():
        raise _BadInput(f"The output directory {out.parent} does not exist.")
    if out.exists() and Path(args.input).exists() and out.samefile(args.input):
        raise _BadInput(f"The output {out} is the input file: choose another output path (the input is never "
                        "overwritten, with or without --overwrite).")
    layout, fps = args.layout, args.fps
    if Path(args.input).suffix.lower() == ".bvh":
        data, file_fps = _read_bvh(Path(args.input))
        if layout not in (None, "h36m32"):
            raise _BadInput(f"--layout {layout}: a BVH file is read as h36m32 joints (matched by name).")
        layout, fps = "h36m32", fps if fps is not None else file_fps
    else:
        data = _read_npz(Path(args.input))
    options = sampler_options(args)
    model = load_model(args.model)
    try:
        f = model.forecast(data["poses"], data.get("mask"), num_samples=args.samples, options=options,
                           seed=args.seed, units=args.units, threads=args.threads,
                           progress=not args.quiet and sys.stderr.isatty(), layout=layout, fps=fps, up=args.up)
    except InvalidInputError as e:
        raise _BadInput(flag_message(e, FLAGS)) from None
    with writing(out):
        times = {} if f.times is None else {"times": f.times}
        write_npz_atomic(out, args.overwrite, mean=f.mean, samples=f.samples, repaired=f.repaired,
                         seed=np.uint64(f.seed), **times)
    print(f"wrote {out}: mean {f.mean.shape}, samples {f.samples.shape}, repaired {f.repaired.shape}, seed {f.seed}")
    return EXIT_OK
