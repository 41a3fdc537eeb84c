"""Accuracy vs latency of the samplers at fewer steps, same trained model, through the Rust engine ``tcd``.

    python benches/steps.py [--model DIR] [--data ../shared/data/h36m] [--windows-per-action N] [--samples N]
                            [--seed S] [--threads N] [--latency-reps R] [--actions A ...] [--only NAME ...]
                            [--accuracy-from JSON] [--json OUT] [--plot OUT.png]

Configurations (ENGINE.md, "Samplers at fewer steps"): DDPM over all 50 steps (the reference), DDIM at
50 / 25 / 10 / 5 / 2 steps with eta 0 and 1 and at one step (from independent and from centred noise:
``noise_coupling``), respaced DDPM at 20 and 10 steps, DPM-Solver++(2M) at 20 / 10 / 5 / 2 steps; trailing timestep
spacing throughout.

Protocol (reusing ``training.evaluate``, ``training.data.h36m``, ``training.masks``, ``training.metrics``):
* windows: Human3.6M S5, every test action, the first ``--windows-per-action`` windows of the 256-per-action
  protocol (RandomState(1234567890); smaller runs are prefixes of larger ones), 50 observed + 25 future
  frames;
* forecast error: the clean observation through the cascade (``training.engines.tcd_engine_predict``),
  error of the **mean of the n samples** per future frame (mean over the 32 joints after pasting the 22
  model joints into the ground truth), averaged over windows, then over actions, at
  80 / 160 / 320 / 400 / 560 / 720 / 880 / 1000 ms; the oracle best-of-n is stored in the JSON too;
* repair ADE: the observation corrupted with ``random_leg_arm`` (``training.masks.corrupt``,
  rng = default_rng([mask_seed, action_index, window])) through the same cascade; mean L2 distance (mm)
  over the occluded (frame, joint) entries of the repaired observation (the short-stage mean, as
  ``training.evaluate --mask``);
* sampling seed of action a: ``seed * 1000 + a`` (as ``training.evaluate``); the same for every
  configuration;
* latency: a separate pass, median wall seconds of ``TCD.forecast`` of ONE sequence with n samples
  (cascade: short + long stage), repetitions interleaved over the configurations (config 1, 2, ...,
  then again), after one warm-up call each.

Run time: proportional to windows x samples x steps. Each window is forecast twice per configuration
(clean and occluded), each forecast is a cascade of two stages, so one configuration costs
2 x 2 x samples x steps forwards per window; over the 19 configurations the steps add up to 303 (DDPM-50 and
the two DDIM-50 rows are 150 of them). Measured on the busy 2-core development machine with the reduced
cpu40 model (batch of one window, 2 samples): ~21 s for a DDIM-5 forecast, ~280 s for a DDPM-50 one, so
``--windows-per-action 1 --samples 2`` over all 13 actions and configurations takes hours there; use
``--actions walking --only DDIM-5 DPM++2M`` for a check in minutes, and an idle many-core machine for real
numbers (chains run in parallel over cores). The full protocol is 256 windows per action. Numbers from the
reduced development model are only a smoke test.

Two phases on a busy machine: the accuracy columns do not depend on timing, so they can be computed while
the machine does other work (``--latency-reps 0``, e.g. with ``RAYON_NUM_THREADS=1``), and the latency
measured later on the idle machine with ``--accuracy-from THAT.json`` (same model and ``--samples``; the
accuracy rows are copied, only the latency pass runs).

Bench-only dependency: matplotlib for ``--plot`` (``pip install tcd-forecast[bench]``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import tcd  # noqa: E402
from training.data.h36m import DEFAULT_H36M_DIR, H36M, model_to_xyz32, xyz32_to_model  # noqa: E402
from training.engines import tcd_engine_predict  # noqa: E402
from training.evaluate import OBS, PRED, summarize  # noqa: E402
from training.masks import corrupt  # noqa: E402
from training.metrics import HORIZONS_MS, oracle_best, per_frame_error, repair_ade  # noqa: E402
from tcd import SamplerOptions  # noqa: E402

MASK_PATTERN = "random_leg_arm"


def configurations() -> list[dict]:
    """name, sampler, num_inference_steps (None = all), eta; trailing spacing."""
    out = [dict(name="DDPM-50", sampler="ddpm", steps=None, eta=0.0, reference=True)]
    for n in (50, 25, 10, 5, 2):
        for eta in (0.0, 1.0):
            out.append(dict(name=f"DDIM-{n} eta={eta:g}", sampler="ddim", steps=n, eta=eta))
    # One step from pure noise to the network's x0 estimate: no noise is added after it, so eta plays no part.
    # With an x0-predicting model it is the model's conditional-mean estimate, the far end of the step axis.
    out.append(dict(name="DDIM-1", sampler="ddim", steps=1, eta=0.0))
    # The bundled forecast's default: the same step from centred noise (docs/samplers.md, "Centred noise").
    out.append(dict(name="DDIM-1 centred", sampler="ddim", steps=1, eta=0.0, noise_coupling="centered"))
    for n in (20, 10):
        out.append(dict(name=f"DDPM-{n} (respaced)", sampler="ddpm", steps=n, eta=0.0))
    for n in (20, 10, 5, 2):
        out.append(dict(name=f"DPM++2M-{n}", sampler="dpmpp2m", steps=n, eta=0.0))
    for c in out:
        c.setdefault("reference", False)
        c.setdefault("noise_coupling", "independent")
        c["timestep_spacing"] = "trailing"
    return out


def sampler_of(cfg: dict) -> SamplerOptions:
    """The sampler of one configuration of the sweep (its ``steps`` the sampler's ``num_inference_steps``)."""
    fields = {k: v for k, v in cfg.items() if k in ("sampler", "eta", "timestep_spacing", "noise_coupling")}
    return SamplerOptions(num_inference_steps=cfg["steps"], **fields)


def load_windows(data_dir: str, per_action: int, mask_seed: int, actions=None) -> list[dict]:
    """Per action: ground truth (W, 25, 32, 3) mm, clean observation (W, 50, 22, 3) m, and the
    random_leg_arm-corrupted observation with its joint mask. ``actions``: a subset (default all);
    action indices (seeds) stay those of the full list."""
    data = H36M(data_dir)
    out = []
    for ai, action in enumerate(data.test_actions()):
        if actions and action not in actions:
            continue
        wins = data.test_windows(action, OBS + PRED, OBS, per_action)  # (W, 75, 32, 3) mm
        obs_clean = xyz32_to_model(wins[:, :OBS]).astype(np.float64)  # (W, 50, 22, 3) m
        occ, jmask = obs_clean.copy(), np.ones(obs_clean.shape[:3], dtype=np.float32)
        for w in range(len(occ)):
            occ[w], jmask[w] = corrupt(obs_clean[w], MASK_PATTERN, OBS, np.random.default_rng([mask_seed, ai, w]))
        out.append(dict(action=action, index=ai, gt32=wins[:, OBS:], obs=obs_clean, occ=occ, jmask=jmask))
    return out


def accuracy(model_arg, cfg: dict, windows: list[dict], samples: int, seed: int) -> dict:
    mean_err, best_err, occ_err = {}, {}, {}
    rep_sum, rep_cnt = 0.0, 0
    for w in windows:
        kw = dict(samples=samples, seed=seed * 1000 + w["index"], sampler=sampler_of(cfg))
        gt32 = w["gt32"]
        clean = tcd_engine_predict(model_arg, w["obs"], np.ones(w["obs"].shape[:3], np.float32), **kw)
        errs = np.stack([per_frame_error(model_to_xyz32(s, gt32), gt32) for s in clean["samples"]])  # (S, W, 25)
        best_err[w["action"]] = oracle_best(errs).mean(axis=0)
        mean_err[w["action"]] = per_frame_error(model_to_xyz32(clean["samples"].mean(axis=0), gt32), gt32).mean(axis=0)
        occ = tcd_engine_predict(model_arg, w["occ"], w["jmask"], **kw)
        occ_err[w["action"]] = per_frame_error(model_to_xyz32(occ["samples"].mean(axis=0), gt32), gt32).mean(axis=0)
        s, c = repair_ade(occ["repaired"], w["obs"], w["jmask"])
        rep_sum, rep_cnt = rep_sum + s, rep_cnt + c
    return {
        "mean_of_n": summarize(mean_err),
        "best_of_n": summarize(best_err),
        "mean_of_n_occluded": summarize(occ_err),
        "repair": {"ade_mm": 1000.0 * rep_sum / max(rep_cnt, 1), "occluded_entries": rep_cnt},
    }


def latency(model, cfgs: list[dict], obs: np.ndarray, samples: int, reps: int, threads) -> dict[str, list[float]]:
    """Interleaved repetitions of one forecast (one sequence, n samples) per configuration."""
    times = {c["name"]: [] for c in cfgs}

    def once(c, seed):
        t0 = time.perf_counter()
        model.forecast(
            obs,
            num_samples=samples,
            sampler=SamplerOptions(
                sampler=c["sampler"],
                num_inference_steps=c["steps"],
                eta=c["eta"],
                timestep_spacing=c["timestep_spacing"],
                noise_coupling=c["noise_coupling"],
            ),
            seed=seed,
            threads=threads,
        )
        return time.perf_counter() - t0

    for c in cfgs:
        once(c, 0)  # warm-up
    for r in range(reps):
        for c in cfgs:
            times[c["name"]].append(once(c, 1 + r))
    return times


def table(rows: list[dict], samples: int) -> str:
    cols = [str(h) for h in HORIZONS_MS]
    head = "| sampler | " + " | ".join(f"{c} ms" for c in cols) + " | repair ADE | latency (s) |"
    sep = "|---" * (len(cols) + 3) + "|"
    lines = [
        f"Forecast error (mm, mean of {samples} samples), repair ADE (mm, {MASK_PATTERN}), "
        f"median latency of one forecast ({samples} samples):",
        "",
        head,
        sep,
    ]
    for r in rows:
        avg = r["mean_of_n"]["average"]
        lines.append(
            f"| {r['name']} | "
            + " | ".join(f"{avg.get(c, float('nan')):.1f}" for c in cols)
            + f" | {r['repair']['ade_mm']:.1f} | {r['latency_s']['median']:.3f} |"
        )
    return "\n".join(lines)


def plot(rows: list[dict], path: str) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("--plot needs matplotlib (pip install tcd-forecast[bench]); skipped", file=sys.stderr)
        return
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for r in rows:
        x, y = r["latency_s"]["median"], r["mean_of_n"]["average"].get("1000", float("nan"))
        marker = {"ddpm": "o", "ddim": "s", "dpmpp2m": "^"}[r["sampler"]]
        ax.scatter([x], [y], marker=marker)
        ax.annotate(r["name"], (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("median latency of one forecast (s, log scale)")
    ax.set_ylabel("error at 1000 ms (mm, mean of samples)")
    ax.set_title("TCD samplers: accuracy vs latency")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="model directory (default: the bundled model, tcd.load())")
    ap.add_argument("--data", default=str(DEFAULT_H36M_DIR), help="Human3.6M data directory")
    ap.add_argument("--windows-per-action", type=int, default=4, help="1..256 (default 4)")
    ap.add_argument("--samples", type=int, default=5, help="samples per forecast, n (default 5)")
    ap.add_argument("--seed", type=int, default=0, help="sampling seed (default 0)")
    ap.add_argument("--mask-seed", type=int, default=0, help="occlusion seed (default 0)")
    ap.add_argument("--threads", type=int, default=None, help="engine threads (default: all cores)")
    ap.add_argument(
        "--latency-reps",
        type=int,
        default=5,
        help="timed repetitions per configuration (default 5; 0 = accuracy only, no latency pass)",
    )
    ap.add_argument(
        "--accuracy-from",
        default=None,
        metavar="JSON",
        help="take the accuracy columns from this earlier --json run (same model, e.g. one made with "
        "--latency-reps 0 while the machine was busy) and only measure the latency now",
    )
    ap.add_argument(
        "--actions",
        nargs="+",
        default=None,
        metavar="ACTION",
        help="only these S5 actions (default: all 13; for quick checks, e.g. walking)",
    )
    ap.add_argument(
        "--only",
        nargs="+",
        default=None,
        metavar="NAME",
        help="run only these configurations: a full name, its first word (DDIM-5: both etas) or its "
        "family (DDIM, DDPM, DPM++2M)",
    )
    ap.add_argument("--json", default=None, help="write results and protocol here")
    ap.add_argument("--plot", default=None, help="PNG: error at 1000 ms vs latency (needs matplotlib)")
    args = ap.parse_args(argv)
    if not 1 <= args.windows_per_action <= 256:
        ap.error("--windows-per-action must be in 1..256")
    if args.samples < 1 or args.latency_reps < 0:
        ap.error("--samples must be >= 1 and --latency-reps >= 0")
    if args.accuracy_from and args.latency_reps < 1:
        ap.error("--accuracy-from measures the latency: --latency-reps must be >= 1")

    t_start = time.time()
    model = tcd.load(args.model, threads=args.threads)
    cfgs = configurations()
    if args.only:

        def wanted(name):
            return any(p in (name, name.split(" ")[0], name.split("-")[0]) for p in args.only)

        cfgs = [c for c in cfgs if wanted(c["name"])]
        if not cfgs:
            ap.error(f"--only {args.only} matches no configuration")
    windows = load_windows(args.data, args.windows_per_action, args.mask_seed, args.actions)
    if not windows:
        ap.error(f"--actions {args.actions} matches no S5 test action")
    n_windows = sum(len(w["obs"]) for w in windows)

    rows, accuracy_protocol = [], None
    if args.accuracy_from:
        prev = json.loads(Path(args.accuracy_from).read_text())
        accuracy_protocol = prev["protocol"]
        if accuracy_protocol.get("model_sha256") != model.sha256:
            ap.error(
                f"--accuracy-from {args.accuracy_from} was measured with another model "
                f"(sha256 {accuracy_protocol.get('model_sha256')}, this one {model.sha256})"
            )
        if accuracy_protocol.get("samples") != args.samples:
            ap.error(f"--accuracy-from {args.accuracy_from} used --samples {accuracy_protocol.get('samples')}")
        by_name = {r["name"]: r for r in prev["results"]}
        missing = [c["name"] for c in cfgs if c["name"] not in by_name]
        if missing:
            ap.error(f"--accuracy-from {args.accuracy_from} lacks the configurations {missing}")
        rows = [dict(by_name[c["name"]]) for c in cfgs]
    else:
        for i, c in enumerate(cfgs):
            t0 = time.time()
            acc = accuracy(args.model, c, windows, args.samples, args.seed)
            rows.append(dict(c, **acc))
            print(
                f"[{i + 1}/{len(cfgs)}] {c['name']}: {time.time() - t0:.0f} s "
                f"(1000 ms: {acc['mean_of_n']['average'].get('1000', float('nan')):.1f} mm)",
                file=sys.stderr,
                flush=True,
            )
    if args.latency_reps:
        times = latency(model, cfgs, windows[0]["obs"][0], args.samples, args.latency_reps, args.threads)
        for r in rows:
            t = times[r["name"]]
            r["latency_s"] = {"median": statistics.median(t), "min": min(t), "all": t}
    else:
        for r in rows:
            r["latency_s"] = {"median": float("nan"), "min": float("nan"), "all": []}

    print(table(rows, args.samples))
    elapsed = time.time() - t_start
    print(
        f"\n{n_windows} windows ({args.windows_per_action}/action), {args.samples} samples, "
        f"{len(cfgs)} configurations, {elapsed:.0f} s in all",
        file=sys.stderr,
    )
    out = {
        "protocol": {
            "dataset": "h36m",
            "subject": "S5",
            "actions": [w["action"] for w in windows],
            "windows_per_action": args.windows_per_action,
            "windows": n_windows,
            "window_draw": "RandomState(1234567890), first windows of the 256-per-action protocol",
            "observed_frames": OBS,
            "predicted_frames": PRED,
            "fps": 25,
            "units": "mm",
            "error": "mean over 32 joints (22 predicted pasted into GT, 6 duplicates copied) of the mean of n samples",
            "repair": f"ADE over occluded entries, {MASK_PATTERN}, short-stage mean of the cascade",
            "samples": args.samples,
            "timestep_spacing": "trailing",
            "seeds": {
                "windows": 1234567890,
                "mask": args.mask_seed,
                "sampling": args.seed,
                "sampling_per_action": "seed * 1000 + action_index",
            },
            "latency": {
                "what": "TCD.forecast of one sequence (the first window), cascade, n samples",
                "repetitions": args.latency_reps,
                "interleaved": True,
                "warmup": 1,
            },
            "engine": "tcd (Rust)",
            "tcd_version": getattr(tcd, "__version__", None),
            "model": str(model.path),
            "model_sha256": model.sha256,
            "threads": args.threads,
            "cpu_count": os.cpu_count(),
            "machine": platform.machine(),
            "platform": platform.platform(),
            "python": platform.python_version(),
            "data": args.data,
            "elapsed_s": elapsed,
            "accuracy_from": args.accuracy_from,
            "accuracy_protocol": accuracy_protocol,
            "command": " ".join(["python benches/steps.py"] + (argv if argv is not None else sys.argv[1:])),
        },
        "results": rows,
    }
    if accuracy_protocol:  # the accuracy columns (and so these fields) come from the earlier run
        for k in ("actions", "windows_per_action", "windows", "seeds", "samples"):
            out["protocol"][k] = accuracy_protocol.get(k)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    if args.plot and args.latency_reps:
        plot(rows, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
