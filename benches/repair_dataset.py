"""End-to-end throughput and quality of ``tcd repair`` on a directory of long occluded recordings (issue 6).

    python benches/repair_dataset.py [--files N] [--max-frames F] [--fps 50|25] [--steps S] [--samples N]
                                     [--jobs N] [--seed S] [--model DIR] [--repair-args "..."] [--work DIR]
                                     [--json OUT]

Builds a directory of occluded recordings the way a practitioner holds them, then runs the command line
on it as a user would, timed from the outside:

1. the Human3.6M S5 exp-map sequences (``../shared/data/h36m/h36m_expmap_50fps.npz`` or
   ``$TCD_DATA_DIR/h36m``), their first ``--max-frames`` frames (default 1000, 20 s), converted by forward
   kinematics (``tcd._fk.expmap_to_model``) to the model's 22 joints **in millimetres at 50 fps** (so the
   ``--units`` and ``--fps`` paths are exercised), or with ``--fps 25`` every other frame (the model's rate);
2. hidden entries: the sequence is cut into blocks of 50 frames and each block gets one of the
   benchmark's occlusion patterns (``training.masks``: random leg + arm 40 %, consecutive frames 20 %,
   random joints 10-40 %) in turn, seeded; written as ``WORK/in/<action>.npz`` with ``poses`` (NaN where
   hidden) and ``mask``;
3. ``tcd repair WORK/in -o WORK/out --units mm --fps 50 --report WORK/report.json --quiet`` (plus
   ``--steps``, ``--samples``, ``--jobs``, ``--seed`` and ``--repair-args``) in a subprocess; the wall
   time includes starting Python and loading the model;
4. checks that every observed value came back bit for bit, then the ADE (mm) over the hidden entries
   against linear interpolation and the natural cubic spline through each joint's observed frames (the
   same baselines as ``benches/repair_quality.py``, over the whole sequence at its own rate).

Frames per second = source frames of all files / wall-clock seconds of the command. At 50 fps the
command resamples to the model's 25 fps, so it generates half as many frames, and the model sees only the
observations of the frames at 25 fps (the baselines use all of them). Needs scipy
(``pip install 'tcd-forecast[bench]'``) and the Human3.6M data.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import tcd  # noqa: E402
from repair_quality import PATTERNS, linear_fill, spline_fill  # noqa: E402
from training import masks  # noqa: E402
from training.data import h36m  # noqa: E402

BLOCK = 50  # frames per occlusion block (1 s at 50 fps, 2 s at 25 fps)


def occlusion_mask(frames: int, num_joints: int, rng: np.random.Generator) -> np.ndarray:
    """(frames, J) bool observed: blocks of 50 frames, each with the next of the benchmark's patterns."""
    out = np.ones((frames, num_joints), dtype=bool)
    for b, s in enumerate(range(0, frames, BLOCK)):
        _, pattern, rate = PATTERNS[b % len(PATTERNS)]
        m = masks.make_mask(pattern, BLOCK, BLOCK, rng, rate=rate).astype(bool)
        out[s : s + BLOCK] = m[: frames - s]
    return out


def build_inputs(data_dir: Path, indir: Path, files: int, max_frames: int, seed: int, fps: int = 50):
    src = data_dir / "h36m_expmap_50fps.npz"
    if not src.is_file():
        raise SystemExit(f"no Human3.6M exp-map file at {src} (--data-dir or $TCD_DATA_DIR)")
    data = np.load(src)
    keys = sorted(k for k in data.files if k.startswith("S5/"))[:files]
    gts, ms = {}, {}
    for i, key in enumerate(keys):
        rows = data[key][:max_frames][:: 50 // fps]  # 50 fps, or every other frame for 25 fps
        gt = (tcd._fk.expmap_to_model(rows) * 1000.0).astype(np.float32)  # (T, 22, 3) mm
        m = occlusion_mask(len(gt), gt.shape[1], np.random.default_rng([seed, i]))
        name = key.split("/", 1)[1]
        np.savez(indir / f"{name}.npz", poses=np.where(m[..., None], gt, np.nan).astype(np.float32), mask=m)
        gts[name], ms[name] = gt, m
    return gts, ms


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--files", type=int, default=24, help="S5 sequences (default all 24)")
    ap.add_argument("--max-frames", type=int, default=1000, help="first frames (50 fps) of each (default 1000)")
    ap.add_argument(
        "--fps",
        type=int,
        default=50,
        choices=(50, 25),
        help="frame rate of the written recordings: the source's 50, or 25 (every other frame)",
    )
    ap.add_argument(
        "--steps", type=int, default=None, help="tcd repair --steps (default: the model's; the bundled model's DDPM-10)"
    )
    ap.add_argument(
        "--samples",
        type=int,
        default=None,
        help="tcd repair --samples (default: the command's, the model's own: the bundled fill alone)",
    )
    ap.add_argument("--jobs", type=int, default=None, help="tcd repair --jobs (default: all cores)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the masks and of tcd repair")
    ap.add_argument("--repair-args", default="", help='more tcd repair arguments, e.g. "--overlap 5 --lookahead 15"')
    ap.add_argument("--model", default=None, help="model directory (default: the bundled model)")
    ap.add_argument("--data-dir", default=str(h36m.DEFAULT_H36M_DIR))
    ap.add_argument("--work", default=None, help="working directory, kept (default: a temporary one, removed)")
    ap.add_argument("--json", default=None, metavar="OUT")
    args = ap.parse_args(argv)

    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="tcd_repair_dataset_"))
    indir, outdir, report = work / "in", work / "out", work / "report.json"
    if outdir.exists():
        raise SystemExit(f"{outdir} exists: give a fresh --work directory")
    indir.mkdir(parents=True, exist_ok=True)
    try:
        gts, ms = build_inputs(Path(args.data_dir), indir, args.files, args.max_frames, args.seed, args.fps)
        cmd = [
            sys.executable,
            "-m",
            "tcd",
            "repair",
            str(indir),
            "-o",
            str(outdir),
            "--units",
            "mm",
            "--fps",
            str(args.fps),
            "--report",
            str(report),
            "--quiet",
            "--seed",
            str(args.seed),
        ]
        for flag, value in (
            ("--samples", args.samples),
            ("--steps", args.steps),
            ("--jobs", args.jobs),
            ("--model", args.model),
        ):
            if value is not None:
                cmd += [flag, str(value)]
        cmd += args.repair_args.split()
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        seconds = time.perf_counter() - t0
        if proc.returncode != 0:
            sys.stderr.write(proc.stderr)
            raise SystemExit(f"tcd repair exited {proc.returncode}")

        err = {"tcd": [], "linear": [], "spline": []}
        for name, gt in gts.items():
            m = ms[name]
            with np.load(outdir / f"{name}.npz") as z:
                out, prov = z["poses"], json.loads(str(z["provenance"]))
            obs = np.where(m[..., None], gt, np.nan)
            if not np.array_equal(out[m], gt[m]):
                raise SystemExit(f"{name}: observed values changed")
            fills = {
                "tcd": out,
                "linear": linear_fill(obs[None], m[None])[0],
                "spline": spline_fill(obs[None], m[None])[0],
            }
            for k, f in fills.items():
                err[k].append(np.linalg.norm(f.astype(np.float64) - gt, axis=-1)[~m])
        ade = {k: float(np.concatenate(v).mean()) for k, v in err.items()}
        frames = sum(len(g) for g in gts.values())
        res = {
            "command": " ".join(["tcd"] + cmd[3:]).replace(str(work), "WORK"),
            "files": len(gts),
            "fps": args.fps,
            "frames": frames,
            "hidden_entries": int(sum((~m).sum() for m in ms.values())),
            "hidden_fraction": float(np.mean(np.concatenate([(~m).ravel() for m in ms.values()]))),
            "seconds": seconds,
            "frames_per_second": frames / seconds,
            "cores": os.cpu_count(),
            "ade_mm": ade,
            "tcd_over_linear": ade["tcd"] / ade["linear"],
            "tcd_over_spline": ade["tcd"] / ade["spline"],
            "provenance": prov,
            "tcd_version": tcd.__version__,
        }
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)

    steps = prov.get("steps")
    print(
        f"`{res['command']}`: {res['files']} files, {frames} frames at {args.fps} fps "
        f"({res['hidden_fraction']:.0%} of the joint-frames hidden), {seconds:.1f} s wall "
        f"on {os.cpu_count()} cores\n"
    )
    print(
        f"| steps | frames/s ({args.fps} fps source) | tcd ADE (mm) | linear interp. | natural cubic spline "
        "| tcd / linear | tcd / spline |"
    )
    print("|---|---|---|---|---|---|---|")
    how = (
        "the repair fill alone"
        if prov.get("num_samples") == 0
        else f"{prov.get('sampler', 'ddpm').upper()}-{steps} x {prov.get('num_samples')}"
    )
    print(
        f"| {how} | {res['frames_per_second']:.0f} | "
        f"{ade['tcd']:.1f} | {ade['linear']:.1f} | {ade['spline']:.1f} | {res['tcd_over_linear']:.2f} | "
        f"{res['tcd_over_spline']:.2f} |"
    )
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
