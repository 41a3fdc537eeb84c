"""Timing the training step: the number that sizes a GPU session's schedule (training.gpu_session's probe)
and the throughput benchmark (benches/train_throughput.py). One function, so both time the same step
that ``training.train`` runs."""
from __future__ import annotations

import statistics
import time
import warnings

import numpy as np
import torch

from .batches import DeviceBatchSource, Windows
from .diffusion import DiffusionConfig, Schedule
from .model import ModelConfig, TCDModel
from .train import (TrainConfig, amp_enabled, make_ema, make_optimizer, train_step, training_forward,
                    validation_loss)


def synthetic_sequences(n: int = 16, frames: int = 400, joints: int = 22, seed: int = 0) -> list[np.ndarray]:
    """Random-walk motion (metres): the step's cost does not depend on the values."""
    rng = np.random.default_rng(seed)
    return [np.cumsum(rng.normal(scale=0.01, size=(frames, joints, 3)), axis=0).astype(np.float32) for _ in range(n)]


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def time_training_steps(cfg: TrainConfig, seqs: list[np.ndarray], device: str, *, reference: bool = False,
                        warmup: int = 5, steps: int = 20, reps: int = 3, log=lambda *a: None) -> dict:
    """Windows per second of ``training.train``'s step for ``cfg`` (its model, batch size, occlusion mix,
    compile, amp, EMA) on batches drawn on ``device`` from ``seqs``: ``warmup`` untimed steps (compiling
    happens there), then ``reps`` synchronised runs of ``steps`` steps; the median run counts.
    ``reference``: step through ``TCDModel.forward`` (the reference layout) instead, the peer."""
    dev = torch.device(device)
    model_cfg = ModelConfig.from_dict(cfg.model)
    diff_cfg = DiffusionConfig.from_dict(cfg.diffusion)
    L = cfg.obs_len + cfg.pred_len
    torch.manual_seed(cfg.seed)
    model = TCDModel(model_cfg, diff_cfg.num_train_timesteps).to(dev).train()
    sched = Schedule(diff_cfg)
    opt = make_optimizer(model, cfg, device)
    ema = make_ema(model, cfg)
    if reference:
        forward = torch.compile(model) if cfg.compile else model
    else:
        forward = training_forward(model, cfg, (cfg.batch_size, model_cfg.num_features, L), device, log)
    source = DeviceBatchSource(cfg, Windows(seqs, L, cfg.train_stride), sched.T, 10 ** 9, dev)
    amp = amp_enabled(cfg, device)

    def step(i: int) -> None:
        train_step(forward, opt, sched, source.batch(0, i), amp)
        if ema is not None:
            ema.update(model)

    def run(n: int, start: int) -> float:
        _sync(dev)
        t0 = time.perf_counter()
        for i in range(start, start + n):
            step(i)
        _sync(dev)
        return time.perf_counter() - t0

    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats(dev)
    t0 = time.perf_counter()
    run(warmup, 0)
    warm_s = time.perf_counter() - t0
    times = [run(steps, warmup + r * steps) for r in range(reps)]
    med = statistics.median(times)
    out = {"batch": cfg.batch_size, "steps": steps, "reps": reps, "warmup_s": round(warm_s, 3),
           "ms_per_step": round(1000 * med / steps, 3), "windows_per_s": round(cfg.batch_size * steps / med, 1),
           "steps_per_s": round(steps / med, 3), "runs_s": [round(t, 4) for t in times]}
    if dev.type == "cuda":
        out["peak_mem_mib"] = round(torch.cuda.max_memory_allocated(dev) / 2 ** 20, 1)
        # what makes the host wait for the GPU inside a step (there should be nothing): CUDA's sync
        # debug mode warns at each synchronising call of one more step
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            torch.cuda.set_sync_debug_mode("warn")
            try:
                step(warmup + reps * steps)
            finally:
                torch.cuda.set_sync_debug_mode("default")
        out["host_syncs_per_step"] = sum("synchroniz" in str(w.message) for w in caught)
    return out


def time_validation(cfg: TrainConfig, val_seqs: list[np.ndarray], device: str) -> float:
    """Seconds of one ``training.train.validation_loss`` of ``cfg`` (its validation windows, steps and batch
    size; the eager forward it runs) on ``device``, with fresh weights: the cost does not depend on them.
    One cold call, so it includes the eval path's first-call overheads: an upper bound for later calls."""
    model_cfg = ModelConfig.from_dict(cfg.model)
    diff_cfg = DiffusionConfig.from_dict(cfg.diffusion)
    torch.manual_seed(cfg.seed)
    model = TCDModel(model_cfg, diff_cfg.num_train_timesteps).to(device)
    val = Windows(val_seqs, cfg.obs_len + cfg.pred_len, cfg.val_stride)
    t0 = time.perf_counter()
    validation_loss(model, Schedule(diff_cfg), cfg, val, device)   # returns a float: the device is done
    return time.perf_counter() - t0
