"""The bundled repair model around other fills of whole missing frames (issue 29, point 4).

    python benches/repair_gap_fill.py [--model DIR] [--windows 256] [--samples 5] [--steps 10] [--seed 0]
                                      [--threads N] [--json OUT]

On the consecutive-frames pattern of benches/repair_quality.py (every joint hidden over one block of frames) the
repair fill is the natural cubic spline (its network has no joint of those frames to correct it from), and the
repair model around it is 6 % worse than the spline alone. benches/repair_learned_fills.py measured a fill
that does better there without training: the prior forecaster run forward from the frames before the gap and
backward from the frames after it, blended, and averaged with the spline. This asks what the repair model does
around that fill, before anything is built into the engine: the same seeded windows, masks and noise as the
repair benchmark (``--seed``; the engine's seeded streams), the fill given to the engine in the observation's
hidden entries, where a model with ``cond_fill: prior`` reads it (``tcd.engine.Denoiser.sample``), so only the
fill differs between the rows. Paired per window against the directory's own repair fill (on these frames within
a hair of the spline, which the last row shows). Needs the Human3.6M data; no torch.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import repair_quality as rq  # noqa: E402
from repair_learned_fills import L, bidirectional_fill  # noqa: E402

PATTERN = "consecutive_frames"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="model directory (default: the bundled one)")
    ap.add_argument("--windows", type=int, default=256, help="benchmark windows (repair_quality's)")
    ap.add_argument("--samples", type=int, default=5)
    ap.add_argument("--steps", type=int, default=10, help="DDPM steps (the bundled repair default: 10)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--data-dir", default=str(rq.h36m.DEFAULT_H36M_DIR))
    ap.add_argument("--json", default=None, metavar="OUT")
    args = ap.parse_args(argv)
    model_dir = Path(args.model) if args.model else Path(rq.tcd.default_model_dir())
    model = rq.tcd.load(model_dir)
    if model.repair_fill is None or model.prior is None:
        ap.error(f"--model: {model_dir} needs a repair model with its repair fill (repair_fill.safetensors) and the "
                 "prior forecaster (prior.safetensors): this bench compares fills under that repair model")
    gt = rq.draw_windows(args.windows, L, args.seed, Path(args.data_dir))
    label, _, m, obs = next(c for c in rq.masked_cases(gt, args.seed) if c[1] == PATTERN)
    spline = rq.spline_fill(obs, m)
    fills = {"the repair fill (bundled)": rq.learned_fill(model)(obs, m),
             **bidirectional_fill(model.prior, gt, m, spline), "spline": spline}
    b, t, j = m.shape
    keep = np.repeat(m[..., None], 3, -1)
    to_bkl = lambda a: np.ascontiguousarray(a.reshape(b, t, j * 3).transpose(0, 2, 1), np.float32)  # noqa: E731
    rows = {}
    for name, fill in fills.items():
        fill = np.where(keep, gt, fill)
        start = time.perf_counter()
        s = model.repair_model.sample(to_bkl(fill), to_bkl(keep), args.samples, seed=args.seed, sampler="ddpm",
                            num_inference_steps=args.steps, threads=args.threads)
        seconds = time.perf_counter() - start
        repaired = np.where(keep, gt, s.mean(0).transpose(0, 2, 1).reshape(b, t, j, 3))
        alone = {k: v for k, v in rq.scores(fill, gt, m, 1, 1.0).items() if k in ("ade_mm", "per_window_mm")}
        rows[name] = {"fill": alone, "tcd": rq.scores(repaired, gt, m, b * t, seconds)}
    base = np.array(rows["the repair fill (bundled)"]["tcd"]["per_window_mm"], float)
    lin = rq.ade_mm(rq.linear_fill(obs, m), gt, m)
    print(f"\n{label}, {args.windows} S5 windows, tcd: DDPM {args.steps} steps, mean of {args.samples} samples, "
          f"model {model_dir}\n\n| fill of the missing frames | fill alone (mm) | tcd around it (mm) | tcd × linear "
          "| tcd × spline | tcd paired against the repair fill's (better on) |\n|---|---|---|---|---|---|")
    for name, r in rows.items():
        d = np.array(r["tcd"]["per_window_mm"], float) - base
        r["paired_mm"] = {"mean": float(d.mean()), "standard_error": float(d.std(ddof=1) / np.sqrt(len(d))),
                          "better_on": int((d < 0).sum()), "windows": len(d)}
        tcd_mm, paired = r["tcd"]["ade_mm"], r["paired_mm"]
        print(f"| {name} | {r['fill']['ade_mm']:.2f} | {tcd_mm:.2f} | {tcd_mm / lin:.2f} | "
              f"{tcd_mm / rows['spline']['fill']['ade_mm']:.2f} | {d.mean():+.2f} ± {paired['standard_error']:.2f} "
              f"({paired['better_on']} of {len(d)}) |")
    if args.json:
        out = {"settings": {k: v for k, v in vars(args).items() if k != "json"}, "pattern": label,
               "linear_mm": lin, "results": rows, "command": " ".join(["python", *sys.argv])}
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
