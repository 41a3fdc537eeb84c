"""A/B timing of two installed versions of tcd, interleaved in one run (issue 16: "speed does not drop").

Each version runs in its own Python interpreter (a venv with that version installed) as a persistent
worker that loads the model once and then times one call per request; the driver asks A, then B, then
A, ... so that both see the same machine state, and reports the median of each. Only one worker computes
at a time. The model directory is made here with the current training code (the weight format is the
same for both versions), so the old version does not need torch.

    python3 benches/ab_versions.py --a /work/venv-base/bin/python --b python3 --reps 15 \
        --out benches/results/ab_redesign.json

Jobs: ``forward`` (one denoiser forward at the paper's size: full preset, 5 samples, 75 frames, the
short model) and ``forecast`` (one whole cascade forecast at the paper's size: DDPM-50 in both stages,
one sample, about 5 s on one Zen 5 core), each at 1 thread and at all cores.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Runs inside each interpreter: reads "job threads" lines, answers with seconds per call.
WORKER = r"""
import sys, time, numpy as np, tcd
model = tcd.load(sys.argv[1])
d = model.short
rng = np.random.default_rng(0)
obs = rng.normal(scale=0.3, size=(50, model.num_joints, 3)).astype(np.float32)
F, L = d.num_features, d.seq_len
noisy = rng.normal(size=(5, F, L)).astype(np.float32)
observed = np.zeros((5, F, L), np.float32)
mask = np.zeros((5, F, L), np.float32)
mask[:, :, :d.obs_len] = 1
jobs = {
    "forward": lambda t: d.forward(noisy, observed, mask, 10, threads=t),
    "forecast": lambda t: model.forecast(obs, num_samples=1, seed=0, threads=t),
}
print(tcd.__file__, flush=True)
for line in sys.stdin:
    job, threads = line.split()
    fn = jobs[job]
    t0 = time.perf_counter()
    fn(int(threads))
    print(time.perf_counter() - t0, flush=True)
"""


class Worker:
    def __init__(self, python: str, model_dir: Path):
        self.proc = subprocess.Popen([python, "-c", WORKER, str(model_dir)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, cwd=tempfile.gettempdir())
        self.location = self.proc.stdout.readline().strip()

    def time(self, job: str, threads: int) -> float:
        self.proc.stdin.write(f"{job} {threads}\n")
        self.proc.stdin.flush()
        answer = self.proc.stdout.readline()
        if not answer:
            raise RuntimeError(f"the worker at {self.location} stopped (exit code {self.proc.wait()})")
        return float(answer)

    def close(self):
        self.proc.stdin.close()
        self.proc.wait()


def cpu_model() -> str:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--a", required=True, help="Python interpreter of version A (the baseline)")
    ap.add_argument("--b", required=True, help="Python interpreter of version B")
    ap.add_argument("--reps", type=int, default=15, help="timed calls per version, job and thread count")
    ap.add_argument("--jobs", nargs="+", default=["forward", "forecast"], choices=["forward", "forecast"])
    ap.add_argument("--out", type=Path, help="write the medians as JSON here")
    args = ap.parse_args(argv)

    sys.path.insert(0, str(ROOT))
    from training.export import random_init_dir
    with tempfile.TemporaryDirectory() as tmp:
        model_dir = random_init_dir(Path(tmp) / "full", preset="full", seed=0)
        workers = {"A": Worker(args.a, model_dir), "B": Worker(args.b, model_dir)}
        results = []
        for job in args.jobs:
            for threads in (1, os.cpu_count() or 1):
                for w in workers.values():
                    w.time(job, threads)                      # warm-up: pools, caches, page faults
                times = {k: [] for k in workers}
                for _ in range(args.reps):
                    for k, w in workers.items():
                        times[k].append(w.time(job, threads))
                med = {k: 1000 * statistics.median(v) for k, v in times.items()}
                row = {"job": job, "threads": threads, "A_ms": round(med["A"], 2), "B_ms": round(med["B"], 2),
                       "B_over_A": round(med["B"] / med["A"], 4)}
                print(json.dumps(row), flush=True)
                results.append(row)
        for w in workers.values():
            w.close()
    report = {"cpu": cpu_model(), "reps": args.reps, "A": {"python": args.a, "tcd": workers["A"].location},
              "B": {"python": args.b, "tcd": workers["B"].location}, "results": results}
    if args.out:
        args.out.write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
