"""Train a model on a lent GPU within a fixed time budget, in one or more resumable calls.

    python -m training.gpu_session --config training/configs/gpu_long.json --run gpu_carry/long \\
        --data gpu_carry/h36m_model_cache.npz --budget-minutes 8 --minutes 8 \\
        [--init-from python/tcd/weights/long.safetensors] [--copy-to $OUT/long] [--export $OUT/export]

First call (no ``RUN/config.json`` yet): the training step of the config (its batches drawn on the
device, its compile and precision settings) is timed by ``training.throughput`` (``--probe-steps``
after the warm-up, which includes compiling) and one validation is timed; the schedule is then cut
(``plan_schedule``: 20 epochs of as many steps as fit) so that the whole learning-rate schedule (warm-up
and milestones) and its validations fit in ``--budget-minutes`` of training, the chosen config is written
to ``RUN/config.json``, and training runs for ``--minutes``. Later calls resume from ``RUN/last.pt`` with
``RUN/config.json`` for another ``--minutes`` (carry ``RUN`` back to the GPU machine between calls).
``--copy-to`` copies the checkpoints, the config and the log there (the device tool's ``$OUT``);
``--export`` writes the best checkpoint's weights (``training.export.named_checkpoint_weights``) as
``ROLE.safetensors`` there, the file a session compares with the bundled weights.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import torch

from .throughput import time_training_steps, time_validation
from .train import TrainConfig, train, validations_per_schedule


RESERVE_MINUTES = 1.0   # after training: the final validation, checkpoints, export and copies
SCHEDULE_EPOCHS = 20    # a schedule's epochs: its decays at 75 % and 90 % fall on whole epochs (15 and 18)
VALIDATIONS = 4         # validations of the exported weights over a schedule (every 5 of the 20 epochs)
OVERHEAD = 0.03         # of the training time: checkpoints at epoch ends, log lines


def deadline(args, t_call: float) -> float | None:
    """The wall-clock time (``time.time()``) at which training must stop so that the last validation, the
    export and the copies fit in ``--call-minutes``; None without it. Training counts its minutes from
    the end of its own compiling, which a resumed call does cold (no probe compiled in its process): the
    deadline holds the call's limit whatever that took."""
    return None if args.call_minutes is None else t_call + 60 * (args.call_minutes - RESERVE_MINUTES)


def plan_schedule(cfg: TrainConfig, steps_per_s: float, minutes: float, validation_s: float) -> TrainConfig:
    """``cfg`` with ``epochs``, ``steps_per_epoch`` and ``val_every`` set so that the whole schedule (its
    steps at the probed rate, its validations at the timed cost, ``OVERHEAD``) fits in ``minutes``.

    The schedule is cut into ``SCHEDULE_EPOCHS`` epochs of as many steps as fit, not into whole epochs of
    the config's size: with a few minutes of training, epochs of a fixed size would leave up to one epoch's
    time unused and round the learning-rate decays (``int(f * epochs)``) onto the same early epoch. Fewer
    steps than ``SCHEDULE_EPOCHS`` make epochs of one step."""
    epochs = SCHEDULE_EPOCHS
    planned = replace(cfg, epochs=epochs, val_every=max(1, epochs // VALIDATIONS))
    train_s = 60 * minutes * (1 - OVERHEAD) - validations_per_schedule(planned) * validation_s
    steps = max(1, int(steps_per_s * train_s))
    if steps < epochs:
        planned = replace(planned, epochs=steps, val_every=max(1, steps // VALIDATIONS))
    return replace(planned, steps_per_epoch=max(1, steps // planned.epochs))


def fit_call(args, t_call: float, compile_minutes: float, log) -> tuple[float, float]:
    """(training minutes of this call, minutes the schedule is sized for) within ``--call-minutes``: what the
    set-up and the probe left, less the training set-up's own compiling (``compile_minutes``) and
    ``RESERVE_MINUTES``. A one-call schedule (budget <= minutes) is sized to the minutes that remain, so
    that its learning-rate decays happen. (The call's end itself is kept by ``deadline``, whatever the
    compiling takes.)"""
    if args.call_minutes is None:
        return args.minutes, args.budget_minutes
    left = args.call_minutes - (time.time() - t_call) / 60 - compile_minutes - RESERVE_MINUTES
    if left < 0.1:
        raise SystemExit(f"--call-minutes {args.call_minutes}: no time left to train in this call "
                         f"({left:.2f} min after set-up, probe and the {RESERVE_MINUTES} min reserve)")
    minutes = min(args.minutes, left)
    budget = minutes if args.budget_minutes <= args.minutes else args.budget_minutes
    if minutes < args.minutes:
        log(f"--call-minutes {args.call_minutes}: training {minutes:.2f} min in this call (asked {args.minutes}), "
            f"the schedule sized for {budget:.2f} min")
    return minutes, budget


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.gpu_session", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", required=True)
    ap.add_argument("--run", required=True, help="run directory (config.json, last.pt, best.pt, log.txt)")
    ap.add_argument("--data", default=None, help="Human3.6M directory or a cache from training.train --write-cache")
    ap.add_argument("--budget-minutes", type=float, required=True,
                    help="training minutes the whole schedule is sized for (all calls together)")
    ap.add_argument("--minutes", type=float, required=True, help="training minutes of this call")
    ap.add_argument("--probe-steps", type=int, default=30, help="timed steps of the throughput probe")
    ap.add_argument("--init-from", default=None, help="warm start (overrides the config's init_from): .safetensors or .pt")
    ap.add_argument("--export", default=None, help="write the best weights as ROLE.safetensors in this directory")
    ap.add_argument("--workers", type=int, default=max(1, min(12, (os.cpu_count() or 2) - 2)))
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--copy-to", default=None)
    ap.add_argument("--call-minutes", type=float, default=None,
                    help="wall-clock minutes this whole call may take (the device tool's limit is 10): training "
                         "gets what the set-up and probe leave, less a reserve for validation and export")
    args = ap.parse_args(argv)
    t_call = time.time()

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
        args.minutes, _ = fit_call(args, t_call, 0.0, log)
    else:
        cfg = TrainConfig.load(args.config)
        if args.init_from:
            cfg = replace(cfg, init_from=args.init_from)
        if not cfg.steps_per_epoch:
            raise SystemExit(f"{args.config}: a GPU session needs steps_per_epoch (the schedule is sized in epochs)")
        seqs = {split: load_sequences(cfg, args.data, split) for split in ("train", "val")}
        t0 = time.time()
        probe = time_training_steps(cfg, seqs["train"], args.device, warmup=3, steps=args.probe_steps, reps=1, log=log)
        rate = probe["steps_per_s"]
        # training compiles its own forward again, which costs a fraction of the cold compile once this
        # process has compiled the step (a CPU measurement: 2.3 s against 14.7 s): time that one step too
        recompile_s = (time_training_steps(cfg, seqs["train"], args.device, warmup=1, steps=1, reps=1)["warmup_s"]
                       if cfg.compile else 0.0)
        validation_s = time_validation(cfg, seqs["val"], args.device)
        args.minutes, args.budget_minutes = fit_call(args, t_call, recompile_s / 60, log)
        cfg = plan_schedule(cfg, rate, args.budget_minutes, validation_s)
        log(f"probe: {rate:.2f} steps/s ({probe['windows_per_s']:.0f} windows/s, batch {cfg.batch_size}; "
            f"warm-up with compiling {probe['warmup_s']:.0f} s, again {recompile_s:.0f} s, "
            f"probe {time.time() - t0:.0f} s in all), one validation {validation_s:.1f} s -> {cfg.epochs} epochs of {cfg.steps_per_epoch} steps "
            f"({cfg.epochs * cfg.steps_per_epoch * cfg.batch_size:,} windows; {validations_per_schedule(cfg)} "
            f"validations) for {args.budget_minutes:.2f} min")
        chosen.write_text(json.dumps(asdict(cfg), indent=1))
        resume = False
    res = train(cfg, run, sequences=seqs, resume=resume, max_minutes=args.minutes, deadline=deadline(args, t_call),
                device=args.device, workers=args.workers, log=log)
    log(json.dumps({k: v for k, v in res.items() if k != "history"}))
    for h in res["history"]:
        if "val_loss" in h:
            log(f"history: {h}")
    if args.export:
        from .export import export_checkpoint
        best = run / "best.pt" if (run / "best.pt").is_file() else run / "last.pt"
        Path(args.export).mkdir(parents=True, exist_ok=True)
        log(f"exported {export_checkpoint(best, args.export)} from {best}")
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
