"""Evaluate a model directory or a baseline on the Human3.6M S5 protocol (or a stochastic one: HumanEva-I, Human3.6M
Setting-A).

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
    python -m training.evaluate --protocol h36m-a --baseline neighbours --data ../shared/data/h36m
    python -m training.evaluate --prior python/tcd/weights --mask consecutive_frames   # the point forecast

HumanEva-I (stochastic, the DLow / GSPS protocol of ``training.data.humaneva``): the 188 windows of the
Validate split, 15 observed frames -> 60 predicted at 60 Hz, ``--samples`` (50: the protocol) samples per
window scored by ADE, FDE, MMADE, MMFDE and APD (``training.stochastic``: metres, the L2 norm of the flattened
42-dim pose), beside Zero-Velocity, the nearest training futures (``--samples`` futures of the Train split's
windows that arrive at the observation's last pose and velocity, joined to it: a baseline that learns nothing,
``--baseline neighbours``), the model directory's prior (its deterministic point forecast, one sample) and the
published numbers (``training.metrics.PUBLISHED_HUMANEVA``). ``--max-windows N`` scores N of the
windows (evenly spaced; their multimodal futures still come from all 188): a quick look, not the protocol.

Human3.6M Setting-A (``--protocol h36m-a``, stochastic, ``training.data.h36m_setting_a``): the same protocol on the
4,313 windows of S9 and S11 in our copy, 25 observed frames -> 100 predicted at 50 Hz, 16 joints (48 dimensions),
the nearest training futures from S1, S5, S6, S7 and S8; published numbers ``training.metrics.PUBLISHED_H36M_A``.
Both stochastic protocols are ``training.evaluate_stochastic``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from .data.h36m import DEFAULT_DATA_ROOT, H36M, model_to_xyz32, xyz32_to_model
from .engines import (
    joint_to_coord_mask,
    mode_of,
    noise_coupling_of,
    sampler_of,
    tcd_engine_predict,
    tcd_predict,
    tempo_run,
)
from .evaluate_stochastic import DATASETS, evaluate_stochastic_protocol, print_stochastic_table
from .metrics import HORIZONS_MS, PUBLISHED_H36M, at_horizons, oracle_best, per_frame_error, repair_ade

OBS, PRED = 50, 25


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
    sampler = sampler_of(args) if models is not None else None
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
            kw = dict(samples=args.samples, sampler=sampler, seed=args.seed * 1000 + ai)
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
        help="neighbours (--protocol humaneva or h36m-a): the nearest training windows' futures",
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
    ap.add_argument(
        "--protocol",
        choices=["h36m", *DATASETS],
        default="h36m",
        help="h36m: Setting-B (S5, deterministic horizons); humaneva, h36m-a: the stochastic DLow / GSPS protocol",
    )
    ap.add_argument("--data", default=None, help="data directory (default ../shared/data/<dataset>)")
    ap.add_argument("--json", help="write the results here")
    ap.add_argument(
        "--samples",
        type=int,
        default=None,
        help="samples per window (default 5; --protocol humaneva / h36m-a: 50, the protocol's)",
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
        choices=sorted({s for d in DATASETS.values() for s in d.splits}),
        default=None,
        help="--protocol humaneva / h36m-a: the split the windows come from (default the protocol's test "
        "windows: Validate, S9+S11; Train, S1+S5-S8: the same rule on the data the models learnt, to see "
        "what a choice does there)",
    )
    ap.add_argument(
        "--max-windows",
        type=int,
        default=None,
        help="--protocol humaneva / h36m-a: score this many of the windows, evenly spaced (a quick look)",
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
        args.samples = 5 if args.protocol == "h36m" else 50
    if args.samples < 1:
        ap.error("--samples must be >= 1")
    if args.max_windows is not None and args.max_windows < 1:
        ap.error("--max-windows must be >= 1")
    if args.baseline == "neighbours" and args.protocol == "h36m":
        ap.error("--baseline neighbours is a stochastic protocol's baseline (--protocol humaneva or h36m-a)")
    if args.protocol != "h36m":
        try:
            DATASETS[args.protocol].split_of(args.split)
        except ValueError as e:
            ap.error(f"--{e}")
    if args.tempo is not None and (args.engine != "tcd" or not args.model):
        ap.error("--tempo needs --model with --engine tcd (tcd.TCD.forecast samples the tempi)")
    if args.tempo is not None and getattr(args, "generator_share", None) is not None:
        ap.error("--tempo and --generator-share name two forecast modes (tcd.Tempo, tcd.Mixture): pass one")
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.data is None:
        args.data = str(DEFAULT_DATA_ROOT / "h36m" if args.protocol == "h36m" else DATASETS[args.protocol].data_path())
    args.noise_coupling = noise_coupling_of(args)  # resolved once: the model directory is read here, not per use
    out = evaluate_h36m(args) if args.protocol == "h36m" else evaluate_stochastic_protocol(args)
    out["command"] = " ".join(["python -m training.evaluate"] + (argv if argv is not None else sys.argv[1:]))
    if args.protocol == "h36m":
        print_table(out)
    else:
        print_stochastic_table(out)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
