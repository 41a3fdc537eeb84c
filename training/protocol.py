"""The whole evaluation of a model directory in one process (issue 15, part 3), resumable part by part.

    python -m training.protocol --model DIR --out RESULTS [--device cuda] [--max-minutes 9]
    python -m training.protocol --compare RESULTS_A RESULTS_B      # which model set is better

For every pattern of ``--patterns`` (default: clean input, then the paper's four imperfect observations:
random leg + arm occlusion 40 %, structured leg occlusion, consecutive missing frames, Gaussian noise
25 mm), on the Human3.6M S5 protocol of :mod:`training.evaluate` (256 windows per action, DDPM over all
steps, 5 samples unless told otherwise):

* ``forecast_<pattern>.json``: the cascade's errors (oracle best of n, mean of n, Zero-Velocity on the same
  windows), written by :func:`training.evaluate.evaluate_h36m`;
* ``repair_<pattern>.json`` (patterns that hide entries, when DIR holds ``repair.safetensors``): ADE in mm
  over the hidden entries of the repair model (mean of n samples), of linear interpolation and of the
  natural cubic spline (``training.model.linear_fill`` / ``spline_fill``, bit for bit the engine's fills),
  on the same corrupted observations.

Each part is written (atomically) as soon as it is done and skipped when its file exists, so the
evaluation can span several device calls of at most 10 minutes: ``--max-minutes`` starts no part that
the slowest part so far would carry past the budget. ``summary.json`` and the table printed last gather
whatever parts exist.

Speed: the samplers run the model through its channels-last forward (``training.channels_last``, equal to
the reference within 1e-5; ``--forward reference`` for the reference itself), with TF32 matrix products
on CUDA by default (``--precision``: fp32, tf32 or bf16 autocast) and optionally ``torch.compile``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

from . import evaluate as E
from .data.h36m import DEFAULT_DATA_ROOT, H36M
from .metrics import repair_ade

PROTOCOL_PATTERNS = ("none", "random_leg_arm", "structured_leg", "consecutive_frames", "noisy_25")
HORIZON = "1000"


# ------------------------------------------------------------------------------------------ forwards

class Autocast(nn.Module):
    """Runs ``module`` under bf16 autocast and returns float32 (the samplers' arithmetic stays float32)."""

    def __init__(self, module: nn.Module, device_type: str):
        super().__init__()
        self.module, self.device_type = module, device_type
        self.cfg = module.cfg

    def forward(self, *args):
        with torch.autocast(self.device_type, dtype=torch.bfloat16):
            return self.module(*args).float()


def fast_models(models: dict, *, forward: str, precision: str, compile_: bool, device: str) -> dict:
    """``export.load_model_dir``'s dict with each model replaced by the forward the samplers call."""
    from .channels_last import ChannelsLast
    dev = torch.device(device)
    if dev.type == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = precision == "tf32"
        torch.backends.cudnn.allow_tf32 = precision == "tf32"
    out = {}
    for role, (model, sched, cfg) in models.items():
        model.eval()
        net = ChannelsLast(model) if forward == "channels_last" else model
        if precision == "bf16":
            net = Autocast(net, dev.type)
        if compile_:
            compiled = torch.compile(net, dynamic=True)
            compiled.cfg = net.cfg
            net = compiled
        out[role] = (net, sched, cfg)
    return out


# ------------------------------------------------------------------------------------------ repair

def repair_errors(models: dict, data: H36M, pattern: str, *, windows_per_action: int, samples: int,
                  steps: int | None, sampler: str, spacing: str, seed: int, mask_seed: int, device: str,
                  batch_size: int, quiet: bool = False) -> dict:
    """ADE (mm) over the hidden observation entries of the repair model and the two interpolations, on
    the protocol windows corrupted as :func:`evaluate.protocol_windows` corrupts them for the forecast."""
    from .diffusion import repair
    from .model import FILLS
    model, sched, cfg = models["repair"]
    seq_len = cfg["window"]["seq_len"]
    sums = {"tcd": 0.0, "linear": 0.0, "spline": 0.0}
    count = 0
    per_action = {}
    t0 = time.time()
    actions = data.test_actions()
    for ai, action in enumerate(actions):
        _, obs_clean, obs, jmask = E.protocol_windows(data, action, ai, windows_per_action, pattern, mask_seed)
        obs = obs * E.joint_to_coord_mask(jmask)
        a_sums = dict.fromkeys(sums, 0.0)
        a_count = 0
        for b0 in range(0, len(obs), batch_size):
            x = E.to_bkl(obs[b0:b0 + batch_size]).to(device)
            m = E.to_bkl(E.joint_to_coord_mask(jmask[b0:b0 + batch_size])).to(device)
            gen = torch.Generator(device=device).manual_seed(seed * 1_000_003 + ai * 10_007 + b0)
            filled = {"tcd": repair(model, sched, x, m, seq_len=seq_len, num_samples=samples, generator=gen,
                                    sampler=sampler, num_inference_steps=steps, timestep_spacing=spacing)}
            for fill in ("linear", "spline"):
                filled[fill] = FILLS[fill](x, m)
            for name, value in filled.items():
                s, c = repair_ade(E.from_bkl(value), obs_clean[b0:b0 + batch_size], jmask[b0:b0 + batch_size])
                a_sums[name] += s
            a_count += c
        per_action[action] = {k: 1000.0 * v / max(a_count, 1) for k, v in a_sums.items()}
        for k in sums:
            sums[k] += a_sums[k]
        count += a_count
        if not quiet:
            print(f"[{ai + 1}/{len(actions)}] repair {pattern} {action}: {time.time() - t0:.0f} s", file=sys.stderr)
    return {"pattern": pattern, "ade_mm": {k: 1000.0 * v / max(count, 1) for k, v in sums.items()},
            "hidden_entries": count, "per_action": per_action,
            "label": "ADE in mm over the hidden observation entries (tcd: mean of the samples)"}


# ------------------------------------------------------------------------------------------ parts

def parts(patterns, has_repair: bool) -> list[tuple[str, str]]:
    """(kind, pattern) in the order they run: every forecast first (the headline numbers), then repair."""
    out = [("forecast", p) for p in patterns]
    if has_repair:
        out += [("repair", p) for p in patterns if p not in ("none",)]
    return out


def weight_digests(d: Path) -> dict:
    """sha256 of each model file: what identifies the weights (the directory's path changes between calls)."""
    import hashlib
    return {p.stem: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(d.glob("*.safetensors"))}


def identity(settings: dict) -> dict:
    """The settings a part's numbers depend on (not the GPU's name or the directory's path)."""
    return {k: v for k, v in settings.items() if k not in ("gpu", "model")}


def write_json(path: Path, obj: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2) + "\n")
    os.replace(tmp, path)


def run(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from .export import load_model_dir
    loaded = load_model_dir(args.model, args.device)
    models = fast_models(loaded, forward=args.forward, precision=args.precision, compile_=args.compile,
                         device=args.device)
    data = H36M(args.data)
    settings = {"model": str(args.model), "weights_sha256": weight_digests(Path(args.model)), "device": args.device, "forward": args.forward,
                "precision": args.precision, "compile": args.compile, "samples": args.samples,
                "steps": args.steps, "sampler": args.sampler, "timestep_spacing": args.timestep_spacing,
                "windows_per_action": args.windows_per_action, "seed": args.seed, "mask_seed": args.mask_seed}
    if torch.cuda.is_available() and torch.device(args.device).type == "cuda":
        settings["gpu"] = torch.cuda.get_device_name()
    t_start, slowest = time.time(), 0.0
    todo = parts(args.patterns, "repair" in models)
    for kind, pattern in todo:
        path = out / f"{kind}_{pattern}.json"
        if path.is_file():
            prev = json.loads(path.read_text()).get("settings", {})
            if identity(prev) != identity(settings):
                raise SystemExit(f"{path} was made with other settings or weights ({identity(prev)}, now "
                                 f"{identity(settings)}); use another --out")
            print(f"{kind} {pattern}: done before ({path.name})", file=sys.stderr)
            continue
        elapsed = (time.time() - t_start) / 60
        if args.max_minutes is not None and elapsed + slowest > args.max_minutes:
            print(f"stopping before {kind} {pattern}: {elapsed:.1f} min used, the slowest part took "
                  f"{slowest:.1f} of the {args.max_minutes} min budget; run again to continue", file=sys.stderr)
            break
        t0 = time.time()
        if kind == "forecast":
            ns = argparse.Namespace(model=args.model, mask=pattern, mask_seed=args.mask_seed, seed=args.seed,
                                    samples=args.samples, steps=args.steps, sampler=args.sampler, eta=0.0,
                                    timestep_spacing=args.timestep_spacing, windows_per_action=args.windows_per_action,
                                    batch_size=args.batch_size, device=args.device, engine="torch",
                                    select="best", quiet=args.quiet)
            res = E.evaluate_h36m(ns, models=models, data=data)
        else:
            res = repair_errors(models, data, pattern, windows_per_action=args.windows_per_action,
                                samples=args.samples, steps=args.steps, sampler=args.sampler,
                                spacing=args.timestep_spacing, seed=args.seed, mask_seed=args.mask_seed,
                                device=args.device, batch_size=args.batch_size, quiet=args.quiet)
        res["settings"], res["seconds"] = settings, time.time() - t0
        write_json(path, res)
        slowest = max(slowest, res["seconds"] / 60)
        print(f"{kind} {pattern}: {res['seconds']:.0f} s -> {path}", file=sys.stderr)
    summary = summarize(out)
    write_json(out / "summary.json", summary)
    print(table(summary))
    missing = [f"{k}_{p}" for k, p in todo if not (out / f"{k}_{p}.json").is_file()]
    if missing:
        print(f"\nnot done yet: {', '.join(missing)}")
    return 0


# ------------------------------------------------------------------------------------------ summary

def summarize(out: Path) -> dict:
    """Every part in ``out`` reduced to the goal table's numbers (errors at 1000 ms, ratios to Zero-Velocity)."""
    from .masks import PATTERNS
    order = lambda path: PATTERNS.index(path.stem.split("_", 1)[1])  # noqa: E731  (protocol order)
    forecast, repair_ = {}, {}
    for path in sorted(out.glob("forecast_*.json"), key=order):
        r = json.loads(path.read_text())
        zv = r["zero_velocity"]["average"][HORIZON]
        forecast[r["protocol"]["mask"]] = {
            "zero_velocity_mm": zv,
            "best_of_n_mm": r["best_of_n"]["average"][HORIZON], "mean_of_n_mm": r["mean_of_n"]["average"][HORIZON],
            "best_of_n_ratio": r["best_of_n"]["average"][HORIZON] / zv,
            "mean_of_n_ratio": r["mean_of_n"]["average"][HORIZON] / zv,
            "mean_of_n_all_horizons": r["mean_of_n"]["average"], "best_of_n_all_horizons": r["best_of_n"]["average"],
            "zero_velocity_all_horizons": r["zero_velocity"]["average"],
            "cascade_repair_ade_mm": r.get("repair", {}).get("ade_mm"),
            "windows_per_action": r["protocol"]["windows_per_action"], "samples": r["sampling"]["samples"],
            "steps": r["sampling"]["steps"]}
    for path in sorted(out.glob("repair_*.json"), key=order):
        r = json.loads(path.read_text())
        a = r["ade_mm"]
        repair_[r["pattern"]] = dict(a, tcd_over_linear=a["tcd"] / a["linear"], tcd_over_spline=a["tcd"] / a["spline"])
    return {"horizon_ms": int(HORIZON), "forecast": forecast, "repair": repair_}


def score(summary: dict) -> dict:
    """The two numbers a model set is judged by: ``forecast``, the mean over the evaluated patterns of
    the mean-of-n error at 1000 ms over Zero-Velocity's (deployable, lower is better); ``repair``, the mean
    over patterns of the repair model's ADE over the natural spline's. None where not evaluated."""
    f = [v["mean_of_n_ratio"] for v in summary["forecast"].values()]
    r = [v["tcd_over_spline"] for v in summary["repair"].values()]
    return {"forecast": float(np.mean(f)) if f else None, "repair": float(np.mean(r)) if r else None,
            "forecast_patterns": sorted(summary["forecast"]), "repair_patterns": sorted(summary["repair"])}


def table(summary: dict) -> str:
    lines = ["| pattern | Zero-Velocity mm | best of n mm (ratio) | mean of n mm (ratio) |", "|---|---|---|---|"]
    for p, v in summary["forecast"].items():
        lines.append(f"| {p} | {v['zero_velocity_mm']:.1f} | {v['best_of_n_mm']:.1f} ({v['best_of_n_ratio']:.3f}) "
                     f"| {v['mean_of_n_mm']:.1f} ({v['mean_of_n_ratio']:.3f}) |")
    if summary["repair"]:
        lines += ["", "| pattern | repair ADE mm: tcd | linear | spline | tcd / linear | tcd / spline |",
                  "|---|---|---|---|---|---|"]
        for p, v in summary["repair"].items():
            lines.append(f"| {p} | {v['tcd']:.2f} | {v['linear']:.2f} | {v['spline']:.2f} | "
                         f"{v['tcd_over_linear']:.3f} | {v['tcd_over_spline']:.3f} |")
    return "\n".join(lines)


def compare(a: Path, b: Path, margin: float = 0.01) -> dict:
    """Scores of two result directories on the patterns both evaluated; ``better`` names, per part, the
    directory whose score is lower by more than ``margin`` (relative): None when neither is (within
    sampling noise, keep what is bundled) or the part was not evaluated in both."""
    sa, sb = summarize(a), summarize(b)
    for key in ("forecast", "repair"):
        common = set(sa[key]) & set(sb[key])
        sa[key] = {p: v for p, v in sa[key].items() if p in common}
        sb[key] = {p: v for p, v in sb[key].items() if p in common}
    fa, fb = score(sa), score(sb)
    better = {}
    for key in ("forecast", "repair"):
        x, y = fa[key], fb[key]
        if x is None or y is None or abs(x - y) <= margin * max(x, y):
            better[key] = None
        else:
            better[key] = str(a) if x < y else str(b)
    return {"a": {"dir": str(a), **fa}, "b": {"dir": str(b), **fb}, "margin": margin, "better": better}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.protocol", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    who = ap.add_mutually_exclusive_group(required=True)
    who.add_argument("--model", help="model directory (short, long and optionally repair .safetensors)")
    who.add_argument("--compare", nargs=2, metavar="RESULTS", help="two result directories to compare")
    ap.add_argument("--margin", type=float, default=0.01,
                    help="with --compare: the relative difference of scores that counts as better (default 0.01)")
    ap.add_argument("--out", help="result directory (one JSON per part; existing parts are kept)")
    ap.add_argument("--data", default=str(DEFAULT_DATA_ROOT / "h36m"), help="Human3.6M exp-map data (S5 is enough)")
    ap.add_argument("--patterns", default=",".join(PROTOCOL_PATTERNS),
                    help=f"comma-separated observation patterns (default {','.join(PROTOCOL_PATTERNS)})")
    ap.add_argument("--windows-per-action", type=int, default=256)
    ap.add_argument("--samples", type=int, default=5)
    ap.add_argument("--steps", type=int, default=None, help="inference steps (default: all training steps)")
    ap.add_argument("--sampler", choices=["ddpm", "ddim", "dpmpp2m"], default="ddpm")
    ap.add_argument("--timestep-spacing", choices=["leading", "trailing", "linspace"], default="trailing")
    ap.add_argument("--seed", type=int, default=0, help="sampling seed")
    ap.add_argument("--mask-seed", type=int, default=0)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--batch-size", type=int, default=None, help="windows per sampling batch (default 16 on the "
                                                                   "CPU, 128 on a GPU)")
    ap.add_argument("--forward", choices=["channels_last", "reference"], default="channels_last")
    ap.add_argument("--precision", choices=["fp32", "tf32", "bf16"], default=None,
                    help="default tf32 on CUDA, fp32 elsewhere")
    ap.add_argument("--compile", action="store_true", help="torch.compile the forwards")
    ap.add_argument("--max-minutes", type=float, default=None)
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    if args.compare:
        res = compare(Path(args.compare[0]), Path(args.compare[1]), args.margin)
        print(json.dumps(res, indent=2))
        return 0
    if not args.out:
        ap.error("--out is required with --model")
    from .masks import PATTERNS
    args.patterns = [p for p in args.patterns.split(",") if p]
    unknown = [p for p in args.patterns if p not in PATTERNS]
    if unknown or not args.patterns:
        ap.error(f"--patterns: unknown {unknown}; choose from {', '.join(PATTERNS)}")
    if not 1 <= args.windows_per_action <= 256:
        ap.error("--windows-per-action must be in 1..256")
    if args.samples < 1:
        ap.error("--samples must be >= 1")
    cuda = torch.device(args.device).type == "cuda"
    args.precision = args.precision or ("tf32" if cuda else "fp32")
    if args.precision == "tf32" and not cuda:
        ap.error("--precision tf32 needs a CUDA device")
    args.batch_size = args.batch_size or (128 if cuda else 16)
    if args.threads:
        torch.set_num_threads(args.threads)
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
