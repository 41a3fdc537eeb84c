"""CMU Motion Capture loader, exponential-map format (the LTD / ConvSeq2Seq 8-action CMU benchmark).

Each sequence is a (T, 117) array with the Human3.6M exp-map column convention: columns 0:3 are the
root position, then 38 exp-map triplets, triplet j (joint j, j = 0 is the root rotation) at
columns ``3 + 3 j : 6 + 3 j``. The benchmark keeps every second frame, removes the global translation
and rotation (columns 0:6 set to zero) and runs forward kinematics on the 38-joint CMU skeleton below.

Skeleton constants: the facts (kinematic tree and bone offsets) are those of ``_some_variables_cmu``
in LTD's ``utils/forward_kinematics.py`` (wei-mao-2019/LearnTrajDep @ eebaf34; later code bases of the
same lineage repeat the same numbers). There the parent list is 1-based and the offsets are a flat list of
CMU ASF bone vectors multiplied by 70. Here they are re-tabulated per joint: parents 0-based (-1 for
the root) and the offsets stored in raw ASF units with the factor 70 applied in code.

Units: the output is in the units of ``CMU_OFFSETS`` = 70 x the ASF bone vectors. The benchmark
(LTD and its successors) treats these as millimetres: with them the thigh (joint 2 -> 3) is 532 and the
shin 510, i.e. a roughly adult-sized skeleton in mm. Divide by 1000 for (approximate) metres.
The root position columns of the raw data are in another unit (ASF units) and are zeroed anyway.
"""

from __future__ import annotations

import numpy as np

from training.data.kinematics import fk_expmap

CMU_NUM_JOINTS = 38
CMU_OFFSET_SCALE = 70.0

# The 8 actions of the benchmark (our copy has the training split of the first 7; washwindow has
# test files only).
CMU_ACTIONS = [
    "basketball",
    "basketball_signal",
    "directing_traffic",
    "jumping",
    "running",
    "soccer",
    "walking",
    "washwindow",
]

# Parent of each joint, 0-based, -1 for the root. Chains: 1-6 one leg (+x side, the subject's left),
# 7-12 the other leg, 13-19 spine, neck and head, 20-28 one arm (+x side; 27-28 the thumb branch from
# 23), 29-37 the other arm (36-37 thumb branch from 32). Every parent precedes its child.
CMU_PARENTS = np.array(
    [
        -1,
        0,
        1,
        2,
        3,
        4,
        5,  # 0 root; 1..6
        0,
        7,
        8,
        9,
        10,
        11,  # 7..12
        0,
        13,
        14,
        15,
        16,
        17,
        18,  # 13..19
        15,
        20,
        21,
        22,
        23,
        24,
        25,
        23,
        27,  # 20..28
        15,
        29,
        30,
        31,
        32,
        33,
        34,
        32,
        36,  # 29..37
    ],
    dtype=np.int64,
)

# Bone offset of each joint from its parent, in CMU ASF units (multiply by CMU_OFFSET_SCALE).
_CMU_OFFSETS_ASF = np.array(
    [
        [0.0, 0.0, 0.0],  # 0
        [0.0, 0.0, 0.0],  # 1
        [1.65674, -1.80282, 0.62477],  # 2
        [2.59720, -7.13576, 0.0],  # 3
        [2.49236, -6.84770, 0.0],  # 4
        [0.19704, -0.54136, 2.14581],  # 5
        [0.0, 0.0, 1.11249],  # 6
        [0.0, 0.0, 0.0],  # 7
        [-1.61070, -1.80282, 0.62476],  # 8
        [-2.59502, -7.12977, 0.0],  # 9
        [-2.46780, -6.78024, 0.0],  # 10
        [-0.23024, -0.63258, 2.13368],  # 11
        [0.0, 0.0, 1.11569],  # 12
        [0.0, 0.0, 0.0],  # 13
        [0.01961, 2.05450, -0.14112],  # 14
        [0.01021, 2.06436, -0.05921],  # 15
        [0.0, 0.0, 0.0],  # 16
        [0.00713, 1.56711, 0.14968],  # 17
        [0.03429, 1.56041, -0.10006],  # 18
        [0.01305, 1.62560, -0.05265],  # 19
        [0.0, 0.0, 0.0],  # 20
        [3.54205, 0.90436, -0.17364],  # 21
        [4.86513, 0.0, 0.0],  # 22
        [3.35554, 0.0, 0.0],  # 23
        [0.0, 0.0, 0.0],  # 24
        [0.66117, 0.0, 0.0],  # 25
        [0.53306, 0.0, 0.0],  # 26
        [0.0, 0.0, 0.0],  # 27
        [0.54120, 0.0, 0.54120],  # 28
        [0.0, 0.0, 0.0],  # 29
        [-3.49802, 0.75994, -0.32616],  # 30
        [-5.02649, 0.0, 0.0],  # 31
        [-3.36431, 0.0, 0.0],  # 32
        [0.0, 0.0, 0.0],  # 33
        [-0.73041, 0.0, 0.0],  # 34
        [-0.58887, 0.0, 0.0],  # 35
        [0.0, 0.0, 0.0],  # 36
        [-0.59786, 0.0, 0.59786],  # 37
    ],
    dtype=np.float64,
)

CMU_OFFSETS = CMU_OFFSET_SCALE * _CMU_OFFSETS_ASF  # (38, 3), ~mm

# Joints LTD's 3D CMU loader (``load_data_cmu_3d``) leaves out of the model: the root, the two hip
# joints, joints that coincide with another joint (zero offsets) and end effectors. 25 joints
# (75 coordinates) remain.
CMU_JOINTS_IGNORED_LTD = [0, 1, 2, 7, 8, 13, 16, 20, 24, 27, 29, 33, 36]
CMU_JOINTS_USED_LTD = [j for j in range(CMU_NUM_JOINTS) if j not in CMU_JOINTS_IGNORED_LTD]

CMU_EXPMAP_DIM = 3 + 3 * CMU_NUM_JOINTS  # 117


def load_cmu_npz(path) -> dict[str, np.ndarray]:
    """Load ``cmu_expmap_train.npz``-style files: ``{"action/action_n": (T, 117) float32}``, in file order."""
    out: dict[str, np.ndarray] = {}
    with np.load(path) as data:
        for key in data.files:
            arr = np.asarray(data[key], dtype=np.float32)
            if arr.ndim != 2 or arr.shape[1] != CMU_EXPMAP_DIM:
                raise ValueError(f"{key}: expected (T, {CMU_EXPMAP_DIM}), got {arr.shape}")
            out[key] = arr
    return out


def expmap_to_positions_cmu(seq: np.ndarray, sample_rate: int = 2) -> np.ndarray:
    """(T, 117) exp-map sequence -> (ceil(T / sample_rate), 38, 3) joint positions (float64, ~mm).

    Keeps frames 0, sample_rate, 2 sample_rate, ...; zeroes the root position and root rotation
    (columns 0:6, on a copy); forward kinematics with ``fk_expmap`` on the CMU skeleton. The root
    stays at the origin.
    """
    seq = np.asarray(seq, dtype=np.float64)
    if seq.ndim != 2 or seq.shape[1] != CMU_EXPMAP_DIM:
        raise ValueError(f"expected (T, {CMU_EXPMAP_DIM}), got {seq.shape}")
    if sample_rate <= 0:
        raise ValueError("sample_rate must be positive")
    seq = seq[::sample_rate].copy()
    seq[:, 0:6] = 0.0
    expmap = seq[:, 3:].reshape(seq.shape[0], CMU_NUM_JOINTS, 3)
    return fk_expmap(expmap, CMU_PARENTS, CMU_OFFSETS)
