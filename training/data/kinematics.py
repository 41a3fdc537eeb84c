"""Rotations and forward kinematics shared by the exp-map (Human3.6M, CMU) and axis-angle (AMASS) loaders.

All functions are vectorised numpy, float64 internally.
"""
from __future__ import annotations

import numpy as np


def expmap_to_rotmat(r: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: exp-map / axis-angle vectors (..., 3) -> rotation matrices (..., 3, 3).

    R = I + sin(theta) S + (1 - cos(theta)) S^2, S the cross-product matrix of the unit axis and
    theta the vector's norm. A zero vector gives the identity.
    """
    r = np.asarray(r, dtype=np.float64)
    theta = np.linalg.norm(r, axis=-1, keepdims=True)  # (..., 1)
    safe = np.where(theta > 1e-12, theta, 1.0)
    axis = np.where(theta > 1e-12, r / safe, 0.0)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = np.zeros_like(x)
    s = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(r.shape[:-1] + (3, 3))
    th = theta[..., None]  # (..., 1, 1)
    eye = np.broadcast_to(np.eye(3), s.shape)
    return eye + np.sin(th) * s + (1.0 - np.cos(th)) * (s @ s)


def fk_expmap(expmap: np.ndarray, parents, offsets) -> np.ndarray:
    """Forward kinematics of the exp-map skeletons (Human3.6M 32 joints, CMU 38 joints).

    expmap: (T, J, 3) local exp-map rotations (joint 0 = root rotation).
    parents: (J,) parent index, -1 for the root; offsets: (J, 3) bone offsets.
    Row-vector convention, processed in joint order: for a joint whose parent is > 0,
    R_j = R_local_j @ R_parent and p_j = offset_j @ R_parent + p_parent; for a child of the root
    (parent == 0) p_j = offset_j and R_j = R_local_j. The root stays at the origin, so the root
    rotation has no effect (the loaders zero it anyway).
    Returns positions (T, J, 3) in the offsets' units.
    """
    expmap = np.asarray(expmap, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.float64)
    T, J, _ = expmap.shape
    if len(parents) != J or offsets.shape != (J, 3):
        raise ValueError(f"skeleton has {len(parents)} parents / {offsets.shape} offsets for {J} joints")
    local = expmap_to_rotmat(expmap)  # (T, J, 3, 3)
    pos = np.zeros((T, J, 3))
    rot = np.zeros((T, J, 3, 3))
    rot[:, 0] = np.eye(3)
    for j in range(1, J):
        p = parents[j]
        if p > 0:
            rot[:, j] = local[:, j] @ rot[:, p]
            pos[:, j] = np.einsum("k,tkl->tl", offsets[j], rot[:, p]) + pos[:, p]
        else:
            rot[:, j] = local[:, j]
            pos[:, j] = offsets[j]
    return pos


def fk_axis_angle(pose: np.ndarray, rest: np.ndarray, parents) -> np.ndarray:
    """SMPL-style forward kinematics (AMASS / 3DPW): global transforms G_i = G_parent @ [R_i | J_i - J_parent].

    pose: (T, J, 3) axis-angle; rest: (J, 3) rest-pose joint positions; parents: (J,), -1 for root.
    Returns joint positions (T, J, 3) in the rest skeleton's units.
    """
    pose = np.asarray(pose, dtype=np.float64)
    rest = np.asarray(rest, dtype=np.float64)
    T, J, _ = pose.shape
    R = expmap_to_rotmat(pose)  # (T, J, 3, 3)
    g_rot = np.zeros((T, J, 3, 3))
    g_pos = np.zeros((T, J, 3))
    g_rot[:, 0] = R[:, 0]
    g_pos[:, 0] = rest[0]
    for i in range(1, J):
        p = parents[i]
        g_rot[:, i] = g_rot[:, p] @ R[:, i]
        g_pos[:, i] = np.einsum("tkl,l->tk", g_rot[:, p], rest[i] - rest[p]) + g_pos[:, p]
    return g_pos
