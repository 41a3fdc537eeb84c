"""Forecasting poses from the wild through the public API (issue 17): Human3.6M S5 fed as other layouts, in
world coordinates, at 50 fps, against the native path on the same windows; CMU in world coordinates.

    python3 benches/in_the_wild.py [--data ../shared/data/h36m] [--windows-per-action 8] [--samples 1] \
        [--sampler ddim --steps 10] [--somof13] [--first-window 0] [--variants all] [--join-frames N] \
        [--noise MM ...] [--body-frame-sigma N] [--json benches/results/in_the_wild.json]

Windows: the S5 test protocol's first ``--windows-per-action`` windows per action (``H36M.test_windows``
order). The native path gets the protocol's input (22 model joints, root and global rotation removed per
frame, 25 fps, 50 frames). The wild paths get the same motion as the sensor would: the 32 (``h36m32``) or 17
(``h36m17``) joints with the recorded global rotation and root position, at 50 fps (99 frames), ``up="y"``,
and the 17 joints at 25 fps too (50 frames ending at the same frame);
variants hide joints with the paper's occlusion patterns (``random_leg_arm``: 40 % of the frames lose a leg
or an arm; ``consecutive_frames``: 20 % of the frames in one block; ``training/masks.py``, seeded) or keep only
the last 0.8 s.

CMU (``--cmu``, a different lab, subjects and proportions): the training-split takes of the LTD benchmark
in world coordinates (the recorded root trajectory and rotation) as ``h36m32`` joints (the correspondence of
``training/make_demo_clip.py``), at their capture rate of 120 fps and at 30 fps; windows of 2 s observed and
1 s to forecast, every 1 s of each take, at most ``--windows-per-action`` per action. Only the wild paths
(there is no native CMU input), errors at the caller's frames.

AMASS (``--amass``): the sample takes in world coordinates (z up, root orientation and translation kept) as
``smpl24`` joints at 120 fps, 2 s observed, 1 s forecast, windows every second; with ``--somof13`` also as
the 13 joints 3DPW gives through SoMoF (hips, knees, ankles, neck, shoulders, elbows, wrists: no pelvis;
errors over those 13, the root the mid-point of the hips). Every source runs in every variant (as given,
the two occlusion patterns, the last 0.8 s; ``--variants as-given``: the first only), and with ``--noise MM``
each of these again with detector jitter: Gaussian noise of MM mm on every observed coordinate (Zero-Velocity
holds the same noisy pose); ``--body-frame-sigma`` sets ``tcd.wild.BODY_FRAME_SIGMA`` for the run.

Errors (mm, mean per-joint position error of the mean forecast) at the first forecast frame (40 ms for
Human3.6M, whose truth is at 25 fps; 8.3 ms at 120 fps, 33.3 ms at 30 fps), 80 ms, 160 ms, 0.5 s and 1 s (the
nearest frame) over the joints the layout shares with the model (22 for h36m32, 14 for h36m17, 19 for
smpl24), each beside Zero-Velocity in the same space (each joint held where the forecast's input last showed
it: with the occlusions, where it was last seen), and the error of the root alone (the extrapolated
trajectory against the root held where it was): the native path in its canonical space (its ground truth has
the future frames' own root rotation removed: information a forecast from the wild does not have); the wild
paths root-relative (each frame's pelvis subtracted, the heading kept) and in world coordinates. Only the
repository's public API is used, but for one diagnostic (``last_pose_conversion_mm``, :mod:`tcd.wild`
directly): how far the conversion alone, without the model, moves the last observed pose when it puts a
forecast on the sequence's median skeleton. ``--first-window N`` skips the first N windows of each action
and AMASS take (windows the default run does not report, to choose a rule on); ``--join-frames`` sets
``tcd.wild.JOIN_FRAMES`` for the run. The bundled model is reduced: the numbers measure the conversions, not
the paper's accuracy.
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
from tcd import _fk as fk, layouts  # noqa: E402
from training.data.h36m import DEFAULT_H36M_DIR, H36MSource, find_indices_256, ACTIONS  # noqa: E402
from training.masks import make_mask  # noqa: E402

PAPER_PATTERNS = ("random_leg_arm", "consecutive_frames")

CMU_FPS = 120.0
DEFAULT_CMU = ROOT.parent / "shared" / "data" / "cmu" / "cmu_expmap_train.npz"
DEFAULT_AMASS = ROOT.parent / "shared" / "data" / "amass_samples"
SMPL24_MODEL = [i for i, t in enumerate(layouts.LAYOUTS["smpl24"].to32) if t in layouts.MODEL_IDS]
#: the 13 SMPL joints 3DPW gives through the SoMoF benchmark (hips, knees, ankles, neck, shoulders, elbows,
#: wrists: no pelvis), as smpl24 indices; their root is the mid-point of the hips (smpl24 joints 1 and 2)
SOMOF13 = [1, 2, 4, 5, 7, 8, 12, 16, 17, 18, 19, 20, 21]


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
    world = (
        np.einsum("tjk,tkl->tjl", local, fk.expmap_to_rotmat(rows[:, 3:6])) + rows[:, None, 0:3] * CMU_OFFSET_SCALE
    ) / 1000.0
    out = np.full((len(rows), 32, 3), np.nan)
    for j, (_, b) in H36M_FROM_CMU_BONE.items():
        out[:, j] = world[:, b]
    for j, c in {0: 0, 1: 8, 6: 2, 11: 13}.items():
        out[:, j] = world[:, c]
    return out


#: seconds after the last observed frame: the short horizons (80 and 160 ms: where a forecast that starts away
#: from the person shows) and the long ones; each at the nearest frame of the row's rate (``first``: its first
#: forecast frame, 40 ms for Human3.6M, 8.3 ms at 120 fps, 33.3 ms at 30 fps)
HORIZONS_S = (0.08, 0.16, 0.5, 1.0)
H36M17_MODEL = [i for i, t in enumerate(layouts.LAYOUTS["h36m17"].to32) if t in layouts.MODEL_IDS]


def world_xyz32(rows: np.ndarray) -> np.ndarray:
    """(T, 99) exp-map rows at 50 Hz -> (T, 32, 3) metres with the recorded global rotation and root position
    (the row-vector convention of ``tcd._fk``: p_world = p_local R_root + root)."""
    local = fk.expmap_to_xyz32(rows)
    rot = fk.expmap_to_rotmat(rows[:, 3:6])
    return (np.einsum("tjk,tkl->tjl", local, rot) + rows[:, None, 0:3]) / 1000.0


def windows(src: H36MSource, action: str, per_action: int, first: int = 0):
    """(canonical 25 fps (W, 75, 32, 3), world 50 fps (W, 149, 32, 3)) metres, the protocol's windows
    ``first`` to ``first + per_action``."""
    subs = [s for s in (1, 2) if src.has(5, action, s)]
    raw = [src.raw(5, action, s) for s in (subs[0], subs[-1])]
    canon = [fk.expmap_to_xyz32(r[::2]) / 1000.0 for r in raw]
    worlds = [world_xyz32(r) for r in raw]
    st1, st2 = find_indices_256(len(canon[0]), len(canon[1]), 75)
    c, w = [], []
    for a, b in zip(st1, st2):
        for i, s in ((0, a), (1, b)):
            c.append(canon[i][s : s + 75])
            w.append(worlds[i][2 * s : 2 * s + 149])
    return np.stack(c[first : first + per_action]), np.stack(w[first : first + per_action])


def last_observed(x: np.ndarray) -> np.ndarray:
    """(B, T, J, 3) with NaN for missing -> (B, J, 3): each joint where it was last observed (Zero-Velocity
    on the same input as the forecast; NaN for a joint never observed)."""
    seen = np.isfinite(x).all(-1)  # (B, T, J)
    idx = x.shape[1] - 1 - np.argmax(seen[:, ::-1], axis=1)  # (B, J) the last observed frame
    out = np.take_along_axis(x, idx[:, None, :, None], axis=1)[:, 0]
    return np.where(seen.any(1)[..., None], out, np.nan)


def conversion_offset_mm(x: np.ndarray, layout: str, up: str, fps: float, joints) -> dict:
    """The conversion alone, no model (``tcd.wild`` directly): the last observed pose into the model's
    convention and back by the forecast's rules, the model's output replaced by that pose itself, root held;
    mm from the caller's last pose over ``joints``, mean over windows: with the sequence's medians (bone
    lengths, hips, carried joints; the forecast's skeleton), with the last frame's own value for each of
    the three in turn (with the join of ``tcd.wild.JOIN_FRAMES`` the forecast starts at the last pose itself)."""
    import copy
    from tcd import wild as w

    lay, upv = layouts.get_layout(layout), w.up_vector(up)
    xm, _ = w.resample_to_model(x, fps, 25.0, 50)
    y, scene = w.to_model(xm, lay, upv)
    last = lambda v: v[:, -1:]  # noqa: E731
    parts = {
        "lengths": lambda s: setattr(s, "lengths", {k: last(v) for k, v in s.lengths.items()}),
        "hips": lambda s: setattr(s, "fixed", {k: last(v) for k, v in s.fixed.items()}),
        "carried": lambda s: setattr(s, "carried", {k: (a, last(v)) for k, (a, v) in s.carried.items()}),
    }

    def offset(sc, frames):
        saved = w.JOIN_FRAMES
        w.JOIN_FRAMES = frames
        try:
            back = w.from_model(y[:, -1:], sc, scene.root[:, -1:], scene.rot[:, -1:], own_frames=False)[:, 0]
        finally:
            w.JOIN_FRAMES = saved
        return round(float(1000.0 * np.linalg.norm(back[:, joints] - x[:, -1, joints], axis=-1).mean()), 2)

    out = {"medians": offset(scene, 0)}
    for name, use_last in parts.items():
        sc = copy.copy(scene)
        use_last(sc)
        out[f"last frame's {name}"] = offset(sc, 0)
    return out


def mpjpe_mm(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(W, F, J, 3) -> (F,) mean over windows and joints, mm."""
    return 1000.0 * np.linalg.norm(pred - gt, axis=-1).mean(axis=(0, 2))


def at_horizons(err: np.ndarray, fps: float) -> dict:
    """The first forecast frame's error and those at HORIZONS_S (the nearest frame at ``fps``)."""
    out = {"first": round(float(err[0]), 2)}
    out.update({f"{h:g}s": round(float(err[max(int(round(h * fps)), 1) - 1]), 1) for h in HORIZONS_S})
    return out


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
    ap.add_argument(
        "--amass", default=str(DEFAULT_AMASS), help="AMASS takes and smpl_skeleton.npz (skipped when absent)"
    )
    ap.add_argument(
        "--first-window",
        type=int,
        default=0,
        help="skip the first N windows of each action (Human3.6M, CMU) and AMASS take: windows the "
        "default run does not report, to choose a rule on",
    )
    ap.add_argument(
        "--variants", choices=("all", "as-given"), default="all", help="as-given: only the unoccluded, 2 s observations"
    )
    ap.add_argument(
        "--join-frames", type=int, default=None, help="tcd.wild.JOIN_FRAMES for this run (default: the library's)"
    )
    ap.add_argument(
        "--body-frame-sigma",
        type=float,
        default=None,
        help="tcd.wild.BODY_FRAME_SIGMA for this run (default: the library's)",
    )
    ap.add_argument(
        "--noise",
        type=float,
        nargs="*",
        default=[],
        metavar="MM",
        help="also each variant with detector jitter: Gaussian noise of MM mm on every observed coordinate (seeded)",
    )
    ap.add_argument(
        "--somof13",
        action="store_true",
        help="also the AMASS takes as the 13 joints 3DPW gives through SoMoF (no pelvis)",
    )
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.join_frames is not None:
        from tcd import wild as wild_rules

        wild_rules.JOIN_FRAMES = args.join_frames
    if args.body_frame_sigma is not None:
        from tcd import wild as wild_rules

        wild_rules.BODY_FRAME_SIGMA = args.body_frame_sigma
    patterns = ("",) if args.variants == "as-given" else ("", *PAPER_PATTERNS, "0.8 s observed")
    variants = [(p, 0.0) for p in patterns] + [(p, mm) for mm in args.noise for p in patterns]  # (pattern, noise)

    model = tcd.load(args.model)
    src = H36MSource(args.data)
    kw = dict(
        num_samples=args.samples,
        sampler=model.sampler_options("forecast", sampler=args.sampler, num_inference_steps=args.steps),
        seed=args.seed,
    )
    rng = np.random.default_rng(args.seed)
    acc: dict = {}
    conversion: dict = {}
    t0 = time.perf_counter()

    def add(name, space, tcd_err, zv_err):
        row = acc.setdefault((name, space), {"tcd": [], "zero_velocity": []})
        row["tcd"].append(tcd_err)
        row["zero_velocity"].append(zv_err)

    somof_rng = np.random.default_rng(args.seed)  # its own: the other rows' masks stay as they are
    noise_rng = np.random.default_rng([args.seed, 1])  # the jitter's own stream, likewise

    def wild(label, x, gt, layout, fps, up, joints, every=1, root=(0,), masks=None):
        """Runs the wild path on x (B, T, J, 3) in every variant; ``gt`` (B, F, J, 3) at the forecast's
        frames ``every``-th; errors over ``joints`` (root-relative, world) and of the root (the mean of the
        ``root`` joints: the pelvis, or the hips' mid-point where there is none); occlusions drawn from
        ``masks`` (default: the run's generator)."""
        to = [t if t is not None else 0 for t in layouts.LAYOUTS[layout].to32]
        short = int(round(0.8 * fps))

        def at(a):  # the root
            return a[:, :, list(root)].mean(axis=2, keepdims=True)

        def rel(a):  # the root subtracted
            return a - at(a)

        c = conversion.setdefault(label, {"windows": 0})
        for k, v in conversion_offset_mm(x, layout, up, fps, joints).items():
            c[k] = c.get(k, 0.0) + v * len(x)
        c["windows"] += len(x)
        for pattern, noise in variants:
            xin = x.copy()
            if pattern in PAPER_PATTERNS:  # the paper's occlusions (training/masks.py)
                for i in range(len(xin)):
                    seen = make_mask(pattern, xin.shape[1], xin.shape[1], masks or rng, joints32=to) > 0
                    xin[i][~seen] = np.nan
            if noise:  # detector jitter, seeded by its own stream (the masks' stream is left as it is)
                xin = xin + noise_rng.normal(0.0, noise / 1000.0, xin.shape)
            if pattern.startswith("0.8"):
                xin = xin[:, -short:]
            f = model.forecast(xin, capture=tcd.Capture(layout, fps=fps, up=up), **kw)
            pred = f.mean[:, every - 1 :: every][:, : gt.shape[1]]
            last = np.repeat(last_observed(xin)[:, None], gt.shape[1], axis=1)  # Zero-Velocity, the same input
            name = label + "".join(f", {part}" for part in (pattern, f"{noise:g} mm noise" if noise else "") if part)
            add(
                name,
                "root-relative",
                mpjpe_mm(rel(pred)[:, :, joints], rel(gt)[:, :, joints]),
                mpjpe_mm(rel(last)[:, :, joints], rel(gt)[:, :, joints]),
            )
            add(
                name,
                "world",
                mpjpe_mm(pred[:, :, joints], gt[:, :, joints]),
                mpjpe_mm(last[:, :, joints], gt[:, :, joints]),
            )
            add(name, "root", mpjpe_mm(at(pred), at(gt)), mpjpe_mm(at(last), at(gt)))

    model_idx = list(layouts.MODEL_IDS)
    for action in [a for a in ACTIONS if src.has(5, a, 1) or src.has(5, a, 2)]:
        canon, world = windows(src, action, args.windows_per_action, args.first_window)
        # native: the protocol's input
        obs, gt = canon[:, :50, model_idx], canon[:, 50:, model_idx]
        f = model.forecast(obs, **kw)
        zv = np.repeat(obs[:, -1:], 25, axis=1)
        add("native h36m22 25fps", "canonical", mpjpe_mm(f.mean, gt), mpjpe_mm(zv, gt))
        add(
            "native h36m22 25fps (h36m17's joints)",
            "canonical",
            mpjpe_mm(f.mean[:, :, _h17_in_model()], gt[:, :, _h17_in_model()]),
            mpjpe_mm(zv[:, :, _h17_in_model()], gt[:, :, _h17_in_model()]),
        )
        future = world[:, 100::2]  # the 25 future frames at 25 fps (1 s)
        for name, joints in (("h36m32", model_idx), ("h36m17", H36M17_MODEL)):
            to = list(layouts.LAYOUTS[name].to32)  # 50 fps, 99 frames (2 s); truth at 25 fps
            wild(
                f"H36M {name} world 50fps", world[:, :99][:, :, to], future[:, :, to], name, 50.0, "y", joints, every=2
            )
        to = list(layouts.LAYOUTS["h36m17"].to32)  # the lifter's layout at 25 fps too: 50 frames ending at the same one
        wild("H36M h36m17 world 25fps", world[:, :99:2][:, :, to], future[:, :, to], "h36m17", 25.0, "y", H36M17_MODEL)
    if args.cmu is not None and Path(args.cmu).is_file():
        from training.data.cmu import load_cmu_npz

        per_action: dict = {}
        for key, take in load_cmu_npz(args.cmu).items():
            action = key.split("/")[0]
            world = cmu_world_h36m32(take.astype(np.float64))
            for start in range(0, len(world) - 361, 120):
                per_action[action] = per_action.get(action, 0) + 1
                if per_action[action] > args.first_window + args.windows_per_action:
                    break
                if per_action[action] <= args.first_window:
                    continue
                for fps in (120.0, 30.0):
                    seq = world[None, start : start + 361 : int(CMU_FPS / fps)]
                    n_obs = int(2 * fps) + 1
                    wild(
                        f"CMU h36m32 world {fps:g}fps",
                        seq[:, :n_obs],
                        seq[:, n_obs : n_obs + int(fps)],
                        "h36m32",
                        fps,
                        "y",
                        model_idx,
                    )
    skeleton = Path(args.amass) / "smpl_skeleton.npz"
    if skeleton.is_file():
        for path in sorted(Path(args.amass).glob("*.npz")):
            if path == skeleton:
                continue
            world, rate = amass_world_smpl24(path, skeleton)
            second = int(round(rate))
            for start in range(args.first_window * second, len(world) - 3 * second, second):
                seq = world[None, start : start + 3 * second + 1]
                wild(
                    f"AMASS smpl24 world {rate:.0f}fps",
                    seq[:, : 2 * second + 1],
                    seq[:, 2 * second + 1 :],
                    "smpl24",
                    rate,
                    "z",
                    SMPL24_MODEL,
                )
                if args.somof13:  # 3DPW's joints: no pelvis
                    obs13 = np.full_like(seq[:, : 2 * second + 1], np.nan)
                    obs13[:, :, SOMOF13] = seq[:, : 2 * second + 1, SOMOF13]
                    wild(
                        f"AMASS as SoMoF 13 joints, no pelvis, world {rate:.0f}fps",
                        obs13,
                        seq[:, 2 * second + 1 :],
                        "smpl24",
                        rate,
                        "z",
                        SOMOF13,
                        root=(1, 2),
                        masks=somof_rng,
                    )
    rows = []
    for (name, space), d in acc.items():
        t, z = np.mean(d["tcd"], axis=0), np.mean(d["zero_velocity"], axis=0)
        fps = len(t)  # 1 s of forecast frames at the input's rate
        rows.append(
            {
                "input": name,
                "space": space,
                "first_ms": round(1000.0 / fps, 1),
                "tcd_mm": at_horizons(t, fps),
                "zero_velocity_mm": at_horizons(z, fps),
                "ratio_first": round(float(t[0] / z[0]), 3),
                "ratio_1s": round(float(t[-1] / z[-1]), 3),
            }
        )
    report = {
        "protocol": {
            "subject": 5,
            "cmu": args.cmu,
            "windows_per_action": args.windows_per_action,
            "first_window": args.first_window,
            "variants": args.variants,
            "somof13": args.somof13,
            "join_frames": tcd.wild.JOIN_FRAMES,
            "body_frame_sigma": tcd.wild.BODY_FRAME_SIGMA,
            "noise_mm": args.noise,
            "sampler": args.sampler,
            "steps": args.steps,
            "samples": args.samples,
            "seed": args.seed,
            "model_sha256": model.sha256,
        },
        "seconds": round(time.perf_counter() - t0, 1),
        "last_pose_conversion_mm": {
            k: {n: (v if n == "windows" else round(v / c["windows"], 2)) for n, v in c.items()}
            for k, c in conversion.items()
        },
        "rows": rows,
    }
    w = max(len(r["input"]) for r in rows)
    keys = ("first", "0.08s", "0.16s", "0.5s", "1s")
    print(
        f"{'input':<{w}}  {'space':<13}  {'tcd ' + ' / '.join(keys):<44}  {'zero-velocity, the same':<44}"
        "  tcd/zv first, 1s"
    )
    for r in rows:
        t, z = r["tcd_mm"], r["zero_velocity_mm"]
        print(
            f"{r['input']:<{w}}  {r['space']:<13}  {' / '.join(f'{t[k]:6.1f}' for k in keys):<44}  "
            f"{' / '.join(f'{z[k]:6.1f}' for k in keys):<44}  {r['ratio_first']:.3f}, {r['ratio_1s']:.3f}"
        )
    print("\nthe last observed pose through the conversion alone, forecast rules (mm; tcd.wild, no model):")
    for k, c in report["last_pose_conversion_mm"].items():
        print(f"  {k:<{w}}  " + ", ".join(f"{n} {v}" for n, v in c.items()))
    if args.json:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return 0


def _h17_in_model() -> list:
    """Positions, among the model's 22 joints, of the joints h36m17 has."""
    ids = [layouts.LAYOUTS["h36m17"].to32[i] for i in H36M17_MODEL]
    return [layouts.MODEL_IDS.index(j) for j in ids]


if __name__ == "__main__":
    sys.exit(main())
