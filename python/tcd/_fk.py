"""Forward kinematics of Human3.6M exp-map files, in numpy (no torch, no ``training`` package).

A Human3.6M exp-map ``.txt`` file (the "h3.6m" release used since Martinez et al. 2017) has one row
per frame at 50 Hz, 99 comma-separated values: columns 0:3 the root position (mm), then 32 exp-map
triplets (joint j in columns 3 + 3j .. 3 + 3j + 2, joint 0 the root rotation). The conversion is the
one of ``training.data.h36m`` (Setting-B): root position and rotation zeroed, forward kinematics on
the 32-joint skeleton (``tcd/data/skeleton32.json``, offsets in mm), then the 22 model joints
(``joints_used_22``) in metres.

Missing values: NaN anywhere in a joint's exp-map triplet makes that joint's rotation unknown, so every
joint below it (whose position depends on it) comes out NaN; a row of NaN is a missing frame. The
root columns (0:6) are ignored (zeroed), as in training.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Any, Dict, List, Sequence, Union

import numpy as np

__all__ = [
    "SKELETON_PATH",
    "skeleton",
    "joints_used",
    "expmap_to_rotmat",
    "fk_expmap",
    "expmap_to_xyz32",
    "expmap_to_model",
    "read_expmap_txt",
    "H36M_TXT_FPS",
]

SKELETON_PATH = Path(__file__).resolve().parent / "data" / "skeleton32.json"
#: Frame rate of the Human3.6M exp-map ``.txt`` files.
H36M_TXT_FPS = 50.0
EXPMAP_COLUMNS = 99


@lru_cache(maxsize=1)
def _skeleton() -> Dict[str, Any]:
    with open(SKELETON_PATH, encoding="utf-8") as f:
        sk = json.load(f)
    sk["offsets_mm"] = np.asarray(sk["offsets_mm"], dtype=np.float64)
    sk["offsets_mm"].setflags(write=False)
    return sk


def skeleton() -> Dict[str, Any]:
    """The 32-joint skeleton: ``parents``, ``offsets_mm`` (32, 3), ``joints_used_22``, ... (a copy)."""
    sk = _skeleton()
    return {k: (v.copy() if isinstance(v, np.ndarray) else json.loads(json.dumps(v))) for k, v in sk.items()}


def joints_used() -> List[int]:
    """32-skeleton ids of the 22 model joints, in model order."""
    return list(_skeleton()["joints_used_22"])


def expmap_to_rotmat(r: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: exp-map vectors (..., 3) -> rotation matrices (..., 3, 3), float64.
    A zero vector gives the identity; a vector with a NaN gives a matrix of NaN."""
    r = np.asarray(r, dtype=np.float64)
    theta = np.linalg.norm(r, axis=-1, keepdims=True)
    ok = theta > 1e-12
    safe = np.where(ok, theta, 1.0)
    axis = np.where(ok, r / safe, 0.0)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = np.zeros_like(x)
    s = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(r.shape[:-1] + (3, 3))
    th = theta[..., None]
    out = np.eye(3) + np.sin(th) * s + (1.0 - np.cos(th)) * (s @ s)
    nan = np.isnan(r).any(axis=-1)
    if nan.any():
        out[nan] = np.nan
    return out


def fk_expmap(expmap: np.ndarray, parents: Sequence[int], offsets: np.ndarray) -> np.ndarray:
    """Positions (T, J, 3) of the exp-map skeleton from local rotations ``expmap`` (T, J, 3).

    Row-vector convention in joint order: for a joint whose parent p > 0, R_j = R_local_j @ R_p and
    p_j = offset_j @ R_p + p_p; a child of the root gets p_j = offset_j, R_j = R_local_j. The root stays
    at the origin (its rotation has no effect)."""
    expmap = np.asarray(expmap, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.float64)
    t, j, _ = expmap.shape
    if len(parents) != j or offsets.shape != (j, 3):
        raise ValueError(f"the skeleton has {len(parents)} parents and offsets {offsets.shape} for {j} joints")
    local = expmap_to_rotmat(expmap)
    pos = np.zeros((t, j, 3))
    rot = np.zeros((t, j, 3, 3))
    rot[:, 0] = np.eye(3)
    for i in range(1, j):
        p = parents[i]
        if p > 0:
            rot[:, i] = local[:, i] @ rot[:, p]
            pos[:, i] = np.einsum("k,tkl->tl", offsets[i], rot[:, p]) + pos[:, p]
        else:
            rot[:, i] = local[:, i]
            pos[:, i] = offsets[i]
    return pos


def expmap_to_xyz32(rows: np.ndarray) -> np.ndarray:
    """(T, 99) exp-map rows -> (T, 32, 3) joint positions in mm, root position and rotation removed."""
    rows = np.array(rows, dtype=np.float64, copy=True)
    if rows.ndim != 2 or rows.shape[1] != EXPMAP_COLUMNS:
        raise ValueError(f"expected exp-map rows of {EXPMAP_COLUMNS} values, got an array of shape {rows.shape}")
    rows[:, 0:6] = 0.0
    sk = _skeleton()
    return fk_expmap(rows[:, 3:].reshape(-1, 32, 3), sk["parents"], sk["offsets_mm"])


def expmap_to_model(rows: np.ndarray) -> np.ndarray:
    """(T, 99) exp-map rows -> (T, 22, 3) float64 positions in metres in the model's joint order
    (``training.data.h36m.xyz32_to_model`` without its float32 cast); NaN where unknown."""
    return expmap_to_xyz32(rows)[:, joints_used(), :] / 1000.0


def read_expmap_txt(path: Union[str, Path]) -> np.ndarray:
    """The (T, 99) float64 rows of a Human3.6M exp-map ``.txt`` file (comma-separated; ``nan`` allowed).
    Raises ``ValueError`` for a file that is not such a table."""
    try:
        rows = np.loadtxt(path, delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError as e:
        raise ValueError(f"not a comma-separated table of numbers ({e})") from None
    if rows.size == 0:
        raise ValueError("the file holds no rows")
    if rows.shape[1] != EXPMAP_COLUMNS:
        raise ValueError(
            f"expected {EXPMAP_COLUMNS} values per row (root position + 32 exp-map triplets), got {rows.shape[1]}"
        )
    return rows
