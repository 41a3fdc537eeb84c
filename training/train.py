"""Train a TCD model (short-term, long-term or repair) with the paper recipe (spec section 2).

    python -m training.train --config training/configs/short.json --out runs/short [--resume]
                             [--max-minutes M] [--device cpu|cuda]

Defaults (TrainConfig) are the paper's: Adam lr 1e-3, weight decay 1e-6, batch 32, 50 epochs,
learning rate x0.1 at 75 % and 90 % of the epochs, validation loss (mean over all diffusion steps)
every 5 epochs on S11 windows of stride 25, all training windows of stride 1 from S1, S6, S7, S8, S9.
Unlike the official code, every draw is seeded (batch order, masks, t and noise are functions of
(seed, epoch, batch)), so a resumed run continues exactly where it stopped, and the best-validation
checkpoint is kept beside the last one (``best.pt``, ``last.pt``).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from .diffusion import DiffusionConfig, Schedule, training_loss
from .model import ModelConfig, TCDModel, count_parameters


@dataclass
class TrainConfig:
    role: str = "short"              # short (50 -> 5), long (55 -> 20, teacher-forced), repair (50 -> 0)
    dataset: str = "h36m"
    obs_len: int = 50                # observed frames (mask 1 unless occluded)
    pred_len: int = 5                # predicted frames (mask 0)
    model: dict = field(default_factory=dict)       # ModelConfig overrides
    diffusion: dict = field(default_factory=dict)   # DiffusionConfig overrides
    batch_size: int = 32
    lr: float = 1e-3
    weight_decay: float = 1e-6
    epochs: int = 50
    milestones: tuple = (0.75, 0.9)  # fractions of the epochs where the lr is multiplied by gamma
    gamma: float = 0.1
    train_stride: int = 1
    val_stride: int = 25
    val_every: int = 5               # epochs between validations (and always after the last one)
    val_timesteps: int = 0           # 0 = all T steps (the reference); n > 0: n evenly spaced steps
    val_max_windows: int = 0         # 0 = all validation windows
    steps_per_epoch: int = 0         # 0 = a full pass over the training windows
    mask_mix: list = field(default_factory=lambda: [["none", 1.0]])  # [[pattern, weight(, rate)], ...] per window
    seed: int = 0
    amp: bool = True                 # bf16 autocast on CUDA
    init_from: str = ""              # warm start: a checkpoint (.pt) or exported .safetensors whose weights start this run

    @classmethod
    def load(cls, path: str | Path) -> "TrainConfig":
        d = json.loads(Path(path).read_text())
        known = set(cls.__dataclass_fields__)
        unknown = set(d) - known - {"comment"}
        if unknown:
            raise ValueError(f"{path}: unknown config keys {sorted(unknown)}")
        return cls(**{k: v for k, v in d.items() if k in known})


# ------------------------------------------------------------------------------------------ data

def load_sequences(cfg: TrainConfig, data: str | None, split: str) -> list[np.ndarray]:
    """Model-space sequences (T, J, 3) metres for a split. ``data`` is a raw data directory or a cache
    written by ``--write-cache`` (an npz of ``{split}/{key}`` arrays)."""
    if cfg.dataset != "h36m":
        raise ValueError(f"dataset {cfg.dataset!r}: only h36m training is wired up")
    from .data.h36m import DEFAULT_H36M_DIR, H36M
    path = Path(data) if data else DEFAULT_H36M_DIR
    if path.is_file() and path.name.startswith("h36m_model_cache"):
        with np.load(path) as z:
            return [z[k].astype(np.float32) for k in sorted(z.files) if k.startswith(split + "/")]
    return [seq for _, seq in H36M(path).sequences(split)]


def write_cache(data: str | None, out: str | Path) -> None:
    """A compact float16 cache of the model-space train/val sequences (to carry to a GPU machine)."""
    from .data.h36m import DEFAULT_H36M_DIR, H36M
    h = H36M(data or DEFAULT_H36M_DIR)
    arrays = {f"{split}/{key}": seq.astype(np.float16) for split in ("train", "val") for key, seq in h.sequences(split)}
    np.savez_compressed(out, **arrays)


class Windows:
    """All windows of ``length`` frames with a stride, gathered on demand."""

    def __init__(self, seqs: list[np.ndarray], length: int, stride: int):
        self.seqs = seqs
        self.length = length
        self.index = np.asarray([(i, s) for i, q in enumerate(seqs) for s in range(0, len(q) - length + 1, stride)],
                                dtype=np.int64).reshape(-1, 2)

    def __len__(self) -> int:
        return len(self.index)

    def gather(self, rows: np.ndarray) -> np.ndarray:
        return np.stack([self.seqs[i][s:s + self.length] for i, s in self.index[rows]]).astype(np.float32)


def _mix_rate(entry):
    """The optional third item of a ``mask_mix`` entry: a rate, or a [low, high] range (random_joints)."""
    if len(entry) not in (2, 3):
        raise ValueError(f"mask_mix entry {entry!r}: expected [pattern, weight] or [pattern, weight, rate]")
    if len(entry) == 2:
        return None
    return tuple(entry[2]) if isinstance(entry[2], (list, tuple)) else entry[2]


def make_batch(cfg: TrainConfig, wins: np.ndarray, rng: np.random.Generator):
    """Clean windows (B, L, J, 3) -> (x0, observed, mask) tensors (B, K, L).
    Each window draws one pattern of ``mask_mix``; occluded observation entries become targets."""
    from .masks import corrupt
    B, L, J, _ = wins.shape
    observed = wins.copy()
    jmask = np.zeros((B, L, J), dtype=np.float32)
    jmask[:, :cfg.obs_len] = 1.0
    rates = [_mix_rate(entry) for entry in cfg.mask_mix]
    patterns = [entry[0] for entry in cfg.mask_mix]
    weights = np.asarray([entry[1] for entry in cfg.mask_mix], dtype=np.float64)
    choice = rng.choice(len(patterns), size=B, p=weights / weights.sum())
    for b in range(B):
        if patterns[choice[b]] != "none":
            observed[b], jmask[b] = corrupt(wins[b], patterns[choice[b]], cfg.obs_len, rng, rate=rates[choice[b]])
    observed[:, cfg.obs_len:] = 0.0
    def bkl(a):
        return torch.from_numpy(np.ascontiguousarray(a.reshape(B, L, J * 3).transpose(0, 2, 1)))
    return bkl(wins), bkl(observed), bkl(np.repeat(jmask[..., None], 3, axis=-1))


class BatchSource:
    """The training batches of an epoch, each a pure function of (seed, epoch, batch index): the window
    rows (a seeded permutation per epoch), the occlusion masks, the diffusion steps t and the noise eps.
    So the batches are the same whether drawn here or in DataLoader worker processes, and a resumed run
    continues with exactly the batches it would have drawn."""

    def __init__(self, cfg: TrainConfig, windows: Windows, T: int, steps_per_epoch: int):
        self.cfg, self.windows, self.T, self.steps_per_epoch = cfg, windows, T, steps_per_epoch
        self._perm_epoch, self._perm = None, None

    def batch(self, epoch: int, batch_i: int):
        cfg = self.cfg
        if self._perm_epoch != epoch:
            self._perm = np.random.default_rng([cfg.seed, epoch]).permutation(len(self.windows))
            self._perm_epoch = epoch
        rows = self._perm[(np.arange(cfg.batch_size) + batch_i * cfg.batch_size) % len(self._perm)]
        x0, obs, mask = make_batch(cfg, self.windows.gather(rows), np.random.default_rng([cfg.seed, epoch, batch_i]))
        g = torch.Generator().manual_seed(((cfg.seed * 1_000_003 + epoch) * 1_000_003 + batch_i) % (1 << 62))
        t = torch.randint(0, self.T, (x0.shape[0],), generator=g)   # the draw order of training_loss
        eps = torch.randn(x0.shape, generator=g)
        return x0, obs, mask, t, eps

    def iterate(self, epoch: int, start: int, workers: int):
        """Batches start..steps_per_epoch-1 of an epoch, in order."""
        if workers <= 0:
            for i in range(start, self.steps_per_epoch):
                yield self.batch(epoch, i)
            return
        ds = _EpochBatches(self, epoch, start)
        loader = torch.utils.data.DataLoader(ds, batch_size=None, shuffle=False, num_workers=workers,
                                             pin_memory=torch.cuda.is_available(), prefetch_factor=4)
        yield from loader


class _EpochBatches(torch.utils.data.Dataset):
    def __init__(self, source: BatchSource, epoch: int, start: int):
        self.source, self.epoch, self.start = source, epoch, start

    def __len__(self) -> int:
        return self.source.steps_per_epoch - self.start

    def __getitem__(self, i: int):
        return self.source.batch(self.epoch, self.start + i)


# ------------------------------------------------------------------------------------------ loop

@torch.no_grad()
def validation_loss(model, sched: Schedule, cfg: TrainConfig, val: Windows, device: str) -> float:
    """Mean masked loss over validation windows and diffusion steps, with fixed noise."""
    model.eval()
    rows = np.arange(len(val))
    if cfg.val_max_windows:
        rows = rows[np.linspace(0, len(val) - 1, min(cfg.val_max_windows, len(val))).astype(int)]
    ts = range(sched.T) if not cfg.val_timesteps else np.linspace(0, sched.T - 1, cfg.val_timesteps).round().astype(int)
    total, n = 0.0, 0
    for b0 in range(0, len(rows), cfg.batch_size):
        r = rows[b0:b0 + cfg.batch_size]
        x0, obs, mask = make_batch(cfg, val.gather(r), np.random.default_rng([cfg.seed, 777, b0]))
        x0, obs, mask = x0.to(device), obs.to(device), mask.to(device)
        for t in ts:
            g = torch.Generator().manual_seed(int(t) * 100_003 + b0)
            tt = torch.full((len(r),), int(t), dtype=torch.long, device=device)
            total += float(training_loss(model, sched, x0, mask, t=tt, generator=g, observed=obs)) * len(r)
            n += len(r)
    model.train()
    return total / max(n, 1)


def save_checkpoint(path: Path, state: dict) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    tmp.replace(path)


def train(cfg: TrainConfig, out: str | Path, *, data: str | None = None, resume: bool = False,
          max_minutes: float | None = None, device: str = "cpu", checkpoint_minutes: float = 5.0,
          sequences: dict | None = None, workers: int = 0, log=print) -> dict:
    """Train (or resume) a model into ``out``. ``sequences`` ({"train": [...], "val": [...]} of (T, J, 3)
    arrays in metres) replaces the dataset, for tests on synthetic motion. ``workers`` > 0 draws the
    batches in that many DataLoader processes (the same batches, bit for bit, as ``workers`` = 0)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model_cfg = ModelConfig.from_dict(cfg.model)
    diff_cfg = DiffusionConfig.from_dict(cfg.diffusion)
    sched = Schedule(diff_cfg)
    L = cfg.obs_len + cfg.pred_len
    torch.manual_seed(cfg.seed)
    model = TCDModel(model_cfg, diff_cfg.num_train_timesteps).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    milestones = [int(f * cfg.epochs) for f in cfg.milestones]
    lr_sched = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=milestones, gamma=cfg.gamma)
    seqs = sequences or {split: load_sequences(cfg, data, split) for split in ("train", "val")}
    train_w = Windows(seqs["train"], L, cfg.train_stride)
    val_w = Windows(seqs["val"], L, cfg.val_stride)
    if not len(train_w) or not len(val_w):
        raise ValueError(f"no training or validation window of {L} frames in the data")
    steps_per_epoch = cfg.steps_per_epoch or math.ceil(len(train_w) / cfg.batch_size)
    from .export import h36m_data_meta
    meta = {"role": cfg.role, "model_config": model_cfg.to_dict(), "diffusion_config": diff_cfg.to_dict(),
            "window": {"obs_len": cfg.obs_len, "pred_len": cfg.pred_len, "seq_len": L},
            "data": h36m_data_meta(), "train_config": asdict(cfg)}
    epoch, batch_i, best_val, elapsed0, history = 0, 0, float("inf"), 0.0, []
    last = out / "last.pt"
    if resume and last.is_file():
        ck = torch.load(last, map_location=device, weights_only=False)
        if ck["train_config"] != asdict(cfg):
            raise ValueError(f"{last} was trained with another config; start a new --out or use the same config")
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        lr_sched.load_state_dict(ck["lr_scheduler"])
        epoch, batch_i, best_val = ck["epoch"], ck["batch"], ck["best_val"]
        elapsed0, history = ck.get("elapsed_s", 0.0), ck.get("history", [])
        log(f"resumed from {last}: epoch {epoch}, batch {batch_i}")
    elif cfg.init_from:
        init = Path(cfg.init_from)
        if not init.is_file():
            raise FileNotFoundError(f"init_from: no checkpoint at {init}")
        if init.suffix == ".safetensors":  # an exported model (e.g. the bundled python/tcd/weights/short.safetensors)
            from safetensors.torch import load_file
            model.load_state_dict(load_file(str(init), device=device))  # strict: the architecture must match
            log(f"warm start from exported weights {init}")
        else:
            ck = torch.load(init, map_location=device, weights_only=False)
            model.load_state_dict(ck["model"])  # strict: the architecture must match
            log(f"warm start from {init} (its best validation loss {ck.get('best_val', float('nan')):.4f})")
    log(f"{cfg.role}: {count_parameters(model):,} parameters, {len(train_w):,} training windows, "
        f"{len(val_w):,} validation windows, {steps_per_epoch} steps/epoch x {cfg.epochs} epochs, device {device}")
    use_amp = cfg.amp and device.startswith("cuda")
    t_start = time.time()
    last_ck = t_start

    def state(best=None):
        return dict(meta, model=model.state_dict(), optimizer=opt.state_dict(), lr_scheduler=lr_sched.state_dict(),
                    epoch=epoch, batch=batch_i, step=epoch * steps_per_epoch + batch_i,
                    best_val=best_val if best is None else best, elapsed_s=elapsed0 + time.time() - t_start,
                    history=history)

    model.train()
    stopped = False
    source = BatchSource(cfg, train_w, sched.T, steps_per_epoch)
    while epoch < cfg.epochs and not stopped:
        run_loss, run_n = torch.zeros((), device=device), 0
        for x0, obs, mask, t, eps in source.iterate(epoch, batch_i, workers):
            x0, obs, mask, t, eps = (a.to(device, non_blocking=True) for a in (x0, obs, mask, t, eps))
            with torch.autocast(device_type="cuda", dtype=torch.bfloat16, enabled=use_amp):
                loss = training_loss(model, sched, x0, mask, t=t, eps=eps, observed=obs)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            run_loss, run_n = run_loss + loss.detach().float(), run_n + 1
            batch_i += 1
            now = time.time()
            if batch_i % 100 == 0:
                log(f"epoch {epoch} batch {batch_i}/{steps_per_epoch} loss {float(run_loss) / run_n:.4f} "
                    f"lr {opt.param_groups[0]['lr']:.1e} {now - t_start:.0f}s")
            if max_minutes is not None and now - t_start > 60 * max_minutes:
                stopped = True
                break
            if now - last_ck > 60 * checkpoint_minutes:
                save_checkpoint(last, state())
                last_ck = now
        if stopped:
            break
        history.append({"epoch": epoch, "train_loss": float(run_loss) / max(run_n, 1)})
        epoch, batch_i = epoch + 1, 0
        lr_sched.step()
        if epoch % cfg.val_every == 0 or epoch == cfg.epochs:
            v = validation_loss(model, sched, cfg, val_w, device)
            history[-1]["val_loss"] = v
            log(f"epoch {epoch}: train loss {history[-1]['train_loss']:.4f} val loss {v:.4f}")
            if v < best_val:
                best_val = v
                save_checkpoint(out / "best.pt", state(best=v))
        save_checkpoint(last, state())
        last_ck = time.time()
    if stopped:
        # time budget reached: validate what we have so that best.pt always exists
        v = validation_loss(model, sched, cfg, val_w, device)
        history.append({"epoch": epoch, "batch": batch_i, "val_loss": v, "stopped": "max-minutes"})
        log(f"stopped after {max_minutes} min at epoch {epoch} batch {batch_i}: val loss {v:.4f}")
        if v < best_val:
            best_val = v
            save_checkpoint(out / "best.pt", state(best=v))
        save_checkpoint(last, state())
    return {"epoch": epoch, "batch": batch_i, "best_val": best_val, "history": history}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.train", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", help="JSON TrainConfig (training/configs/*.json)")
    ap.add_argument("--out", help="run directory (checkpoints last.pt, best.pt)")
    ap.add_argument("--data", default=None, help="Human3.6M directory or a cache from --write-cache")
    ap.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    ap.add_argument("--max-minutes", type=float, default=None, help="stop (resumably) after this many minutes")
    ap.add_argument("--device", default="cpu", help="cpu | cuda")
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    ap.add_argument("--workers", type=int, default=0,
                    help="DataLoader processes drawing the batches (0: in the training process; same batches either way)")
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
    res = train(cfg, args.out, data=args.data, resume=args.resume, max_minutes=args.max_minutes, device=args.device,
                workers=args.workers)
    print(json.dumps({k: v for k, v in res.items() if k != "history"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
