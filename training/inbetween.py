"""The repair fill's in-betweener (issue 29): over a whole-frame gap, a learned linear correction of the fill.

A repair fill with ``gap_fill: "forecaster"`` fills a run of wholly hidden frames [s, s + n) from the prior
forecaster run forward and backward into it, averaged with its own correction of the spline
(``training.model.fill_gaps``). Its network cannot see where a gap is, so nothing in it was trained for one;
``benches/repair_inbetween.py`` measured that a linear map from the fill over a segment aligned on the gap to the
fill's error there gains 6-7 % on the repair benchmark's 10-frame gaps, and that one temporal kernel shared by every
coordinate keeps most of that. This module is that kernel for every gap length n = 1 .. ``max_gap``: its inputs,
per window and coordinate (:func:`per_coordinate` of :func:`segment_features`), are

* the fill over frames [s - C, s + n + C) (C = ``context``; indices clamped to the window), minus its frame s - 1
  (clamped): 2 C + n values;
* the fractions of the C context frames inside the window before and after the gap (2 values: a gap at the
  window's edge has no context on one side);
* the segment times each fraction (2 (2 C + n) values: the kernel can change where a side has no context);

and its output is the correction of the fill over the gap's n frames: ``correction = inputs @ W_n.T``, W_n of shape
(n, 3 (2 C + n) + 2). Every correction of a window is computed from the fill before any is added (windows with
several gaps). The engine does the same after its gap fill (``tcd_core``'s ``fill_with_prior``); the repair fill's
file holds W_n as ``inbetween_{n}`` and C and ``max_gap`` in its config (docs/weights.md).

Fitted by ridge regression (closed form, no schedule to tune) on training-subject windows (S1, S6-S9) with one gap
each, of every length, at a uniform start, and their time reversals, the fills the bundled model's own
(``tcd.TCD.repair_fill``, the engine's)::

    python -m training.inbetween --out runs/inbetween.npz [--windows 20000] [--max-gap 25] [--lam 100]
    python -m training.export --inbetween runs/inbetween.npz --out DIR      # into DIR/repair_fill.safetensors
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

#: context frames each side of a gap (benches/repair_inbetween.py: 20 were no better than 10)
CONTEXT = 10
#: the longest gap with a kernel; longer ones keep the gap fill alone
MAX_GAP = 25
#: the ridge penalty (benches/repair_inbetween.py's best for the shared kernel on 10-frame gaps)
LAM = 100.0
#: the joint in-betweener's (:func:`fit_joint_runs`): context, longest run, penalty
JOINT_CONTEXT, JOINT_MAX_RUN, JOINT_LAM = 5, 20, 0.1


def kernel_width(n: int, context: int) -> int:
    """The inputs of the kernel of an n-frame gap: 3 (2 C + n) + 2."""
    return 3 * (2 * context + n) + 2


def segment_features(fill: np.ndarray, starts: np.ndarray, n: int, context: int) -> np.ndarray:
    """(B, (2 C + n) F + 2): the fill (B, T, F) over frames [s - C, s + n + C) (indices clamped to the window)
    relative to its frame s - 1 (clamped), and the fractions of the C context frames inside the window each side."""
    b, t, _ = fill.shape
    idx = np.clip(starts[:, None] + np.arange(-context - 1, n + context)[None], 0, t - 1)
    seg = np.take_along_axis(fill, idx[..., None], 1)
    rel = seg[:, 1:] - seg[:, context : context + 1]  # seg[:, context]: frame s - 1
    side = np.stack([np.minimum(starts, context), np.minimum(t - n - starts, context)], 1) / context
    return np.concatenate([rel.reshape(b, -1), side], 1)


def per_coordinate(x: np.ndarray, n: int, context: int) -> np.ndarray:
    """:func:`segment_features` (B, (2 C + n) F + 2) as one row per window and coordinate (B F, 3 (2 C + n) + 2):
    the coordinate's segment, the two context fractions, and the segment times each fraction."""
    b, seg = len(x), 2 * context + n
    f = (x.shape[1] - 2) // seg
    xs = x[:, :-2].reshape(b, seg, f).transpose(0, 2, 1).reshape(b * f, seg)
    side = np.repeat(x[:, -2:], f, 0)
    return np.concatenate([xs, side, xs * side[:, :1], xs * side[:, 1:]], 1)


def correct(fill: np.ndarray, gaps: list, kernels: dict, context: int) -> np.ndarray:
    """``fill`` (B, T, F) with each gap (b, s, e) of ``gaps`` (``training.model.whole_frame_gaps``) whose length
    has a kernel (``kernels[n]``, (n, 3 (2 C + n) + 2)) corrected on every coordinate (:func:`correct_runs`)."""
    return correct_runs(fill, [(b, None, s, e) for b, s, e in gaps], kernels, context)


def joint_runs(mask: np.ndarray, gaps: list) -> list:
    """The runs ``(b, f, s, e)`` of hidden frames [s, e) of each coordinate f of each window b of ``mask`` (B, T, F),
    1 = observed, that hold no frame of a whole-frame gap of ``gaps`` (``training.model.whole_frame_gaps``'s
    (b, s, e)) and are not the whole window: what the joint in-betweener corrects (a joint hidden while others
    are seen)."""
    hidden = np.asarray(mask) <= 0.5
    in_gap = np.zeros(hidden.shape[:2], bool)
    for b, s, e in gaps:
        in_gap[b, s:e] = True
    runs = []
    for b, f in zip(*np.nonzero(hidden.any(1) & ~hidden.all(1))):
        col = np.concatenate([[False], hidden[b, :, f], [False]]).astype(np.int8)
        starts, ends = np.nonzero(np.diff(col) == 1)[0], np.nonzero(np.diff(col) == -1)[0]
        runs += [(int(b), int(f), int(s), int(e)) for s, e in zip(starts, ends) if not in_gap[b, s:e].any()]
    return runs


def correct_runs(fill: np.ndarray, runs: list, kernels: dict, context: int) -> np.ndarray:
    """``fill`` (B, T, F) with each run (b, f, s, e) of ``runs`` (:func:`joint_runs`) whose length has a kernel
    (``kernels[n]``, (n, 3 (2 C + n) + 2)) corrected on its coordinate f (every coordinate where f is None: a
    whole-frame gap, :func:`correct`); every correction read from ``fill`` as given."""
    out = np.array(fill, dtype=np.float64, copy=True)
    src = np.asarray(fill, dtype=np.float64)
    for b, f, s, e in runs:
        w = kernels.get(e - s)
        if w is None:
            continue
        cols = slice(None) if f is None else slice(f, f + 1)
        x = per_coordinate(
            segment_features(src[b : b + 1, :, cols], np.array([s]), e - s, context), e - s, context
        )  # (F', D)
        out[b, s:e, cols] += (x @ np.asarray(w, np.float64).T).T
    return out


def correct_window(prior, fill: np.ndarray, mask: np.ndarray, gaps: list) -> np.ndarray:
    """A repair fill's (``prior``, a ``training.prior_net.PriorNet``) in-betweeners on its gap-filled window ``fill``
    (B, T, F) with ``mask`` (B, T, F): the whole-frame gaps ``gaps`` by :func:`correct`, the joint runs by
    :func:`correct_runs`, both read from ``fill`` as given (the engine's order)."""
    src = np.asarray(fill, dtype=np.float64)
    out = src.copy()
    cfg = prior.cfg
    if cfg.inbetween_max_gap:
        out += correct(src, gaps, prior.inbetween_kernels(), cfg.inbetween_context) - src
    if cfg.joint_inbetween_max_gap:
        out += (
            correct_runs(
                src, joint_runs(mask, gaps), prior.inbetween_kernels("joint_inbetween"), cfg.joint_inbetween_context
            )
            - src
        )
    return out


def training_gaps(
    model, n: int, windows: int, reverse: bool, context: int, rng: np.random.Generator, seqs: list, batch: int = 2000
):
    """(X'X, X'Y) of the ridge fit of the n-frame gap's kernel: ``windows`` training windows (and their time
    reversals with ``reverse``), one gap each at a uniform start, filled by ``model``'s repair fill (the engine's,
    with its gap fill); Y the fill's error over the gap (metres)."""
    from training.data.h36m import random_windows

    t = model.obs_len
    xtx = xty = 0.0
    for lo in range(0, windows, batch):
        k = min(batch, windows - lo)
        gt = random_windows(seqs, k, t, rng)
        for g in [gt, gt[:, ::-1]] if reverse else [gt]:
            starts = rng.integers(0, t - n + 1, k)
            mask = np.ones(g.shape[:3], bool)
            for i, s in enumerate(starts):
                mask[i, s : s + n] = False
            keep = np.repeat(mask[..., None], 3, -1).reshape(k, t, -1).astype(np.float32)
            filled = model.repair_fill.fill(
                np.ascontiguousarray(g.reshape(k, t, -1) * keep, np.float32), keep, forecaster=model.prior
            )  # the engine's fill
            x = per_coordinate(segment_features(filled.astype(np.float64), starts, n, context), n, context)
            idx = (starts[:, None] + np.arange(n)[None])[..., None]
            err = np.take_along_axis(g.reshape(k, t, -1), idx, 1) - np.take_along_axis(filled, idx, 1)
            y = err.transpose(0, 2, 1).reshape(-1, n)  # (k F, n)
            xtx, xty = xtx + x.T @ x, xty + x.T @ y
    return xtx, xty


def fit(
    model,
    max_gap: int = MAX_GAP,
    windows: int = 20000,
    reverse: bool = True,
    lam: float = LAM,
    context: int = CONTEXT,
    seed: int = 2,
    data_dir=None,
    log=print,
) -> dict:
    """{n: W_n float32 (n, 3 (2 C + n) + 2)} for n = 1 .. ``max_gap``, fitted for ``model``'s repair fill."""
    from training.data import h36m

    seqs = [x for _, x in h36m.H36M(data_dir or h36m.DEFAULT_H36M_DIR).sequences("train")]
    rng = np.random.default_rng(seed)
    out = {}
    for n in range(1, max_gap + 1):
        t0 = time.time()
        xtx, xty = training_gaps(model, n, windows, reverse, context, rng, seqs)
        out[n] = np.ascontiguousarray(np.linalg.solve(xtx + lam * np.eye(len(xtx)), xty).T, dtype=np.float32)
        log(f"gap of {n} frames: kernel {out[n].shape} in {time.time() - t0:.0f} s")
    return out


def fit_joint_runs(
    model,
    max_run: int = JOINT_MAX_RUN,
    windows: int = 20000,
    lam: float = JOINT_LAM,
    context: int = JOINT_CONTEXT,
    seed: int = 3,
    data_dir=None,
    log=print,
    batch: int = 1000,
    reverse: bool = True,
) -> dict:
    """{n: W_n float32 (n, 3 (2 C + n) + 2)} for n = 1 .. ``max_run``: the joint in-betweener of ``model``'s repair
    fill, fitted on ``windows`` training windows (and, with ``reverse``, their time reversals), half with the
    ``random_joints`` mask (10-40 %) and half with ``random_leg_arm`` (40 %) of ``training.masks`` (the fill's own
    training mix has both), on every run of hidden frames of a coordinate (:func:`joint_runs`); a length without data
    gets zeros."""
    from training import masks
    from training.data import h36m

    seqs = [x for _, x in h36m.H36M(data_dir or h36m.DEFAULT_H36M_DIR).sequences("train")]
    rng = np.random.default_rng(seed)
    t = model.obs_len
    width = {n: kernel_width(n, context) for n in range(1, max_run + 1)}
    xtx = {n: np.zeros((d, d)) for n, d in width.items()}
    xty = {n: np.zeros((d, n)) for n, d in width.items()}
    t0 = time.time()
    for lo in range(0, windows, batch):
        k = min(batch, windows - lo)
        gt = h36m.random_windows(seqs, k, t, rng)
        for g in (gt, gt[:, ::-1]) if reverse else (gt,):
            m = np.stack(
                [
                    masks.make_mask("random_joints", t, t, rng, rate=(0.1, 0.4))
                    if i % 2
                    else masks.make_mask("random_leg_arm", t, t, rng, rate=0.4)
                    for i in range(k)
                ]
            )
            keep = np.repeat(m[..., None] > 0.5, 3, -1).reshape(k, t, -1)
            g2 = g.reshape(k, t, -1).astype(np.float64)
            filled = model.repair_fill.fill(
                np.ascontiguousarray(g2 * keep, np.float32), keep.astype(np.float32), forecaster=model.prior
            ).astype(np.float64)
            runs = np.array(joint_runs(keep, []), dtype=np.int64).reshape(-1, 4)
            for n in range(1, max_run + 1):
                r = runs[runs[:, 3] - runs[:, 2] == n]
                if not len(r):
                    continue
                rows = filled[r[:, 0], :, r[:, 1]][..., None]  # (R, T, 1)
                x = per_coordinate(segment_features(rows, r[:, 2], n, context), n, context)
                idx = r[:, 2:3] + np.arange(n)[None]
                y = g2[r[:, 0][:, None], idx, r[:, 1][:, None]] - filled[r[:, 0][:, None], idx, r[:, 1][:, None]]
                xtx[n] += x.T @ x
                xty[n] += x.T @ y
        log(f"{lo + k} of {windows} windows, {time.time() - t0:.0f} s")
    return {
        n: np.ascontiguousarray(np.linalg.solve(xtx[n] + lam * np.eye(width[n]), xty[n]).T, dtype=np.float32)
        for n in width
    }


def save_kernels(path, kernels: dict, context: int, meta: dict) -> None:
    np.savez(
        path, context=np.int64(context), meta=json.dumps(meta), **{f"inbetween_{n}": w for n, w in kernels.items()}
    )


def load_kernels(path) -> tuple[dict, int, dict]:
    """({n: W_n}, context, meta) from :func:`save_kernels`'s file."""
    with np.load(path) as z:
        kernels = {int(k.split("_")[1]): z[k].astype(np.float32) for k in z.files if k.startswith("inbetween_")}
        return kernels, int(z["context"]), json.loads(str(z["meta"]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="model directory with a repair fill (default: the bundled)")
    ap.add_argument("--out", required=True, help="the kernels (.npz), for training.export --inbetween")
    ap.add_argument("--windows", type=int, default=20000, help="training windows per gap length (default 20,000)")
    ap.add_argument(
        "--max-gap",
        type=int,
        default=None,
        help=f"longest gap with a kernel (default {MAX_GAP}; --joints: {JOINT_MAX_RUN})",
    )
    ap.add_argument(
        "--context",
        type=int,
        default=None,
        help=f"context frames each side (default {CONTEXT}; --joints: {JOINT_CONTEXT})",
    )
    ap.add_argument(
        "--lam",
        type=float,
        default=None,
        help=f"ridge penalty, on features in metres (default {LAM:g}; --joints: {JOINT_LAM:g})",
    )
    ap.add_argument("--no-reverse", action="store_true", help="do not also fit on the windows time-reversed")
    ap.add_argument(
        "--joints",
        action="store_true",
        help="fit the joint in-betweener instead (runs of a hidden joint in seen frames; "
        "fit_joint_runs: --max-gap is the longest run, default context 5, lam 0.1)",
    )
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--data-dir", default=None)
    args = ap.parse_args(argv)
    for name, plain, joints in (
        ("max_gap", MAX_GAP, JOINT_MAX_RUN),
        ("context", CONTEXT, JOINT_CONTEXT),
        ("lam", LAM, JOINT_LAM),
    ):
        if getattr(args, name) is None:
            setattr(args, name, joints if args.joints else plain)
    import tcd

    model = tcd.load(args.model)
    if model.repair_fill is None or model.repair_fill.gap_fill != "forecaster":
        ap.error(f'{model.path}: the in-betweener corrects a repair fill with gap_fill "forecaster"')
    if not 1 <= args.max_gap < model.obs_len or args.context < 1 or args.windows < 1 or args.lam < 0:
        ap.error(f"--max-gap must be in [1, {model.obs_len - 1}], --context and --windows >= 1, --lam >= 0")
    t0 = time.time()
    log = lambda m: print(m, file=sys.stderr, flush=True)  # noqa: E731
    if args.joints:
        kernels = fit_joint_runs(
            model,
            args.max_gap,
            args.windows,
            args.lam,
            args.context,
            args.seed,
            args.data_dir,
            log=log,
            reverse=not args.no_reverse,
        )
    else:
        kernels = fit(
            model,
            args.max_gap,
            args.windows,
            not args.no_reverse,
            args.lam,
            args.context,
            args.seed,
            args.data_dir,
            log=log,
        )
    meta = {
        "windows": args.windows,
        "reverse": not args.no_reverse,
        "lam": args.lam,
        "seed": args.seed,
        "fill_sha256": model.file_sha256.get("repair_fill.safetensors"),
        "seconds": time.time() - t0,
        "command": "python -m training.inbetween " + " ".join(sys.argv[1:] if argv is None else argv),
    }
    save_kernels(args.out, kernels, args.context, meta)
    print(f"{len(kernels)} kernels -> {args.out} in {time.time() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
