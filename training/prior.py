"""Training the deterministic prior forecaster (its network and file: ``training.prior_net``) on the CPU, in
resumable installments.

Training (``python -m training.prior``): random windows of ``obs_len + chunk`` frames (``obs_len +
loss_frames`` when set) from the training subjects of ``dataset`` (``"h36m"``: Human3.6M, the 22 model joints
at 25 fps; ``"humaneva"``: HumanEva-I's Train split, 14 root-relative joints at 60 Hz,
``training.data.humaneva.training_sequences``; ``"h36m-a"``: Human3.6M Setting-A's training subjects, 16
root-relative joints at 50 Hz, ``training.data.h36m_setting_a``), reversed in time with probability
``flip_prob``; loss = mean per-joint L2 distance of the chunk (of the ``loss_frames`` frames rolled out, when
set) plus the same on its frame-to-frame velocities; Adam with weight decay; the learning rate decays once at
``lr_decay_at`` of the iterations (``lr`` -> ``lr_final``). Every draw is a pure function of (seed, iteration), so
a resumed run continues exactly where it stopped.

A **repair fill** (``"anchor": "window"``, ``chunk`` = ``obs_len``; docs/repair.md) is the same network over a
whole window, its output added to its input window instead of to the last pose: it trains on windows of
``obs_len`` frames, each hidden by a mask of ``mask_mix`` and filled by the natural cubic spline
(:func:`repair_batch`), with the loss over the hidden joints (:func:`hidden_loss`). Any run may validate on
held-out subjects (``val_subjects``, every ``val_every`` iterations; ``best.pt`` keeps the lowest).

    python -m training.prior --config training/configs/prior.json --out runs/prior [--resume]
                             [--max-minutes M] [--threads 1]
    python -m training.prior --config training/configs/humaneva_prior.json --out runs/humaneva_prior
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .augment import mirror, mirror_permutation, resample, rotate_about, sequence_ends
from .prior_net import PriorConfig, PriorNet, count_parameters, load_prior_file


# ------------------------------------------------------------------------------------------ data


def dataset_joint_names(dataset: str) -> tuple:
    """The names of the model joints of ``dataset``, in the data's order (left/right are the subject's)."""
    if dataset == "humaneva":
        from .data.humaneva import HUMANEVA_MODEL_JOINT_NAMES

        return HUMANEVA_MODEL_JOINT_NAMES
    from tcd.layouts import get_layout

    if dataset == "h36m-a":
        return get_layout("h36m17").joint_names[1:]  # the pelvis is the origin, not a model joint
    return get_layout("h36m22").joint_names


def training_sequences(cfg: PriorConfig, data: str | None = None) -> list[np.ndarray]:
    """The training sequences of ``cfg.subjects`` in ``cfg.dataset``, (T, J, 3) float32 metres each."""
    if cfg.dataset == "humaneva":
        from .data.humaneva import training_mix

        return training_mix(cfg.h36m_share, cfg.obs_len + cfg.future, data, cfg.subjects)
    if cfg.dataset == "h36m-a":
        from .data.h36m import DEFAULT_H36M_DIR
        from .data.h36m_setting_a import setting_a_sequences

        return [s.astype(np.float32) for s in setting_a_sequences(cfg.subjects, data or DEFAULT_H36M_DIR).values()]
    from .data.h36m import DEFAULT_H36M_DIR, H36M, SPLITS

    known = {s for subs in SPLITS.values() for s in subs}
    if set(cfg.subjects) - known or 5 in cfg.subjects:
        raise ValueError(
            f"prior config: subjects must be among {sorted(known - {5})} (S5 is the test subject), "
            f"got {list(cfg.subjects)}"
        )
    h = H36M(data or DEFAULT_H36M_DIR)
    return [
        seq
        for split in ("train", "val")
        for key, seq in h.sequences(split)
        if int(key.split("/")[0][1:]) in cfg.subjects
    ]


def training_frames(
    cfg: PriorConfig, data: str | None = None, seqs: list[np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """All training sequences (``seqs``, else :func:`training_sequences`) concatenated, (N, K) float32
    metres, and the start rows of every window of ``obs_len + future`` frames that lies inside one sequence."""
    seqs = training_sequences(cfg, data) if seqs is None else seqs
    L = cfg.obs_len + cfg.future
    frames, starts, offset = [], [], 0
    for seq in seqs:
        frames.append(seq.reshape(len(seq), -1))
        starts.extend(range(offset, offset + len(seq) - L + 1))
        offset += len(seq)
    if not starts:
        raise ValueError(f"no training window of {L} frames (obs_len + future) in the {cfg.dataset} data")
    return np.concatenate(frames).astype(np.float32), np.asarray(starts, dtype=np.int64)


def batch(cfg: PriorConfig, frames: np.ndarray, starts: np.ndarray, iteration: int) -> torch.Tensor:
    """Iteration ``iteration``'s windows (B, obs_len + future, K): uniform window starts, each reversed
    in time with probability ``flip_prob``, turned about ``rotate_axis`` when set, and with probability
    ``obs_noise_prob`` given N(0, obs_noise_mm^2) noise on its observed frames (metres: the data's units), so the
    prior learns to forecast from noisy keypoints (the protocol's noisy_25); a pure function of (seed, iteration)."""
    rng = np.random.default_rng([cfg.seed, iteration])
    rows = starts[rng.integers(0, len(starts), cfg.batch_size)]
    L = cfg.obs_len + cfg.future
    if cfg.speed_range:  # its own stream: configs without it keep their batches bit for bit
        lo, hi = np.log(cfg.speed_range)
        speeds = np.exp(np.random.default_rng([cfg.seed, iteration, 1]).uniform(lo, hi, cfg.batch_size))
        wins = resample(frames, rows, sequence_ends(starts, L)[np.searchsorted(starts, rows)], L, speeds)
    else:
        wins = frames[rows[:, None] + np.arange(L)]
    flip = rng.random(cfg.batch_size) < cfg.flip_prob
    wins[flip] = wins[flip, ::-1]
    if cfg.rotate_axis:  # drawn after the flips: configs without it keep their batches bit for bit
        B, T, K = wins.shape
        wins = rotate_about(wins.reshape(B, T, K // 3, 3), cfg.rotate_axis, rng).reshape(B, T, K)
    if cfg.mirror_prob > 0.0:  # drawn after the rotation, for the same reason
        B, T, K = wins.shape
        which = rng.random(cfg.batch_size) < cfg.mirror_prob
        perm = mirror_permutation(dataset_joint_names(cfg.dataset))
        wins = mirror(wins.reshape(B, T, K // 3, 3), cfg.rotate_axis, perm, which).reshape(B, T, K)
    if cfg.obs_noise_prob > 0.0:  # drawn last, for the same reason
        noisy = rng.random(cfg.batch_size) < cfg.obs_noise_prob
        noise = rng.normal(0.0, cfg.obs_noise_mm * 1e-3, (cfg.batch_size, cfg.obs_len, wins.shape[2]))
        wins[noisy, : cfg.obs_len] += noise[noisy].astype(wins.dtype)
    return torch.from_numpy(np.ascontiguousarray(wins))


def loss_fn(pred: torch.Tensor, target: torch.Tensor, velocity_weight: float) -> torch.Tensor:
    """Mean per-joint L2 distance of the positions plus ``velocity_weight`` x the same of the frame-to-frame
    velocities. (B, T, K) each, K = 3 J."""
    B, T, K = pred.shape
    pos = torch.linalg.vector_norm((pred - target).reshape(B, T, K // 3, 3), dim=-1).mean()
    if velocity_weight == 0.0 or T < 2:
        return pos
    dv = (pred[:, 1:] - pred[:, :-1]) - (target[:, 1:] - target[:, :-1])
    return pos + velocity_weight * torch.linalg.vector_norm(dv.reshape(B, T - 1, K // 3, 3), dim=-1).mean()


def repair_batch(cfg: PriorConfig, wins: torch.Tensor, iteration: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A repair fill's training input for ``wins`` (B, obs_len, K), anchor ``"window"``: each window given one
    mask of ``cfg.mask_mix`` (drawn by weight from the (seed, iteration, 2) stream, so the window draws of
    :func:`batch` are those of a forecaster's config) -> (the window with its hidden entries filled by the
    natural cubic spline through each coordinate's observed frames, the joint mask (B, obs_len, J): 1 observed).
    The spline is what the engine computes before the fill's forward (``tcd-core`` ``fill_spline``)."""
    from .masks import make_mask, mix_entry
    from .model import spline_fill

    mix = [mix_entry(e) for e in cfg.mask_mix]
    p = np.array([w for _, w, _ in mix], dtype=np.float64)
    rng = np.random.default_rng([cfg.seed, iteration, 2])
    B, L, K = wins.shape
    joint_mask = torch.from_numpy(
        np.stack([make_mask(mix[i][0], L, L, rng, rate=mix[i][2]) for i in rng.choice(len(mix), B, p=p / p.sum())])
    )
    mk = joint_mask.repeat_interleave(3, -1).transpose(1, 2)  # (B, K, L)
    return spline_fill(wins.transpose(1, 2), mk).transpose(1, 2).contiguous(), joint_mask


def hidden_loss(
    pred: torch.Tensor, target: torch.Tensor, joint_mask: torch.Tensor, how: str = "pooled"
) -> torch.Tensor:
    """The mean per-joint L2 distance over the hidden joints (joint_mask 0) of (B, L, K) windows: what
    ``benches/repair_quality.py`` scores (the observed entries are given back exactly). ``how="log_window"``:
    the mean over the windows with a hidden joint of the log of each one's mean distance instead."""
    B, L, K = pred.shape
    err = torch.linalg.vector_norm((pred - target).reshape(B, L, K // 3, 3), dim=-1)
    hidden = 1.0 - joint_mask
    if how == "pooled":
        return (err * hidden).sum() / hidden.sum().clamp(min=1.0)
    n = hidden.sum(dim=(1, 2))
    per_window = (err * hidden).sum(dim=(1, 2))[n > 0] / n[n > 0]
    return torch.log(per_window + 1e-6).mean()


def window_loss(cfg: PriorConfig, model: nn.Module, forward, wins: torch.Tensor, draw: int) -> torch.Tensor:
    """The training loss of the windows ``wins`` (:func:`batch`'s): a forecaster's (:func:`loss_fn` on its
    chunk, or on ``loss_frames`` rolled out), or a repair fill's (:func:`hidden_loss` over the masks of
    :func:`repair_batch`'s draw ``draw``). ``forward``: the forward to call (a compiled one), else ``model``."""
    if cfg.anchor == "window":  # a repair fill: the spline-filled masked window in, the window out
        filled, joint_mask = repair_batch(cfg, wins, draw)
        return hidden_loss(forward(filled), wins, joint_mask, cfg.window_loss)
    obs = wins[:, : cfg.obs_len]
    # loss_frames > chunk: the loss covers the rolled-out horizon the prior is used at (HumanEva-I rolls 15
    # frames out to 60), so the network learns to forecast from its own chunks, not only from the data's
    pred = forward(obs) if cfg.future == cfg.chunk else model.rollout(obs, cfg.future, forward)
    return loss_fn(pred, wins[:, cfg.obs_len :], cfg.velocity_weight)


def validation_windows(
    cfg: PriorConfig, data: str | None = None, frames: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[PriorConfig, torch.Tensor]:
    """The held-out windows of ``cfg.val_subjects`` a run validates on: ``val_windows`` of them, drawn once
    (draw 0 of a config of those subjects, without flips or turns), and that config (whose ``repair_batch``
    draw 0 gives a repair fill's masks). ``frames`` replaces those subjects' frames (tests)."""
    vcfg = replace(
        cfg,
        subjects=cfg.val_subjects,
        val_subjects=(),
        val_every=0,
        batch_size=cfg.val_windows,
        flip_prob=0.0,
        rotate_axis="",
        mirror_prob=0.0,
        h36m_share=0.0,
    )
    return vcfg, batch(vcfg, *(frames if frames is not None else training_frames(vcfg, data)), 0)


def validation_loss(vcfg: PriorConfig, model: nn.Module, val: torch.Tensor) -> float:
    """The validation score of ``model`` on the windows ``val`` (:func:`validation_windows`): its training
    loss on them; for a repair fill with ``val_mask_mix``, the geometric mean over those patterns of the
    pooled hidden error of each (every window masked by each pattern in turn: draw 0)."""
    if not vcfg.val_mask_mix:
        return window_loss(vcfg, model, model, val, 0).item()
    logs = [
        math.log(window_loss(replace(vcfg, mask_mix=(entry,), window_loss="pooled"), model, model, val, 0).item())
        for entry in vcfg.val_mask_mix
    ]
    return math.exp(sum(logs) / len(logs))


def learning_rate(cfg: PriorConfig, iteration: int) -> float:
    return cfg.lr if iteration < int(cfg.lr_decay_at * cfg.iterations) else cfg.lr_final


def same_run_so_far(old: PriorConfig, new: PriorConfig, iterations: int) -> bool:
    """Whether ``iterations`` iterations of ``old`` are exactly the first ones of ``new``: the configs differ
    at most in the schedule's length (``iterations``, ``lr_decay_at``) and every learning rate used so far is
    the same. Then a run may be resumed under ``new`` (a schedule shortened or lengthened before its decay):
    the batches are functions of (seed, iteration) only, so the result is the run ``new`` would have made."""
    schedule = {"iterations", "lr_decay_at"}
    if {k: v for k, v in old.to_dict().items() if k not in schedule} != {
        k: v for k, v in new.to_dict().items() if k not in schedule
    }:
        return False
    return all(learning_rate(old, i) == learning_rate(new, i) for i in range(iterations))


# ------------------------------------------------------------------------------------------ loop


def _save(path: Path, state: dict) -> None:
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    tmp.replace(path)


def train(
    cfg: PriorConfig,
    out: str | Path,
    *,
    data: str | None = None,
    resume: bool = False,
    max_minutes: float | None = None,
    checkpoint_minutes: float = 5.0,
    compile: bool = False,
    frames: tuple[np.ndarray, np.ndarray] | None = None,
    val_frames: tuple[np.ndarray, np.ndarray] | None = None,
    log=print,
) -> dict:
    """Train (or resume) into ``out`` (``last.pt``: weights, optimizer, iteration, loss history, CPU
    seconds). Stops resumably after ``max_minutes``. ``compile``: ``torch.compile`` the forward (1.9x
    the windows/s of eager at 48 blocks on one Zen 5 core, after about 50 s of compiling; the weights are
    the eager module's). ``frames`` replaces the dataset, ``val_frames`` the validation subjects' (tests).
    With ``val_every``, ``best.pt`` (as ``last.pt``) holds the weights of the lowest validation loss."""
    if cfg.anchor == "window" and not cfg.mask_mix:
        raise ValueError('prior config: anchor "window" trains on a mask_mix (the occlusions it learns to fill)')
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(cfg.seed)
    model = PriorNet(cfg)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    last = out / "last.pt"
    it, elapsed0, history = 0, 0.0, []
    if resume and last.is_file():
        ck = torch.load(last, map_location="cpu", weights_only=False)
        if PriorConfig.from_dict(ck["config"]).to_dict() != cfg.to_dict():  # (a config before `dataset`: h36m)
            if not same_run_so_far(PriorConfig.from_dict(ck["config"]), cfg, ck["iteration"]):
                raise ValueError(f"{last} was trained with another config; start a new --out or use the same config")
            log(
                f"{last}: the schedule changes to {cfg.iterations} iterations (decay at {cfg.lr_decay_at}); "
                f"its {ck['iteration']} iterations are the new schedule's first"
            )
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        it, elapsed0, history = ck["iteration"], ck["elapsed_s"], ck["history"]
        log(f"resumed from {last}: iteration {it}")
    elif cfg.init_from:
        if str(cfg.init_from).endswith(".safetensors"):  # an exported prior (a bundled one's run may be gone)
            init = {"model": load_prior_file(cfg.init_from)[0].state_dict(), "iteration": "exported"}
        else:
            init = torch.load(cfg.init_from, map_location="cpu", weights_only=False)
        grown = load_grown(model, init["model"])
        log(
            f"weights from {cfg.init_from} (iteration {init['iteration']} of its run)"
            + (f"; blocks {cfg.blocks - grown + 1}..{cfg.blocks} added as identities" if grown else "")
        )
    fr, starts = frames if frames is not None else training_frames(cfg, data)
    if fr.shape[1] != 3 * cfg.num_joints:
        raise ValueError(
            f"the {cfg.dataset} prior has {cfg.num_joints} joints ({3 * cfg.num_joints} coordinates), "
            f"the training frames {fr.shape[1]} coordinates"
        )
    forward = torch.compile(model) if compile else model
    log(
        f"prior: {count_parameters(model):,} parameters, {len(starts):,} training windows, "
        f"{torch.get_num_threads()} thread(s)"
    )

    if cfg.val_every:
        vcfg, val = validation_windows(cfg, data, val_frames)
        best_val = min((h["val"] for h in history if "val" in h), default=float("inf"))
        log(f"validation: {len(val)} windows of subjects {list(cfg.val_subjects)} every {cfg.val_every} iterations")

    def state() -> dict:
        return {
            "config": cfg.to_dict(),
            "model": model.state_dict(),
            "optimizer": opt.state_dict(),
            "iteration": it,
            "elapsed_s": elapsed0 + time.time() - t0,
            "history": history,
        }

    t0 = last_ck = time.time()
    run_loss, run_n = 0.0, 0
    while it < cfg.iterations:
        for g in opt.param_groups:
            g["lr"] = learning_rate(cfg, it)
        loss = window_loss(cfg, model, forward, batch(cfg, fr, starts, it), it)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        it += 1
        run_loss, run_n = run_loss + loss.item(), run_n + 1
        if it % 200 == 0 or it == cfg.iterations:
            history.append({"iteration": it, "loss": run_loss / run_n, "elapsed_s": elapsed0 + time.time() - t0})
            log(
                f"iteration {it}/{cfg.iterations}: loss {run_loss / run_n:.5f}, "
                f"{(elapsed0 + time.time() - t0) / 60:.1f} min"
            )
            run_loss, run_n = 0.0, 0
        if cfg.val_every and (it % cfg.val_every == 0 or it == cfg.iterations):
            with torch.no_grad():
                v = validation_loss(vcfg, model, val)
            history.append({"iteration": it, "val": v, "elapsed_s": elapsed0 + time.time() - t0})
            if v < best_val:
                best_val = v
                _save(out / "best.pt", state())
            log(f"iteration {it}: validation loss {v:.5f} (best {best_val:.5f})")
        now = time.time()
        if now - last_ck > 60 * checkpoint_minutes:
            _save(last, state())
            last_ck = now
        if max_minutes is not None and now - t0 > 60 * max_minutes:
            log(f"stopping after {max_minutes} min at iteration {it} (resume with --resume)")
            break
    _save(last, state())
    return {"iteration": it, "history": history, "done": it >= cfg.iterations}


def load_grown(model: PriorNet, state: dict) -> int:
    """Load ``state`` (a prior's weights) into ``model``, which may have more blocks than it: the extra blocks
    come last, each made the identity (layer-norm weight and bias zero: ``x + 0``), so the deeper network
    starts as the function ``state`` computes and training adds depth from there. Anything else that differs
    is an error. Returns the number of blocks added."""
    have = 1 + max((int(k.split(".")[1]) for k in state if k.startswith("blocks.")), default=-1)
    added = len(model.blocks) - have
    if added < 0:
        raise ValueError(f"init_from has {have} blocks, the config {len(model.blocks)}: a prior can grow, not shrink")
    try:
        missing, unexpected = model.load_state_dict(state, strict=False)
    except RuntimeError as e:  # shapes differ: another dataset, obs_len or joint count
        raise ValueError(f"init_from does not fit the config: {e}") from None
    new = {
        f"blocks.{i}.{name}"
        for i in range(have, len(model.blocks))
        for name in ("fc.weight", "fc.bias", "norm_weight", "norm_bias")
    }
    if unexpected or set(missing) != new:
        raise ValueError(
            f"init_from does not fit the config: missing {sorted(set(missing) - new)}, unexpected {sorted(unexpected)}"
        )
    with torch.no_grad():
        for block in model.blocks[have:]:
            block.norm_weight.zero_()
            block.norm_bias.zero_()
    return added


def load(path: str | Path) -> PriorNet:
    """A trained prior from a ``last.pt`` checkpoint, in eval mode."""
    ck = torch.load(path, map_location="cpu", weights_only=False)
    model = PriorNet(PriorConfig.from_dict(ck["config"]))
    model.load_state_dict(ck["model"])
    return model.eval()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m training.prior", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--config", required=True, help="prior config JSON (keys of PriorConfig)")
    ap.add_argument("--out", required=True, help="run directory (last.pt)")
    ap.add_argument(
        "--data",
        default=None,
        help="the config's dataset: the Human3.6M directory (default "
        "../shared/data/h36m) or the HumanEva-I directory or .npz (default ../shared/data/humaneva)",
    )
    ap.add_argument("--resume", action="store_true", help="continue from <out>/last.pt")
    ap.add_argument("--max-minutes", type=float, default=None)
    ap.add_argument("--checkpoint-minutes", type=float, default=5.0)
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1: keep a core free)")
    ap.add_argument("--no-compile", dest="compile", action="store_false", help="train the eager forward")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    res = train(
        PriorConfig.load(args.config),
        args.out,
        data=args.data,
        resume=args.resume,
        max_minutes=args.max_minutes,
        checkpoint_minutes=args.checkpoint_minutes,
        compile=args.compile,
        log=lambda m: print(m, flush=True),
    )
    print(json.dumps({k: v for k, v in res.items() if k != "history"}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
