"""The future root of a forecast from the wild (``tcd.wild.future_frames``), rule by rule, without the model:
the root's velocity and turn rate of the last 0.2 s held (constant velocity), decaying with a time
constant, or the root held where it was.

    python3 benches/root_extrapolation.py [--json benches/results/root_extrapolation.json]

The root path is the one ``TCD.forecast(..., capture=tcd.Capture(layout, ...))`` takes (resampled to the model's
25 fps over its 2 s of observation, the root and heading measured by ``tcd.wild.to_model``, extrapolated, then read
at the caller's frames), so its error here is the "root" error of ``benches/in_the_wild.py`` without the model's
cost. Sources, each in world coordinates with 2 s observed and 1 s forecast:

* Human3.6M as ``h36m32`` at 50 fps: the training subjects (S1, S6, S7, S8, S9, S11; every action, a window
  every second: where the time constant is chosen) and S5 (the test protocol's first 8 windows per
  action, as ``in_the_wild.py``);
* CMU as ``h36m32`` at 120 fps (the LTD training takes, a window every second, at most 8 per action);
* the AMASS samples as ``smpl24`` at 120 fps (a window every second).

Root error in mm at 0.5 s and 1 s (mean over windows of the distance to the recorded root) per source and
rule, and each rule's error over holding the root. CMU and AMASS have no separate split: a time constant
chosen on them is not tested apart.

Rules: the time constants of ``RULES`` (no dead zone, clean input), then at the library's time constant the
dead zones ``--dead-zones`` (m/s taken off the measured root speed, ``tcd.wild.ROOT_DEAD_ZONE_MPS``) on the clean
input and with ``--noise-mm`` of Gaussian noise on every observed coordinate (a video pipeline's jitter; seeded),
with the error at 40 ms beside (the in-the-wild benchmark's first Human3.6M frame). For the dead-zone rows the
training subjects are every ``--subsample``-th window (2 by default: the sweep runs the sources 2 x 5 times).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benches"))

from tcd import layouts, wild  # noqa: E402
from training.data.h36m import ACTIONS, DEFAULT_H36M_DIR, H36MSource  # noqa: E402
import in_the_wild as itw  # noqa: E402

MODEL_FPS, OBS_FRAMES, HORIZON = 25.0, 50, 25
RULES = {
    "held": 0.0,
    "tau 0.1 s": 0.1,
    "tau 0.2 s": 0.2,
    "tau 0.4 s": 0.4,
    "tau 0.8 s": 0.8,
    "tau 1.6 s": 1.6,
    "constant velocity": None,
}
TRAIN_SUBJECTS = (1, 6, 7, 8, 9, 11)


def root_forecast(x: np.ndarray, layout: str, fps: float, up: str, damping_s) -> np.ndarray:
    """(B, T, J, 3) world poses at ``fps`` -> (B, n, 3) the forecast root at the caller's frames (1 s)."""
    xm, _ = wild.resample_to_model(x, fps, MODEL_FPS, OBS_FRAMES)
    _, scene = wild.to_model(xm, layouts.get_layout(layout), wild.up_vector(up))
    root_f, _ = wild.future_frames(scene, HORIZON, MODEL_FPS, damping_s)
    track = np.concatenate([scene.root[:, -1:], root_f], axis=1)  # model frames 0..25 after the last
    n = int(math.floor(HORIZON / MODEL_FPS * fps + 1e-9))
    at = np.arange(1, n + 1) / fps * MODEL_FPS  # in model frames
    idx = np.clip(np.floor(at).astype(int), 0, HORIZON - 1)
    w = (at - idx)[None, :, None]
    return track[:, idx] * (1 - w) + track[:, idx + 1] * w


def sources(args) -> dict:
    """name -> list of (x (B, T, J, 3), future root (B, n, 3), layout, fps, up)."""
    out: dict = {}
    src = H36MSource(args.data)
    for subject in TRAIN_SUBJECTS:
        for action in ACTIONS:
            for sub in (1, 2):
                if not src.has(subject, action, sub):
                    continue
                world = itw.world_xyz32(src.raw(subject, action, sub))  # 50 fps
                for start in range(0, len(world) - 150, 50):
                    seq = world[None, start : start + 150]
                    out.setdefault("H36M train subjects (choice)", []).append(
                        (seq[:, :100], seq[:, 100:, 0], "h36m32", 50.0, "y")
                    )
    for action in [a for a in ACTIONS if src.has(5, a, 1) or src.has(5, a, 2)]:
        _, world = itw.windows(src, action, 8)  # (W, 149, 32, 3) at 50 fps
        out.setdefault("H36M S5 (test)", []).append((world[:, :99], world[:, 99:149, 0], "h36m32", 50.0, "y"))
    if Path(args.cmu).is_file():
        from training.data.cmu import load_cmu_npz

        per_action: dict = {}
        for key, take in load_cmu_npz(args.cmu).items():
            action = key.split("/")[0]
            world = itw.cmu_world_h36m32(take.astype(np.float64))
            for start in range(0, len(world) - 361, 120):
                if per_action.get(action, 0) >= 8:
                    break
                per_action[action] = per_action.get(action, 0) + 1
                seq = world[None, start : start + 361]
                out.setdefault("CMU 120 fps", []).append((seq[:, :241], seq[:, 241:361, 0], "h36m32", 120.0, "y"))
    skeleton = Path(args.amass) / "smpl_skeleton.npz"
    if skeleton.is_file():
        for path in sorted(Path(args.amass).glob("*.npz")):
            if path == skeleton:
                continue
            world, rate = itw.amass_world_smpl24(path, skeleton)
            second = int(round(rate))
            for start in range(0, len(world) - 3 * second, second):
                seq = world[None, start : start + 3 * second + 1]
                out.setdefault(f"AMASS {rate:.0f} fps", []).append(
                    (seq[:, : 2 * second + 1], seq[:, 2 * second + 1 : 3 * second + 1, 0], "smpl24", rate, "z")
                )
    return out


def evaluate(items, damping_s, dead_zone: float = 0.0) -> np.ndarray:
    """(n,) root error in mm per forecast frame, mean over the windows, with ``dead_zone`` m/s taken off the
    root's speed (``tcd.wild.ROOT_DEAD_ZONE_MPS`` for the call)."""
    saved, wild.ROOT_DEAD_ZONE_MPS = wild.ROOT_DEAD_ZONE_MPS, dead_zone
    try:
        errs = [
            1000.0 * np.linalg.norm(root_forecast(x, lay, fps, up, damping_s) - gt, axis=-1)
            for x, gt, lay, fps, up in items
        ]
    finally:
        wild.ROOT_DEAD_ZONE_MPS = saved
    return np.concatenate(errs, axis=0).mean(axis=0)


def with_noise(items, sigma_m: float, rng: np.random.Generator):
    return [(x + rng.normal(0.0, sigma_m, x.shape), gt, lay, fps, up) for x, gt, lay, fps, up in items]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(DEFAULT_H36M_DIR))
    ap.add_argument("--cmu", default=str(itw.DEFAULT_CMU))
    ap.add_argument("--amass", default=str(itw.DEFAULT_AMASS))
    ap.add_argument(
        "--dead-zones",
        type=float,
        nargs="*",
        default=[0.0, 0.05, 0.1, 0.2, 0.3],
        help="dead zones (m/s) compared at the library's time constant",
    )
    ap.add_argument("--noise-mm", type=float, default=10.0, help="noise of the dead-zone rows' noisy input (mm)")
    ap.add_argument(
        "--subsample", type=int, default=2, help="the dead-zone rows take every N-th window of the training subjects"
    )
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    rows = []

    def row(name, windows, rule, tau, e, held, fps, **extra):
        rows.append(
            {
                "source": name,
                "windows": windows,
                "rule": rule,
                "damping_s": tau,
                **extra,
                "root_mm": {
                    "40ms": round(float(e[int(round(0.04 * fps)) - 1]), 2),
                    "0.5s": round(float(e[int(round(0.5 * fps)) - 1]), 1),
                    "1s": round(float(e[-1]), 1),
                },
                "over_held_1s": round(float(e[-1] / held[-1]), 3),
            }
        )

    rng = np.random.default_rng(0)
    for name, items in sources(args).items():
        windows = sum(len(x) for x, *_ in items)
        held = evaluate(items, 0.0)
        fps = items[0][3]
        for rule, tau in RULES.items():
            row(name, windows, rule, tau, held if tau == 0.0 else evaluate(items, tau), held, fps)
        few = items[:: args.subsample] if name.startswith("H36M train") else items
        for noise in (0.0, args.noise_mm):
            inp = with_noise(few, noise / 1000.0, rng) if noise else few
            held_n = evaluate(inp, 0.0)
            n = sum(len(x) for x, *_ in inp)
            for dz in args.dead_zones:
                row(
                    name,
                    n,
                    f"dead zone {dz:g} m/s",
                    wild.ROOT_DAMPING_S,
                    evaluate(inp, wild.ROOT_DAMPING_S, dz),
                    held_n,
                    fps,
                    dead_zone_mps=dz,
                    noise_mm=noise,
                )
    w = max(len(r["source"]) for r in rows)
    print(f"{'source':<{w}}  windows  noise  {'rule':<20}  root mm 40 ms / 0.5 s / 1 s   over held at 1 s")
    for r in rows:
        print(
            f"{r['source']:<{w}}  {r['windows']:>7}  {r.get('noise_mm', 0.0):5.0f}  {r['rule']:<20}  "
            f"{r['root_mm']['40ms']:7.2f} / {r['root_mm']['0.5s']:7.1f} / {r['root_mm']['1s']:7.1f}      "
            f"{r['over_held_1s']:.3f}"
        )
    for noise in (0.0, args.noise_mm):
        sums = {
            dz: sum(
                r["root_mm"]["1s"]
                for r in rows
                if r.get("dead_zone_mps") == dz and r["noise_mm"] == noise and "S5" not in r["source"]
            )
            for dz in args.dead_zones
        }
        print(
            f"summed 1 s root error over the choice sources, noise {noise:g} mm, per dead zone: "
            + ", ".join(f"{dz:g}: {v:.1f}" for dz, v in sums.items())
        )
    if args.json:
        command = " ".join(["python3 benches/root_extrapolation.py"] + (argv or sys.argv[1:]))
        args.json.write_text(json.dumps({"command": command, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
