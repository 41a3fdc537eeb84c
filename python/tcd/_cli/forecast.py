"""``tcd forecast IN.npz -o OUT.npz``: forecast the frames after the observed poses of a file."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, Dict

import numpy as np

from .._mixture import Mixture
from .._tempo import Tempo
from ..exceptions import InvalidInputError
from .._files import UnreadableFile, read_pose_npz, write_npz_atomic
from .._poses import UNIT_SCALE
from . import common

# The arguments the input file sets, for the error messages.
FLAGS = {
    **common.OPTION_FLAGS,
    "obs": "the `poses` array of the input file",
    "mask": "the `mask` array of the input file",
    "fps": "--fps",
    "layout": "--layout",
    "up": "--up",
    "fill": "--fill",
    "tempo": "--tempo",
    "share": "--generator-share",
    "mode": "--generator-share",
}


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "forecast",
        help="forecast the poses of an .npz file",
        description="Forecast the frames after the observed poses of IN.npz.",
    )
    p.add_argument(
        "input",
        metavar="IN.npz",
        help="input: `poses` (T, J, 3) or (B, T, J, 3), NaN = missing, any T "
        "(the model reads the last obs_len frames; fewer are padded with missing frames); optional "
        "`mask` (1 = observed); or a .bvh file (read as h36m32 joints, at its frame rate)",
    )
    p.add_argument(
        "-o",
        "--output",
        metavar="OUT.npz",
        required=True,
        help="output: mean, samples (not with --point), repaired, seed, times (s after the last observed frame)",
    )
    common.add_model_flag(p)
    p.add_argument(
        "--point",
        action="store_true",
        help="the deterministic point forecast of the prior (TCD.predict): missing entries are "
        "repaired first (see --fill); OUT gets mean, repaired, seed, times and no samples",
    )
    p.add_argument(
        "--fill",
        default="auto",
        choices=("auto", "model", "spline", "linear"),
        help="--point: how missing entries are filled before the prior forecasts (auto: the repair "
        "model where the directory has one, else the natural cubic spline)",
    )
    p.add_argument(
        "--samples",
        type=int,
        default=5,
        metavar="N",
        help="samples per sequence (default 5; with --point, of the repair)",
    )
    common.add_sampler_flags(p)
    p.add_argument("--seed", type=int, default=None, help="noise seed (default: random, recorded in OUT)")
    p.add_argument("--units", default="m", choices=tuple(UNIT_SCALE), help="units of the poses: m (default), cm or mm")
    common.add_capture_flags(p, "the poses", "frame rate of the poses (default: the model's)")
    p.add_argument(
        "--tempo",
        type=float,
        nargs=2,
        default=None,
        metavar=("LO", "HI"),
        help="each sample from the observation replayed at its own tempo, LO to HI (tcd._tempo; 1 1: "
        "none; default: the model's, `tcd info`)",
    )
    p.add_argument(
        "--generator-share",
        type=float,
        default=None,
        metavar="F",
        help="the share of the samples the model's MLP generator draws, after the cascade's (0: the "
        "cascade alone; default: the model's, `tcd info`: 0.5 for the bundled HumanEva-I model)",
    )
    p.add_argument("--threads", type=int, default=None, metavar="N", help="worker threads (default: all cores)")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--quiet", action="store_true", help="no progress bar (shown on a terminal otherwise)")
    return p


def _read_npz(path: Path) -> Dict[str, np.ndarray]:
    try:
        return read_pose_npz(path)
    except FileNotFoundError:
        raise common._BadInput(f"The input file {path} does not exist.") from None
    except UnreadableFile as e:
        raise common._BadInput(f"The input file {path} cannot be read: it is {e}.") from None


def _read_bvh(path: Path):
    from .._bvh import read_bvh_h36m32

    if not path.is_file():
        raise common._BadInput(f"The input file {path} does not exist.")
    try:
        poses, rate = read_bvh_h36m32(path)
    except (UnreadableFile, ImportError) as e:
        raise common._BadInput(f"The input file {path} cannot be read: {e}.") from None
    return {"poses": poses}, rate


def run(args: argparse.Namespace) -> int:
    out = Path(args.output)
    if out.exists() and not args.overwrite:
        raise common.output_exists(out)
    if out.exists() and out.is_dir():
        raise common._BadInput(f"The output path {out} is a directory.")
    if not out.parent.is_dir():
        raise common._BadInput(f"The output directory {out.parent} does not exist.")
    if out.exists() and Path(args.input).exists() and out.samefile(args.input):
        raise common._BadInput(
            f"The output {out} is the input file: choose another output path (the input is never "
            "overwritten, with or without --overwrite)."
        )
    layout, fps = args.layout, args.fps
    if Path(args.input).suffix.lower() == ".bvh":
        data, file_fps = _read_bvh(Path(args.input))
        if layout not in (None, "h36m32"):
            raise common._BadInput(f"--layout {layout}: a BVH file is read as h36m32 joints (matched by name).")
        layout, fps = "h36m32", fps if fps is not None else file_fps
    else:
        data = _read_npz(Path(args.input))
    changes = common.sampler_changes(args)
    model = common.load_model(args.model)
    if args.point and model.prior is None:
        raise common._BadInput(f"--point: the model directory {model.path} has no prior.safetensors.")
    if args.point and args.tempo is not None:
        raise common._BadInput("--tempo samples tempi of the diffusion forecast; --point forecasts one point forecast.")
    if args.tempo is not None and args.generator_share is not None:
        raise common._BadInput("--tempo and --generator-share name two forecast modes: pass one.")
    if args.point and args.generator_share is not None:
        raise common._BadInput(
            "--generator-share splits the samples of a forecast; --point forecasts one point forecast."
        )
    call = model.predict if args.point else model.forecast
    sampler = model.sampler_options("repair" if args.point else "forecast", **changes)
    try:
        capture = common.capture_of(layout, fps, args.up)
        if args.point:
            extra: Dict[str, Any] = {"fill": args.fill}
        elif args.tempo is not None:
            extra = {"mode": Tempo(*args.tempo)}
        else:
            extra = {"mode": None if args.generator_share is None else Mixture(args.generator_share)}
        f = call(
            data["poses"],
            data.get("mask"),
            num_samples=args.samples,
            seed=args.seed,
            units=args.units,
            threads=args.threads,
            progress=not args.quiet and sys.stderr.isatty(),
            capture=capture,
            sampler=sampler,
            **extra,
        )
    except InvalidInputError as e:
        raise common._BadInput(common.flag_message(e, FLAGS)) from None
    arrays = {"mean": f.mean, "repaired": f.repaired, "seed": np.uint64(f.seed)}
    if f.samples is not None:
        arrays["samples"] = f.samples
    if f.times is not None:
        arrays["times"] = f.times
    with common.writing(out):
        write_npz_atomic(out, args.overwrite, **arrays)
    shapes = ", ".join(f"{k} {v.shape}" for k, v in arrays.items() if k in ("mean", "samples", "repaired"))
    print(f"wrote {out}: {shapes}, seed {f.seed}")
    return common.EXIT_OK
