"""Forecasting poses from the wild through the public API (issue 17): Human3.6M S5 fed as other layouts, in
world coordinates, at 50 fps, against the native path on the same windows; CMU in world coordinates.

    python3 benches/in_the_wild.py [--data ../shared/data/h36m] [--windows-per-action 8] [--samples 1] \
        [--sampler ddim --steps 10] [--json benches/results/in_the_wild.json]

Windows: the S5 test protocol's first ``--windows-per-action`` windows per action (``H36M.test_windows``
order). The native path gets the protocol's input (22 model joints, root and global rotation removed per
frame, 25 fps, 50 frames). The wild paths get the same motion as the sensor would: the 32 (``h36m32``) or 17
(``h36m17``) joints with the recorded global rotation and root position, at 50 fps (99 frames), ``up="y"``;
variants hide joints with the paper's occlusion patterns (``random_leg_arm``: 40 % of the frames lose a leg
or an arm; ``consecutive_frames``: 20 % of the frames in one block; ``training/masks.py``, seeded) or keep only
the last 0.8 s.

CMU (``--cmu``, a different lab, subjects and proportions): the training-split takes of the LTD benchmark
in world coordinates (the recorded root trajectory and rotation) as ``h36m32`` joints (the correspondence of
``training/make_demo_clip.py``), at their capture rate of 120 fps and at 30 fps; windows of 2 s observed and
1 s to forecast, every 1 s of each take, at most ``--windows-per-action`` per action. Only the wild paths
(there is no native CMU input), errors at the caller's frames.

AMASS (``--amass``): the sample takes in world coordinates (z up, root orientation and translation kept) as
``smpl24`` joints at 120 fps, 2 s observed, 1 s forecast, windows every second. Every source runs in every
variant (as given, the two occlusion patterns, the last 0.8 s).

Errors (mm, mean per-joint position error of the mean forecast, at 0.5 s and 1 s) over the joints the layout
shares with the model (22 for h36m32, 14 for h36m17, 19 for smpl24), each beside Zero-Velocity (the last
observed pose held) in the same space, and the error of the root alone (the extrapolated trajectory against
the root held where it was): the native path in its canonical space (its ground truth has the future frames' own root
rotation removed: information a forecast from the wild does not have); the wild paths root-relative (each
frame's pelvis subtracted, the heading kept) and in world coordinates. Only the repository's public API is
used. The bundled model is reduced: the numbers measure the conversions, not the paper's accuracy.
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
from tcd import fk, layouts  # noqa: E402
from training.data.h36m import DEFAULT_H36M_DIR, H36MSource, find_indices_256, ACTIONS  # noqa: E402
from training.masks import make_mask  # noqa: E402

PAPER_PATTERNS = ("random_leg_arm", "consecutive_frames")

CMU_FPS = 120.0
DEFAULT_CMU = ROOT.parent / "shared" / "data" / "cmu" / "cmu_expmap_train.npz"
DEFAULT_AMASS = ROOT.parent / "shared" / "data" / "amass_samples"
SMPL24_MODEL = [i for i, t in enumerate(layouts.LAYOUTS["smpl24"].to32) if t in layouts.MODEL_IDS]


def amass_world_smpl24(path: Path, skeleton: Path):
    """An AMASS take -> ((T, 24, 3) SMPL joints in world coordinates (z up, metres), frame rate): forward
    kinematics on the mean SMPL-H skeleton with the recorded root orientation and translation; SMPL's hand
    joints are SMPL-H's index-finger bases (joints 22 and 37)."""
    from training.data.amass import load_smpl_skeleton
    from training.data.kinematics import fk_axis_angle
    rest, parents = load_smpl_skeleton(skeleton)
    with np.load(path) as z:
        poses = np.asarray(z["poses"], dtype=np.float64).reshape(len(z["poses"]), -1, 3)
        trans = np.asarray(z["trans"], dtype=np.float64)
        rate = float(z["mocap_framerate"])
    joints = fk_axis_angle(poses, rest, parents) - rest[0] + trans[:, None, :]
    return joints[:, list(range(22)) + [22, 37]], rate


def cmu_world_h36m32(rows: np.ndarray) -> np.ndarray:
    """(T, 117) CMU exp-map rows -> (T, 32, 3) metres in world coordinates (y up) as h36m32 joints: each
    Human3.6M joint at the CMU joint ending the bone it is built from (``training/make_demo_clip.py``),
    the root, hips and spine base at their CMU counterparts, the duplicated joints missing."""
    from training.data.cmu import CMU_OFFSETS, CMU_PARENTS, CMU_OFFSET_SCALE
    from training.data.kinematics import fk_expmap
    from training.make_demo_clip import H36M_FROM_CMU_BONE
    local_rows = rows.copy()
    local_rows[:, 0:6] = 0.0
    local = fk_expmap(local_rows[:, 3:].reshape(len(rows), -1, 3), CMU_PARENTS, CMU_OFFSETS)
    world = (np.einsum("tjk,tkl->tjl", local, fk.expmap_to_rotmat(rows[:, 3:6]))
             + rows[:, None, 0:3] * CMU_OFFSET_SCALE) / 1000.0
    out = np.full((len(rows), 32, 3), np.nan)
    for j, (_, b) in H36M_FROM_CMU_BONE.items():
        out[:, j] = world[:, b]
    for j, c in {0: 0, 1: 8, 6: 2, 11: 13}.items():
        out[:, j] = world[:, c]
    return out

HORIZONS_S = (0.5, 1.0)
H36M17_MODEL = [i for i, t in enumerate(layouts.LAYOUTS["h36m17"].to32) if t in layouts.MODEL_IDS]


def world_xyz32(rows: np.ndarray) -> np.ndarray:
    """(T, 99) exp-map rows at 50 Hz -> (T, 32, 3) metres with the recorded global rotation and root position
    (the row-vector convention of ``tcd.fk``: p_world = p_local R_root + root)."""
    local = fk.expmap_to_xyz32(rows)
    rot = fk.expmap_to_rotmat(rows[:, 3:6])
    return (np.einsum("tjk,tkl->tjl", local, rot) + rows[:, None, 0:3]) / 1000.0


def windows(src: H36MSource, action: str, per_action: int):
    """(canonical 25 fps (W, 75, 32, 3), world 50 fps (W, 149, 32, 3)) metres, the protocol's windows."""
    subs = [s for s in (1, 2) if src.has(5, action, s)]
    raw = [src.raw(5, action, s) for s in (subs[0], subs[-1])]
    canon = [fk.expmap_to_xyz32(r[::2]) / 1000.0 for r in raw]
    worlds = [world_xyz32(r) for r in raw]
    st1, st2 = find_indices_256(len(canon[0]), len(canon[1]), 75)
    c, w = [], []
    for a, b in zip(st1, st2):
        for i, s in ((0, a), (1, b)):
            c.append(canon[i][s:s + 75])
            w.append(worlds[i][2 * s:2 * s + 149])
    return np.stack(c[:per_action]), np.stack(w[:per_action])


def mpjpe_mm(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(W, F, J, 3) -> (F,) mean over windows and joints, mm."""
    return 1000.0 * np.linalg.norm(pred - gt, axis=-1).mean(axis=(0, 2))


def at_horizons(err: np.ndarray, fps: float) -> dict:
    return {f"{h:g}s": round(float(err[int(round(h * fps)) - 1]), 1) for h in HORIZONS_S}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DEFAULT_H36M_DIR))
    ap.add_argument("--model", default=None, help="model directory (default: the bundled model)")
    ap.add_argument("--windows-per-action", type=int, default=8)
    ap.add_argument("--samples", type=int, default=1)
    ap.add_argument("--sampler", default="ddim")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cmu", default=str(DEFAULT_CMU), help="the CMU exp-map takes (skipped when absent)")
    ap.add_argument("--amass", default=str(DEFAULT_AMASS), help="AMASS takes and smpl_skeleton.npz (skipped when absent)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    model = tcd.load(args.model)
    src = H36MSource(args.data)
    kw = dict(num_samples=args.samples, sampler=args.sampler, num_inference_steps=args.steps, seed=args.seed)
    rng = np.random.default_rng(args.seed)
    acc: dict = {}
    t0 = time.perf_counter()

    def add(name, space, tcd_err, zv_err):
        row = acc.setdefault((name, space), {"tcd": [], "zero_velocity": []})
        row["tcd"].append(tcd_err)
        row["zero_velocity"].append(zv_err)

    def wild(label, x, gt, layout, fps, up, joints, every=1):
        """Runs the wild path on x (B, T, J, 3) in every variant; ``gt`` (B, F, J, 3) at the forecast's
        frames ``every``-th; errors over ``joints`` (root-relative, world) and of the root (joint 0)."""
        to = [t if t is not None else 0 for t in layouts.LAYOUTS[layout].to32]
        short = int(round(0.8 * fps))
        for variant in ("", *PAPER_PATTERNS, "0.8 s observed"):
            xin = x.copy()
            if variant in PAPER_PATTERNS:                           # the paper's occlusions (training/masks.py)
                for i in range(len(xin)):
                    seen = make_mask(variant, xin.shape[1], xin.shape[1], rng, joints32=to) > 0
                    xin[i][~seen] = np.nan
            if variant.startswith("0.8"):
                xin = xin[:, -short:]
            f = model.forecast(xin, layout=layout, fps=fps, up=up, **kw)
            pred = f.mean[:, every - 1::every][:, :gt.shape[1]]
            last = np.repeat(x[:, -1:], gt.shape[1], axis=1)
            name = label + (f", {variant}" if variant else "")
            rel = lambda a: a - a[:, :, :1]                         # noqa: E731  the pelvis (joint 0) subtracted
            add(name, "root-relative", mpjpe_mm(rel(pred)[:, :, joints], rel(gt)[:, :, joints]),
                mpjpe_mm(rel(last)[:, :, joints], rel(gt)[:, :, joints]))
            add(name, "world", mpjpe_mm(pred[:, :, joints], gt[:, :, joints]),
                mpjpe_mm(last[:, :, joints], gt[:, :, joints]))
            add(name, "root", mpjpe_mm(pred[:, :, :1], gt[:, :, :1]), mpjpe_mm(last[:, :, :1], gt[:, :, :1]))

    model_idx = list(layouts.MODEL_IDS)
    for action in [a for a in ACTIONS if src.has(5, a, 1) or src.has(5, a, 2)]:
        canon, world = windows(src, action, args.windows_per_action)
        # native: the protocol's input
        obs, gt = canon[:, :50, model_idx], canon[:, 50:, model_idx]
        f = model.forecast(obs, **kw)
        zv = np.repeat(obs[:, -1:], 25, axis=1)
        add("native h36m22 25fps", "canonical", mpjpe_mm(f.mean, gt), mpjpe_mm(zv, gt))
        add("native h36m22 25fps (h36m17's joints)", "canonical",
            mpjpe_mm(f.mean[:, :, _h17_in_model()], gt[:, :, _h17_in_model()]),
            mpjpe_mm(zv[:, :, _h17_in_model()], gt[:, :, _h17_in_model()]))
        future = world[:, 100::2]                                   # the 25 future frames at 25 fps (1 s)
        for name, joints in (("h36m32", model_idx), ("h36m17", H36M17_MODEL)):
            to = list(layouts.LAYOUTS[name].to32)                   # 50 fps, 99 frames (2 s); truth at 25 fps
            wild(f"H36M {name} world 50fps", world[:, :99][:, :, to], future[:, :, to], name, 50.0, "y", joints,
                 every=2)
    if args.cmu is not None and Path(args.cmu).is_file():
        from training.data.cmu import load_cmu_npz
        per_action: dict = {}
        for key, take in load_cmu_npz(args.cmu).items():
            action = key.split("/")[0]
            world = cmu_world_h36m32(take.astype(np.float64))
            for start in range(0, len(world) - 361, 120):
                if per_action.get(action, 0) >= args.windows_per_action:
                    break
                per_action[action] = per_action.get(action, 0) + 1
                for fps in (120.0, 30.0):
                    seq = world[None, start:start + 361:int(CMU_FPS / fps)]
                    n_obs = int(2 * fps) + 1
                    wild(f"CMU h36m32 world {fps:g}fps", seq[:, :n_obs], seq[:, n_obs:n_obs + int(fps)], "h36m32",
                         fps, "y", model_idx)
    skeleton = Path(args.amass) / "smpl_skeleton.npz"
    if skeleton.is_file():
        for path in sorted(Path(args.amass).glob("*.npz")):
            if path == skeleton:
                continue
            world, rate = amass_world_smpl24(path, skeleton)
            second = int(round(rate))
            for start in range(0, len(world) - 3 * second, second):
                seq = world[None, start:start + 3 * second + 1]
                wild(f"AMASS smpl24 world {rate:.0f}fps", seq[:, :2 * second + 1], seq[:, 2 * second + 1:], "smpl24",
                     rate, "z", SMPL24_MODEL)
    rows = []
    for (name, space), d in acc.items():
        t, z = np.mean(d["tcd"], axis=0), np.mean(d["zero_velocity"], axis=0)
        fps = len(t)                                             # 1 s of forecast frames at the input's rate
        rows.append({"input": name, "space": space, "tcd_mm": at_horizons(t, fps),
                     "zero_velocity_mm": at_horizons(z, fps),
                     "ratio_1s": round(float(t[-1] / z[-1]), 3)})
    report = {"protocol": {"subject": 5, "cmu": args.cmu, "windows_per_action": args.windows_per_action, "sampler": args.sampler,
                           "steps": args.steps, "samples": args.samples, "seed": args.seed,
                           "model_sha256": model.sha256}, "seconds": round(time.perf_counter() - t0, 1), "rows": rows}
    w = max(len(r["input"]) for r in rows)
    print(f"{'input':<{w}}  {'space':<13}  tcd 0.5s / 1s   zero-vel 0.5s / 1s   tcd/zv at 1s")
    for r in rows:
        t, z = r["tcd_mm"], r["zero_velocity_mm"]
        print(f"{r['input']:<{w}}  {r['space']:<13}  {t['0.5s']:6.1f} / {t['1s']:6.1f}   "
              f"{z['0.5s']:6.1f} / {z['1s']:6.1f}        {r['ratio_1s']:.3f}")
    if args.json:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return 0


def _h17_in_model() -> list:
    """Positions, among the model's 22 joints, of the joints h36m17 has."""
    ids = [layouts.LAYOUTS["h36m17"].to32[i] for i in H36M17_MODEL]
    return [layouts.MODEL_IDS.index(j) for j in ids]


if __name__ == "__main__":
    sys.exit(main())
