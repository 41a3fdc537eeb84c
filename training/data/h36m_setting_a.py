"""Human3.6M Setting-A: the stochastic benchmark's data (DLow / GSPS ``dataset_h36m.py``), from the exp-map release.

Protocol, as DLow's code does it:

* the 17 joints ``joints_h36m_17`` of the 32-joint skeleton (``tcd/data/skeleton32.json``; the ``h36m17`` layout),
  joints 1..16 relative to the pelvis and the pelvis dropped: 16 joints, 48 dimensions, metres, 50 Hz;
* the world rotation kept (heading and tilt), the translation removed;
* t_his = 25 observed, t_pred = 100 predicted frames (0.5 s -> 2 s);
* test subjects S9 and S11, training subjects S1, S5, S6, S7 and S8;
* test windows start at ``range(0, T - 125, t_his)`` (``training.data.humaneva.window_starts``: DLow's
  ``iter_generator(step=t_his)``), and each window's multimodal ground truth is the futures of the test windows
  whose last observed pose lies within 0.5 of its own (``training.data.humaneva.multimodal_gt``).

Where we must deviate: DLow reads VideoPose3D's per-subject 3D positions (``data_3d_h36m.npz``), which we do not
have. Ours come from the exp-map by forward kinematics with one skeleton for every subject (bone lengths are the
release's, not each subject's), and the world rotation is the exp-map's root rotation integrated from the first
frame of each file (the release stores it as a per-frame increment: R_t = R_diff_t R_{t-1}, as Martinez et al.'s
``revert_coordinate_space`` does), so a sequence's absolute heading starts at the identity rather than at the
camera-world one. The heading changes within a window, which every error metric sees, are the data's; the
absolute heading, which only the multimodal sets see (through the distance between two windows' last poses), is
not. Our copy also lacks some files (S11 has no ``sittingdown``; the data README). With these, Zero-Velocity scores
ADE 0.563 / FDE 0.834 on our 4,313 test windows (tests/test_h36m_setting_a.py).
"""

from __future__ import annotations

import os

import numpy as np

from .h36m import DEFAULT_H36M_DIR, H36MSource, skeleton
from .humaneva import window_starts
from .kinematics import expmap_to_rotmat, fk_expmap

SETTING_A_T_HIS = 25
SETTING_A_T_PRED = 100
SETTING_A_FPS = 50
SETTING_A_TEST_SUBJECTS = (9, 11)
SETTING_A_TRAIN_SUBJECTS = (1, 5, 6, 7, 8)


def joints17() -> list[int]:
    """The 32-skeleton ids of the 17 joints, pelvis first (the ``h36m17`` layout's order)."""
    return list(skeleton()["joints_h36m_17"])


def world_rotations(root_expmap: np.ndarray) -> np.ndarray:
    """(T, 3, 3) world rotations of the root from its per-frame increments ``root_expmap`` (T, 3):
    R_0 = R_diff_0, R_t = R_diff_t R_{t-1} (row-vector convention, as the skeleton's forward kinematics)."""
    diff = expmap_to_rotmat(np.asarray(root_expmap, dtype=np.float64))
    out = np.empty_like(diff)
    prev = np.eye(3)
    for t in range(len(diff)):
        prev = diff[t] @ prev
        out[t] = prev
    return out


def setting_a_positions(rows: np.ndarray) -> np.ndarray:
    """(T, 99) exp-map rows at 50 Hz -> (T, 16, 3) metres: joints 1..16 of the 17 relative to the pelvis, in the
    world rotation (module docstring)."""
    rows = np.asarray(rows, dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] != 99:
        raise ValueError(f"expected exp-map rows of 99 values, got shape {rows.shape}")
    local = rows[:, 3:].reshape(-1, 32, 3)
    sk = skeleton()
    body = fk_expmap(local, sk["parents"], sk["offsets_mm"])[:, joints17()]  # root at the origin, unrotated
    world = np.einsum("tjk,tkl->tjl", body, world_rotations(local[:, 0])) / 1000.0
    return world[:, 1:] - world[:, :1]


def setting_a_sequences(
    subjects=SETTING_A_TEST_SUBJECTS, data_dir: str | os.PathLike = DEFAULT_H36M_DIR
) -> dict[str, np.ndarray]:
    """Every file of ``subjects`` in our copy, as ``{"S9/walking_1": (T, 16, 3) metres}``, in sorted key order."""
    src = H36MSource(data_dir)
    keys = sorted(k for k in src.keys if int(k.split("/")[0][1:]) in subjects)
    if not keys:
        raise FileNotFoundError(f"no Human3.6M file of subjects {tuple(subjects)} in {src.origin}")
    out = {}
    for key in keys:
        subject, take = key.split("/")
        action, subact = take.rsplit("_", 1)
        out[key] = setting_a_positions(src.raw(int(subject[1:]), action, int(subact)))
    return out


def setting_a_test_windows(sequences: dict[str, np.ndarray]) -> tuple[np.ndarray, list[str]]:
    """The test windows (N, 125, 16, 3) of ``sequences`` (:func:`setting_a_sequences`), in their order, and each
    window's action (``"walking"`` for a window of ``S9/walking_1``)."""
    t_total = SETTING_A_T_HIS + SETTING_A_T_PRED
    windows, actions = [], []
    for key, seq in sequences.items():
        for start in window_starts(len(seq), t_total, SETTING_A_T_HIS):
            windows.append(seq[start : start + t_total])
            actions.append(key.split("/")[1].rsplit("_", 1)[0])
    if not windows:
        return np.zeros((0, t_total, 16, 3)), []
    return np.stack(windows), actions
