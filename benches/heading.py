"""Does a prior forecast a motion as well whichever way the subject faces? The prior's point-forecast error on
protocol windows as recorded and turned about the vertical by a random angle per window (issue 31's finding:
a prior trained on one room's headings forecasts turned windows far worse; ``training.augment``).

    python3 benches/heading.py [--h36m-model DIR] [--humaneva-model DIR] [--json benches/results/heading_bundled.json]

* Human3.6M: S5, the first 8 windows per action of the protocol's draw, 50 -> 25 frames; the model directory's
  ``TCD.predict``; mm at 560 ms and 1 s (``training.evaluate``'s error: 32 joints). Vertical: y.
* HumanEva-I: every window of the Train split (what the prior trained on) and of the Validate split (the
  protocol's), 15 -> 60 frames; the directory's prior (``training.evaluate.humaneva_prior_forecast``); ADE and
  FDE in metres (the L2 norm of the flattened 42-dim pose). Vertical: z.

The angles: ``default_rng(seed)``, one per window, uniform in [0, 2 pi); the ground truth is turned with its
observation.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import tcd  # noqa: E402
from training.augment import rotate_about  # noqa: E402
from training.data.h36m import DEFAULT_DATA_ROOT, H36M, model_to_xyz32, xyz32_to_model  # noqa: E402
from training.data.humaneva import humaneva_file, humaneva_test_windows, load_humaneva  # noqa: E402
from training.evaluate import humaneva_prior_forecast  # noqa: E402
from training.metrics import per_frame_error  # noqa: E402


def h36m(model_dir, data_dir, windows_per_action: int, seed: int) -> dict:
    data = H36M(data_dir)
    w = np.concatenate([data.test_windows(a, 75, 50, windows_per_action) for a in data.test_actions()])  # mm
    model = tcd.load(model_dir) if model_dir else tcd.load()
    out = {}
    turned = rotate_about(w.astype(np.float64), "y", np.random.default_rng(seed))
    for name, win in (("as recorded", w), ("turned", turned)):
        x = xyz32_to_model(win[:, :50]).astype(np.float64)
        pred = np.asarray(model.predict(x).mean, np.float64)
        e = per_frame_error(model_to_xyz32(pred, win[:, 50:]), win[:, 50:]).mean(axis=0)
        out[name] = {"560": round(float(e[13]), 1), "1000": round(float(e[24]), 1)}
    return {"windows": len(w), "model": str(model_dir or "bundled"), "mm": out}


def humaneva(model_dir, data_path, seed: int) -> dict:
    out = {}
    for split in ("Train", "Validate"):
        w = humaneva_test_windows(load_humaneva(humaneva_file(data_path), split=split)).astype(np.float64)
        res = {}
        for name, win in (("as recorded", w), ("turned", rotate_about(w, "z", np.random.default_rng(seed)))):
            pred = humaneva_prior_forecast(model_dir, win[:, :15])
            d = np.linalg.norm((pred - win[:, 15:]).reshape(len(w), 60, -1), axis=-1)
            res[name] = {"ADE": round(float(d.mean()), 4), "FDE": round(float(d[:, -1].mean()), 4)}
        out[split] = {"windows": len(w), "m": res}
    return {"model": str(model_dir), **out}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--h36m-model", default=None, help="model directory with prior.safetensors (default: bundled)")
    ap.add_argument("--humaneva-model", default=str(ROOT / "python" / "tcd" / "weights_humaneva"))
    ap.add_argument("--data", default=str(DEFAULT_DATA_ROOT / "h36m"))
    ap.add_argument("--humaneva-data", default=None)
    ap.add_argument("--windows-per-action", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip", choices=("h36m", "humaneva"), default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    given = sys.argv[1:] if argv is None else argv
    out = {"seed": args.seed, "command": "python3 benches/heading.py " + " ".join(given)}
    if args.skip != "h36m":
        out["h36m"] = r = h36m(args.h36m_model, args.data, args.windows_per_action, args.seed)
        for name, v in r["mm"].items():
            print(f"Human3.6M S5 ({r['windows']} windows) {name:12s} 560 ms {v['560']:6.1f}  1 s {v['1000']:6.1f} mm")
    if args.skip != "humaneva":
        out["humaneva"] = r = humaneva(args.humaneva_model, args.humaneva_data, args.seed)
        for split in ("Train", "Validate"):
            for name, v in r[split]["m"].items():
                print(
                    f"HumanEva-I {split:8s} ({r[split]['windows']} windows) {name:12s} "
                    f"ADE {v['ADE']:.3f}  FDE {v['FDE']:.3f} m"
                )
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
