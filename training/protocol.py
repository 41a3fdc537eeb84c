"""The whole evaluation of a model directory in one process (issue 15, part 3), resumable action by action.

    python -m training.protocol --model DIR --out RESULTS [--device cuda] [--max-minutes 9]
    python -m training.protocol --compare RESULTS_A RESULTS_B      # which model set is better (paired test)

For every pattern of ``--patterns`` (default: clean input, then the paper's four imperfect observations:
random leg + arm occlusion 40 %, structured leg occlusion, consecutive missing frames, Gaussian noise
25 mm), on the Human3.6M S5 protocol of :mod:`training.evaluate` (256 windows per action, DDPM over all
steps, 5 samples unless told otherwise):

* ``forecast_<pattern>/<action>.json``: the cascade's errors (oracle best of n, mean of n, Zero-Velocity on
  the same windows), written by :func:`training.evaluate.evaluate_h36m` for that action alone;
* ``repair_<pattern>/<action>.json`` (patterns that hide entries, when DIR holds ``repair.safetensors``):
  the summed distances over the hidden entries of the repair model (mean of n samples), of linear
  interpolation and of the natural cubic spline (``training.model.linear_fill`` / ``spline_fill``, bit for
  bit the engine's fills), on the same corrupted observations.

Each unit (one action of one part) is written atomically as soon as it is done and skipped when its file
exists, so an evaluation can be stopped and resumed, a run cut short losing one action at most;
``--max-minutes`` starts no unit that the slowest unit so far would carry past the budget. ``summary.json``
and the table printed last pool the units that exist over actions (the mean over actions of each action's
errors, as the whole protocol averages them; repair ADE pooled over hidden entries) and say how many
actions each pattern has so far; a pattern counts as done with all of them.

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
from .engines import from_bkl, joint_to_coord_mask, to_bkl
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
            compiled = torch.compile(net)  # static shapes: one (chains, K, L) per role
            compiled.cfg = net.cfg
            net = compiled
        out[role] = (net, sched, cfg)
    return out


# ------------------------------------------------------------------------------------------ repair


def repair_action(
    models: dict,
    data: H36M,
    pattern: str,
    action_index: int,
    action: str,
    *,
    windows_per_action: int,
    samples: int,
    steps: int | None,
    sampler: str,
    spacing: str,
    seed: int,
    mask_seed: int,
    device: str,
    batch_size: int,
) -> dict:
    """Summed distances (mm) over the hidden observation entries of one action's protocol windows, corrupted
    as :func:`evaluate.protocol_windows` corrupts them for the forecast: the repair model and the two
    interpolations."""
    from .diffusion import repair
    from .model import FILLS

    model, sched, cfg = models["repair"]
    seq_len = cfg["window"]["seq_len"]
    _, obs_clean, obs, jmask = E.protocol_windows(data, action, action_index, windows_per_action, pattern, mask_seed)
    obs = obs * joint_to_coord_mask(jmask)
    sums, count = {"tcd": 0.0, "linear": 0.0, "spline": 0.0}, 0
    for b0 in range(0, len(obs), batch_size):
        x = to_bkl(obs[b0 : b0 + batch_size]).to(device)
        m = to_bkl(joint_to_coord_mask(jmask[b0 : b0 + batch_size])).to(device)
        gen = torch.Generator(device=device).manual_seed(seed * 1_000_003 + action_index * 10_007 + b0)
        filled = {
            "tcd": repair(
                model,
                sched,
                x,
                m,
                seq_len=seq_len,
                num_samples=samples,
                generator=gen,
                sampler=sampler,
                num_inference_steps=steps,
                timestep_spacing=spacing,
            ),
            "linear": FILLS["linear"](x, m),
            "spline": FILLS["spline"](x, m),
        }
        for name, value in filled.items():
            total, c = repair_ade(from_bkl(value), obs_clean[b0 : b0 + batch_size], jmask[b0 : b0 + batch_size])
            sums[name] += 1000.0 * total
        count += c
    return {
        "pattern": pattern,
        "action": action,
        "sum_mm": sums,
        "hidden_entries": count,
        "ade_mm": {k: v / max(count, 1) for k, v in sums.items()},
        "label": "distances in mm over the hidden observation entries (tcd: mean of the samples)",
    }


# ------------------------------------------------------------------------------------------ parts


def parts(patterns, has_repair: bool) -> list[tuple[str, str]]:
    """(kind, pattern) in the order they run: every forecast first (the headline numbers), then repair."""
    out = [("forecast", p) for p in patterns]
    if has_repair:
        out += [("repair", p) for p in patterns if p != "none"]
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
    models = fast_models(
        loaded, forward=args.forward, precision=args.precision, compile_=args.compile, device=args.device
    )
    data = H36M(args.data)
    actions = data.test_actions()
    settings = {
        "model": str(args.model),
        "weights_sha256": weight_digests(Path(args.model)),
        "device": args.device,
        "forward": args.forward,
        "precision": args.precision,
        "compile": args.compile,
        "samples": args.samples,
        "steps": args.steps,
        "sampler": args.sampler,
        "timestep_spacing": args.timestep_spacing,
        "windows_per_action": args.windows_per_action,
        "seed": args.seed,
        "mask_seed": args.mask_seed,
    }
    if torch.cuda.is_available() and torch.device(args.device).type == "cuda":
        settings["gpu"] = torch.cuda.get_device_name()
    t_start, slowest, stopped = time.time(), 0.0, False
    for kind, pattern in parts(args.patterns, "repair" in models):
        part = out / f"{kind}_{pattern}"
        part.mkdir(exist_ok=True)
        done_before = 0
        for ai, action in enumerate(actions):
            path = part / f"{action}.json"
            if path.is_file():
                prev = json.loads(path.read_text()).get("settings", {})
                if identity(prev) != identity(settings):
                    raise SystemExit(
                        f"{path} was made with other settings or weights ({identity(prev)}, now "
                        f"{identity(settings)}); use another --out"
                    )
                done_before += 1
                continue
            elapsed = (time.time() - t_start) / 60
            if args.max_minutes is not None and elapsed + slowest > args.max_minutes:
                print(
                    f"stopping before {kind} {pattern} {action}: {elapsed:.1f} min used, the slowest unit took "
                    f"{slowest:.1f} of the {args.max_minutes} min budget; run again to continue",
                    file=sys.stderr,
                )
                stopped = True
                break
            t0 = time.time()
            if kind == "forecast":
                ns = argparse.Namespace(
                    model=args.model,
                    mask=pattern,
                    mask_seed=args.mask_seed,
                    seed=args.seed,
                    samples=args.samples,
                    steps=args.steps,
                    sampler=args.sampler,
                    eta=0.0,
                    timestep_spacing=args.timestep_spacing,
                    windows_per_action=args.windows_per_action,
                    batch_size=args.batch_size,
                    device=args.device,
                    engine="torch",
                    select="best",
                    quiet=True,
                )
                res = E.evaluate_h36m(ns, models=models, data=data, only=[action])
            else:
                res = repair_action(
                    models,
                    data,
                    pattern,
                    ai,
                    action,
                    windows_per_action=args.windows_per_action,
                    samples=args.samples,
                    steps=args.steps,
                    sampler=args.sampler,
                    spacing=args.timestep_spacing,
                    seed=args.seed,
                    mask_seed=args.mask_seed,
                    device=args.device,
                    batch_size=args.batch_size,
                )
            res["settings"], res["seconds"] = settings, time.time() - t0
            write_json(path, res)
            slowest = max(slowest, res["seconds"] / 60)
            if not args.quiet:
                print(f"{kind} {pattern} [{ai + 1}/{len(actions)}] {action}: {res['seconds']:.0f} s", file=sys.stderr)
        if done_before:
            print(f"{kind} {pattern}: {done_before} of {len(actions)} actions done before", file=sys.stderr)
        if stopped:
            break
    summary = summarize(out, actions)
    write_json(out / "summary.json", summary)
    print(table(summary))
    if summary["incomplete"]:
        print(f"\nnot done yet: {', '.join(summary['incomplete'])}")
    return 0


# ------------------------------------------------------------------------------------------ summary


def _mean_over_actions(units: list[dict], block: str) -> dict[str, float]:
    """The whole protocol's average at each horizon: the mean over actions of each action's error."""
    rows = [next(iter(u[block]["per_action"].values())) for u in units]
    return {h: float(np.mean([r[h] for r in rows])) for h in rows[0]}


def summarize(out: Path, actions: list[str]) -> dict:
    """The units in ``out`` pooled per pattern (see the module docstring), with the goal table's numbers at
    1000 ms and the ratios to Zero-Velocity. ``incomplete`` lists the parts that lack actions."""
    from .masks import PATTERNS

    forecast, repair_, incomplete = {}, {}, []
    parts_found = sorted(
        (d for d in out.iterdir() if d.is_dir() and "_" in d.name),
        key=lambda d: (d.name.split("_", 1)[0] != "forecast", PATTERNS.index(d.name.split("_", 1)[1])),
    )
    for d in parts_found:
        kind, pattern = d.name.split("_", 1)
        units = [json.loads((d / f"{a}.json").read_text()) for a in actions if (d / f"{a}.json").is_file()]
        if len(units) < len(actions):
            incomplete.append(f"{d.name} ({len(units)} of {len(actions)} actions)")
        if not units:
            continue
        if kind == "forecast":
            zv, best, mean = (_mean_over_actions(units, b) for b in ("zero_velocity", "best_of_n", "mean_of_n"))
            entries = sum(u.get("repair", {}).get("occluded_entries", 0) for u in units)
            rep = sum(u["repair"]["ade_mm"] * u["repair"]["occluded_entries"] for u in units if "repair" in u)
            forecast[pattern] = {
                "actions": len(units),
                "zero_velocity_mm": zv[HORIZON],
                "best_of_n_mm": best[HORIZON],
                "mean_of_n_mm": mean[HORIZON],
                "best_of_n_ratio": best[HORIZON] / zv[HORIZON],
                "mean_of_n_ratio": mean[HORIZON] / zv[HORIZON],
                "zero_velocity_all_horizons": zv,
                "best_of_n_all_horizons": best,
                "mean_of_n_all_horizons": mean,
                "cascade_repair_ade_mm": rep / entries if entries else None,
                "windows_per_action": units[0]["protocol"]["windows_per_action"],
                "samples": units[0]["sampling"]["samples"],
                "steps": units[0]["sampling"]["steps"],
            }
        else:
            count = sum(u["hidden_entries"] for u in units)
            a = {k: sum(u["sum_mm"][k] for u in units) / max(count, 1) for k in ("tcd", "linear", "spline")}
            repair_[pattern] = dict(
                a,
                actions=len(units),
                hidden_entries=count,
                tcd_over_linear=a["tcd"] / a["linear"],
                tcd_over_spline=a["tcd"] / a["spline"],
            )
    return {
        "horizon_ms": int(HORIZON),
        "actions": len(actions),
        "forecast": forecast,
        "repair": repair_,
        "incomplete": incomplete,
    }


def score(summary: dict) -> dict:
    """The two numbers a model set is judged by: ``forecast``, the mean over the evaluated patterns of
    the mean-of-n error at 1000 ms over Zero-Velocity's (deployable, lower is better); ``repair``, the mean
    over patterns of the repair model's ADE over the natural spline's. None where not evaluated."""
    f = [v["mean_of_n_ratio"] for v in summary["forecast"].values()]
    r = [v["tcd_over_spline"] for v in summary["repair"].values()]
    return {
        "forecast": float(np.mean(f)) if f else None,
        "repair": float(np.mean(r)) if r else None,
        "forecast_patterns": sorted(summary["forecast"]),
        "repair_patterns": sorted(summary["repair"]),
    }


def table(summary: dict) -> str:
    lines = ["| pattern | Zero-Velocity mm | best of n mm (ratio) | mean of n mm (ratio) |", "|---|---|---|---|"]
    for p, v in summary["forecast"].items():
        p = p if v["actions"] == summary["actions"] else f"{p} ({v['actions']} of {summary['actions']} actions)"
        lines.append(
            f"| {p} | {v['zero_velocity_mm']:.1f} | {v['best_of_n_mm']:.1f} ({v['best_of_n_ratio']:.3f}) "
            f"| {v['mean_of_n_mm']:.1f} ({v['mean_of_n_ratio']:.3f}) |"
        )
    if summary["repair"]:
        lines += [
            "",
            "| pattern | repair ADE mm: tcd | linear | spline | tcd / linear | tcd / spline |",
            "|---|---|---|---|---|---|",
        ]
        for p, v in summary["repair"].items():
            p = p if v["actions"] == summary["actions"] else f"{p} ({v['actions']} of {summary['actions']} actions)"
            lines.append(
                f"| {p} | {v['tcd']:.2f} | {v['linear']:.2f} | {v['spline']:.2f} | "
                f"{v['tcd_over_linear']:.3f} | {v['tcd_over_spline']:.3f} |"
            )
    return "\n".join(lines)


def unit_scores(d: Path, key: str, pattern: str) -> dict[str, float]:
    """action -> that action's score in one part: mean-of-n over Zero-Velocity at 1 s (forecast), the repair
    model's summed distances over the spline's (repair)."""
    out = {}
    for path in sorted((d / f"{key}_{pattern}").glob("*.json")):
        u = json.loads(path.read_text())
        if key == "forecast":
            action = next(iter(u["mean_of_n"]["per_action"]))
            out[action] = (
                u["mean_of_n"]["per_action"][action][HORIZON] / u["zero_velocity"]["per_action"][action][HORIZON]
            )
        else:
            out[u["action"]] = u["sum_mm"]["tcd"] / u["sum_mm"]["spline"]
    return out


def compare(a: Path, b: Path, margin: float = 0.01) -> dict:
    """Scores of two result directories (their ``summary.json``) on the patterns both evaluated on every
    action, and per part a paired test over (pattern, action): the mean difference of the two sets' per-action
    scores and its standard error. ``better`` names the directory whose scores are lower by more than two
    standard errors and by more than ``margin`` (relative); None when neither is (within sampling noise:
    keep what is bundled) or the part was not evaluated in both."""
    sa, sb = (json.loads((d / "summary.json").read_text()) for d in (a, b))
    paired, better = {}, {}
    for key in ("forecast", "repair"):
        common = sorted(
            p
            for p in set(sa[key]) & set(sb[key])
            if sa[key][p]["actions"] == sa["actions"] and sb[key][p]["actions"] == sb["actions"]
        )
        sa[key] = {p: v for p, v in sa[key].items() if p in common}
        sb[key] = {p: v for p, v in sb[key].items() if p in common}
        diffs = []
        for p in common:
            ua, ub = unit_scores(a, key, p), unit_scores(b, key, p)
            diffs += [ua[act] - ub[act] for act in sorted(set(ua) & set(ub))]
        d = np.asarray(diffs, dtype=np.float64)
        se = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("inf")
        paired[key] = {"pairs": len(d), "mean_difference": float(d.mean()) if len(d) else None, "standard_error": se}
    fa, fb = score(sa), score(sb)
    for key in ("forecast", "repair"):
        x, y, pr = fa[key], fb[key], paired[key]
        if (
            x is None
            or y is None
            or not pr["pairs"]
            or abs(x - y) <= margin * max(x, y)
            or abs(pr["mean_difference"]) <= 2 * pr["standard_error"]
            or (x < y) != (pr["mean_difference"] < 0)
        ):
            better[key] = None  # too close, too noisy, or the pooled and per-action views disagree
        else:
            better[key] = str(a) if x < y else str(b)
    return {
        "a": {"dir": str(a), **fa},
        "b": {"dir": str(b), **fb},
        "margin": margin,
        "paired": paired,
        "better": better,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m training.protocol", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    who = ap.add_mutually_exclusive_group(required=True)
    who.add_argument("--model", help="model directory (short, long and optionally repair .safetensors)")
    who.add_argument("--compare", nargs=2, metavar="RESULTS", help="two result directories to compare")
    ap.add_argument(
        "--margin",
        type=float,
        default=0.01,
        help="with --compare: the relative difference of scores that counts as better (default 0.01)",
    )
    ap.add_argument("--out", help="result directory (one JSON per part; existing parts are kept)")
    ap.add_argument("--data", default=str(DEFAULT_DATA_ROOT / "h36m"), help="Human3.6M exp-map data (S5 is enough)")
    ap.add_argument(
        "--patterns",
        default=",".join(PROTOCOL_PATTERNS),
        help=f"comma-separated observation patterns (default {','.join(PROTOCOL_PATTERNS)})",
    )
    ap.add_argument("--windows-per-action", type=int, default=256)
    ap.add_argument("--samples", type=int, default=5)
    ap.add_argument("--steps", type=int, default=None, help="inference steps (default: all training steps)")
    ap.add_argument("--sampler", choices=["ddpm", "ddim", "dpmpp2m"], default="ddpm")
    ap.add_argument("--timestep-spacing", choices=["leading", "trailing", "linspace"], default="trailing")
    ap.add_argument("--seed", type=int, default=0, help="sampling seed")
    ap.add_argument("--mask-seed", type=int, default=0)
    ap.add_argument("--device", default="cpu")
    ap.add_argument(
        "--batch-size", type=int, default=None, help="windows per sampling batch (default 16 on the CPU, 128 on a GPU)"
    )
    ap.add_argument("--forward", choices=["channels_last", "reference"], default="channels_last")
    ap.add_argument(
        "--precision", choices=["fp32", "tf32", "bf16"], default=None, help="default tf32 on CUDA, fp32 elsewhere"
    )
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
