"""Rotations and forward kinematics of the loaders.

The exp-map kinematics (``expmap_to_rotmat``, ``fk_expmap``; Human3.6M and CMU) are the package's
(``python/tcd/_fk.py``), one copy for inference and training; the SMPL-style ``fk_axis_angle`` (AMASS,
3DPW) is training's own. All vectorised numpy, float64 internally.

``_fk.py`` is loaded from this repository's source tree rather than by ``import tcd``: the package's
``__init__`` loads the compiled engine, and training must use this checkout's skeleton and kinematics
whichever ``tcd`` is installed (``_fk.py`` imports nothing from the package).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np


def _load_package_fk():
    """``python/tcd/_fk.py`` of this checkout as the module ``training._tcd_fk`` (loaded once)."""
    key = "training._tcd_fk"
    if key not in sys.modules:
        path = Path(__file__).resolve().parents[2] / "python" / "tcd" / "_fk.py"
        spec = importlib.util.spec_from_file_location(key, path)
        if spec is None or spec.loader is None:
            raise ImportError(f"cannot load {path}")
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        spec.loader.exec_module(module)
    return sys.modules[key]


_fk = _load_package_fk()
expmap_to_rotmat = _fk.expmap_to_rotmat
fk_expmap = _fk.fk_expmap
#: The Human3.6M 32-joint skeleton (parents, offsets in mm, the 22 model joints), packaged with tcd.
SKELETON_PATH = _fk.SKELETON_PATH


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
