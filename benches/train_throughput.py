"""Training throughput: windows per second of a full training step (batch drawn, forward, backward,
optimizer step, EMA update) for the short (L = 55), long (L = 75) and repair (L = 50) models.

    python benches/train_throughput.py --json benches/results/train_throughput_h100.json      # on a GPU
    python benches/train_throughput.py --device cpu --preset tiny --batch 8 --steps 3 --warmup 1   # smoke

Every combination of ``--roles`` x ``--impls`` x ``--modes`` x ``--precisions`` is timed in one process,
the goal's configuration (long, channels-last, compiled, bf16) and today's step (long, reference, eager,
fp32) first:

* impl ``channels_last``: the training forward (training/channels_last.py) as ``training.train`` runs
  it; ``reference``: ``TCDModel.forward`` itself, the (B, C, K, L) layout with sequence-first permutes
  that training used before (the peer);
* mode ``eager`` or ``compiled`` (``torch.compile``; its compile time is reported apart, in the warm-up);
* precision ``fp32`` (TF32 matrix products on a GPU) or ``bf16`` (autocast).

The step is ``training.train.train_step`` on batches of ``training.batches.DeviceBatchSource`` (all
drawn on the device) with the role's config (``training/configs/{role}.json``: windows, occlusion mix)
at the size of ``--preset`` (default: the paper's 12 x 64) and ``--batch``. Synthetic motion (random
walks; throughput does not depend on the values) unless ``--data`` names a data cache. Per combination:
``--warmup`` steps, then ``--reps`` timed runs of ``--steps`` steps each, synchronised; the median run
gives windows/s. ``--max-minutes`` skips the combinations left when the time is up (recorded as skipped).
"""
from __future__ import annotations

import argparse
import gc
import itertools
import json
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from training.export import PRESETS  # noqa: E402
from training.throughput import synthetic_sequences, time_training_steps  # noqa: E402
from training.train import TrainConfig, load_sequences  # noqa: E402

ROLES, IMPLS, MODES, PRECISIONS = ("long", "short", "repair"), ("channels_last", "reference"), ("compiled", "eager"), ("bf16", "fp32")
# Timed first, so that a short time budget still measures them: the goal's configuration (the long-term
# model's step as gpu12_long.json trains it) and today's step (the reference layout, eager, fp32), its peer.
FIRST = (("long", "channels_last", "compiled", "bf16"), ("long", "reference", "eager", "fp32"))


def combinations(args) -> list[tuple[str, str, str, str]]:
    """Every requested (role, impl, mode, precision), the ``FIRST`` ones first, then role by role."""
    every = list(itertools.product(args.roles, args.impls, args.modes, args.precisions))
    return [c for c in FIRST if c in every] + [c for c in every if c not in FIRST]


def measure(role: str, impl: str, mode: str, precision: str, args, seqs, batch: int) -> dict:
    cfg = TrainConfig.load(ROOT / "training" / "configs" / f"{role}.json")
    cfg = replace(cfg, model={**PRESETS[args.preset].to_dict(), **cfg.model}, batch_size=batch,
                  ema_decay=args.ema_decay, batches="device", compile=mode == "compiled", amp=precision == "bf16")
    r = time_training_steps(cfg, seqs, args.device, reference=impl == "reference", warmup=args.warmup,
                            steps=args.steps, reps=args.reps)
    return {"role": role, "seq_len": cfg.obs_len + cfg.pred_len, "impl": impl, "mode": mode, "precision": precision, **r}


def measure_fitting(role: str, impl: str, mode: str, precision: str, args, seqs) -> dict:
    """``measure`` at ``--batch``, halved while the step runs out of device memory: windows/s is per window,
    so a smaller batch still measures the step (the full-size fp32 steps need about 444 MiB of saved
    activations per window, benches/train_step_floor.py: batch 256 of the long-term model does not fit an
    H100). The batches that did not fit are recorded (``out_of_memory_at``)."""
    batch, too_big = args.batch, []
    while True:
        try:
            r = measure(role, impl, mode, precision, args, seqs, batch)
            break
        except torch.cuda.OutOfMemoryError:
            too_big.append(batch)
            if batch == 1:
                raise
        finally:
            gc.collect()                      # the failed step's tensors, before the next try takes memory
            if torch.cuda.is_available():
                torch.cuda.empty_cache()
        batch //= 2
    return {**r, "out_of_memory_at": too_big} if too_big else r


def table(results: list[dict]) -> str:
    lines = ["| role (L) | impl | mode | precision | batch | windows/s | ms/step | warm-up s |",
             "|---|---|---|---|---|---|---|---|"]
    for r in results:
        if "windows_per_s" in r:
            lines.append(f"| {r['role']} ({r['seq_len']}) | {r['impl']} | {r['mode']} | {r['precision']} | {r['batch']} | "
                         f"{r['windows_per_s']:,.1f} | {r['ms_per_step']:.1f} | {r['warmup_s']:.1f} |")
        else:
            lines.append(f"| {r['role']} | {r['impl']} | {r['mode']} | {r['precision']} | | "
                         f"{r.get('error') or r.get('skipped')} | | |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--preset", choices=sorted(PRESETS), default="full")
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--steps", type=int, default=20, help="steps per timed run")
    ap.add_argument("--reps", type=int, default=3, help="timed runs per combination (median)")
    ap.add_argument("--warmup", type=int, default=5, help="untimed steps first (compilation happens here)")
    ap.add_argument("--ema-decay", type=float, default=0.999)
    ap.add_argument("--roles", nargs="+", choices=ROLES, default=list(ROLES))
    ap.add_argument("--impls", nargs="+", choices=IMPLS, default=list(IMPLS))
    ap.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    ap.add_argument("--precisions", nargs="+", choices=PRECISIONS, default=list(PRECISIONS))
    ap.add_argument("--data", default=None, help="a data cache (training.train --write-cache) instead of synthetic motion")
    ap.add_argument("--max-minutes", type=float, default=None, help="skip the combinations left after this long")
    ap.add_argument("--json", default=None, help="write the results here")
    args = ap.parse_args(argv)
    for name in ("batch", "steps", "reps"):
        if getattr(args, name) < 1:
            ap.error(f"--{name} must be >= 1")
    device = torch.device(args.device)
    if device.type == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = True      # fp32 means TF32 matrix products, as training runs
        torch.backends.cudnn.allow_tf32 = True
    seqs = load_sequences(TrainConfig(), args.data, "train") if args.data else synthetic_sequences()
    t_start = time.time()
    results = []
    for role, impl, mode, precision in combinations(args):
        skip = None
        if args.max_minutes is not None and time.time() - t_start > 60 * args.max_minutes:
            skip = "time budget"
        elif precision == "bf16" and device.type != "cuda":
            skip = "bf16 autocast is used on CUDA only (TrainConfig.amp)"
        if skip:
            results.append({"role": role, "impl": impl, "mode": mode, "precision": precision, "skipped": skip})
            continue
        try:
            r = measure_fitting(role, impl, mode, precision, args, seqs)
        except Exception as exc:  # noqa: BLE001 - one failing combination (a compiler error) must not stop the rest
            r = {"role": role, "impl": impl, "mode": mode, "precision": precision,
                 "error": f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"[:300]}
        results.append(r)
        print(json.dumps(r), flush=True)
    meta = {"device": torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or "cpu",
            "torch": torch.__version__, "preset": args.preset, "batch": args.batch, "ema_decay": args.ema_decay,
            "data": args.data or "synthetic", "cpu_threads": torch.get_num_threads(),
            "total_s": round(time.time() - t_start, 1)}
    print(table(results))
    if args.json:
        Path(args.json).write_text(json.dumps({"meta": meta, "results": results}, indent=1) + "\n")
    return 0 if all("error" not in r for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
