"""Builds the demo clips bundled with the package (``python/tcd/data/demo_walking.npz``; for the HumanEva-I
model ``python/tcd/data/demo_walking_humaneva.npz``; for the Setting-A model ``demo_walking_setting_a.npz``).

    python -m training.make_demo_clip [--cmu ../shared/data/cmu/cmu_expmap_train.npz] [--key walking/walking_2]
    python -m training.make_demo_clip --layout humaneva [--humaneva ../shared/data/humaneva]
    python -m training.make_demo_clip --layout setting-a

Source: the CMU Graphics Lab Motion Capture Database (mocap.cs.cmu.edu; free for research and for use in
products, with attribution), exp-map release of the LTD / ConvSeq2Seq CMU benchmark.

Conversion to the model's 22-joint Human3.6M layout:

1. forward kinematics on the 38-joint CMU skeleton with the global translation and rotation removed
   (``training.data.cmu.expmap_to_positions_cmu``), at the capture rate (120 Hz: the gait and running
   periods of the clips, 1.2 s and 0.76 s per stride at 120 Hz, fix it);
2. resampled to 25 fps by linear interpolation of the joint positions;
3. rebuilt on the Human3.6M skeleton: the hips and the spine base stay at their fixed Human3.6M offsets
   from the root (the global rotation is removed in both conventions: +x = the subject's left, +y up,
   +z forward), and every other Human3.6M bone takes the **direction** of the matching CMU bone and
   the **length** of the Human3.6M bone (``skeleton32.json``);
4. the 22 model joints in metres (``xyz32_to_model``).

The HumanEva-I clip (``--layout humaneva``) is the same CMU clip resampled to 60 Hz (every second frame) and
rebuilt the same way on the Human3.6M skeleton, then on HumanEva-I's 15 joints: each joint takes the direction
from its HumanEva parent of the Human3.6M joint it stands for (``tcd.layouts`` ``humaneva15``) and HumanEva-I's
bone length (the median over the Train split's frames: 14 numbers, no motion of the licensed data); +z up, as
HumanEva-I; the model's 14 joints relative to the pelvis, metres.

The Setting-A clip (``--layout setting-a``) is the same CMU clip resampled to 50 Hz and rebuilt on the Human3.6M
skeleton, then joints 1..16 of its 17 (``h36m17``) relative to the pelvis, metres, +y up: the Setting-A model's
input.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from training.data.cmu import expmap_to_positions_cmu, load_cmu_npz
from training.data.h36m import joint_names_22, skeleton, xyz32_to_model

CMU_FPS = 120.0
MODEL_FPS = 25.0
OUT = Path(__file__).resolve().parent.parent / "python" / "tcd" / "data" / "demo_walking.npz"

# Human3.6M joint (32-joint index) -> the CMU bone (from joint, to joint) whose direction it takes.
# Joints absent here either keep their fixed offset from the root (1, 6, 11) or coincide with their
# parent (zero offset: 16 and 24 sit on the thorax like 13, 20 / 23 / 28 / 31 on their parent).
H36M_FROM_CMU_BONE = {
    # right leg (H36M 1..5, -x side) <- CMU 7..12
    2: (8, 9),
    3: (9, 10),
    4: (10, 11),
    5: (11, 12),
    # left leg (H36M 6..10, +x side) <- CMU 1..6
    7: (2, 3),
    8: (3, 4),
    9: (4, 5),
    10: (5, 6),
    # spine, neck, head
    12: (13, 14),
    13: (14, 15),
    14: (15, 17),
    15: (17, 19),
    # left arm (H36M 16..23) <- CMU 20..28: clavicle, humerus, radius, thumb, hand
    17: (20, 21),
    18: (21, 22),
    19: (22, 23),
    21: (27, 28),
    22: (23, 25),
    # right arm (H36M 24..31) <- CMU 29..37
    25: (29, 30),
    26: (30, 31),
    27: (31, 32),
    29: (36, 37),
    30: (32, 34),
}


def resample(x: np.ndarray, fps_in: float, fps_out: float) -> np.ndarray:
    """Linear interpolation in time of (T, ...) samples taken at fps_in onto a fps_out grid."""
    t_in = np.arange(len(x)) / fps_in
    t_out = np.arange(0.0, t_in[-1] + 1e-9, 1.0 / fps_out)
    flat = x.reshape(len(x), -1)
    out = np.stack([np.interp(t_out, t_in, flat[:, c]) for c in range(flat.shape[1])], axis=1)
    return out.reshape((len(t_out),) + x.shape[1:])


def cmu_to_h36m32(cmu_mm: np.ndarray) -> np.ndarray:
    """(T, 38, 3) CMU positions -> (T, 32, 3) Human3.6M positions in mm (see the module docstring)."""
    sk = skeleton()
    parents, offsets = sk["parents"], sk["offsets_mm"]
    lengths = np.linalg.norm(offsets, axis=1)
    out = np.zeros(cmu_mm.shape[:1] + (32, 3))
    for j in range(1, 32):
        p = parents[j]
        if j in H36M_FROM_CMU_BONE:
            a, b = H36M_FROM_CMU_BONE[j]
            d = cmu_mm[:, b] - cmu_mm[:, a]
            n = np.linalg.norm(d, axis=-1, keepdims=True)
            if np.any(n < 1e-9):
                raise ValueError(f"CMU bone {a}->{b} has zero length")
            out[:, j] = out[:, p] + lengths[j] * d / n
        elif p == 0:
            out[:, j] = offsets[j]  # fixed offset from the root (hips, spine base)
        elif lengths[j] == 0.0 or j in (16, 24):
            out[:, j] = out[:, 13] if j in (16, 24) else out[:, p]  # shoulders' base = thorax
        else:
            raise AssertionError(f"Human3.6M joint {j} has no CMU bone")
    return out


HUMANEVA_FPS = 60.0
HUMANEVA_OUT = OUT.with_name("demo_walking_humaneva.npz")
# HumanEva-I's 15 joints -> the Human3.6M 32-skeleton joint each stands for (tcd.layouts.HUMANEVA15.to32)
HUMANEVA_FROM_H36M32 = (0, 13, 17, 18, 19, 25, 26, 27, 6, 7, 8, 1, 2, 3, 15)
# the model's +y up (Human3.6M) -> HumanEva-I's +z up: a quarter turn about +x
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def humaneva_bone_lengths(path=None) -> np.ndarray:
    """(15,) metres: each HumanEva-I joint's distance from its parent, the median over every frame of the Train
    split (0 for the pelvis)."""
    from training.data.humaneva import HUMANEVA_PARENTS, humaneva_file, load_humaneva

    frames = np.concatenate(list(load_humaneva(humaneva_file(path), "Train").values()))
    parents = np.asarray(HUMANEVA_PARENTS)
    out = np.zeros(len(parents))
    out[1:] = np.median(np.linalg.norm(frames[:, 1:] - frames[:, parents[1:]], axis=-1), axis=0)
    return out


def cmu_source(key: str, extra: dict) -> np.ndarray:
    """The ``source`` entry of a clip converted from CMU: the database's attribution, the clip, then ``extra``."""
    return np.array(
        json.dumps(
            {
                "dataset": "CMU Graphics Lab Motion Capture Database (mocap.cs.cmu.edu)",
                "attribution": "The data used in this project was obtained from mocap.cs.cmu.edu. "
                "The database was created with funding from NSF EIA-0196217.",
                "clip": key,
                "capture_fps": CMU_FPS,
                **extra,
            }
        )
    )


def build_humaneva(cmu_path: str, key: str, humaneva_path=None) -> dict:
    from training.data.humaneva import HUMANEVA_MODEL_JOINT_NAMES, HUMANEVA_PARENTS

    seqs = load_cmu_npz(cmu_path)
    if key not in seqs:
        raise KeyError(f"{key} not in {cmu_path}")
    # the release's first frame is not part of the motion (the Human3.6M clip's first step is 0.76 m): dropped
    cmu = resample(expmap_to_positions_cmu(seqs[key], sample_rate=1)[1:], CMU_FPS, HUMANEVA_FPS)
    h32 = cmu_to_h36m32(cmu) / 1000.0 @ Y_UP_TO_Z_UP.T  # metres, +z up
    src = h32[:, HUMANEVA_FROM_H36M32]
    lengths = humaneva_bone_lengths(humaneva_path)
    out = np.zeros_like(src)
    for j, p in enumerate(HUMANEVA_PARENTS):
        if p >= 0:
            d = src[:, j] - src[:, p]
            out[:, j] = out[:, p] + lengths[j] * d / np.linalg.norm(d, axis=-1, keepdims=True)
    return {
        "poses": (out[:, 1:] - out[:, :1]).astype(np.float32),
        "fps": np.float32(HUMANEVA_FPS),
        "joint_names": np.array(HUMANEVA_MODEL_JOINT_NAMES),
        "source": cmu_source(
            key,
            {
                "conversion": "python -m training.make_demo_clip --layout humaneva (CMU bone directions through the "
                "Human3.6M skeleton, HumanEva-I median bone lengths, joints 1..14 of humaneva15 relative "
                "to the pelvis, metres, +z up, 60 fps)",
            },
        ),
    }


SETTING_A_FPS = 50.0
SETTING_A_OUT = OUT.with_name("demo_walking_setting_a.npz")


def build_setting_a(cmu_path: str, key: str) -> dict:
    from tcd.layouts import get_layout
    from training.data.h36m_setting_a import joints17

    seqs = load_cmu_npz(cmu_path)
    if key not in seqs:
        raise KeyError(f"{key} not in {cmu_path}")
    # the release's first frame is not part of the motion (as for the HumanEva-I clip): dropped
    cmu = resample(expmap_to_positions_cmu(seqs[key], sample_rate=1)[1:], CMU_FPS, SETTING_A_FPS)
    p17 = (cmu_to_h36m32(cmu) / 1000.0)[:, joints17()]
    return {
        "poses": (p17[:, 1:] - p17[:, :1]).astype(np.float32),
        "fps": np.float32(SETTING_A_FPS),
        "joint_names": np.array(get_layout("h36m17").joint_names[1:]),
        "source": cmu_source(
            key,
            {
                "conversion": "python -m training.make_demo_clip --layout setting-a (CMU bone directions, Human3.6M "
                "bone lengths, joints 1..16 of h36m17 relative to the pelvis, metres, +y up, 50 fps)",
            },
        ),
    }


def build(cmu_path: str, key: str) -> dict:
    seqs = load_cmu_npz(cmu_path)
    if key not in seqs:
        raise KeyError(f"{key} not in {cmu_path}")
    cmu = expmap_to_positions_cmu(seqs[key], sample_rate=1)
    cmu25 = resample(cmu, CMU_FPS, MODEL_FPS)
    poses = xyz32_to_model(cmu_to_h36m32(cmu25))
    return {
        "poses": poses.astype(np.float32),
        "fps": np.float32(MODEL_FPS),
        "joint_names": np.array(joint_names_22()),
        "source": cmu_source(
            key,
            {
                "conversion": "python -m training.make_demo_clip (CMU bone directions, Human3.6M bone lengths, "
                "22-joint model layout, metres, root-relative, 25 fps)",
            },
        ),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m training.make_demo_clip",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--cmu", default="../shared/data/cmu/cmu_expmap_train.npz")
    ap.add_argument("--key", default="walking/walking_2")
    ap.add_argument(
        "--layout",
        choices=["h36m", "humaneva", "setting-a"],
        default="h36m",
        help="the model the clip is for: the Human3.6M 22-joint model, the HumanEva-I model or the Setting-A model",
    )
    ap.add_argument("--humaneva", default=None, help="HumanEva-I data (bone lengths; default ../shared/data/humaneva)")
    ap.add_argument("--out", default=None, help="default: python/tcd/data/demo_walking[_humaneva|_setting_a].npz")
    args = ap.parse_args(argv)
    if args.layout == "humaneva":
        clip, out = build_humaneva(args.cmu, args.key, args.humaneva), args.out or str(HUMANEVA_OUT)
    elif args.layout == "setting-a":
        clip, out = build_setting_a(args.cmu, args.key), args.out or str(SETTING_A_OUT)
    else:
        clip, out = build(args.cmu, args.key), args.out or str(OUT)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, **clip)
    print(
        f"wrote {out}: {clip['poses'].shape[0]} frames at {float(clip['fps']):g} fps, {clip['poses'].shape[1]} joints"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
