"""Time one denoiser forward (batch 1) of the tcd Rust engine against PyTorch eager, same weights.

    python benches/forward_vs_torch.py [--preset full] [--lengths 75 55] [--reps 15] [--threads 1 2] [--json OUT]

Runs are interleaved (tcd, torch, tcd, torch, ...) and medians reported, with the ratio torch / tcd.
``--threads`` sets PyTorch's intra-op threads; the portable tcd engine runs one chain's forward on one
thread (independent chains run in parallel).
Outputs are checked to agree (rtol 1e-4, atol 1e-5) before timing.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import tcd  # noqa: E402
from training.export import load_model_file, random_init_dir  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="full", choices=["full", "tiny"])
    ap.add_argument("--lengths", type=int, nargs="+", default=[75, 55])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    d = random_init_dir(Path(tempfile.mkdtemp()) / "m", preset=args.preset, seed=0)
    rows = []
    for L in args.lengths:
        path = d / ("long.safetensors" if L > 55 else "short.safetensors")
        model, _, cfg = load_model_file(path)
        K = cfg["model"]["num_features"]
        rng = np.random.default_rng(0)
        noisy = rng.normal(size=(1, K, L)).astype(np.float32)
        observed = rng.normal(scale=0.3, size=(1, K, L)).astype(np.float32)
        mask = np.zeros((1, K, L), np.float32)
        mask[..., :50] = 1
        for threads in args.threads:
            torch.set_num_threads(threads)
            den = tcd.Denoiser.load(path)   # one forward of one chain runs on one thread in the portable engine
            t_in = [torch.from_numpy(a) for a in (noisy, observed, mask)]
            step = torch.tensor([25])

            def run_torch():
                with torch.no_grad():
                    return model(*t_in, step).numpy()

            def run_tcd():
                return den.forward(noisy, observed, mask, 25)

            np.testing.assert_allclose(run_tcd(), run_torch(), rtol=1e-4, atol=1e-5)
            times = {"tcd": [], "torch": []}
            for _ in range(args.reps):
                for name, fn in (("tcd", run_tcd), ("torch", run_torch)):
                    t0 = time.perf_counter()
                    fn()
                    times[name].append(time.perf_counter() - t0)
            med = {k: 1000 * statistics.median(v) for k, v in times.items()}
            row = {"L": L, "K": K, "threads": threads, "tcd_ms": med["tcd"], "torch_eager_ms": med["torch"],
                   "torch_over_tcd": med["torch"] / med["tcd"], "reps": args.reps}
            rows.append(row)
            print(f"L={L} threads={threads}: tcd {med['tcd']:.1f} ms, torch eager {med['torch']:.1f} ms, "
                  f"ratio torch/tcd {row['torch_over_tcd']:.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"preset": args.preset, "torch": torch.__version__, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
