"""Dataset repair on one machine and on a local Ray cluster (issue 18): frames/s for the local path
(``--jobs`` 1 and 2: engine threads) and for Ray with 1 and 2 workers on the same files, and the Ray
overhead per file on many small files.

    python3 benches/repair_scaling.py [--files 12] [--frames 500] [--small-files 40] \
        [--json benches/results/repair_scaling.json]

Files: the bundled demo clip (25 fps) tiled to ``--frames`` frames, 20 % of joint-frames and one 0.4 s block
hidden per file (seeded), written to a temporary directory; sampler DDPM-10, 1 sample (``--steps``,
``--samples``). Each configuration repairs every file into an empty directory; wall-clock seconds exclude
the Ray cluster's start (reported apart). The overhead per file is (Ray, 1 worker, 1 file per task) minus
(local, 1 thread), divided by the number of small files (``--small-files`` of 50 frames).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import tcd  # noqa: E402
from tcd._repair import RepairOptions, distributed  # noqa: E402
from tcd._repair.runner import collect_tasks, run_tasks  # noqa: E402
from tcd._demo import load_clip  # noqa: E402


def make_files(d: Path, n: int, frames: int, seed: int) -> Path:
    clip = load_clip()["poses"]
    reps = int(np.ceil(frames / len(clip)))
    base = np.concatenate([clip, clip[::-1]] * reps)[:frames]
    rng = np.random.default_rng(seed)
    d.mkdir(parents=True)
    for i in range(n):
        x = base.copy()
        x[rng.random(x.shape[:2]) < 0.2] = np.nan
        s = int(rng.integers(0, frames - 10))
        x[s : s + 10] = np.nan
        np.savez(d / f"take{i:03d}.npz", poses=x)
    return d


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=12)
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--small-files", type=int, default=40)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--samples", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    import ray

    model = tcd.load()
    results: dict = {
        "cpus": os.cpu_count(),
        "files": args.files,
        "frames_per_file": args.frames,
        "sampler": "ddpm",
        "steps": args.steps,
        "samples": args.samples,
        "rows": [],
    }
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        big = make_files(tmp / "big", args.files, args.frames, 0)
        small = make_files(tmp / "small", args.small_files, 50, 1)
        total = args.files * args.frames

        def opts(threads):
            return RepairOptions.make(
                model,
                sampler=tcd.SamplerOptions(sampler="ddpm", num_inference_steps=args.steps),
                num_samples=args.samples,
                threads=threads,
            )

        def local(src, out, threads):
            tasks, _ = collect_tasks([src], out)
            return timed(lambda: run_tasks(model, tasks, opts(threads)))

        def on_ray(src, out, workers, per_task):
            ray.shutdown()
            start = timed(
                lambda: ray.init(num_cpus=workers, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
            )
            distributed.check_writable(out)  # warms a worker up, as the command does
            tasks, _ = collect_tasks([src], out)
            secs = timed(lambda: distributed.run_tasks_ray(model, tasks, opts(1), files_per_task=per_task))
            ray.shutdown()
            return secs, start

        for threads in (1, 2):
            s = local(big, tmp / f"local{threads}", threads)
            results["rows"].append(
                {"path": f"local, --jobs {threads}", "seconds": round(s, 2), "frames_per_s": round(total / s, 1)}
            )
            print(results["rows"][-1], flush=True)
        for workers in (1, 2):
            s, start = on_ray(big, tmp / f"ray{workers}", workers, 1)
            results["rows"].append(
                {
                    "path": f"ray, {workers} worker(s)",
                    "seconds": round(s, 2),
                    "frames_per_s": round(total / s, 1),
                    "cluster_start_s": round(start, 2),
                }
            )
            print(results["rows"][-1], flush=True)
        s_local = local(small, tmp / "small_local", 1)
        s_ray, _ = on_ray(small, tmp / "small_ray", 1, 1)
        s_ray4, _ = on_ray(small, tmp / "small_ray4", 1, 4)
        results["small_files"] = {
            "files": args.small_files,
            "local_s": round(s_local, 2),
            "ray_1_file_per_task_s": round(s_ray, 2),
            "ray_4_files_per_task_s": round(s_ray4, 2),
            "overhead_per_file_ms": round(1000 * (s_ray - s_local) / args.small_files, 1),
            "overhead_per_file_ms_4_per_task": round(1000 * (s_ray4 - s_local) / args.small_files, 1),
        }
        print(results["small_files"], flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
