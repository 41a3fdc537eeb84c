"""Training speed on this CPU (issue 29, "learn more per CPU-minute, measured"): windows per second of the
real training step of a config, per batch size, thread count and forward variant, in one run.

    python3 benches/train_speed.py --config training/configs/humaneva_long_2.json \
        [--prior python/tcd/weights_humaneva/prior.safetensors] [--batch 8 32 128] [--threads 1 2] \
        [--variants eager sdpa compile bf16] [--seconds 20] [--profile STEPS] [--json benches/results/train_speed.json]

A step is what ``training.train`` runs: the batch drawn by ``training.batches.BatchSource`` from the config's real
training windows (the dataset must be present), ``training.train.train_step`` through the channels-last forward, and
the EMA update when the config has one. Variants: ``eager``; ``sdpa`` (eager with PyTorch's fused attention kernel
in place of the explicit product the CPU forward uses, ``training.channels_last``); ``compile`` (``torch.compile``
of the forward, as ``"compile": true`` does); ``bf16`` (eager under ``torch.autocast("cpu", torch.bfloat16)``, which
only pays on a CPU with AVX512-BF16 or AMX). Each cell warms up, then times whole steps for ``--seconds`` in 5
blocks and reports the median block's windows/s and the process's CPU seconds per 1,000 windows. Timings on a shared
machine are noisy: compare cells of one run, never against a fixed threshold.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benches"))

import torch  # noqa: E402

from machine import cpu_model, cpu_simd_flags  # noqa: E402
from training import channels_last  # noqa: E402
from training.batches import BatchSource, Windows  # noqa: E402
from training.train import build_model, load_sequences, make_ema, make_optimizer, train_step, training_forward  # noqa: E402
from training.train_config import TrainConfig  # noqa: E402


def measure(cfg: TrainConfig, windows: Windows, variant: str, seconds: float, log, profile: int = 0) -> dict:
    model, sched = build_model(cfg, "cpu")
    opt = make_optimizer(model, cfg, "cpu")
    ema = make_ema(model, cfg)
    L = cfg.obs_len + cfg.pred_len
    run_cfg = dataclasses.replace(cfg, compile=variant == "compile")
    forward = training_forward(model, run_cfg, (cfg.batch_size, model.cfg.num_features, L), "cpu", log)
    source = BatchSource(cfg, windows, sched.T, 1 << 30)
    amp = variant == "bf16"
    channels_last.EXPLICIT_CPU_ATTENTION = variant != "sdpa"
    i = 0

    def step():
        nonlocal i
        loss = train_step(forward, opt, sched, source.batch(0, i), amp)
        if ema is not None:
            ema.update(model)
        i += 1
        return loss

    for _ in range(3):
        step()
    if profile:  # where a step's time goes: torch.profiler over a few steps, ops by their own CPU time
        from torch.profiler import ProfilerActivity

        with torch.profiler.profile(activities=[ProfilerActivity.CPU]) as prof:
            for _ in range(profile):
                step()
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=12), flush=True)
    blocks = []
    per_block = seconds / 5
    for _ in range(5):
        w0, c0, n = time.perf_counter(), time.process_time(), 0
        while time.perf_counter() - w0 < per_block:
            float(step())
            n += 1
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        blocks.append({"steps": n, "wall_s": wall, "cpu_s": cpu})
    rates = [b["steps"] * cfg.batch_size / b["wall_s"] for b in blocks]
    cpu_per_k = [1000 * b["cpu_s"] / (b["steps"] * cfg.batch_size) for b in blocks]
    return {
        "windows_per_s": statistics.median(rates),
        "cpu_s_per_1000_windows": statistics.median(cpu_per_k),
        "blocks": blocks,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", required=True, help="a training config (training/configs/*.json)")
    ap.add_argument("--prior", help="the prior of a cond_fill='prior' config, in place of the config's 'prior'")
    ap.add_argument("--data", help="the dataset directory (default: the config's dataset at its default place)")
    ap.add_argument("--batch", type=int, nargs="+", default=[8, 32, 128])
    ap.add_argument("--threads", type=int, nargs="+", default=[1])
    ap.add_argument(
        "--variants",
        nargs="+",
        default=["eager", "sdpa", "compile", "bf16"],
        choices=["eager", "sdpa", "compile", "bf16"],
    )
    ap.add_argument("--seconds", type=float, default=20.0, help="timed seconds per cell (after the warm-up)")
    ap.add_argument(
        "--profile",
        type=int,
        default=0,
        metavar="STEPS",
        help="before each cell's timing, profile this many steps and print the ops' CPU time",
    )
    ap.add_argument("--json", help="write the table here")
    args = ap.parse_args(argv)

    cfg = TrainConfig.load(args.config)
    if args.prior:
        cfg = dataclasses.replace(cfg, prior=args.prior)
    windows = Windows(load_sequences(cfg, args.data, "train"), cfg.obs_len + cfg.pred_len, cfg.train_stride)
    print(
        f"{cpu_model()}, {os.cpu_count()} cores, torch {torch.__version__}; {args.config}: "
        f"{len(windows):,} training windows",
        flush=True,
    )
    rows, threads_before = [], torch.get_num_threads()
    for threads in args.threads:
        torch.set_num_threads(threads)
        for batch in args.batch:
            for variant in args.variants:
                cell = measure(
                    dataclasses.replace(cfg, batch_size=batch), windows, variant, args.seconds, print, args.profile
                )
                cell.update(threads=threads, batch=batch, variant=variant)
                rows.append(cell)
                print(
                    f"threads {threads} batch {batch:4d} {variant:8s} {cell['windows_per_s']:8.1f} windows/s "
                    f"{cell['cpu_s_per_1000_windows']:7.1f} CPU s / 1,000 windows",
                    flush=True,
                )
                if args.json:  # after every cell: a run cut short keeps what it measured
                    Path(args.json).write_text(
                        json.dumps(
                            {
                                "command": "python3 benches/train_speed.py "
                                + " ".join(sys.argv[1:] if argv is None else argv),
                                "config": args.config,
                                "cpu": cpu_model(),
                                "cores": os.cpu_count(),
                                "cpu_simd_flags": cpu_simd_flags(),
                                "torch": torch.__version__,
                                "load_avg": os.getloadavg(),
                                "rows": rows,
                            },
                            indent=1,
                        )
                        + "\n"
                    )
    torch.set_num_threads(threads_before)
    return 0


if __name__ == "__main__":
    sys.exit(main())
