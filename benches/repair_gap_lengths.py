"""Whole-frame gaps of every length: the repair's default (the repair fill alone, ``num_samples=0``) of model
directories side by side, against linear interpolation (issue 29).

The repair benchmark (``benches/repair_quality.py``) hides one block of 10 frames; a user's dropped frames come in
runs of any length. This bench draws ``--windows`` seeded S5 windows of 50 frames (the benchmark's draw) and hides,
for each gap length n of ``--lengths``, n consecutive whole frames at a start drawn uniformly (seeded by n), then
repairs them with ``tcd.TCD.repair(..., num_samples=0)`` of each ``--model`` (a bundled name or a directory; the
first is the reference ``training.compare`` pairs the others with) and scores the ADE over the hidden entries (mm)::

    python benches/repair_gap_lengths.py --model default models/ib --json benches/results/repair_gap_lengths.json

The JSON holds each model's per-window ADE per length (method ``model<i>``, ``linear``), for ``training.compare
NEW OLD --key gap_<n>:model1 --bundled-key gap_<n>:model0``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benches"))

import repair_quality as rq  # noqa: E402
import tcd  # noqa: E402
from training.data import h36m  # noqa: E402


def gap_masks(windows: int, length: int, n: int, seed: int) -> np.ndarray:
    """(W, T, 22) bool observed: every joint of n consecutive frames hidden, the start uniform in [0, T - n]."""
    starts = np.random.default_rng([seed, n]).integers(0, length - n + 1, windows)
    m = np.ones((windows, length, 22), bool)
    for w, s in enumerate(starts):
        m[w, s : s + n] = False
    return m


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--model",
        nargs="+",
        default=["default"],
        help='model directories or bundled names ("default": the bundled Human3.6M model)',
    )
    ap.add_argument("--lengths", type=int, nargs="+", default=[1, 2, 5, 10, 15, 20, 25, 30])
    ap.add_argument("--windows", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--data-dir", default=str(h36m.DEFAULT_H36M_DIR))
    ap.add_argument("--json", default=None, metavar="OUT")
    args = ap.parse_args(argv)
    models = [tcd.load(None if m == "default" else m) for m in args.model]
    t = models[0].obs_len
    if any(not 1 <= n < t for n in args.lengths):
        ap.error(f"--lengths must be in [1, {t - 1}]")
    gt = rq.draw_windows(args.windows, t, args.seed, Path(args.data_dir))
    rows = []
    print("| gap (frames) | " + " | ".join(f"model {i}" for i in range(len(models))) + " | linear interp. |")
    print("|---|" + "---|" * (len(models) + 1))
    for n in args.lengths:
        m = gap_masks(args.windows, t, n, args.seed)
        obs = np.where(m[..., None], gt, np.nan).astype(np.float32)
        res = {"pattern": f"gap_{n}", "windows": args.windows, "hidden_entries": int((~m).sum())}
        for i, model in enumerate(models):
            res[f"model{i}"] = rq.scores(model.repair(obs, num_samples=0).poses, gt, m, 0, 1.0)
        res["linear"] = rq.scores(rq.linear_fill(obs, m), gt, m, 0, 1.0)
        rows.append(res)
        print(
            f"| {n} | "
            + " | ".join(f"{res[f'model{i}']['ade_mm']:.2f}" for i in range(len(models)))
            + f" | {res['linear']['ade_mm']:.2f} |",
            flush=True,
        )
    if args.json:
        rq.write_json(
            args.json,
            rq.repair_result(
                [[r["pattern"], None] for r in rows],
                args.windows,
                t,
                args.seed,
                rows,
                models=[{"path": str(md.path), "sha256": md.sha256} for md in models],
                command="python benches/repair_gap_lengths.py " + " ".join(sys.argv[1:] if argv is None else argv),
            ),
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
