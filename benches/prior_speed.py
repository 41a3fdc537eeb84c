"""Speed of the prior forecaster (issue 28): ``tcd.engine.Prior.predict`` against the same model in PyTorch eager
(``training.prior_net.PriorNet.rollout``), in one run.

    python3 benches/prior_speed.py [--model DIR_OR_FILE | --random] [--reps 21] [--batch 1000] \
        [--threads 1 2] [--json benches/results/prior_speed.json]

Jobs: one forecast of ``--horizon`` (25) frames of one sequence, and of a batch of ``--batch`` (1,000)
sequences; each at every ``--threads`` count (tcd's ``threads=``, torch's ``set_num_threads``). Inputs: 50-frame
windows of the bundled demo clip (real motion, metres), repeated to fill the batch. The model: ``--model``
(a model directory holding prior.safetensors, or the file), else the bundled prior where the package has one,
else (or with ``--random``) a seeded random 24-block prior (``training.prior_net.random_prior``; the speed does
not depend on the weights). PyTorch runs the model loaded from the same file, under ``torch.inference_mode``.

Each job times a block of torch calls, then (after a pause: torch's OpenMP workers spin on after a call and
would take the cores from tcd) a block of tcd calls on the same input, each block after one warm-up call;
the table gives medians (ms) and the ratio torch / tcd. Both outputs are
compared first (max abs difference, recorded). The JSON records the CPU model, core count, tcd's kernel path,
the machine's SIMD flags and its load average before and after (on a shared machine other processes take
cores: compare within one run). The issue's goals, reported, never asserted: one forecast under 1 ms, a batch
of 1,000 under 0.1 s on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benches"))

import torch  # noqa: E402

import tcd  # noqa: E402
from machine import cpu_model, cpu_simd_flags  # noqa: E402
from training import fileformat, prior_net  # noqa: E402

GOALS_S = {"one": 1e-3, "batch": 0.1}  # the goals, at 2 threads for the batch
# After a block of torch calls: its OpenMP workers keep spinning after each call and take the cores (tcd's
# next call at 2 threads measured 10x slower right after a torch call, 6x slower 50 ms after, here).
PAUSE_S = 1.0  # --pause


def model_file(args, tmp: Path) -> tuple[Path, str]:
    """(prior.safetensors to time, a description of it)."""
    if args.model:
        p = Path(args.model)
        p = p / fileformat.PRIOR_FILE if p.is_dir() else p
        return p, str(p)
    bundled = tcd.default_model_dir() / fileformat.PRIOR_FILE
    if bundled.is_file() and not args.random:
        return bundled, "bundled"
    path = prior_net.save_prior(tmp / fileformat.PRIOR_FILE, prior_net.random_prior(blocks=args.blocks, seed=0))
    return path, f"random, {args.blocks} blocks"


def windows(batch: int, obs_len: int) -> np.ndarray:
    """(batch, obs_len, K) float32: windows of the demo clip, repeated."""
    from tcd._demo import load_clip

    clip = load_clip()["poses"]
    clip = clip.reshape(len(clip), -1).astype(np.float32)
    wins = np.stack([clip[s : s + obs_len] for s in range(len(clip) - obs_len + 1)])
    return np.ascontiguousarray(wins[np.arange(batch) % len(wins)])


def time_pair(prior, model, obs: np.ndarray, horizon: int, threads: int, reps: int, pause: float = PAUSE_S) -> dict:
    torch.set_num_threads(threads)
    x = torch.from_numpy(obs)

    def run_tcd():
        return prior.predict(obs, horizon, threads=threads)

    def run_torch():
        with torch.inference_mode():
            return model.rollout(x, horizon)

    times = {"tcd": [], "torch": []}
    outputs = {}
    for name, fn in (("torch", run_torch), ("tcd", run_tcd)):
        outputs[name] = np.asarray(fn())  # warm-up; the outputs are compared below
        for _ in range(reps):
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
        time.sleep(pause)
    got, want = outputs["tcd"], outputs["torch"]
    med = {k: statistics.median(v) for k, v in times.items()}
    return {
        "batch": len(obs),
        "threads": threads,
        "horizon": horizon,
        "reps": reps,
        "median_s": med,
        "min_s": {k: min(v) for k, v in times.items()},
        "torch_over_tcd": med["torch"] / med["tcd"],
        "max_abs_diff": float(np.abs(got.astype(np.float64) - want).max()),
    }


def markdown(result: dict) -> str:
    rows = result["rows"]

    def column(r):
        return ("1 forecast" if r["batch"] == 1 else f"batch of {r['batch']:,}") + f", {r['threads']} thr."

    head = "| median | " + " | ".join(column(r) for r in rows) + " |"
    lines = [head, "|---" * (len(rows) + 1) + "|"]
    for name, label in (("tcd", "tcd (Rust)"), ("torch", "PyTorch eager")):
        cells = []
        for r in rows:
            s = r["median_s"][name]
            cell = f"{s * 1e3:.3f} ms" if r["batch"] == 1 else f"{s * 1e3:.1f} ms"
            if name == "torch":
                cell += f" ({r['torch_over_tcd']:.1f}×)"
            cells.append(cell)
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--model", help="a model directory with prior.safetensors, or the file (default: the bundled prior)"
    )
    ap.add_argument("--random", action="store_true", help="time a seeded random prior even where one is bundled")
    ap.add_argument("--blocks", type=int, default=24, help="blocks of the random prior")
    ap.add_argument("--reps", type=int, default=21, help="timed repetitions of each job (the batch job: a third)")
    ap.add_argument("--batch", type=int, default=1000)
    ap.add_argument("--horizon", type=int, default=25)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--pause", type=float, default=PAUSE_S, help="seconds between the torch and the tcd blocks")
    ap.add_argument("--json", type=Path, help="write the result here")
    args = ap.parse_args(argv)

    load_before = os.getloadavg()
    torch_threads = torch.get_num_threads()
    with tempfile.TemporaryDirectory() as tmp:
        path, what = model_file(args, Path(tmp))
        prior = tcd.engine.Prior.load(path)
        model, _ = prior_net.load_prior_file(path)
        rows = []
        for batch, reps in ((1, args.reps), (args.batch, max(1, args.reps // 3))):
            obs = windows(batch, prior.obs_len)
            for threads in args.threads:
                r = time_pair(prior, model, obs, args.horizon, threads, reps, args.pause)
                rows.append(r)
                print(
                    f"B={batch:5d} threads={threads}: tcd {r['median_s']['tcd'] * 1e3:9.3f} ms, torch "
                    f"{r['median_s']['torch'] * 1e3:9.3f} ms ({r['torch_over_tcd']:.1f}x), "
                    f"max abs diff {r['max_abs_diff']:.2g}",
                    flush=True,
                )
    torch.set_num_threads(torch_threads)
    one = [r for r in rows if r["batch"] == 1]
    big = [r for r in rows if r["batch"] == args.batch and r["threads"] == 2]
    result = {
        "model": {
            "weights": what,
            "blocks": prior.blocks,
            "obs_len": prior.obs_len,
            "chunk": prior.chunk,
            "num_features": prior.num_features,
        },
        "machine": {
            "cpu": cpu_model(),
            "cores": os.cpu_count(),
            "cpu_simd_flags": cpu_simd_flags(),
            "tcd_kernel": prior.kernel,
            "tcd_supported_kernels": tcd.engine.supported_kernels(),
            "python": platform.python_version(),
            "torch": torch.__version__,
            "tcd": tcd.__version__,
            # 1-minute load averages before and after: other processes share the cores
            "load_average": [load_before[0], os.getloadavg()[0]],
        },
        "rows": rows,
        "goals": {
            "one_forecast_s": GOALS_S["one"],
            "batch_1000_on_2_threads_s": GOALS_S["batch"],
            "one_forecast_met": bool(one) and min(r["median_s"]["tcd"] for r in one) < GOALS_S["one"],
            "batch_met": (big[0]["median_s"]["tcd"] < GOALS_S["batch"]) if big and args.batch == 1000 else None,
        },
        "command": "python3 benches/prior_speed.py " + " ".join(sys.argv[1:] if argv is None else argv),
    }
    print(markdown(result))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
