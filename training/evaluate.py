"""Evaluate a model directory or a baseline on the Human3.6M S5 protocol (or HumanEva-I, stochastic).

Human3.6M (Setting-B, spec sections 3.1, 6, 10.2): subject S5, the actions present in the data (13 of 15
in our copy), ``--windows-per-action`` windows per action (256 = the full protocol) drawn with
RandomState(1234567890); 50 observed frames, 25 predicted (1 s at 25 fps); error per future frame =
mean over the 32 joints of the L2 distance in mm after pasting the 22 model joints into the ground
truth and copying the 6 duplicated joints. Per action averaged over windows, then over actions.
Zero-Velocity on the same windows (and the same corrupted observations) is reported beside every model.

Aggregation of the n samples (``--select``): ``best`` is the oracle best-of-n against the ground truth
(the paper's figure; not deployable), ``mean`` the mean of the samples (deployable). Both are always
computed and stored; ``--select`` picks the one printed first and stored under "average".

    python -m training.evaluate --baseline zero-velocity --data ../shared/data/h36m --json out.json
    python -m training.evaluate --model models/h36m --samples 5 --windows-per-action 8 --mask random_leg_arm
    python -m training.evaluate --protocol humaneva --baseline zero-velocity --data ../shared/data/humaneva
    python -m training.evaluate --protocol humaneva --model models/humaneva --engine tcd --samples 50
    python -m training.evaluate --protocol humaneva --prior models/humaneva     # the prior's point forecast

HumanEva-I (stochastic, the DLow / GSPS protocol of ``training.data.humaneva``): the 188 windows of the
Validate split, 15 observed frames -> 60 predicted at 60 Hz, ``--samples`` (50: the protocol) samples per
window scored by ADE, FDE, MMADE, MMFDE and APD (``training.stochastic``: metres, the L2 norm of the flattened
42-dim pose), beside Zero-Velocity, the nearest training futures (``--samples`` futures of the Train split's
windows that arrive at the observation's last pose and velocity, joined to it: a baseline that learns nothing,
``--baseline neighbours``), the model directory's prior (its deterministic point forecast, one sample) and the
published numbers (``training.metrics.PUBLISHED_HUMANEVA``). ``--max-windows N`` scores N of the
windows (evenly spaced; their multimodal futures still come from all 188): a quick look, not the protocol.
    python -m training.evaluate --prior python/tcd/weights --mask consecutive_frames   # the point forecast
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .data.h36m import DEFAULT_DATA_ROOT, H36M, model_to_xyz32, xyz32_to_model
from .metrics import HORIZONS_MS, PUBLISHED_H36M, at_horizons, oracle_best, per_frame_error, repair_ade

OBS, PRED = 50, 25


# ------------------------------------------------------------------------------------------ layout


def to_bkl(x: np.ndarray) -> torch.Tensor:
    """(B, L, J, 3) -> (B, K, L) float32 tensor, K = 3 J in joint-major order."""
    B, L, J, _ = x.shape
    t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))
    return t.reshape(B, L, J * 3).permute(0, 2, 1).contiguous()


def from_bkl(x: torch.Tensor) -> np.ndarray:
    """(..., K, L) -> (..., L, J, 3) float64 numpy."""
    x = x.detach().cpu().double()
    *lead, K, L = x.shape
    return x.transpose(-1, -2).reshape(*lead, L, K // 3, 3).numpy()


def joint_to_coord_mask(jmask: np.ndarray) -> np.ndarray:
    """(..., J) -> (..., J, 3)"""
    return np.repeat(np.asarray(jmask)[..., None], 3, axis=-1)


# ------------------------------------------------------------------------------------------ predictors


def zero_velocity(obs: np.ndarray, jmask: np.ndarray, horizon: int = PRED) -> np.ndarray:
    """Repeat the last visible value of every joint: (W, O, J, 3), (W, O, J) -> (W, horizon, J, 3).
    A joint never visible stays at 0."""
    W, obs_len, J, _ = obs.shape
    last = np.zeros((W, J, 3))
    for f in range(obs_len):
        vis = jmask[:, f] > 0.5
        last[vis] = obs[:, f][vis]
    return np.repeat(last[:, None], horizon, axis=1)


def noise_coupling_of(args) -> str:
    """The noise coupling a run samples with (``tcd.SamplerOptions.noise_coupling``): ``--noise-coupling``, else the
    model directory's forecast default where ``--sampler`` is its sampler (``SamplerOptions.build``'s rule, what
    ``tcd.TCD.forecast`` does), else ``"independent"``; both engines are given it explicitly."""
    given = getattr(args, "noise_coupling", None)
    if given or not getattr(args, "model", None):
        return given or "independent"
    import tcd

    return tcd.SamplerOptions.build(tcd.load(args.model).sampling.get("forecast"), sampler=args.sampler).noise_coupling


def tcd_predict(
    models: dict,
    obs: np.ndarray,
    jmask: np.ndarray,
    *,
    samples: int,
    steps: int | None,
    sampler: str,
    eta: float,
    spacing: str,
    seed: int,
    device: str,
    batch_size: int = 16,
    horizon: int = PRED,
    noise_coupling: str = "independent",
) -> dict:
    """Cascade forecast for windows obs (W, O, J, 3) metres (Human3.6M: O = 50) with joint mask (W, O, J).
    Returns samples (S, W, horizon, J, 3) and the repaired observation (W, O, J, 3) (mean of short-term samples)."""
    from .diffusion import cascade

    short_m, short_s, short_cfg = models["short"]
    long_m, long_s, long_cfg = models["long"]
    short_len, long_len = short_cfg["window"]["seq_len"], long_cfg["window"]["seq_len"]
    obs_len = obs.shape[1]
    if short_cfg["window"]["obs_len"] != obs_len or long_len - obs_len != horizon:
        raise ValueError(
            f"models expect {short_cfg['window']['obs_len']} observed frames and {long_len} in all; "
            f"the protocol has {obs_len} + {horizon}"
        )
    obs = obs * joint_to_coord_mask(jmask)  # missing values are zero in the model input
    outs, reps = [], []
    for b0 in range(0, len(obs), batch_size):
        gen = torch.Generator(device=device).manual_seed(int(seed) * 1_000_003 + b0)
        x = to_bkl(obs[b0 : b0 + batch_size]).to(device)
        m = to_bkl(joint_to_coord_mask(jmask[b0 : b0 + batch_size])).to(device)
        res = cascade(
            short_m,
            short_s,
            long_m,
            long_s,
            x,
            m,
            short_len=short_len,
            long_len=long_len,
            num_samples=samples,
            generator=gen,
            sampler=sampler,
            num_inference_steps=steps,
            eta=eta,
            timestep_spacing=spacing,
            noise_coupling=noise_coupling,
        )
        outs.append(from_bkl(res["samples"][..., obs_len:]))
        reps.append(from_bkl(res["short_mean"][..., :obs_len]))
    return {"samples": np.concatenate(outs, axis=1), "repaired": np.concatenate(reps, axis=0)}


def tcd_engine_predict(
    model_dir: str,
    obs: np.ndarray,
    jmask: np.ndarray,
    *,
    samples: int,
    steps: int | None,
    sampler: str,
    eta: float,
    spacing: str,
    seed: int,
    mode=None,
    noise_coupling: str = "independent",
) -> dict:
    """The same cascade through the Rust engine (``tcd``): fast on the CPU, in parity with the reference.
    Missing entries are passed as NaN; ``mode``: ``tcd.TCD.forecast``'s (None: the directory's)."""
    import tcd

    model = tcd.load(model_dir)
    x = np.where(joint_to_coord_mask(jmask) > 0.5, obs, np.nan)
    f = model.forecast(
        x,
        num_samples=samples,
        sampler=tcd.SamplerOptions(
            num_inference_steps=steps, sampler=sampler, eta=eta, timestep_spacing=spacing, noise_coupling=noise_coupling
        ),
        seed=int(seed),
        mode=mode,
    )
    return {"samples": np.asarray(f.samples, np.float64), "repaired": np.asarray(f.repaired, np.float64)}


def mode_of(args):
    """The forecast mode of a run with --engine tcd (``tcd.TCD.forecast``'s ``mode``): --tempo (``tcd.Tempo``),
    --generator-share (``tcd.Mixture``; 0: ``tcd.Cascade``), else None, the model directory's default
    (``tcd.TCD.forecast_mode``: its sampling.json)."""
    import tcd

    if args.tempo is not None:
        return tcd.Tempo(*args.tempo)
    share = getattr(args, "generator_share", None)
    if share is not None:
        return tcd.Mixture(share) if share else tcd.Cascade()
    return None


def _run_mode(args):
    """The mode the samples ran with: :func:`mode_of`, the directory's where it is None; None with --engine torch
    (the cascade alone, no generator)."""
    if args.engine != "tcd":
        return None
    import tcd

    mode = mode_of(args)
    return tcd.load(args.model).forecast_mode if mode is None else mode


def generator_share_of(args) -> float:
    """The share of each window's samples the model directory's MLP generator draws in this run (a results file's
    ``sampling.generator_share``; 0 with --engine torch, which runs no generator)."""
    import tcd

    mode = _run_mode(args)
    return mode.share if isinstance(mode, tcd.Mixture) else 0.0


def tempo_run(args) -> list | None:
    """The tempo range the samples ran with (a results file's ``sampling.tempo``; None: none)."""
    import tcd

    mode = _run_mode(args)
    return [mode.lo, mode.hi] if isinstance(mode, tcd.Tempo) and (mode.lo, mode.hi) != (1.0, 1.0) else None


def prior_predict(args, obs: np.ndarray, jmask: np.ndarray, seed: int) -> np.ndarray:
    """The prior's point forecast (W, 25, J, 3) metres from windows obs (W, 50, J, 3) with joint mask
    (W, 50, J): repair-then-predict, the missing entries filled first (``args.fill``).

    ``args.prior`` is a model directory holding ``prior.safetensors`` (through the public API,
    ``tcd.load(dir).predict``: the engine fills and forecasts) or a training checkpoint ``last.pt`` (the
    PyTorch reference; missing entries filled by ``tcd.interpolate`` or the bundled repair model)."""
    x = np.where(joint_to_coord_mask(jmask) > 0.5, obs, np.nan)
    path = Path(args.prior)
    if path.is_dir():
        import tcd

        f = tcd.load(path).predict(x, fill=args.fill, seed=seed)
        return np.asarray(f.mean, np.float64)
    from .prior import load

    if np.isnan(x).any():
        import tcd

        if args.fill in ("spline", "linear"):
            x = tcd.interpolate(x, method=args.fill)
        else:  # "auto" / "model": the bundled repair model, as the public API does without a directory
            x = tcd.load().repair(x, seed=seed).poses
    net = load(path)
    W, obs_len, J, _ = x.shape
    with torch.no_grad():
        out = net.rollout(torch.from_numpy(x.reshape(W, obs_len, J * 3).astype(np.float32)), PRED)
    return out.double().numpy().reshape(W, PRED, J, 3)


# ------------------------------------------------------------------------------------------ protocol


def summarize(per_action_frames: dict[str, np.ndarray]) -> dict:
    per_frame = np.mean(np.stack(list(per_action_frames.values())), axis=0)
    return {
        "average": at_horizons(per_frame),
        "per_action": {a: at_horizons(v) for a, v in per_action_frames.items()},
        "per_frame": [float(v) for v in per_frame],
    }


def protocol_windows(
    data: H36M, action: str, action_index: int, windows_per_action: int, mask: str, mask_seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One action's protocol windows: the future ground truth (W, 25, 32, 3) mm, the clean observation
    (W, 50, 22, 3) m, and the observation corrupted by the pattern ``mask`` with its joint mask (W, 50, 22)
    (window w's corruption drawn from ``default_rng([mask_seed, action_index, w])``)."""
    wins = data.test_windows(action, OBS + PRED, OBS, windows_per_action)  # (W, 75, 32, 3) mm
    obs_clean = xyz32_to_model(wins[:, :OBS]).astype(np.float64)  # (W, 50, 22, 3) m
    obs, jmask = obs_clean.copy(), np.ones(obs_clean.shape[:3], dtype=np.float32)
    if mask != "none":
        from .masks import corrupt

        for w in range(len(obs)):
            rng = np.random.default_rng([mask_seed, action_index, w])
            obs[w], jmask[w] = corrupt(obs_clean[w], mask, OBS, rng)
    return wins[:, OBS:], obs_clean, obs, jmask


def evaluate_h36m(args, models: dict | None = None, data: H36M | None = None, only: list[str] | None = None) -> dict:
    """The protocol for ``args`` (the options of :func:`main`). ``models`` (``export.load_model_dir``'s
    dict, possibly with faster forwards: ``training.protocol``) and ``data`` are loaded when not given.
    ``only``: evaluate these actions alone, each with the seeds it has in the whole protocol (its index
    among all actions), so that per-action results pooled later equal the whole run's."""
    data = data if data is not None else H36M(args.data)
    actions = data.test_actions()
    if models is None and args.model:
        from .export import load_model_dir

        models = load_model_dir(args.model, args.device)
    zv, zv_rep, best, mean, point = {}, {}, {}, {}, {}
    coupling = noise_coupling_of(args)
    rep_sum, rep_cnt = 0.0, 0
    t0 = time.time()
    for ai, action in enumerate(actions):
        if only is not None and action not in only:
            continue
        gt32, obs_clean, obs, jmask = protocol_windows(
            data, action, ai, args.windows_per_action, args.mask, args.mask_seed
        )
        zv[action] = per_frame_error(model_to_xyz32(zero_velocity(obs, jmask), gt32), gt32).mean(axis=0)
        if getattr(args, "prior", None):
            pred = prior_predict(args, obs, jmask, seed=args.seed * 1000 + ai)
            point[action] = per_frame_error(model_to_xyz32(pred, gt32), gt32).mean(axis=0)
        if models is not None:
            kw = dict(
                samples=args.samples,
                steps=args.steps,
                sampler=args.sampler,
                eta=args.eta,
                spacing=args.timestep_spacing,
                seed=args.seed * 1000 + ai,
                noise_coupling=coupling,
            )
            if args.engine == "tcd":
                res = tcd_engine_predict(args.model, obs, jmask, mode=mode_of(args), **kw)
            else:
                res = tcd_predict(models, obs, jmask, device=args.device, batch_size=args.batch_size, **kw)
            errs = np.stack([per_frame_error(model_to_xyz32(s, gt32), gt32) for s in res["samples"]])  # (S, W, 25)
            best[action] = oracle_best(errs).mean(axis=0)
            mean[action] = per_frame_error(model_to_xyz32(res["samples"].mean(axis=0), gt32), gt32).mean(axis=0)
            if args.mask != "none":
                s, c = repair_ade(res["repaired"], obs_clean, jmask)
                rep_sum, rep_cnt = rep_sum + s, rep_cnt + c
                zv_rep[action] = per_frame_error(
                    model_to_xyz32(zero_velocity(res["repaired"], np.ones_like(jmask)), gt32), gt32
                ).mean(axis=0)
        if not args.quiet:
            print(f"[{ai + 1}/{len(actions)}] {action}: {len(obs)} windows, {time.time() - t0:.0f} s", file=sys.stderr)
    evaluated = [a for a in actions if only is None or a in only]
    out = {
        "protocol": {
            "dataset": "h36m",
            "subject": "S5",
            "actions": evaluated,
            "windows_per_action": args.windows_per_action,
            "observed_frames": OBS,
            "predicted_frames": PRED,
            "fps": 25,
            "units": "mm",
            "error": "mean over 32 joints (22 predicted pasted into GT, 6 duplicates copied)",
            "mask": args.mask,
            "data": str(data.source.origin),
        },
        "seeds": {"windows": 1234567890, "mask": args.mask_seed, "sampling": args.seed},
        "zero_velocity": summarize(zv),
    }
    if getattr(args, "prior", None):
        out.update(method=f"prior {args.prior}", fill=args.fill, **summarize(point))
    elif models is None:
        out.update(method="zero-velocity", **summarize(zv))
    else:
        out["method"] = f"tcd {args.model}"
        out["sampling"] = {
            "engine": args.engine,
            "samples": args.samples,
            "steps": args.steps or models["short"][1].T,
            "sampler": args.sampler,
            "eta": args.eta,
            "timestep_spacing": args.timestep_spacing,
            "noise_coupling": coupling,
            "tempo": tempo_run(args),
        }
        out["best_of_n"] = dict(summarize(best), label=f"oracle best-of-{args.samples} (selected against ground truth)")
        out["mean_of_n"] = dict(summarize(mean), label=f"mean of {args.samples} samples (deployable)")
        chosen = out["best_of_n" if args.select == "best" else "mean_of_n"]
        out.update(
            select=args.select,
            average=chosen["average"],
            per_action=chosen["per_action"],
            per_frame=chosen["per_frame"],
        )
        if args.mask != "none":
            out["repair"] = {
                "ade_mm": 1000.0 * rep_sum / max(rep_cnt, 1),
                "occluded_entries": rep_cnt,
                "label": "ADE over occluded observation entries (mean of short-term samples)",
            }
            out["zero_velocity_on_repaired"] = summarize(zv_rep)
    return out


HE_OBS, HE_PRED = 15, 60  # HumanEva-I: 15 observed -> 60 predicted frames at 60 Hz


def _check_humaneva_model(where: str, obs_len: int, horizon: int, num_joints: int) -> None:
    if (obs_len, horizon, num_joints) != (HE_OBS, HE_PRED, 14):
        raise SystemExit(
            f"{where}: the model reads {obs_len} frames and forecasts {horizon} of {num_joints} joints; "
            f"the HumanEva-I protocol needs {HE_OBS} -> {HE_PRED} frames of 14 joints (a model trained "
            "with training/configs/humaneva_*.json)"
        )


def humaneva_model_samples(args, obs: np.ndarray, log=lambda m: None) -> np.ndarray:
    """``args.samples`` samples (S, W, 60, 14, 3) metres of the model directory ``args.model`` from the windows'
    observations obs (W, 15, 14, 3): through the Rust engine (``--engine tcd``: ``tcd.load(DIR).forecast``, the
    cascade with the directory's prior where the models are conditioned on it) or the PyTorch reference
    (``--engine torch``). ``args.batch_size`` windows per call, seeded by (``args.seed``, first window)."""
    W = len(obs)
    outs = []
    t0 = time.time()
    coupling = noise_coupling_of(args)
    if args.engine == "tcd":
        import tcd

        model = tcd.load(args.model)
        _check_humaneva_model(args.model, model.obs_len, model.horizon, model.num_joints)
    else:
        from .export import GENERATOR_FILE, load_model_dir

        if (Path(args.model) / GENERATOR_FILE).is_file() and getattr(args, "generator_share", None) != 0:
            raise SystemExit(
                f"{args.model} holds an MLP generator ({GENERATOR_FILE}), whose samples only the engine "
                "draws: score it with --engine tcd, or the cascade alone with --generator-share 0"
            )
        models = load_model_dir(args.model, args.device)
        w = models["short"][2]["window"]
        _check_humaneva_model(
            args.model,
            w["obs_len"],
            models["long"][2]["window"]["seq_len"] - w["obs_len"],
            models["short"][0].cfg.num_joints,
        )
    mode = mode_of(args) if args.engine == "tcd" else None
    for b0 in range(0, W, args.batch_size):
        x = obs[b0 : b0 + args.batch_size]
        seed = args.seed * 1_000_003 + b0
        if args.engine == "tcd":
            f = model.forecast(
                x,
                num_samples=args.samples,
                sampler=tcd.SamplerOptions(
                    num_inference_steps=args.steps,
                    sampler=args.sampler,
                    eta=args.eta,
                    timestep_spacing=args.timestep_spacing,
                    noise_coupling=coupling,
                ),
                seed=seed,
                mode=mode,
            )
            outs.append(np.asarray(f.samples, np.float64))
        else:
            res = tcd_predict(
                models,
                x,
                np.ones(x.shape[:3], np.float32),
                samples=args.samples,
                steps=args.steps,
                sampler=args.sampler,
                eta=args.eta,
                spacing=args.timestep_spacing,
                seed=seed,
                device=args.device,
                batch_size=len(x),
                horizon=HE_PRED,
                noise_coupling=coupling,
            )
            outs.append(res["samples"])
        log(f"[{min(b0 + args.batch_size, W)}/{W} windows] {args.samples} samples each, {time.time() - t0:.0f} s")
    return np.concatenate(outs, axis=1)


def humaneva_prior_forecast(path: str | Path, obs: np.ndarray) -> np.ndarray:
    """The prior's deterministic forecast (W, 60, 14, 3) from obs (W, 15, 14, 3): ``path`` a directory holding
    ``prior.safetensors`` or that file (the engine, ``tcd.engine.Prior``), or a ``training.prior`` checkpoint
    (PyTorch)."""
    path = Path(path)
    W, T, J, _ = obs.shape
    x = np.ascontiguousarray(obs.reshape(W, T, J * 3), dtype=np.float32)
    if path.is_dir() or path.suffix == ".safetensors":
        import tcd

        prior = tcd.engine.Prior.load(path / "prior.safetensors" if path.is_dir() else path)
        if prior.num_features != J * 3 or prior.obs_len > T:
            raise SystemExit(
                f"{path}: the prior reads {prior.obs_len} frames of {prior.num_joints} joints; the "
                f"HumanEva-I protocol gives {T} frames of {J}"
            )
        out = prior.predict(x, HE_PRED)
    else:
        from .prior import load

        net = load(path)
        with torch.no_grad():
            out = net.rollout(torch.from_numpy(x), HE_PRED).numpy()
    return np.asarray(out, np.float64).reshape(W, HE_PRED, J, 3)


def humaneva_neighbour_forecast(obs: np.ndarray, n: int, data=None) -> np.ndarray:
    """A baseline that learns nothing: for each observation (W, 15, 14, 3), the futures of the ``n`` windows of the
    Train split (every window of 75 frames) that arrive nearest to its last pose and velocity
    (``training.augment.arrival_keys``), each joined to the observation's last pose (``training.augment.swap_futures``,
    the augmentation ``future_swap`` trains with): (n, W, 60, 14, 3). The futures similar pasts had, which is what
    the samples of a stochastic forecaster should cover."""
    from .augment import arrival_keys, squared_distances, swap_futures
    from .batches import Windows
    from .data.humaneva import training_sequences

    windows = Windows(list(training_sequences(data).values()), HE_OBS + HE_PRED, 1)
    train = windows.gather(np.arange(len(windows)))
    if not 1 <= n <= len(train):
        raise SystemExit(
            f"the nearest training futures: --samples must be in 1..{len(train)} (the training windows), got {n}"
        )
    d = squared_distances(arrival_keys(obs, HE_OBS), arrival_keys(train, HE_OBS))
    nearest = np.argsort(d, axis=1, kind="stable")[:, :n]  # (W, n)
    past = np.concatenate([obs, np.zeros((len(obs), HE_PRED) + obs.shape[2:])], axis=1)
    out = [swap_futures(past, train[nearest[:, i]].astype(np.float64), HE_OBS)[:, HE_OBS:] for i in range(n)]
    return np.stack(out)


def humaneva_protocol(windows: int, windows_in_protocol: int, split: str = "Validate") -> dict:
    """The ``protocol`` block of a HumanEva-I result: ``training.compare`` pairs two results only where it is equal."""
    return {
        "dataset": "humaneva-i",
        "split": split,
        "t_his": HE_OBS,
        "t_pred": HE_PRED,
        "fps": 60,
        "windows": windows,
        "windows_in_protocol": windows_in_protocol,
        "units": "m (DLow/GSPS: L2 norm of the flattened 42-dim pose)",
    }


@dataclass
class HumanEvaCases:
    """The protocol's windows a HumanEva-I evaluation scores (all 188, or ``max_windows`` evenly spaced) and how:
    one place for the evaluator and the trainers that score samples (``training.generator_imle``)."""

    rows: np.ndarray  # which of the protocol's windows
    windows_in_protocol: int
    obs: np.ndarray  # (W, 15, 14, 3) metres
    gts: list  # each window's future (60, 42)
    gt_multi: list  # each window's multimodal futures (M, 60, 42), from every window as DLow does
    actions: np.ndarray  # each window's action ("Box", ...)
    split: str = "Validate"  # the protocol's; "Train" draws the same windows from the training split

    @classmethod
    def load(cls, data=None, max_windows: int | None = None, split: str = "Validate") -> "HumanEvaCases":
        from .data.humaneva import (
            humaneva_file,
            humaneva_test_actions,
            humaneva_test_windows,
            load_humaneva,
            multimodal_gt,
        )

        data = load_humaneva(humaneva_file(data), split=split)
        wins = humaneva_test_windows(data)  # (N, 75, 14, 3) metres
        D = wins.shape[2] * 3
        gt_multi_all = multimodal_gt(wins, HE_OBS)
        rows = np.arange(len(wins))
        if max_windows:
            rows = np.unique(np.linspace(0, len(wins) - 1, min(max_windows, len(wins))).round().astype(int))
        return cls(
            rows,
            len(wins),
            wins[rows, :HE_OBS].astype(np.float64),
            [wins[i, HE_OBS:].reshape(-1, D) for i in rows],
            [gt_multi_all[i] for i in rows],
            np.asarray(humaneva_test_actions(data))[rows],
            split,
        )

    def protocol(self) -> dict:
        return humaneva_protocol(len(self.rows), self.windows_in_protocol, self.split)

    def score(self, pred: np.ndarray) -> dict:
        """The protocol's metrics, with each window's, of samples ``pred`` (S, W, 60, 14, 3); and beside them
        ``mean_ADE`` / ``mean_FDE``, the ADE / FDE of the samples' mean (what ``Forecast.mean`` returns: the
        point forecast a user deploys, not a protocol metric)."""
        from .stochastic import ade, evaluate_stochastic, fde

        S, W = pred.shape[:2]
        flat = [pred[:, w].reshape(S, HE_PRED, -1) for w in range(W)]
        out = evaluate_stochastic(flat, self.gts, self.gt_multi, per_window=True)
        for name, metric in (("mean_ADE", ade), ("mean_FDE", fde)):
            out["per_window"][name] = [metric(f.mean(axis=0, keepdims=True), gt) for f, gt in zip(flat, self.gts)]
            out[name] = float(np.mean(out["per_window"][name]))
        return out

    def per_action(self, scores: dict) -> dict:
        """Each action's windows and means of ``scores``' per-window values (Box has a fifth of the windows and
        about twice the mean's error: where the error is)."""
        return {
            a: {
                "windows": int((self.actions == a).sum()),
                **{k: float(np.mean(np.asarray(v)[self.actions == a])) for k, v in scores["per_window"].items()},
            }
            for a in sorted(set(self.actions))
        }


def evaluate_humaneva(args) -> dict:
    """The stochastic HumanEva-I protocol for ``args`` (the options of :func:`main`); see the module docstring."""
    from .metrics import PUBLISHED_HUMANEVA, PUBLISHED_HUMANEVA_SOURCES

    cases = HumanEvaCases.load(args.data, getattr(args, "max_windows", None), getattr(args, "split", "Validate"))
    obs, score = cases.obs, cases.score
    say = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))

    results = {"zero_velocity": score(np.repeat(obs[None, :, -1:], HE_PRED, axis=2))}
    prior_path = args.prior or (
        args.model if args.model and (Path(args.model) / "prior.safetensors").is_file() else None
    )
    if prior_path:
        results["prior"] = score(humaneva_prior_forecast(prior_path, obs)[None])
    if cases.split == "Validate":  # on the Train split each window would find itself
        results["neighbours"] = score(humaneva_neighbour_forecast(obs, args.samples, args.data))
    t0 = time.time()
    if args.model:
        results["model"] = score(humaneva_model_samples(args, obs, log=say))
    out = {
        "protocol": cases.protocol(),
        "seeds": {"sampling": args.seed} if args.model else {},
        **results,
        "published": {k: v for k, v in PUBLISHED_HUMANEVA.items()},
        "published_sources": PUBLISHED_HUMANEVA_SOURCES,
    }
    if args.model:
        out.update(
            method=f"tcd {args.model}",
            stochastic=results["model"],
            seconds=time.time() - t0,
            sampling={
                "engine": args.engine,
                "samples": args.samples,
                "steps": args.steps,
                "sampler": args.sampler,
                "eta": args.eta,
                "timestep_spacing": args.timestep_spacing,
                "noise_coupling": noise_coupling_of(args),
                "tempo": tempo_run(args),
                "generator_share": generator_share_of(args),
            },
        )
    elif args.prior:
        out.update(method=f"prior {args.prior}", stochastic=results["prior"])
    elif args.baseline == "neighbours":
        if "neighbours" not in results:
            raise SystemExit("--baseline neighbours: on the Train split each window would find itself")
        out.update(method="nearest training futures", stochastic=results["neighbours"])
    else:
        out.update(method="zero-velocity", stochastic=results["zero_velocity"])
    if prior_path:
        out["prior_source"] = str(prior_path)
    out["per_action"] = cases.per_action(out["stochastic"])
    return out


def print_humaneva_table(out: dict) -> None:
    keys = ("ADE", "FDE", "MMADE", "MMFDE", "APD")
    p = out["protocol"]
    print(
        f"\nHumanEva-I, {p['windows']} of {p['windows_in_protocol']} Validate windows, {p['t_his']} -> {p['t_pred']} "
        f"frames at {p['fps']} Hz; metres (L2 norm of the flattened 42-dim pose; lower is better but APD, the "
        "diversity)"
    )
    print(f"{'method':<44}" + "".join(f"{k:>8}" for k in keys))

    def row(name: str, d: dict | None) -> None:
        cells = "".join(f"{d[k]:>8.3f}" if d and d.get(k) is not None else f"{'-':>8}" for k in keys)
        print(f"{name:<44}{cells}")

    if "model" in out:
        s = out["sampling"]
        share = s.get("generator_share") or 0
        row(
            f"tcd ({s['samples']} samples, {s['engine']}, {s['sampler']} {s['steps'] or 'all'} steps"
            + (f", {int(s['samples'] * share)} MLP" if share else "")
            + ")",
            out["model"],
        )
    if "prior" in out:
        row("prior (deterministic point forecast)", out["prior"])
    row("Zero-Velocity", out["zero_velocity"])
    if "neighbours" in out:
        row("nearest training futures, joined", out["neighbours"])
    print("published (50 samples; - : not given by the spec)")
    for name, d in out["published"].items():
        row(f"  {name}", d)
    if "per_action" in out:
        print(f"{out['method']}, per action (its windows' means)")
        for name, d in out["per_action"].items():
            row(f"  {name} ({d['windows']} windows)", d)


def print_table(out: dict) -> None:
    cols = [str(h) for h in HORIZONS_MS]

    def row(name, d):
        return f"{name:<18}" + "".join(f"{d.get(c, float('nan')):>8.1f}" for c in cols)

    blocks = [("zero-velocity", out["zero_velocity"])]
    if out["method"].startswith("prior"):
        blocks = [(f"{out['method']} (point forecast, missing entries: {out['fill']})", out)] + blocks
    if "best_of_n" in out:
        blocks = [(out["best_of_n"]["label"], out["best_of_n"]), (out["mean_of_n"]["label"], out["mean_of_n"])] + blocks
    for label, block in blocks:
        print(
            f"\n{label}  (mm; S5, {out['protocol']['windows_per_action']} windows/action, "
            f"mask={out['protocol']['mask']})"
        )
        print(f"{'action':<18}" + "".join(f"{c + 'ms':>8}" for c in cols))
        for a, d in block["per_action"].items():
            print(row(a, d))
        print(row("average", block["average"]))
    if out["method"].startswith("prior") and out["protocol"]["mask"] == "none":
        print("\npublished (15 actions, clean input; our 13 actions are about 2 % harder for Zero-Velocity)")
        for name, d in PUBLISHED_H36M.items():
            print(row(name, d))
    if "repair" in out:
        print(
            f"\nrepair ADE over occluded entries: {out['repair']['ade_mm']:.2f} mm "
            f"({out['repair']['occluded_entries']} entries)"
        )


def build_parser() -> argparse.ArgumentParser:
    """The command line of :func:`main` (its defaults are the protocol's; benches parse their sampling with it)."""
    from .masks import PATTERNS

    ap = argparse.ArgumentParser(
        prog="python -m training.evaluate", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    who = ap.add_mutually_exclusive_group(required=True)
    who.add_argument(
        "--baseline",
        choices=["zero-velocity", "neighbours"],
        help="neighbours (--protocol humaneva): the nearest training windows' futures",
    )
    who.add_argument("--model", help="model directory (short.safetensors + long.safetensors)")
    who.add_argument(
        "--prior",
        help="the deterministic prior: a model directory with prior.safetensors (the public "
        "API, tcd.load(DIR).predict; --protocol humaneva: tcd.engine.Prior, so the "
        "directory may hold the prior alone) or a training checkpoint last.pt (PyTorch)",
    )
    ap.add_argument(
        "--fill",
        choices=["auto", "model", "spline", "linear"],
        default="auto",
        help="--prior: how missing observation entries are filled before predicting (auto: the "
        "repair model where one is loaded, else the natural cubic spline)",
    )
    ap.add_argument("--protocol", choices=["h36m", "humaneva"], default="h36m")
    ap.add_argument("--data", default=None, help="data directory (default ../shared/data/<dataset>)")
    ap.add_argument("--json", help="write the results here")
    ap.add_argument(
        "--samples",
        type=int,
        default=None,
        help="samples per window (default 5; --protocol humaneva: 50, the protocol's)",
    )
    ap.add_argument("--steps", type=int, default=None, help="inference steps (default: all training steps)")
    ap.add_argument("--sampler", choices=["ddpm", "ddim", "dpmpp2m"], default="ddpm")
    ap.add_argument("--eta", type=float, default=0.0, help="DDIM eta")
    ap.add_argument(
        "--noise-coupling",
        choices=["independent", "centered"],
        default=None,
        help="how a window's samples share their starting noise (tcd.SamplerOptions.noise_coupling; "
        "default: the model directory's forecast default for --sampler, else independent)",
    )
    ap.add_argument("--timestep-spacing", choices=["leading", "trailing", "linspace"], default="trailing")
    ap.add_argument(
        "--tempo",
        type=float,
        nargs=2,
        metavar=("LO", "HI"),
        default=None,
        help="--engine tcd: each sample from the observation replayed at its own tempo, LO to HI "
        "(tcd._tempo; 1 1: none; default: the model directory's sampling.json)",
    )
    ap.add_argument(
        "--generator-share",
        type=float,
        default=None,
        help="--engine tcd: the share of each window's samples the directory's MLP generator draws "
        "(tcd.Mixture's share; 0: the cascade alone, tcd.Cascade; default: the directory's "
        "sampling.json, 0.5 for the bundled HumanEva-I model)",
    )
    ap.add_argument(
        "--select",
        choices=["best", "mean"],
        default="best",
        help="best = oracle best-of-n (paper), mean = mean of samples (deployable)",
    )
    ap.add_argument("--mask", choices=list(PATTERNS), default="none", help="observation corruption pattern")
    ap.add_argument("--mask-seed", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0, help="sampling seed")
    ap.add_argument("--windows-per-action", type=int, default=256)
    ap.add_argument(
        "--split",
        choices=["Validate", "Train"],
        default="Validate",
        help="--protocol humaneva: the split the windows come from (Validate: the protocol's test "
        "windows; Train: the same rule on the data the models learnt, to see what a choice does "
        "there)",
    )
    ap.add_argument(
        "--max-windows",
        type=int,
        default=None,
        help="--protocol humaneva: score this many of the 188 windows, evenly spaced (a quick look)",
    )
    ap.add_argument("--batch-size", type=int, default=16, help="windows per sampling batch")
    ap.add_argument("--device", default="cpu")
    ap.add_argument(
        "--engine",
        choices=["torch", "tcd"],
        default="torch",
        help="torch: this PyTorch reference; tcd: the Rust engine of the installed tcd package "
        "(same model, parity-tested; its own seeded noise streams)",
    )
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    ap.add_argument("--quiet", action="store_true")
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if not 1 <= args.windows_per_action <= 256:
        ap.error("--windows-per-action must be in 1..256")
    if args.samples is None:
        args.samples = 50 if args.protocol == "humaneva" else 5
    if args.samples < 1:
        ap.error("--samples must be >= 1")
    if args.max_windows is not None and args.max_windows < 1:
        ap.error("--max-windows must be >= 1")
    if args.baseline == "neighbours" and args.protocol != "humaneva":
        ap.error("--baseline neighbours is a HumanEva-I baseline (--protocol humaneva)")
    if args.tempo is not None and (args.engine != "tcd" or not args.model):
        ap.error("--tempo needs --model with --engine tcd (tcd.TCD.forecast samples the tempi)")
    if args.tempo is not None and getattr(args, "generator_share", None) is not None:
        ap.error("--tempo and --generator-share name two forecast modes (tcd.Tempo, tcd.Mixture): pass one")
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.data is None:
        args.data = str(DEFAULT_DATA_ROOT / ("h36m" if args.protocol == "h36m" else "humaneva"))
    args.noise_coupling = noise_coupling_of(args)  # resolved once: the model directory is read here, not per use
    out = evaluate_h36m(args) if args.protocol == "h36m" else evaluate_humaneva(args)
    out["command"] = " ".join(["python -m training.evaluate"] + (argv if argv is not None else sys.argv[1:]))
    if args.protocol == "h36m":
        print_table(out)
    else:
        print_humaneva_table(out)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
