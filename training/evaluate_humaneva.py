"""The HumanEva-I protocol of ``python -m training.evaluate --protocol humaneva`` (stochastic, the DLow / GSPS
protocol of ``training.data.humaneva``): the 188 windows of the Validate split, 15 observed frames -> 60 predicted at
60 Hz, each window's samples scored by ADE, FDE, MMADE, MMFDE and APD (``training.stochastic``) beside the
baselines (Zero-Velocity, the nearest training futures, the directory's prior) and the published numbers."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .engines import generator_share_of, mode_of, noise_coupling_of, sampler_of, tcd_predict, tempo_run


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
    sampler = sampler_of(args)
    if args.engine == "tcd":
        import tcd

        model = tcd.load(args.model)
        _check_humaneva_model(args.model, model.obs_len, model.horizon, model.num_joints)
    else:
        from .export import load_model_dir
        from .fileformat import GENERATOR_FILE

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
                sampler=sampler,
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
                sampler=sampler,
                seed=seed,
                device=args.device,
                batch_size=len(x),
                horizon=HE_PRED,
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
