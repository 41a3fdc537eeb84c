"""Train a TCD model (short-term, long-term or repair) with the paper recipe (spec section 2).

    python -m training.train --config training/configs/short.json --out runs/short [--resume]
                             [--max-minutes M] [--device cpu|cuda]
    python -m training.train --config training/configs/humaneva_long.json --out runs/humaneva_long

``"dataset": "humaneva"`` trains on HumanEva-I instead (the DLow / GSPS split: the Train split's chunks,
bad takes removed, joints 1..14 relative to the pelvis, 60 Hz; ``training.data.humaneva``). That protocol
has no validation split, so the validation loss is measured on windows of the training chunks (stride
``val_stride``): it tracks the fit, it is not held out.

Defaults (TrainConfig) are the paper's: Adam lr 1e-3, weight decay 1e-6, batch 32, 50 epochs,
learning rate x0.1 at 75 % and 90 % of the epochs, validation loss (mean over all diffusion steps)
every 5 epochs on S11 windows of stride 25, all training windows of stride 1 from S1, S6, S7, S8, S9.
Unlike the official code, every draw is seeded (batch order, masks, t and noise are functions of
(seed, epoch, batch)), so a resumed run continues exactly where it stopped, and the best-validation
checkpoint is kept beside the last one (``best.pt``, ``last.pt``).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from .batches import BatchSource, Windows, action_weights, make_batch
from .train_config import TrainConfig, stored_config
from .diffusion import DiffusionConfig, Schedule, training_loss
from .imle import Choice, EngineSearch, imle_choose, imle_loss
from .model import ModelConfig, TCDModel, count_parameters, load_grown
from .widen import widen_to


# ------------------------------------------------------------------------------------------ data


def load_sequences(cfg: TrainConfig, data: str | None, split: str) -> list[np.ndarray]:
    """Model-space sequences (T, J, 3) metres for a split. ``data`` is a raw data directory or a cache
    written by ``--write-cache`` (an npz of ``{split}/{key}`` arrays); for HumanEva-I the data directory
    or its .npz, and both splits are the Train split's chunks (see the module docstring)."""
    if cfg.dataset == "humaneva":
        from .data.humaneva import training_mix, training_sequences

        if split == "train":
            return training_mix(cfg.h36m_share, cfg.obs_len + cfg.pred_len, data)
        return list(training_sequences(data).values())
    from .data.h36m import DEFAULT_H36M_DIR, H36M

    path = Path(data) if data else DEFAULT_H36M_DIR
    if path.is_file() and path.name.startswith("h36m_model_cache"):
        with np.load(path) as z:
            return [z[k].astype(np.float32) for k in sorted(z.files) if k.startswith(split + "/")]
    return [seq for _, seq in H36M(path).sequences(split)]


def write_cache(data: str | None, out: str | Path) -> None:
    """A compact float16 cache of the model-space train/val sequences (quicker to load than the raw data)."""
    from .data.h36m import DEFAULT_H36M_DIR, H36M

    h = H36M(data or DEFAULT_H36M_DIR)
    arrays = {f"{split}/{key}": seq.astype(np.float16) for split in ("train", "val") for key, seq in h.sequences(split)}
    np.savez_compressed(out, **arrays)


def load_prior(path: str):
    """The prior forecaster a ``cond_fill="prior"`` model is trained around: an exported
    ``prior.safetensors`` or a ``training.prior`` checkpoint (``last.pt``)."""
    if not path:
        raise ValueError("train config: a cond_fill='prior' model needs 'prior' (prior.safetensors or a prior last.pt)")
    if not Path(path).is_file():
        raise FileNotFoundError(f"train config: prior: no file at {path}")
    if str(path).endswith(".safetensors"):
        from .prior_net import load_prior_file

        return load_prior_file(path)[0]
    from .prior import load

    return load(path)


# ------------------------------------------------------------------------------------------ loop


def learning_rate(cfg: TrainConfig, step: int, steps_per_epoch: int) -> float:
    """The learning rate of optimizer step ``step`` (0-based): ``cfg.lr``, times ``gamma`` for each
    milestone epoch (``int(f * epochs)``) reached (the paper's MultiStepLR), times a linear warm-up over
    the first ``warmup_steps`` steps. A pure function of the step, so a resumed run needs no scheduler state."""
    epoch = step // steps_per_epoch
    lr = cfg.lr * cfg.gamma ** sum(epoch >= int(f * cfg.epochs) for f in cfg.milestones)
    return lr * min(1.0, (step + 1) / cfg.warmup_steps) if cfg.warmup_steps else lr


def validates_after(cfg: TrainConfig, epoch: int) -> bool:
    """Whether training validates after ``epoch`` (1-based count of finished epochs): every ``val_every``
    epochs and after the last one."""
    return epoch % cfg.val_every == 0 or epoch == cfg.epochs


def training_forward(model: TCDModel, cfg: TrainConfig, batch_shape: tuple, device: str, log=print):
    """The forward the optimizer steps through: the channels-last forward (training.channels_last), and
    with ``cfg.compile`` that forward compiled by ``torch.compile``. The compiled forward is tried once,
    forward and backward, on a batch of the training shape (B, K, L); where compiling fails (no compiler,
    an unsupported backend) training goes on eagerly and the log says why."""
    from .channels_last import ChannelsLast

    fast = ChannelsLast(model)
    if not cfg.compile:
        return fast
    try:
        compiled = torch.compile(fast)
        # three distinct tensors, as a training step passes: Dynamo guards on aliasing, so one tensor passed
        # three times compiled a graph that the first real step discarded and compiled again (on an H100 in
        # 2026-11-26's seventh session that doubled the compile time and took a run's calibration)
        x, observed, mask = (torch.zeros(batch_shape, device=device) for _ in range(3))
        t = torch.zeros(batch_shape[0], dtype=torch.long, device=device)
        with torch.autocast(
            device_type=torch.device(device).type, dtype=torch.bfloat16, enabled=amp_enabled(cfg, device)
        ):
            out = compiled(x, observed, mask, t)
        out.float().sum().backward()
        model.zero_grad(set_to_none=True)
        return compiled
    except Exception as exc:  # noqa: BLE001 - any compiler failure means: train eagerly
        model.zero_grad(set_to_none=True)
        first_line = str(exc).splitlines()[0] if str(exc) else ""
        log(f"torch.compile failed ({type(exc).__name__}: {first_line}); training eagerly")
        return fast


def amp_enabled(cfg: TrainConfig, device: str) -> bool:
    return cfg.amp and torch.device(device).type == "cuda"


def imle_choice(forward, sched: Schedule, batch, search, final_weight: float) -> Choice:
    """:func:`training.imle.imle_choose` on a batch (x0, observed, mask, t, eps, candidates[, others])."""
    x0, obs, mask, _t, _eps, cands, *others = batch
    return imle_choose(
        forward,
        sched,
        x0,
        mask,
        cands,
        observed=obs,
        search=search,
        final_weight=final_weight,
        others=next(iter(others), None),
    )


def train_step(
    forward,
    opt: torch.optim.Optimizer,
    sched: Schedule,
    batch,
    amp: bool,
    imle_weight: float = 1.0,
    imle_search=None,
    imle_final_weight: float = 0.0,
    choice: Choice | None = None,
) -> torch.Tensor:
    """One optimizer step on one batch (x0, observed, mask, t, eps[, candidates[, others]]); the loss (a device
    tensor: no sync). With the candidates (``imle_samples``) the loss adds ``imle_weight`` x the one-step sampler's
    IMLE loss (``training.imle``; ``imle_search`` computes the candidates' samples, default the forward itself;
    ``imle_final_weight`` its final-frame term; ``others`` the further futures of ``imle_targets``; ``choice``
    an earlier search's result for this batch, :func:`training.imle.imle_choose`, instead of searching again)."""
    x0, obs, mask, t, eps, *imle = batch
    with torch.autocast(device_type=x0.device.type, dtype=torch.bfloat16, enabled=amp):
        loss = training_loss(forward, sched, x0, mask, t=t, eps=eps, observed=obs)
        if imle:
            choice = choice or imle_choice(forward, sched, batch, imle_search, imle_final_weight)
            loss = loss + imle_weight * imle_loss(forward, sched, x0, mask, imle[0], choice, observed=obs)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return loss.detach()


def make_optimizer(model: torch.nn.Module, cfg: TrainConfig, device: str) -> torch.optim.Adam:
    # fused Adam: one kernel for all parameters on a GPU instead of a dozen per tensor
    return torch.optim.Adam(
        model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay, fused=torch.device(device).type == "cuda"
    )


class EMA:
    """Exponential moving average of the weights: a copy of the model (``.module``) that each ``update``
    moves towards the trained weights by ``1 - decay`` (the first update copies them), one foreach lerp.
    ``torch.optim.swa_utils.AveragedModel`` with ``get_ema_multi_avg_fn`` computes the same, but copies its
    step counter from the host to the device on every update, which makes the host wait for the GPU once
    per training step."""

    def __init__(self, model: TCDModel, decay: float):
        self.decay = decay
        self.module = copy.deepcopy(model).eval().requires_grad_(False)
        self.n_averaged = 0

    @torch.no_grad()
    def update(self, model: TCDModel) -> None:
        mine, theirs = list(self.module.parameters()), [p.detach() for p in model.parameters()]
        if self.n_averaged == 0:
            torch._foreach_copy_(mine, theirs)
        else:
            torch._foreach_lerp_(mine, theirs, 1.0 - self.decay)
        self.n_averaged += 1


def make_ema(model: TCDModel, cfg: TrainConfig) -> EMA | None:
    """The exponential moving average of the weights (``cfg.ema_decay`` > 0), or None."""
    return EMA(model, cfg.ema_decay) if cfg.ema_decay else None


@torch.no_grad()
def validation_loss(model, sched: Schedule, cfg: TrainConfig, val: Windows, device: str) -> float:
    """Mean masked loss over validation windows and diffusion steps, with fixed noise (host masks, the
    same windows and draws whatever the batch source of training)."""
    from .channels_last import ChannelsLast

    was_training = model.training
    model.eval()
    forward = ChannelsLast(model)
    rows = np.arange(len(val))
    if cfg.val_max_windows:
        rows = rows[np.linspace(0, len(val) - 1, min(cfg.val_max_windows, len(val))).astype(int)]
    ts = range(sched.T) if not cfg.val_timesteps else np.linspace(0, sched.T - 1, cfg.val_timesteps).round().astype(int)
    total, n = 0.0, 0
    for b0 in range(0, len(rows), cfg.batch_size):
        r = rows[b0 : b0 + cfg.batch_size]
        x0, obs, mask = make_batch(cfg, val.gather(r), np.random.default_rng([cfg.seed, 777, b0]))
        x0, obs, mask = x0.to(device), obs.to(device), mask.to(device)
        for t in ts:
            g = torch.Generator().manual_seed(int(t) * 100_003 + b0)
            tt = torch.full((len(r),), int(t), dtype=torch.long, device=device)
            total += float(training_loss(forward, sched, x0, mask, t=tt, generator=g, observed=obs)) * len(r)
            n += len(r)
    model.train(was_training)
    return total / max(n, 1)


def save_checkpoint(path: Path, state: dict) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    tmp.replace(path)


def build_model(cfg: TrainConfig, device: str) -> tuple[TCDModel, Schedule]:
    """A run's freshly initialised model (seeded with ``cfg.seed``; around its prior when the config says so) and
    its noise schedule: what ``train`` starts from, and what benches/train_speed.py times."""
    diff_cfg = DiffusionConfig.from_dict(cfg.diffusion)
    torch.manual_seed(cfg.seed)
    model = TCDModel(ModelConfig.from_dict(cfg.model), diff_cfg.num_train_timesteps).to(device)
    if model.cfg.cond_fill == "prior":
        model.attach_prior(load_prior(cfg.prior).to(device))
    return model, Schedule(diff_cfg)


def train(
    cfg: TrainConfig,
    out: str | Path,
    *,
    data: str | None = None,
    resume: bool = False,
    max_minutes: float | None = None,
    device: str = "cpu",
    checkpoint_minutes: float = 5.0,
    sequences: dict | None = None,
    workers: int = 0,
    deadline: float | None = None,
    stop_after_steps: int | None = None,
    log=print,
) -> dict:
    """Train (or resume) a model into ``out``. ``sequences`` ({"train": [...], "val": [...]} of (T, J, 3)
    arrays in metres) replaces the dataset, for tests on synthetic motion. ``workers`` > 0 draws the
    host batches in that many DataLoader processes (the same batches, bit for bit, as ``workers`` = 0).
    Training stops resumably after ``max_minutes`` of training (counted once the forward is compiled) or
    at ``deadline`` (a ``time.time()`` value: a wall-clock stop, whatever set-up and compiling took),
    or after ``stop_after_steps`` optimizer steps of the schedule (a recipe stage whose weights were taken part-way:
    the schedule stays the config's), whichever comes first.

    Checkpoints hold the raw weights (``model``), the optimizer, and with ``ema_decay`` the averaged
    weights (``ema``), which are the ones validated, kept in ``best.pt`` and exported."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    L = cfg.obs_len + cfg.pred_len
    if torch.device(device).type == "cuda":
        torch.set_float32_matmul_precision("high")  # TF32 for what autocast leaves in float32
    model, sched = build_model(cfg, device)
    model_cfg, diff_cfg = model.cfg, sched.cfg
    opt = make_optimizer(model, cfg, device)
    seqs = sequences or {split: load_sequences(cfg, data, split) for split in ("train", "val")}
    joints = {int(q.shape[1]) for split in seqs.values() for q in split}
    if joints != {model_cfg.num_joints}:
        raise ValueError(
            f"the {cfg.dataset} sequences have {sorted(joints)} joints, the model "
            f"{model_cfg.num_joints} (model.num_joints in the config)"
        )
    train_w = Windows(seqs["train"], L, cfg.train_stride)
    val_w = Windows(seqs["val"], L, cfg.val_stride)
    if not len(train_w) or not len(val_w):
        raise ValueError(f"no training or validation window of {L} frames in the data")
    steps_per_epoch = cfg.steps_per_epoch or math.ceil(len(train_w) / cfg.batch_size)
    weights = None  # how BatchSource draws the windows: None is a uniform permutation per epoch
    if cfg.action_balance > 0:  # here, before the warm start and the forward are set up: a bad call fails early
        if sequences is not None:
            raise ValueError("action_balance needs the HumanEva-I data's actions, not given sequences")
        from .data.humaneva import training_actions

        weights = action_weights(np.asarray(training_actions(data))[train_w.index[:, 0]], cfg.action_balance)
    from .fileformat import data_meta

    meta = {
        "role": cfg.role,
        "model_config": model_cfg.to_dict(),
        "diffusion_config": diff_cfg.to_dict(),
        "window": {"obs_len": cfg.obs_len, "pred_len": cfg.pred_len, "seq_len": L},
        "data": data_meta(cfg.dataset, h36m_share=cfg.h36m_share),
        "train_config": asdict(cfg),
    }
    if model_cfg.cond_fill == "prior":  # which prior the model was trained around (a path can be overwritten)
        import hashlib

        meta["prior_sha256"] = hashlib.sha256(Path(cfg.prior).read_bytes()).hexdigest()
    epoch, batch_i, best_val, elapsed0, history = 0, 0, float("inf"), 0.0, []
    last = out / "last.pt"
    ck = None
    if resume and last.is_file():
        ck = torch.load(last, map_location=device, weights_only=False)
        if stored_config(ck["train_config"], last) != asdict(cfg):
            raise ValueError(f"{last} was trained with another config; start a new --out or use the same config")
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        epoch, batch_i, best_val = ck["epoch"], ck["batch"], ck["best_val"]
        elapsed0, history = ck.get("elapsed_s", 0.0), ck.get("history", [])
        log(f"resumed from {last}: epoch {epoch}, batch {batch_i}")
    elif cfg.init_from:
        init = Path(cfg.init_from)
        if not init.is_file():
            raise FileNotFoundError(f"init_from: no checkpoint at {init}")
        if init.suffix == ".safetensors":  # an exported model (e.g. the bundled python/tcd/weights/short.safetensors)
            from safetensors.torch import load_file

            init_state = load_file(str(init), device=device)
            log(f"warm start from exported weights {init}")
        else:
            init_ck = torch.load(init, map_location=device, weights_only=False)
            from .export import checkpoint_weights

            init_state = checkpoint_weights(init_ck)
            log(f"warm start from {init} (its best validation loss {init_ck.get('best_val', float('nan')):.4f})")
        # the architecture must match, except for wider channels (training.widen: the same function) and more
        # residual layers (those start as no-ops, load_grown)
        init_state, factor = widen_to(model.cfg, init_state, cfg.seed)
        if factor > 1:
            log(
                f"widened {factor} x to {model.cfg.channels} channels and a feed-forward width of "
                f"{model.cfg.ffn_dim}, computing what the warm start computes (training.widen)"
            )
        added = load_grown(model, init_state)
        if added:
            log(f"{added} residual layers added after the warm start's, each starting as a no-op")
        if cfg.reset_output_head:
            head = model.diffmodel.output_projection2
            torch.nn.init.zeros_(head.weight)
            torch.nn.init.zeros_(head.bias)
            log("the output head restarts at zero (reset_output_head)")
    ema = make_ema(model, cfg)
    if ema is not None and ck is not None:
        ema.module.load_state_dict(ck["ema"])
        ema.n_averaged = ck["ema_n"]
    evaluated = model if ema is None else ema.module  # the weights validated and exported
    log(
        f"{cfg.role}: {count_parameters(model):,} parameters, {len(train_w):,} training windows, "
        f"{len(val_w):,} validation windows, {steps_per_epoch} steps/epoch x {cfg.epochs} epochs, device {device}"
        + (f", EMA {cfg.ema_decay}" if ema is not None else "")
    )
    amp = amp_enabled(cfg, device)
    model.train()
    forward = training_forward(model, cfg, (cfg.batch_size, model_cfg.num_features, L), device, log)
    source = BatchSource(cfg, train_w, sched.T, steps_per_epoch, weights)
    imle_search = None
    if cfg.imle_samples and torch.device(device).type == "cpu":  # the engine runs on the CPU only
        from .export import build_config

        imle_search = EngineSearch(
            model,
            build_config(cfg.role, model_cfg, diff_cfg, cfg.obs_len, cfg.pred_len, meta["data"]),
            threads=torch.get_num_threads(),
        )
    t_start = time.time()
    last_ck = t_start
    ends = [t for t in (None if max_minutes is None else t_start + 60 * max_minutes, deadline) if t is not None]
    stop_at = min(ends) if ends else None

    def state(best=None):
        # best.pt holds the weights only: it is exported or warm-started from, never resumed
        s = dict(
            meta,
            model=model.state_dict(),
            epoch=epoch,
            batch=batch_i,
            step=epoch * steps_per_epoch + batch_i,
            best_val=best_val if best is None else best,
            elapsed_s=elapsed0 + time.time() - t_start,
            history=history,
        )
        if best is None:
            s["optimizer"] = opt.state_dict()
        if ema is not None:
            s.update(ema=ema.module.state_dict(), ema_n=ema.n_averaged)
        return s

    def validate(entry: dict) -> float:
        """The exported weights' validation loss (returned and in ``entry``); best.pt is written when it is
        the lowest so far."""
        nonlocal best_val
        v = validation_loss(evaluated, sched, cfg, val_w, device)
        entry["val_loss"] = v
        if v < best_val:
            best_val = v
            save_checkpoint(out / "best.pt", state(best=v))
        return v

    stopped = False
    while epoch < cfg.epochs and not stopped:
        run_loss, run_n = torch.zeros((), device=device), 0
        for batch in source.iterate(epoch, batch_i, workers):
            lr = learning_rate(cfg, epoch * steps_per_epoch + batch_i, steps_per_epoch)
            for group in opt.param_groups:
                group["lr"] = lr
            batch = tuple(a.to(device, non_blocking=True) for a in batch)
            choice = None
            if cfg.imle_echo > 1:
                # data echoing (Choi et al., 2019): the search stands upstream of the optimizer as a slow input
                # pipeline would, and one search serves imle_echo steps (docs/training.md: its one run was worse)
                choice = imle_choice(forward, sched, batch, imle_search, cfg.imle_final_weight)
            for _ in range(cfg.imle_echo):
                loss = train_step(
                    forward, opt, sched, batch, amp, cfg.imle_weight, imle_search, cfg.imle_final_weight, choice
                )
                if ema is not None:
                    ema.update(model)
            run_loss, run_n = run_loss + loss.float(), run_n + 1
            batch_i += 1
            now = time.time()
            if batch_i % min(100, steps_per_epoch) == 0:  # at least once an epoch: the runner's progress
                log(
                    f"epoch {epoch} batch {batch_i}/{steps_per_epoch} loss {float(run_loss) / run_n:.4f} "
                    f"lr {lr:.1e} {now - t_start:.0f}s"
                )
            if (stop_at is not None and now > stop_at) or (
                stop_after_steps is not None and epoch * steps_per_epoch + batch_i >= stop_after_steps
            ):
                stopped = True
                break
            if now - last_ck > 60 * checkpoint_minutes:
                save_checkpoint(last, state())
                last_ck = now
        if stopped:
            break
        history.append({"epoch": epoch, "train_loss": float(run_loss) / max(run_n, 1)})
        epoch, batch_i = epoch + 1, 0
        if validates_after(cfg, epoch):
            v = validate(history[-1])
            log(f"epoch {epoch}: train loss {history[-1]['train_loss']:.4f} val loss {v:.4f}")
        save_checkpoint(last, state())
        last_ck = time.time()
    if stopped:
        # time budget reached: validate what we have so that best.pt always exists
        trained = (time.time() - t_start) / 60
        history.append({"epoch": epoch, "batch": batch_i, "stopped": "max-minutes" if stop_at else "steps"})
        v = validate(history[-1])
        log(f"stopped after {trained:.2f} min of training at epoch {epoch} batch {batch_i}: val loss {v:.4f}")
        save_checkpoint(last, state())
    return {"epoch": epoch, "batch": batch_i, "best_val": best_val, "history": history}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m training.train", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--config", help="JSON TrainConfig (training/configs/*.json)")
    ap.add_argument("--out", help="run directory (checkpoints last.pt, best.pt)")
    ap.add_argument(
        "--data",
        default=None,
        help="Human3.6M directory or a cache from --write-cache; HumanEva-I "
        'directory or .npz for a "dataset": "humaneva" config (default ../shared/data/<dataset>)',
    )
    ap.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    ap.add_argument("--max-minutes", type=float, default=None, help="stop (resumably) after this many minutes")
    ap.add_argument(
        "--stop-at",
        type=float,
        default=None,
        metavar="UNIX_SECONDS",
        help="stop (resumably) at this wall-clock time (date +%%s), whatever set-up and compiling took",
    )
    ap.add_argument(
        "--stop-after-steps",
        type=int,
        default=None,
        metavar="N",
        help="stop (resumably) after N optimizer steps of the config's schedule",
    )
    ap.add_argument("--device", default="cpu", help="cpu | cuda")
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    ap.add_argument(
        "--workers",
        type=int,
        default=0,
        help="DataLoader processes drawing the batches (0: in the training process; same batches either way)",
    )
    ap.add_argument("--write-cache", metavar="NPZ", help="write a compact model-space data cache and exit")
    args = ap.parse_args(argv)
    if args.write_cache:
        write_cache(args.data, args.write_cache)
        print(f"wrote {args.write_cache}")
        return 0
    if not args.config or not args.out:
        ap.error("--config and --out are required")
    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = TrainConfig.load(args.config)
    res = train(
        cfg,
        args.out,
        data=args.data,
        resume=args.resume,
        max_minutes=args.max_minutes,
        device=args.device,
        workers=args.workers,
        deadline=args.stop_at,
        stop_after_steps=args.stop_after_steps,
    )
    print(json.dumps({k: v for k, v in res.items() if k != "history"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
