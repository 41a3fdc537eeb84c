"""AMASS loader (SMPL-H axis-angle ``poses`` -> 18 joint positions in metres).

Protocol (spec section 3.3, the DePOSit / HisRepItself AMASS pipeline):

* downsample to about 25 fps by keeping every ``int(mocap_framerate // fps)``-th frame, starting at 0;
* zero the root orientation (joint 0) and ignore ``trans`` (no global translation);
* forward kinematics on all 52 SMPL-H joints (``poses`` has 156 = 52 x 3 columns) with the fixed
  mean SMPL-H rest skeleton ``smpl_skeleton.npz`` (``p3d0`` (1, 52, 3) metres, ``parents`` (52,)),
  not the subject's own shape (``betas`` are ignored);
* keep joints 4..21, i.e. 18 joints, K = 54 coordinates, in metres.

The same FK and joint subset serve 3DPW (whose loader lives elsewhere).
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

import numpy as np

from tcd.layouts import LAYOUTS

from training.data.kinematics import fk_axis_angle

# Dataset names of the AMASS splits used with ``all_data = True`` in the reference pipeline (spec 3.3).
AMASS_SPLITS: dict[str, list[str]] = {
    "train": ["CMU", "MPI_Limits", "TotalCapture", "Eyes_Japan_Dataset", "KIT", "EKUT", "TCD_handMocap", "ACCAD"],
    "val": ["SFU"],
    "test": ["BioMotionLab_NTroje"],
}

# First and one-past-last SMPL joint index kept by the protocol.
AMASS_JOINT_START = 4
AMASS_JOINT_STOP = 22
AMASS_JOINTS_USED = list(range(AMASS_JOINT_START, AMASS_JOINT_STOP))  # 18 joints

# Standard SMPL body-joint names (indices 0..21 are shared by SMPL and SMPL-H): the package's ``smpl24`` layout
# without its hands. "left" is the subject's left, which is +x in the SMPL rest pose (p3d0[1] = left hip has x > 0).
SMPL_BODY_JOINT_NAMES = list(LAYOUTS["smpl24"].joint_names[:22])
# Names of the 18 kept joints, in output order (SMPL joints 4..21).
JOINTS_AMASS_18 = SMPL_BODY_JOINT_NAMES[AMASS_JOINT_START:AMASS_JOINT_STOP]


def load_smpl_skeleton(skeleton_path) -> tuple[np.ndarray, np.ndarray]:
    """Load the mean SMPL-H rest skeleton: ``(rest (52, 3) float64 metres, parents (52,) int)``."""
    with np.load(skeleton_path) as skel:
        rest = np.asarray(skel["p3d0"], dtype=np.float64)
        parents = np.asarray(skel["parents"]).astype(np.int64)
    if rest.ndim == 3:
        rest = rest[0]
    if rest.shape != (parents.shape[0], 3):
        raise ValueError(f"skeleton p3d0 {rest.shape} does not match parents {parents.shape}")
    return rest, parents


def amass_sample_step(mocap_framerate: float, fps: int = 25) -> int:
    """Frame step of the reference loader: ``int(mocap_framerate // fps)`` (at least 1)."""
    return max(int(float(mocap_framerate) // fps), 1)


def amass_poses_to_joints(poses: np.ndarray, rest: np.ndarray, parents) -> np.ndarray:
    """Axis-angle poses (T, 3J) or (T, J, 3) -> kept joint positions (T, 18, 3).

    The root orientation is zeroed (on a copy) before FK; the root sits at ``rest[0]``.
    """
    poses = np.asarray(poses, dtype=np.float64)
    n_joints = len(parents)
    poses = poses.reshape(poses.shape[0], -1, 3)
    if poses.shape[1] != n_joints:
        raise ValueError(f"poses have {poses.shape[1]} joints, skeleton has {n_joints}")
    poses = poses.copy()
    poses[:, 0] = 0.0  # remove the global orientation
    joints = fk_axis_angle(poses, rest, parents)
    return joints[:, AMASS_JOINT_START:AMASS_JOINT_STOP]


def load_amass_file(path, skeleton_path, fps: int = 25) -> np.ndarray:
    """Load one AMASS ``.npz`` and return joint positions (T', 18, 3) float64 in metres.

    ``T' = ceil(T / step)`` with ``step = int(mocap_framerate // fps)`` (frames 0, step, 2 step, ...).
    """
    rest, parents = load_smpl_skeleton(skeleton_path)
    with np.load(path) as data:
        poses = np.asarray(data["poses"], dtype=np.float64)
        framerate = float(data["mocap_framerate"])
    step = amass_sample_step(framerate, fps)
    poses = poses[::step]
    return amass_poses_to_joints(poses, rest, parents)


def iter_windows(seq: np.ndarray, seq_len: int, stride: int = 1) -> Iterator[np.ndarray]:
    """Yield the windows ``seq[i : i + seq_len]`` for ``i = 0, stride, ...`` that fit entirely in ``seq``.

    This is the reference ``valid_frames = arange(0, T - seq_len + 1, stride)`` rule: a sequence of
    exactly ``seq_len`` frames gives one window, a shorter one gives none. Windows are views.
    """
    if seq_len <= 0 or stride <= 0:
        raise ValueError("seq_len and stride must be positive")
    for start in range(0, len(seq) - seq_len + 1, stride):
        yield seq[start : start + seq_len]


def list_amass_files(root, datasets) -> list[Path]:
    """All ``.npz`` files under ``root/<dataset>/`` for the given dataset names, sorted, excluding
    ``shape.npz`` files (AMASS keeps the subject's betas there)."""
    root = Path(root)
    files: list[Path] = []
    for name in datasets:
        files.extend(p for p in sorted((root / name).rglob("*.npz")) if p.name != "shape.npz")
    return files
