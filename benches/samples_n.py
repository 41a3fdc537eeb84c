"""How the number of samples decides a TCD forecast's error: the mean of n samples and the oracle best of n,
against n, beside the prior's point forecast, through the public API (issue 29).

    python3 benches/samples_n.py [--model DIR] [--subject 5] [--windows-per-action 4] [--samples 40]
                                 [--sampler ddim] [--steps 10] [--json benches/results/samples_n_bundled.json]

Why: the mean of n samples from a model whose samples spread like the data's futures has, in squared error,
the error of the model's conditional mean plus the samples' variance divided by n. With few samples the
variance term dominates: the mean of 5 can be worse than a point forecast (the prior) even when the model's
conditional mean is not. This measures both terms' effect on real windows: one call of ``TCD.forecast`` with
``--samples`` samples per window; the first n of them give the "n" row (prefixes, so the rows are nested).

Windows: Human3.6M subject ``--subject`` (default S5, the test protocol's: nothing is chosen on these numbers;
S11 is the diffusion runs' validation subject but one the prior trains on), every action it has, the first
``--windows-per-action`` windows of the protocol's draw (RandomState(1234567890)), 50 observed frames -> 25
(1 s at 25 fps), clean input. Error
per future frame: ``training.evaluate``'s (mean over 32 joints, mm), averaged over windows then actions, at
560 ms and 1 s. Sampling seed of action a: ``seed * 1000 + a``; the prior (``TCD.predict``) on the same windows.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import tcd  # noqa: E402
from training.data.h36m import DEFAULT_DATA_ROOT, H36M, model_to_xyz32, xyz32_to_model  # noqa: E402
from training.metrics import oracle_best, per_frame_error  # noqa: E402

OBS, PRED = 50, 25
AT = {"560": 13, "1000": 24}  # future frame index of each reported horizon (ms)


def sample_counts(n_max: int) -> list[int]:
    """1, 2, 5, 10, 20, 40, ... up to n_max, and n_max itself."""
    return [n for n in (1, 2, 5, 10, 20, 40, 80, 160) if n < n_max] + [n_max]


def errors(pred: np.ndarray, gt32: np.ndarray) -> np.ndarray:
    """(W, 25, 22, 3) forecast in metres vs the (W, 25, 32, 3) ground truth in mm -> (W, 25) errors, mm."""
    return per_frame_error(model_to_xyz32(pred, gt32), gt32)


def run(args) -> dict:
    data = H36M(args.data)
    model = tcd.load(args.model) if args.model else tcd.load()
    ns = sample_counts(args.samples)
    mean_n = {n: [] for n in ns}
    best_n = {n: [] for n in ns}
    prior, zv = [], []
    t0 = time.time()
    actions = data.test_actions(args.subject)
    for ai, action in enumerate(actions):
        wins = data.test_windows(action, OBS + PRED, OBS, args.windows_per_action, subject=args.subject)
        gt32, obs = wins[:, OBS:], xyz32_to_model(wins[:, :OBS]).astype(np.float64)
        f = model.forecast(
            obs,
            num_samples=args.samples,
            sampler=model.sampler_options("forecast", sampler=args.sampler, num_inference_steps=args.steps),
            seed=args.seed * 1000 + ai,
        )
        samples = np.asarray(f.samples, np.float64)  # (S, W, 25, 22, 3)
        per_sample = np.stack([errors(s, gt32) for s in samples])  # (S, W, 25)
        for n in ns:
            mean_n[n].append(errors(samples[:n].mean(axis=0), gt32).mean(axis=0))
            best_n[n].append(oracle_best(per_sample[:n]).mean(axis=0))
        prior.append(errors(np.asarray(model.predict(obs).mean, np.float64), gt32).mean(axis=0))
        zv.append(errors(np.repeat(obs[:, -1:], PRED, axis=1), gt32).mean(axis=0))
        print(f"[{ai + 1}/{len(actions)}] {action}: {time.time() - t0:.0f} s", file=sys.stderr)

    def at(rows: list) -> dict:
        per_frame = np.mean(rows, axis=0)
        return {ms: round(float(per_frame[i]), 2) for ms, i in AT.items()}

    return {
        "protocol": {
            "dataset": "h36m",
            "subject": f"S{args.subject}",
            "actions": actions,
            "windows_per_action": args.windows_per_action,
            "observed_frames": OBS,
            "predicted_frames": PRED,
            "units": "mm",
            "error": "mean over 32 joints (22 predicted pasted into GT, 6 duplicates copied)",
            "samples": args.samples,
            "sampler": args.sampler,
            "steps": args.steps,
            "seed": args.seed,
            "rows": "the first n of the samples of one forecast call",
        },
        "model": str(args.model or "bundled"),
        "elapsed_s": round(time.time() - t0, 1),
        "prior": at(prior),
        "zero_velocity": at(zv),
        "mean_of_n": {str(n): at(mean_n[n]) for n in ns},
        "best_of_n": {str(n): at(best_n[n]) for n in ns},
        "command": "python3 benches/samples_n.py " + " ".join(sys.argv[1:]),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="model directory (default: the bundled models)")
    ap.add_argument("--data", default=str(DEFAULT_DATA_ROOT / "h36m"))
    ap.add_argument("--subject", type=int, default=5)
    ap.add_argument("--windows-per-action", type=int, default=4)
    ap.add_argument("--samples", type=int, default=40, help="samples per window (the largest n)")
    ap.add_argument("--sampler", default="ddim", choices=("ddpm", "ddim", "dpmpp2m"))
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    if args.samples < 1 or args.windows_per_action < 1:
        ap.error("--samples and --windows-per-action must be at least 1")
    out = run(args)
    print(f"S{args.subject}, {args.windows_per_action} windows/action, {args.sampler}-{args.steps}; mm at 560 ms / 1 s")
    print(f"prior alone          {out['prior']['560']:6.1f} {out['prior']['1000']:6.1f}")
    print(f"zero-velocity        {out['zero_velocity']['560']:6.1f} {out['zero_velocity']['1000']:6.1f}")
    for n in out["mean_of_n"]:
        m, b = out["mean_of_n"][n], out["best_of_n"][n]
        print(f"n {n:>3}: mean of n {m['560']:6.1f} {m['1000']:6.1f} | best of n {b['560']:6.1f} {b['1000']:6.1f}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
