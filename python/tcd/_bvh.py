"""Biovision BVH motion files as poses: parsed and posed by ``bvhio`` (a maintained reader from PyPI:
``pip install "tcd-forecast[bvh]"``), then matched onto the 32-joint Human3.6M skeleton by joint name, so
that they go through the ``h36m32`` layout (:mod:`tcd.wild`).

Matching: names are compared without a ``prefix:`` (Mixamo's ``mixamorig:``) and case-insensitively. The
hips are the root; the thorax is the parent of the neck; the spine base is the hips' child on the way to
it; legs, arms, hands and thumbs by the usual names (``LeftUpLeg``/``LeftThigh``, ``LeftLeg``/``LeftShin``,
``LeftFoot``, ``LeftToeBase``, ``LeftShoulder``/``LeftCollar``, ``LeftArm``/``LeftUpArm``,
``LeftForeArm``/``LeftLowArm``, ``LeftHand``, ``LeftHandThumb*``, ``LeftHandIndex1``; the same on the
right). A Human3.6M joint without a match is missing (in-painted); BVH joints without a match are not used.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from ._files import UnreadableFile

__all__ = ["read_bvh", "to_h36m32", "read_bvh_h36m32"]

# Human3.6M 32-skeleton id <- accepted BVH names (compared lower-case, without a "prefix:")
_NAMES: Dict[int, Tuple[str, ...]] = {
    0: ("hips", "pelvis", "root"),
    1: ("rightupleg", "rightthigh", "rightuplegroll", "rthigh", "rightupperleg"),
    2: ("rightleg", "rightshin", "rightknee", "rshin", "rightlowerleg"),
    3: ("rightfoot", "rightankle", "rfoot"),
    4: ("righttoebase", "righttoe", "rtoes", "righttoes"),
    6: ("leftupleg", "leftthigh", "leftuplegroll", "lthigh", "leftupperleg"),
    7: ("leftleg", "leftshin", "leftknee", "lshin", "leftlowerleg"),
    8: ("leftfoot", "leftankle", "lfoot"),
    9: ("lefttoebase", "lefttoe", "ltoes", "lefttoes"),
    13: ("neck", "neck1", "neckbase"),
    14: ("head",),
    16: ("leftshoulder", "leftcollar", "lcollar", "leftclavicle"),
    17: ("leftarm", "leftuparm", "lshldr", "leftupperarm"),
    18: ("leftforearm", "leftlowarm", "lforearm", "leftlowerarm"),
    19: ("lefthand", "lhand", "leftwrist"),
    21: ("lefthandthumb", "lefthandthumb1", "leftthumb", "lthumb"),
    22: ("lefthandindex1", "lefthandindex", "leftfingerbase"),
    24: ("rightshoulder", "rightcollar", "rcollar", "rightclavicle"),
    25: ("rightarm", "rightuparm", "rshldr", "rightupperarm"),
    26: ("rightforearm", "rightlowarm", "rforearm", "rightlowerarm"),
    27: ("righthand", "rhand", "rightwrist"),
    29: ("righthandthumb", "righthandthumb1", "rightthumb", "rthumb"),
    30: ("righthandindex1", "righthandindex", "rightfingerbase"),
}


def _key(name: str) -> str:
    return name.split(":")[-1].replace("_", "").replace(" ", "").lower()


def read_bvh(path: Path) -> Tuple[np.ndarray, List[str], List[int], float]:
    """World positions (T, J, 3) in the file's units, joint names, parents (-1 for the root) and frame rate
    of a BVH file. Raises ImportError naming the extra when bvhio is missing, :class:`UnreadableFile` when
    the file is not a readable BVH file."""
    try:
        import bvhio
    except ImportError:
        raise ImportError('reading BVH files needs bvhio: pip install "tcd-forecast[bvh]"') from None
    try:
        container = bvhio.readAsBvh(str(path))
        root = bvhio.readAsHierarchy(str(path))
    except Exception as e:  # noqa: BLE001 - the reader's many failure types all mean "not a BVH we can read"
        raise UnreadableFile(f"not a readable BVH file ({type(e).__name__}: {e})") from None
    joints = [j for j, _, _ in root.layout()]
    names = [j.Name for j in joints]
    index = {id(j): i for i, j in enumerate(joints)}
    parents = [index.get(id(j.Parent), -1) if j.Parent is not None else -1 for j in joints]
    frames = int(container.FrameCount)
    if frames < 1 or not container.FrameTime or container.FrameTime <= 0:
        raise UnreadableFile("a BVH file without frames or with no positive frame time")
    pos = np.empty((frames, len(joints), 3))
    for f in range(frames):
        root.loadPose(f)
        for i, j in enumerate(joints):
            p = j.PositionWorld
            pos[f, i] = (p.x, p.y, p.z)
    return pos, names, parents, 1.0 / float(container.FrameTime)


def to_h36m32(pos: np.ndarray, names: List[str], parents: List[int]) -> np.ndarray:
    """(T, J, 3) BVH joint positions -> (T, 32, 3) Human3.6M joints (NaN where the file has no match)."""
    keys = [_key(n) for n in names]
    found: Dict[int, Optional[int]] = {}
    for id32, accepted in _NAMES.items():
        found[id32] = next((i for i, k in enumerate(keys) if k in accepted), None)
    if found[0] is None:
        found[0] = next((i for i, p in enumerate(parents) if p < 0), None)
    neck = found.get(13)
    if neck is not None and parents[neck] >= 0:
        found[12] = parents[neck]  # the thorax: where the neck hangs from
        chain, j = [], parents[neck]
        while j >= 0 and j != found[0]:
            chain.append(j)
            j = parents[j]
        if j == found[0] and chain:
            found[11] = chain[-1]  # the spine base: the hips' child towards it
    out = np.full((pos.shape[0], 32, 3), np.nan)
    for id32, i in found.items():
        if i is not None:
            out[:, id32] = pos[:, i]
    return out


def read_bvh_h36m32(path: Path) -> Tuple[np.ndarray, float]:
    """A BVH file as (T, 32, 3) h36m32 poses in the file's units (NaN where it has no such joint) and its
    frame rate: what ``tcd forecast`` and ``tcd repair`` read. Errors as :func:`read_bvh`."""
    pos, names, parents, rate = read_bvh(path)
    return to_h36m32(pos, names, parents), rate
