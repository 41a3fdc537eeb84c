"""Prepare the folder a GPU period carries (the device tool's ``carry``; ignored by git), in one command.

    python -m training.gpu_carry [--data ../shared/data/h36m] [--out gpu_carry]
                                 [--candidate DIR] [--protocol RESULTS]

Writes into ``--out``:

* ``h36m_model_cache.npz``: the float16 model-space train/val sequences (``training.train --write-cache``),
  what ``training/gpu_period.sh`` trains on;
* ``h36m/h36m_expmap_50fps.npz``: subject S5 of the exp-map data only, what the evaluation protocol
  (``training.protocol``) reads: the whole file (86 MB) exceeds what a call carries (64 MiB);
* ``init/ROLE.safetensors``: the bundled weights of each role when they are full size (the paper's
  12 x 64), from which the period warm-starts; smaller bundled weights are not carried (the period trains
  from scratch);
* ``candidate/``: ``--candidate DIR``, weights exported by an earlier call to evaluate on the GPU
  (``gpu_period.sh eval``);
* ``protocol/``: ``--protocol RESULTS``, the ``protocol/`` folder an earlier ``gpu_period.sh eval`` call
  handed back (one sub-folder per model directory evaluated): the next call resumes from it.

The data files are kept when they already exist (delete them to rebuild). It ends with the folder's size
against the carry limit.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from .data.h36m import DEFAULT_H36M_DIR

CARRY_LIMIT = 64 * 2**20      # bytes the device tool carries in all (working tree included)
FULL_SIZE = {"channels": 64, "num_layers": 12}
ROLES = ("short", "long", "repair")
BUNDLED = Path(__file__).resolve().parents[1] / "python" / "tcd" / "weights"


def write_eval_subset(data: Path, out: Path, subject: int = 5) -> int:
    """The exp-map sequences of one subject, in the layout ``training.data.h36m.H36MSource`` reads.
    Returns the number of sequences."""
    src = data / "h36m_expmap_50fps.npz" if data.is_dir() else data
    with np.load(src) as z:
        keep = {k: z[k] for k in z.files if k.startswith(f"S{subject}/")}
    if not keep:
        raise SystemExit(f"{src} has no S{subject} sequences")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp.npz")
    np.savez_compressed(tmp, **keep)
    tmp.replace(out)
    return len(keep)


def full_size(path: Path) -> bool:
    from safetensors import safe_open
    with safe_open(str(path), "np") as f:
        model = json.loads(f.metadata()["tcd_config"])["model"]
    return all(model.get(k) == v for k, v in FULL_SIZE.items())


def folder_bytes(d: Path) -> int:
    return sum(p.stat().st_size for p in d.rglob("*") if p.is_file())


def copy_files(src: Path, dst: Path, pattern: str) -> list[str]:
    files = sorted(src.glob(pattern))
    if not files:
        raise SystemExit(f"{src} has no {pattern}")
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for f in files:
        shutil.copy2(f, dst / f.name)
    return [f.name for f in files]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.gpu_carry", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(DEFAULT_H36M_DIR), help="Human3.6M exp-map directory")
    ap.add_argument("--out", default="gpu_carry")
    ap.add_argument("--weights", default=str(BUNDLED), help="the best weights so far (default: the bundled ones)")
    ap.add_argument("--candidate", help="exported weights to evaluate on the GPU")
    ap.add_argument("--protocol", help="evaluation parts already done")
    args = ap.parse_args(argv)
    out, data = Path(args.out), Path(args.data)
    out.mkdir(parents=True, exist_ok=True)

    cache = out / "h36m_model_cache.npz"
    if not cache.is_file():
        from .train import write_cache
        write_cache(str(data), cache)
    print(f"{cache}: {cache.stat().st_size / 2**20:.1f} MiB")
    subset = out / "h36m" / "h36m_expmap_50fps.npz"
    if not subset.is_file():
        write_eval_subset(data, subset)
    print(f"{subset}: {subset.stat().st_size / 2**20:.1f} MiB")

    init = out / "init"
    if init.exists():
        shutil.rmtree(init)
    for role in ROLES:
        src = Path(args.weights) / f"{role}.safetensors"
        if src.is_file() and full_size(src):
            init.mkdir(exist_ok=True)
            shutil.copy2(src, init / src.name)
            print(f"{init / src.name}: warm start")
        else:
            print(f"{role}: no full-size weights in {args.weights}; the period trains it from scratch")
    if args.candidate:
        print(f"{out / 'candidate'}: {', '.join(copy_files(Path(args.candidate), out / 'candidate', '*.safetensors'))}")
    if args.protocol:
        dst = out / "protocol"
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(args.protocol, dst)
        print(f"{dst}: {len(list(dst.rglob('*_*/*.json')))} units (action x part) done")

    size = folder_bytes(out)
    print(f"{out}: {size / 2**20:.1f} MiB of the {CARRY_LIMIT / 2**20:.0f} MiB a call carries (with the working tree)")
    if size > CARRY_LIMIT:
        print(f"{out} is too large to carry", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
