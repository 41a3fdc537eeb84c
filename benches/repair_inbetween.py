"""Whole-frame gaps: how much would a learned in-betweener add to the bundled repair fill? (issue 29, point 4)

On the repair benchmark's consecutive-frames pattern (one block of 10 frames of 50, every joint hidden) the bundled
repair fill, the prior forecaster run forward and backward into the gap averaged with its spline correction
(docs/repair.md, "Whole-frame gaps"), is 18.9 mm against linear interpolation's 31.2: 0.61 x, where issue 29 asks
for 0.5 x. Its network cannot see where a gap is (it reads the filled window, not the mask), so nothing in it was
trained for the gap. This bench asks what the cheapest gap-specific correction buys before anything is built into
the engine: a linear map, fitted by ridge regression (closed form, no training schedule to tune), from the fill
over a segment aligned on the gap (``--context`` frames each side of it, indices clamped at the window's edges,
relative to the fill's frame before the gap; plus how many of the context frames lie inside the window on either
side) to the fill's error over the gap's frames.

It is fitted on ``--train`` windows of the training subjects (S1, S6-S9) with a gap each (start uniform, as the
benchmark draws it; each also time-reversed when ``--reverse``: a gap looks the same both ways), their fills the
bundled model's own (``tcd.TCD.repair_fill``, the engine's), and scored on the benchmark's 256 S5 windows and masks
(``benches/repair_quality.py``'s draws, seed 0), window by window::

    python benches/repair_inbetween.py --train 100000 --reverse --lambdas 10 100 1000 10000 \\
        --json benches/results/repair_inbetween.json
    python -m training.compare benches/results/repair_inbetween.json benches/results/repair_inbetween.json \\
        --key consecutive_frames:ridge_10 --bundled-key consecutive_frames:fill

``--shared`` fits instead one temporal kernel that every coordinate shares (its own segment in, its gap frames
out; 920 numbers where the full map has 1.3 million)::

    python benches/repair_inbetween.py --train 100000 --reverse --shared --lambdas 0.1 10 100 \\
        --json benches/results/repair_inbetween_shared.json

The result holds the fill's and each fit's per-window ADE on the pattern (methods ``fill``, ``ridge_<lambda>`` or
``shared_<lambda>``), so ``training.compare`` pairs them like the repair benchmark's methods. A measurement, not in
the engine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benches"))

import repair_quality as rq  # noqa: E402
import tcd  # noqa: E402
from training import inbetween  # noqa: E402
from training.data import h36m  # noqa: E402

GAP = 10  # the benchmark's consecutive-frames block: round(0.2 * 50)
PATTERN = 1  # its index in repair_quality.PATTERNS


def gap_starts(mask: np.ndarray) -> np.ndarray:
    """(B,) the first frame of each window's whole-frame gap; ``mask`` (B, T, J) bool observed."""
    hidden = ~mask.any(2)
    if not hidden.any(1).all():
        raise ValueError("every window needs a whole-frame gap")
    return hidden.argmax(1)


def features(fill: np.ndarray, starts: np.ndarray, context: int) -> np.ndarray:
    """(B, (2 C + GAP) F + 2): ``training.inbetween.segment_features`` of the benchmark's gap: the fill (B, T, F)
    over frames [s - C, s + GAP + C) (indices clamped to the window) relative to its frame s - 1 (clamped), and
    the fractions of the C context frames inside the window each side."""
    return inbetween.segment_features(fill, starts, GAP, context)


def per_coordinate(x: np.ndarray, context: int) -> np.ndarray:
    """``--shared``'s inputs: :func:`features` as one row per window and coordinate (B F, 3 (2 C + GAP) + 2)
    (``training.inbetween.per_coordinate``, the engine's in-betweener's inputs)."""
    return inbetween.per_coordinate(x, GAP, context)


def normal_equations(x: np.ndarray, y: np.ndarray, context: int, shared: bool, chunk: int = 4096):
    """(X'X, X'Y) of the ridge fit, accumulated over chunks of windows (the per-coordinate rows of ``--shared``
    would not fit in memory at once); y (B, GAP F)."""
    xtx = xty = 0.0
    for lo in range(0, len(x), chunk):
        a, t = x[lo : lo + chunk], y[lo : lo + chunk]
        if shared:
            a = per_coordinate(a, context)
            t = t.reshape(len(t), GAP, -1).transpose(0, 2, 1).reshape(-1, GAP)
        xtx, xty = xtx + a.T @ a, xty + a.T @ t
    return xtx, xty


def scores(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> dict:
    """The repair benchmark's ADE over the hidden entries and per window (``repair_quality.scores``), untimed."""
    res = rq.scores(pred, gt, mask, 0, 1.0)
    return {k: res[k] for k in ("ade_mm", "per_window_mm")}


def gap_index(starts: np.ndarray) -> np.ndarray:
    """(B, GAP, 1): the frames of each window's gap, for ``np.take_along_axis`` / ``np.put_along_axis`` on axis 1."""
    return (starts[:, None] + np.arange(GAP)[None])[..., None]


def gap_frames(x: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(B, GAP, F): x (B, T, F) over each window's gap."""
    return np.take_along_axis(x, gap_index(starts), 1)


def training_set(model: "tcd.TCD", n: int, reverse: bool, context: int, seed: int, data_dir: Path, batch: int = 2000):
    """(X, Y): features and the fill's error over the gap (metres) of ``n`` training windows (2 n with their
    time reversals)."""
    seqs = [x for _, x in h36m.H36M(data_dir).sequences("train")]
    rng = np.random.default_rng(seed)
    fill_fn, t = rq.learned_fill(model), model.obs_len
    xs, ys = [], []
    for lo in range(0, n, batch):
        k = min(batch, n - lo)
        gt = rq.windows_from(seqs, k, t, rng)
        for g in [gt, gt[:, ::-1]] if reverse else [gt]:
            starts = rng.integers(0, t - GAP + 1, k)
            mask = np.ones(g.shape[:3], bool)
            for i, s in enumerate(starts):
                mask[i, s : s + GAP] = False
            filled = fill_fn(np.where(mask[..., None], g, 0.0).astype(np.float32), mask).reshape(k, t, -1)
            xs.append(features(filled, starts, context))
            ys.append((gap_frames(g.reshape(k, t, -1), starts) - gap_frames(filled, starts)).reshape(k, -1))
    return np.concatenate(xs), np.concatenate(ys)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="model directory with a repair fill (default: the bundled)")
    ap.add_argument("--train", type=int, default=100000, help="training windows (default 100,000)")
    ap.add_argument("--reverse", action="store_true", help="also fit on each training window time-reversed")
    ap.add_argument("--context", type=int, default=10, help="frames of context each side of the gap (default 10)")
    ap.add_argument(
        "--lambdas",
        type=float,
        nargs="+",
        default=[1e0, 1e1, 1e2, 1e3],
        help="ridge penalties, on features in metres (default 1 10 100 1000)",
    )
    ap.add_argument(
        "--shared",
        action="store_true",
        help="fit one temporal kernel shared by every coordinate instead of a map over all of them "
        "(methods shared_<lambda>)",
    )
    ap.add_argument("--seed", type=int, default=1, help="seed of the training windows (the benchmark's is 0)")
    ap.add_argument("--data-dir", default=str(h36m.DEFAULT_H36M_DIR))
    ap.add_argument("--json", default=None, metavar="OUT")
    args = ap.parse_args(argv)
    if args.train < 1 or args.context < 1 or min(args.lambdas) < 0:
        ap.error("--train and --context must be >= 1 and --lambdas >= 0")
    model = tcd.load(args.model)
    if model.repair_fill is None:
        ap.error(f"--model {model.path} has no repair fill")
    t0 = time.time()
    X, Y = training_set(model, args.train, args.reverse, args.context, args.seed, Path(args.data_dir))
    print(f"{len(X)} training gaps and their fills in {time.time() - t0:.0f} s", file=sys.stderr)

    gt = rq.draw_windows(256, model.obs_len, 0, Path(args.data_dir))
    _, pattern, mask, obs = list(rq.masked_cases(gt, 0))[PATTERN]
    starts = gap_starts(mask)
    filled = rq.learned_fill(model)(np.nan_to_num(obs), mask)
    fx = features(filled.reshape(len(gt), model.obs_len, -1), starts, args.context)
    res = {"pattern": pattern, "windows": len(gt), "fill": scores(filled, gt, mask)}
    print(f"fill alone: {res['fill']['ade_mm']:.2f} mm")
    xtx, xty = normal_equations(X, Y, args.context, args.shared)
    name = "shared" if args.shared else "ridge"
    for lam in args.lambdas:
        w = np.linalg.solve(xtx + lam * np.eye(len(xtx)), xty)
        if args.shared:  # (B F, GAP) per coordinate -> (B, GAP, F)
            corr = (per_coordinate(fx, args.context) @ w).reshape(len(gt), -1, GAP).transpose(0, 2, 1)
        else:
            corr = (fx @ w).reshape(len(gt), GAP, -1)
        pred = filled.copy().reshape(len(gt), model.obs_len, -1)
        np.put_along_axis(pred, gap_index(starts), gap_frames(pred, starts) + corr, 1)
        res[f"{name}_{lam:g}"] = scores(pred.reshape(gt.shape), gt, mask)
        print(f"{name} lambda {lam:g}: {res[f'{name}_{lam:g}']['ade_mm']:.2f} mm")
    if args.json:
        rq.write_json(
            args.json,
            rq.repair_result(
                [rq.PATTERNS[PATTERN][1:]],
                256,
                model.obs_len,
                0,
                [res],
                model=str(model.path),
                model_sha256=model.sha256,
                train_windows=args.train,
                reverse=args.reverse,
                context=args.context,
                shared=args.shared,
                train_seed=args.seed,
                command="python benches/repair_inbetween.py " + " ".join(sys.argv[1:] if argv is None else argv),
            ),
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
