"""Train a model on a lent GPU within a fixed time budget, in one or more resumable calls.

    python -m training.gpu_session --config training/configs/gpu_repair.json --run runs/gpu_repair \\
        --data data_cache/h36m_model_cache.npz --budget-minutes 16 --minutes 8 [--copy-to DIR]

First call (no ``RUN/config.json`` yet): a short probe (``--probe-seconds``) measures the training
steps per second on this machine with the real data pipeline; the number of epochs is then set so that
the whole learning-rate schedule (milestones included) fits in ``--budget-minutes`` of training, the
chosen config is written to ``RUN/config.json``, and training runs for ``--minutes``. Later calls
resume from ``RUN/last.pt`` with ``RUN/config.json`` for another ``--minutes``. ``--copy-to`` copies the
checkpoints, the config and the log there (the device tool's ``$OUT``).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import time
from dataclasses import asdict, replace
from pathlib import Path

import torch

from .train import TrainConfig, train


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.gpu_session", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", required=True)
    ap.add_argument("--run", required=True, help="run directory (config.json, last.pt, best.pt, log.txt)")
    ap.add_argument("--data", default=None, help="Human3.6M directory or a cache from training.train --write-cache")
    ap.add_argument("--budget-minutes", type=float, required=True,
                    help="training minutes the whole schedule is sized for (all calls together)")
    ap.add_argument("--minutes", type=float, required=True, help="training minutes of this call")
    ap.add_argument("--probe-seconds", type=float, default=45.0)
    ap.add_argument("--workers", type=int, default=max(1, min(12, (os.cpu_count() or 2) - 2)))
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--copy-to", default=None)
    args = ap.parse_args(argv)

    run = Path(args.run)
    run.mkdir(parents=True, exist_ok=True)
    logf = open(run / "log.txt", "a")

    def log(*a):
        msg = " ".join(str(x) for x in a)
        print(msg, flush=True)
        logf.write(msg + "\n")
        logf.flush()

    if args.device.startswith("cuda"):
        log(f"device {torch.cuda.get_device_name(0)}, torch {torch.__version__}, {os.cpu_count()} CPUs, "
            f"{args.workers} loader workers")
    chosen = run / "config.json"
    from .train import load_sequences
    if chosen.is_file():
        cfg = TrainConfig(**json.loads(chosen.read_text()))
        seqs = {split: load_sequences(cfg, args.data, split) for split in ("train", "val")}
        resume = True
    else:
        cfg = TrainConfig.load(args.config)
        seqs = {split: load_sequences(cfg, args.data, split) for split in ("train", "val")}
        probe_cfg = replace(cfg, epochs=10_000, val_every=10_000)
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.time()
            res = train(probe_cfg, tmp, sequences=seqs, max_minutes=args.probe_seconds / 60, device=args.device,
                        workers=args.workers, log=lambda *a: None)
            steps = res["epoch"] * cfg.steps_per_epoch + res["batch"]
        rate = steps / args.probe_seconds
        epochs = max(1, int(rate * 60 * args.budget_minutes * 0.97 / cfg.steps_per_epoch))
        log(f"probe: {steps} steps in {args.probe_seconds:.0f} s of training ({time.time() - t0:.0f} s with start-up): "
            f"{rate:.1f} steps/s, batch {cfg.batch_size} -> {epochs} epochs of {cfg.steps_per_epoch} steps "
            f"for {args.budget_minutes} min")
        cfg = replace(cfg, epochs=epochs, val_every=min(cfg.val_every, epochs))
        chosen.write_text(json.dumps(asdict(cfg), indent=1))
        resume = False
    res = train(cfg, run, sequences=seqs, resume=resume, max_minutes=args.minutes, device=args.device,
                workers=args.workers, log=log)
    log(json.dumps({k: v for k, v in res.items() if k != "history"}))
    for h in res["history"]:
        if "val_loss" in h:
            log(f"history: {h}")
    logf.close()
    if args.copy_to:
        dst = Path(args.copy_to)
        dst.mkdir(parents=True, exist_ok=True)
        for name in ("config.json", "last.pt", "best.pt", "log.txt"):
            if (run / name).is_file():
                shutil.copy2(run / name, dst / name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
