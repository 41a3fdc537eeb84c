"""Reading and checking one input file (``.npz`` poses or a Human3.6M exp-map ``.txt``)."""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, Optional, Sequence, Tuple

import numpy as np

from .. import _fk as fk, wild
from ..exceptions import InvalidInputError
from .._files import UnreadableFile, read_pose_npz
from ..layouts import get_layout
from .._poses import UNIT_SCALE, validate_poses
from .options import BadFile, PathLike


# ---------------------------------------------------------------------------------------------- inputs
@dataclass
class Loaded:
    poses: np.ndarray  # (T, J, 3) the caller's values in the output dtype (NaN / anything where missing)
    full_mask: np.ndarray  # (T, J, 3) bool, True = observed
    mask_out: np.ndarray  # what goes to the output's `mask`
    fps: float  # the input's frame rate
    # another joint layout (tcd.wild): poses / full_mask above are the model-layout conversion, in the
    # caller's units; these keep the caller's own poses and what brings the repair back to them
    scene: Optional[wild.Scene] = None
    original: Optional[np.ndarray] = None
    original_mask: Optional[np.ndarray] = None

    def back(self, repaired: np.ndarray, scale: float) -> np.ndarray:
        """Model-layout repaired poses (T, 22, 3) in the caller's units -> the caller's layout, observed
        entries bit for bit (identity for the model's own layout)."""
        if self.scene is None:
            return repaired
        s = self.scene
        y = wild.from_model(repaired[None].astype(np.float64) / scale, s, s.root, s.rot, own_frames=True)[0]
        return np.where(self.original_mask, self.original, (y * scale).astype(self.original.dtype))

    @property
    def frames(self) -> int:
        return int(self.poses.shape[0])


def is_expmap_txt(path: Path) -> bool:
    return path.suffix.lower() == ".txt"


def _read_npz(path: Path) -> Dict[str, np.ndarray]:
    try:
        return read_pose_npz(path)
    except (UnreadableFile, OSError) as e:
        raise BadFile(f"unreadable: {e}") from None


def _checked_poses(data: Dict[str, np.ndarray], num_joints: int, units: str) -> Tuple[np.ndarray, np.ndarray]:
    """``poses`` (T, J, 3) in a float dtype and the observed entries (T, J, 3) bool, checked by the API's
    :func:`tcd._poses.validate_poses`; a problem is a :class:`BadFile` naming the array."""
    try:
        p = validate_poses(
            data["poses"],
            data.get("mask"),
            num_joints=num_joints,
            batched_ok=False,
            names=("poses", "mask"),
            owner="The file's",
            units=units,
        )
    except InvalidInputError as e:
        raise BadFile(str(e)) from None
    return p.values[0], p.observed[0]


def load_input(
    path: PathLike,
    num_joints: int,
    units: str = "m",
    fps: Optional[float] = None,
    model_fps: Optional[float] = None,
    joint_index_32: Optional[Sequence[int]] = None,
    layout: str = "h36m22",
    up: str = "y",
) -> Loaded:
    """Reads and checks one input file; raises :class:`BadFile` with the reason when it cannot be repaired."""
    path = Path(path)
    if not path.is_file():
        raise BadFile("unreadable: not a file" if path.exists() else "unreadable: the file does not exist")
    if path.suffix.lower() == ".bvh":
        poses32, rate = _bvh_poses(path)
        poses, full = _checked_poses({"poses": poses32}, 32, units)
        src_fps = fps if fps is not None else rate
        return _converted(poses, full, full, src_fps, get_layout("h36m32"), up, units)
    if is_expmap_txt(path):
        if num_joints != 22 or (joint_index_32 is not None and list(joint_index_32) != fk.joints_used()):
            raise BadFile("a Human3.6M exp-map .txt file, but the model does not use the Human3.6M 22-joint layout")
        try:
            rows = fk.read_expmap_txt(path)
        except (OSError, UnicodeDecodeError) as e:
            raise BadFile(f"unreadable: {e}") from None
        except ValueError as e:
            raise BadFile(f"unreadable as a Human3.6M exp-map file: {e}") from None
        if np.isinf(rows).any():
            t, c = (int(i) for i in np.argwhere(np.isinf(rows))[0])
            raise BadFile(f"the exp-map file holds an infinite value at row {t}, column {c}")
        poses = fk.expmap_to_model(rows) * UNIT_SCALE[units]
        full = ~np.isnan(poses)
        src_fps = fk.H36M_TXT_FPS if fps is None else fps
        mask_out = full
    else:
        data = _read_npz(path)
        lay = get_layout(layout)
        poses, full = _checked_poses(data, lay.num_joints if not lay.canonical else num_joints, units)
        mask_out = data["mask"] if "mask" in data else full
        src_fps = fps if fps is not None else (model_fps if model_fps is not None else float("nan"))
        if not lay.canonical:
            return _converted(poses, full, mask_out, src_fps, lay, up, units)
    if not full.any():
        raise BadFile("every value is missing: nothing to condition the repair on")
    return Loaded(poses=poses, full_mask=full, mask_out=mask_out, fps=src_fps)


def _converted(
    poses: np.ndarray, full: np.ndarray, mask_out: np.ndarray, fps: float, lay: Any, up: str, units: str
) -> Loaded:
    """A file in another layout: converted to the model's convention for the windows (:mod:`tcd.wild`)."""
    scale = UNIT_SCALE[units]
    joint_seen = full.all(-1, keepdims=True)
    x = np.where(joint_seen, poses, np.nan).astype(np.float64)[None] / scale
    try:
        y, scene = wild.to_model(x, lay, wild.up_vector(up), arg="poses")
    except InvalidInputError as e:
        raise BadFile(str(e).replace("Argument `poses`", "The file's `poses`", 1)) from None
    seen = np.isfinite(y[0])
    model_poses = np.where(seen, y[0] * scale, 0.0).astype(poses.dtype)
    if not seen.any():
        raise BadFile("no model joint is observed: nothing to condition the repair on")
    return Loaded(
        poses=model_poses, full_mask=seen, mask_out=mask_out, fps=fps, scene=scene, original=poses, original_mask=full
    )


def _bvh_poses(path: Path) -> Tuple[np.ndarray, float]:
    """A BVH file as (T, 32, 3) h36m32 poses (NaN where it has no such joint) and its frame rate."""
    from .._bvh import read_bvh_h36m32

    try:
        return read_bvh_h36m32(path)
    except UnreadableFile as e:
        raise BadFile(f"unreadable: {e}") from None
    except ImportError as e:
        raise BadFile(str(e)) from None


def peek_frames(path: Path) -> int:
    """T of an input without loading it (0 when that fails): the npz header or the txt line count."""
    try:
        if is_expmap_txt(path):
            with open(path, "rb") as f:
                return sum(1 for line in f if line.strip())
        with zipfile.ZipFile(path) as z:
            with z.open("poses.npy") as f:
                version = np.lib.format.read_magic(f)
                shape = (
                    np.lib.format.read_array_header_1_0(f)
                    if version == (1, 0)
                    else np.lib.format.read_array_header_2_0(f)
                )[0]
                return int(shape[0]) if len(shape) == 3 else 0
    except Exception:  # noqa: BLE001 - a progress estimate only; the real read reports the problem
        return 0
