"""Repair quality of tcd against interpolation baselines on Human3.6M S5 windows (issue 6).

    python benches/repair_quality.py [--model DIR] [--windows N] [--steps S] [--sampler ddpm|ddim]
                                     [--samples N] [--seed S] [--jobs N] [--json OUT]

Draws ``--windows`` seeded windows of ``obs_len`` (50) frames at 25 fps from the S5 test sequences
(``training.data.h36m``; data in ``../shared/data/h36m`` or ``$TCD_DATA_DIR``) and hides entries with
three occlusion patterns of ``training.masks``: random leg + arm occlusion (40 % of the frames),
consecutive missing frames (20 %, one block of 10 frames, every joint) and random joints (each
(frame, joint) hidden with a probability drawn in [10 %, 40 %] per window). Each method fills the hidden
entries; the error is the ADE in mm over the hidden (frame, joint) entries only (mean Euclidean distance
to the ground truth):

* ``tcd``: :meth:`tcd.TCD.repair` (mean of ``--samples`` samples; every window of a pattern in one batched
  call, the engine spreading the chains over ``--jobs`` threads);
* ``linear``: per joint and coordinate, linear interpolation in time between the observed frames (held
  constant before the first / after the last observed frame);
* ``linear + Savitzky-Golay``: the linear interpolation smoothed along time with a Savitzky-Golay filter
  (window 9 frames, polynomial order 2, ``scipy.signal.savgol_filter``), observed entries kept;
* ``cubic spline``: per joint and coordinate, the natural cubic spline in time through the observed frames
  (``scipy.interpolate.CubicSpline``), held constant outside them: a stronger classical peer, and the fill
  a spline-conditioned repair model starts from (``tcd / spline`` < 1 means the diffusion improves on it);
* ``repair fill`` (a model directory with ``repair_fill.safetensors`` only): the repair fill alone, its
  correction of that spline (:attr:`tcd.TCD.repair_fill`, one forward), what a repair model conditioned on it
  starts from.

Frames per second = repaired window frames / wall-clock seconds of the method (all windows of a pattern).
Prints a markdown table; ``--json`` writes every number and the settings, with each window's ADE per method
(``per_window_mm``), which ``python -m training.compare NEW.json OLD.json --key PATTERN[:METHOD]`` pairs: two
models or samplers on the same windows, or (``--bundled-key PATTERN:spline``) a model against the spline.
Needs scipy (``pip install 'tcd-forecast[bench]'``) and the Human3.6M data.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import tcd  # noqa: E402
from training import masks  # noqa: E402
from training.data import h36m
from training.data.h36m import random_windows as windows_from  # noqa: E402

PATTERNS = (
    ("random leg + arm (40 %)", "random_leg_arm", 0.4),
    ("consecutive frames (20 %)", "consecutive_frames", 0.2),
    ("random joints (10-40 %)", "random_joints", (0.1, 0.4)),
)
SAVGOL_WINDOW = 9
SAVGOL_ORDER = 2


def draw_windows(n: int, length: int, seed: int, data_dir: Path) -> np.ndarray:
    """(n, length, 22, 3) metres: seeded windows of the S5 test sequences (:func:`windows_from`)."""
    return windows_from([x for _, x in h36m.H36M(data_dir).sequences("test")], n, length, np.random.default_rng(seed))


def linear_fill(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """x (B, T, J, 3), m (B, T, J) bool observed -> per (window, joint) linear interpolation in time
    (:func:`tcd.interpolate`, the engine's fill); a joint never observed in its window gets 0 (the root, a
    crude guess)."""
    return np.nan_to_num(tcd.interpolate(x.astype(np.float64), m, method="linear"), nan=0.0)


def savgol_fill(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    from scipy.signal import savgol_filter

    lin = linear_fill(x, m)
    smooth = savgol_filter(lin, SAVGOL_WINDOW, SAVGOL_ORDER, axis=1, mode="interp")
    keep = np.repeat(m[..., None], 3, -1)
    return np.where(keep, lin, smooth)


def spline_fill(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Per (window, joint) natural cubic spline in time through the observed frames (:func:`tcd.interpolate`,
    the engine's fill: what the bundled repair model is conditioned on; tests/test_interpolation.py checks
    it against scipy's ``CubicSpline(bc_type="natural")``), held constant before the first / after the last
    observed frame; :func:`linear_fill`'s rule for a joint never observed."""
    return np.nan_to_num(tcd.interpolate(x.astype(np.float64), m, method="spline"), nan=0.0)


def learned_fill(model: "tcd.TCD"):
    """The model directory's repair fill (``model.repair_fill``, which it must have) alone as a fill function
    (x, m) -> filled: what its repair model is given (``tcd.engine.Prior.fill``, the engine's): the fill's
    correction of the natural cubic spline over the whole window, whole-frame gaps then filled from the prior
    forecaster where the fill says so (``gap_fill``), observed entries kept."""

    def fill(x: np.ndarray, m: np.ndarray) -> np.ndarray:
        b, t = x.shape[:2]
        keep = np.repeat(m[..., None], 3, -1)
        flat = lambda a: np.ascontiguousarray(a, np.float32).reshape(b, t, -1)  # noqa: E731
        # the forecaster, which the engine uses where the fill's gap_fill says so and ignores otherwise
        return model.repair_fill.fill(flat(np.where(keep, x, 0.0)), flat(keep), forecaster=model.prior).reshape(x.shape)

    return fill


def masked_cases(gt: np.ndarray, seed: int):
    """Each pattern of :data:`PATTERNS` on the windows ``gt`` (B, T, J, 3): (label, pattern, mask (B, T, J) bool,
    observation (B, T, J, 3) float32 with NaN at the hidden entries), the masks drawn from
    ``default_rng([seed, pattern index])``: the benchmark's windows, for every method that is scored on them."""
    t = gt.shape[1]
    for p_i, (label, pattern, rate) in enumerate(PATTERNS):
        rng = np.random.default_rng([seed, p_i])
        m = np.stack([masks.make_mask(pattern, t, t, rng, rate=rate) for _ in range(len(gt))]).astype(bool)
        yield label, pattern, m, np.where(np.repeat(m[..., None], 3, -1), gt, np.nan).astype(np.float32)


def distances(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(B, T, J) Euclidean distances, in the data's units (metres)."""
    return np.linalg.norm(pred.astype(np.float64) - gt.astype(np.float64), axis=-1)


def ade_mm(pred: np.ndarray, gt: np.ndarray, m: np.ndarray) -> float:
    return float(distances(pred, gt)[~m].mean() * 1000.0)


def scores(pred: np.ndarray, gt: np.ndarray, m: np.ndarray, frames: int, seconds: float) -> dict:
    """The ADE over all hidden entries, and each window's over its own (``per_window_mm``, None for a window with
    none: what ``training.compare`` pairs between two runs, or two methods of one run)."""
    err, hidden = distances(pred, gt), ~m
    per_window = err * 1000.0
    return {
        "ade_mm": float(err[hidden].mean() * 1000.0),
        "per_window_mm": [float(e[h].mean()) if h.any() else None for e, h in zip(per_window, hidden)],
        "fps": frames / seconds,
        "seconds": seconds,
    }


def repair_result(patterns: list, n_windows: int, frames: int, mask_seed: int, results: list, **fields) -> dict:
    """A repair result's JSON: the protocol (``n_windows`` S5 windows of ``frames`` frames) and seeds blocks
    ``training.compare`` checks before it pairs two runs (``patterns``: [name, rate] per entry of ``results``, in
    order; ``mask_seed`` the windows', masks' and noise's), the results and the bench's other ``fields``."""
    return {
        "protocol": {
            "task": "repair",
            "dataset": "h36m",
            "subject": "S5",
            "windows": n_windows,
            "window_frames": frames,
            "patterns": [list(p) for p in patterns],
        },
        "seeds": {"windows_masks_sampling": mask_seed},
        **fields,
        "results": results,
    }


def write_json(path, out: dict) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(out, indent=1) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="model directory (default: the bundled model)")
    ap.add_argument("--windows", type=int, default=64, help="windows per pattern (default 64)")
    ap.add_argument("--steps", type=int, default=None, help="inference steps (default: all, DDPM)")
    ap.add_argument("--sampler", default="ddpm")
    ap.add_argument(
        "--samples",
        type=int,
        default=5,
        help="samples averaged (default 5); 0: the repair fill alone (TCD.repair's default for a "
        "directory with one), sampler and steps unused",
    )
    ap.add_argument("--seed", type=int, default=0, help="seed of the windows, the masks and the noise")
    ap.add_argument("--jobs", type=int, default=None, help="engine threads (default: all cores)")
    ap.add_argument("--data-dir", default=str(h36m.DEFAULT_H36M_DIR))
    ap.add_argument("--json", default=None, metavar="OUT")
    args = ap.parse_args(argv)

    model = tcd.load(args.model)
    w = model.obs_len
    gt = draw_windows(args.windows, w, args.seed, Path(args.data_dir))
    rows = []
    for label, _, m, obs in masked_cases(gt, args.seed):
        frames = gt.shape[0] * w
        res = {
            "pattern": label,
            "windows": int(gt.shape[0]),
            "hidden_entries": int((~m).sum()),
            "hidden_fraction": float((~m).mean()),
        }
        t0 = time.perf_counter()
        pred = model.repair(
            obs,
            num_samples=args.samples,
            sampler=model.sampler_options("repair", num_inference_steps=args.steps, sampler=args.sampler),
            seed=args.seed,
            threads=args.jobs,
        ).poses
        dt = time.perf_counter() - t0
        res["tcd"] = scores(pred, gt, m, frames, dt)
        fills = [("linear", linear_fill), ("savgol", savgol_fill), ("spline", spline_fill)]
        for name, fn in fills + ([("fill", learned_fill(model))] if model.repair_fill is not None else []):
            t0 = time.perf_counter()
            pred = fn(obs, m)
            dt = time.perf_counter() - t0
            res[name] = scores(pred, gt, m, frames, dt)
        res["tcd_over_linear"] = res["tcd"]["ade_mm"] / res["linear"]["ade_mm"]
        res["tcd_over_spline"] = res["tcd"]["ade_mm"] / res["spline"]["ade_mm"]
        rows.append(res)
        print(
            f"{label}: tcd {res['tcd']['ade_mm']:.1f} mm, linear {res['linear']['ade_mm']:.1f} mm, "
            f"savgol {res['savgol']['ade_mm']:.1f} mm, spline {res['spline']['ade_mm']:.1f} mm"
            + (f", repair fill {res['fill']['ade_mm']:.1f} mm" if "fill" in res else ""),
            file=sys.stderr,
        )

    steps = args.steps if args.steps is not None else model.num_train_timesteps
    print(
        f"\nRepair ADE (mm) over the hidden entries, {args.windows} S5 windows of {w} frames per pattern; "
        + (
            "tcd: the repair fill alone (0 samples)"
            if args.samples == 0
            else f"tcd: {args.sampler.upper()} {steps} steps, mean of {args.samples} samples"
        )
        + f", model {model.path} "
        f"(sha256 {str(model.sha256)[:12]}), {os.cpu_count()} cores.\n"
    )
    print(
        "| occlusion | tcd | linear interp. | interp. + Savitzky-Golay | cubic spline | tcd / linear | "
        "tcd / spline | tcd frames/s | spline frames/s |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['pattern']} | {r['tcd']['ade_mm']:.1f} | {r['linear']['ade_mm']:.1f} | "
            f"{r['savgol']['ade_mm']:.1f} | {r['spline']['ade_mm']:.1f} | {r['tcd_over_linear']:.2f} | "
            f"{r['tcd_over_spline']:.2f} | {r['tcd']['fps']:.0f} | {r['spline']['fps']:.0f} |"
        )
    if model.repair_fill is not None:
        print("\n| occlusion | repair fill alone | × linear | × spline |\n|---|---|---|---|")
        for r in rows:
            f = r["fill"]["ade_mm"]
            print(f"| {r['pattern']} | {f:.1f} | {f / r['linear']['ade_mm']:.2f} | {f / r['spline']['ade_mm']:.2f} |")
    if args.json:
        # protocol and seeds: what training.compare checks before it pairs two runs window by window
        write_json(
            args.json,
            repair_result(
                [[p, r] for _, p, r in PATTERNS],
                args.windows,
                w,
                args.seed,
                rows,
                model=str(model.path),
                model_sha256=model.sha256,
                tcd_version=tcd.__version__,
                windows=args.windows,
                window_frames=w,
                sampler=args.sampler,
                steps=steps,
                samples=args.samples,
                seed=args.seed,
                jobs=args.jobs,
                cores=os.cpu_count(),
                savgol={"window": SAVGOL_WINDOW, "order": SAVGOL_ORDER},
            ),
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
