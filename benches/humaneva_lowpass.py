"""Does the HumanEva-I model's spread carry information, or jitter? Its samples low-passed, scored.

The bundled HumanEva-I model's samples spread about its prior's forecast, and on Jog the best of 50 is further
from the truth than the prior alone (MODEL_CARD.md, "Ninth session"): over 60 frames of 42 coordinates a spread
that does not follow the motion adds error. Motion is smooth, and forecasters that work in the DCT domain keep
only its first coefficients (siMLPe, HumanMAC). This bench keeps the first K DCT coefficients, over the 60
future frames, of each sample's residual over the prior (the prior's forecast itself is untouched), for several
K, and scores each set of samples by the full stochastic protocol. The samples are drawn once, exactly as
``training.evaluate --protocol humaneva --engine tcd`` draws them (same seeds and batches), so the unfiltered
row equals that command's result and every row pairs with it window by window::

    python benches/humaneva_lowpass.py --keep 5 10 20 --threads 2 --json-prefix benches/results/humaneva_lowpass/bundled
    python -m training.compare benches/results/humaneva_lowpass/bundled_K10.json \\
        benches/results/humaneva_lowpass/bundled_raw.json --key FDE

``--spread C ...`` scores the same samples with each one's deviation from the samples' mean scaled by C (the mean,
``Forecast.mean``, untouched; C > 1 spreads them, C < 1 draws them in), PREFIX_S{C}.json: whether the samples are
too close together or apart in the wrong directions (MODEL_CARD.md, "Spread about the mean")::

    python benches/humaneva_lowpass.py --keep --spread 0.75 0.9 1.25 1.5 2 --threads 1 \\
        --json-prefix benches/results/humaneva_lowpass/long20

``--noise-scale C ...`` draws the samples again with the engine's own seeded noise but each chain's starting
noise x_T (both stages of the cascade) scaled by C, PREFIX_N{C}.json: a sampler temperature, the spread changed
before the network rather than after it (C = 1 gives the raw row bit for bit)::

    python benches/humaneva_lowpass.py --keep --noise-scale 0.85 1.25 --sampler ddim --steps 1 --threads 1 \\
        --json-prefix benches/results/humaneva_lowpass/imle50

The low-pass and the spread are post-processes, the noise scale a change of the sampler's input; each is
measured here, not in the engine: where one pays, the engine is the place for it.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from training.evaluate import (  # noqa: E402
    HE_PRED,
    HumanEvaCases,
    build_parser,
    humaneva_model_samples,
    humaneva_prior_forecast,
)
from training.prior import dct_matrix  # noqa: E402


def check_keep(keep: int, frames: int) -> None:
    """``keep`` DCT coefficients of ``frames``: in [1, frames] (:func:`lowpass`; ``main`` before it samples)."""
    if not 1 <= keep <= frames:
        raise ValueError(f"keep must be in [1, {frames}], got {keep}")


def check_spread(c: float) -> None:
    """A scale of the samples' deviations from their mean: > 0 (:func:`spread`; ``main`` before it samples)."""
    if not c > 0:
        raise ValueError(f"spread must be > 0, got {c}")


@contextlib.contextmanager
def noise_scale(c: float):
    """Within it, ``tcd.TCD.forecast`` draws its seeded noise as usual (``tcd.engine.seeded_noise``, the streams
    the engine draws itself) and scales each chain's x_T block by ``c`` in both stages of the cascade."""
    check_spread(c)
    import tcd.engine as te
    import tcd._model as tm

    plain = tm.cascade_raw

    def scaled(short, long, observed, mask, *, num_samples, seed, sequences=None, **kw):
        if sequences is not None:
            raise ValueError("noise_scale draws every sample's stream in order (no tempo sampling)")
        b, k, _ = np.shape(observed)
        noise = {}
        for name, model, stage in (("noise_short", short, te.STAGE_SHORT), ("noise_long", long, te.STAGE_LONG)):
            blocks = model.num_noise_blocks(kw.get("sampler", te.DEFAULT_SAMPLER))
            noise[name] = te.seeded_noise(seed, stage, num_samples, blocks, b, k, model.seq_len)
            noise[name][:, 0] *= c
        return plain(short, long, observed, mask, num_samples=num_samples, **noise, **kw)

    tm.cascade_raw = scaled
    try:
        yield
    finally:
        tm.cascade_raw = plain


def lowpass(samples: np.ndarray, prior: np.ndarray, keep: int) -> np.ndarray:
    """``samples`` (S, W, T, J, 3) with each sample's residual over ``prior`` (W, T, J, 3) reduced to its first
    ``keep`` DCT coefficients over the T frames (orthonormal DCT-II: ``keep`` = T changes nothing)."""
    T = samples.shape[2]
    check_keep(keep, T)
    d = dct_matrix(T)
    project = d[:keep].T @ d[:keep]  # (T, T): onto the first `keep` cosines
    residual = samples - prior[None]
    return prior[None] + np.einsum("ts,...sjc->...tjc", project, residual)


def spread(samples: np.ndarray, c: float) -> np.ndarray:
    """``samples`` (S, W, ...) with each one's deviation from the mean of the S scaled by ``c`` (the mean kept)."""
    check_spread(c)
    mean = samples.mean(axis=0, keepdims=True)
    return mean + c * (samples - mean)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=str(ROOT / "python" / "tcd" / "weights_humaneva"))
    ap.add_argument(
        "--keep",
        type=int,
        nargs="*",
        default=[5, 10, 20],
        help="DCT coefficients kept (of 60); none after it: no low-passed rows",
    )
    ap.add_argument(
        "--spread",
        type=float,
        nargs="*",
        default=[],
        help="also score the samples with their deviations from their mean scaled by each of these",
    )
    ap.add_argument(
        "--noise-scale",
        type=float,
        nargs="*",
        default=[],
        help="also draw the samples with each chain's starting noise scaled by each of these",
    )
    ap.add_argument("--samples", type=int, default=50)
    ap.add_argument("--sampler", default="ddpm")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--threads", type=int, default=1, help="torch CPU threads (the engine uses every core, as in training.evaluate)"
    )
    ap.add_argument("--max-windows", type=int, default=0, help="evenly spaced windows (0: all 188)")
    ap.add_argument("--data", default=None, help="the HumanEva-I file or directory (default ../shared/data)")
    ap.add_argument(
        "--json-prefix",
        required=True,
        help="writes PREFIX_raw.json, PREFIX_K{k}.json, PREFIX_S{c}.json and PREFIX_N{c}.json",
    )
    args = ap.parse_args(argv)
    for option, values, check in (
        ("--keep", args.keep, lambda k: check_keep(k, HE_PRED)),
        ("--spread", args.spread, check_spread),
        ("--noise-scale", args.noise_scale, check_spread),
    ):
        try:  # checked before the samples are drawn (minutes), not after
            for v in values:
                check(v)
        except ValueError as e:
            ap.error(f"{option}: {e}")
    import torch

    torch.set_num_threads(args.threads)

    cases = HumanEvaCases.load(args.data, args.max_windows)
    # sampled as training.evaluate samples (its options and defaults: the same seeds and batches)
    sampling = build_parser().parse_args(
        [
            "--protocol",
            "humaneva",
            "--model",
            args.model,
            "--engine",
            "tcd",
            "--samples",
            str(args.samples),
            "--sampler",
            args.sampler,
            "--steps",
            str(args.steps),
            "--seed",
            str(args.seed),
        ]
    )
    t0 = time.time()
    samples = humaneva_model_samples(sampling, cases.obs, log=lambda m: print(m, file=sys.stderr, flush=True))
    prior = humaneva_prior_forecast(args.model, cases.obs)
    print(f"{args.samples} samples of {len(cases.rows)} windows in {time.time() - t0:.0f} s", file=sys.stderr)

    Path(args.json_prefix).parent.mkdir(parents=True, exist_ok=True)
    print(f"{'samples':<16}{'ADE':>8}{'FDE':>8}{'MMADE':>8}{'MMFDE':>8}{'APD':>8}")
    # (file name, samples, what the method adds, lowpass_keep, spread, noise_scale)
    variants = (
        [("raw", samples, "", None, None, None)]
        + [
            (
                f"K{k}",
                lowpass(samples, prior, k),
                f", residual over the prior low-passed to its first {k} DCT coefficients",
                k,
                None,
                None,
            )
            for k in sorted(set(args.keep))
        ]
        + [
            (f"S{c:g}", spread(samples, c), f", each sample's deviation from the samples' mean x {c:g}", None, c, None)
            for c in sorted(set(args.spread))
        ]
    )
    for c in sorted(set(args.noise_scale)):
        with noise_scale(c):
            scaled = humaneva_model_samples(sampling, cases.obs)
        variants.append((f"N{c:g}", scaled, f", each chain's starting noise x {c:g}", None, None, c))
    for name, pred, how, keep, c, noise in variants:
        m = cases.score(pred)
        out = {
            "protocol": cases.protocol(),
            "method": f"tcd {args.model}{how}",
            "seeds": {"sampling": args.seed},
            "model": m,
            "stochastic": m,
            "sampling": {"engine": "tcd", "samples": args.samples, "steps": args.steps, "sampler": args.sampler},
            "lowpass_keep": keep,
            "spread": c,
            "noise_scale": noise,
            "per_action": cases.per_action(m),
            "command": "python benches/humaneva_lowpass.py " + " ".join(sys.argv[1:] if argv is None else argv),
        }
        Path(f"{args.json_prefix}_{name}.json").write_text(json.dumps(out, indent=1))
        print(f"{name:<16}" + "".join(f"{m[k]:>8.3f}" for k in ("ADE", "FDE", "MMADE", "MMFDE", "APD")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
