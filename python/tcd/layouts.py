"""Joint layouts other pipelines produce, and how each maps onto the model's 22 Human3.6M joints.

Every layout is described against the Human3.6M 32-joint skeleton (``tcd/data/skeleton32.json``), whose
joint ids are the common language: a layout joint either *stands for* a 32-skeleton joint (``to32``), or
is *carried* (the model has no such joint: it is put back on output rigidly attached to its anchor, see
:mod:`tcd.wild`). A model joint that a layout lacks is missing in the observation and in-painted by the
model; a model joint a layout has only as a combination (COCO's neck: the mid-point of the shoulders) is
listed in ``combined``.

==========  ======  ==========================================================================================
layout      joints  model joints it lacks (in-painted)
==========  ======  ==========================================================================================
h36m22      22      none: the model's own layout (root-relative, heading removed, +x left, +y up, +z forward)
h36m32      32      none
h36m17      17      toes and toe sites, thumbs and hands, head site (VideoPose3D / MotionBERT order)
smpl24      24      toe sites, head site, thumbs (SMPL / AMASS / 3DPW joint order)
coco17      17      toes and toe sites, thorax, head site, thumbs and hands (COCO keypoints lifted to 3D)
humaneva15  15      toes and toe sites, thorax, head (its head is the head site), thumbs and hands (HumanEva-I)
==========  ======  ==========================================================================================

``humaneva15`` is HumanEva-I's 15-joint layout (VideoPose3D's ``humaneva15``, the stochastic benchmark's data:
pelvis, thorax, left shoulder / elbow / wrist, right shoulder / elbow / wrist, left hip / knee / ankle, right
hip / knee / ankle, head), mapped here onto the Human3.6M skeleton like the others so that a Human3.6M model
forecasts it. A model trained on HumanEva-I itself (``tcd.load("humaneva")``) works in that layout directly:
its joints are joints 1..14 of ``humaneva15`` relative to the pelvis (``TCD.joint_names``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

from . import _checks, _fk as fk

__all__ = ["Layout", "LAYOUTS", "get_layout", "MODEL_IDS", "FIXED_IDS", "NAMES32"]

#: Names of the Human3.6M 32-joint skeleton's joints (left/right are the subject's).
NAMES32 = (
    "pelvis",
    "right_hip",
    "right_knee",
    "right_ankle",
    "right_toe",
    "right_toe_site",
    "left_hip",
    "left_knee",
    "left_ankle",
    "left_toe",
    "left_toe_site",
    "spine",
    "thorax",
    "neck",
    "head",
    "head_site",
    "left_clavicle",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "left_wrist_end",
    "left_thumb",
    "left_hand",
    "left_hand_site",
    "right_clavicle",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
    "right_wrist_end",
    "right_thumb",
    "right_hand",
    "right_hand_site",
)
#: 32-skeleton ids of the model's 22 joints, in model order.
MODEL_IDS: Tuple[int, ...] = tuple(fk.joints_used())
#: 32-skeleton joints the model's convention fixes: the root at the origin, the hips and the spine base at
#: their offsets from it (the model does not predict them).
FIXED_IDS: Tuple[int, ...] = (0, 1, 6, 11)


@dataclass(frozen=True)
class Layout:
    """A joint layout: names, kinematic parents (-1 for a root) and its correspondence to the 32-skeleton."""

    name: str
    joint_names: Tuple[str, ...]
    parents: Tuple[int, ...]
    #: for each joint, the 32-skeleton joint it stands for, or None (carried back on output)
    to32: Tuple[Optional[int], ...]
    #: 32-skeleton joints the layout gives as the mean of several of its joints
    combined: Dict[int, Tuple[int, ...]] = field(default_factory=dict)
    #: the joints whose midpoint is the root (pelvis) when the layout has no pelvis joint
    pelvis_from: Tuple[int, ...] = ()
    #: carried joints (to32 None) -> the 32-skeleton joint they hang from, where it is not their nearest
    #: layout ancestor that stands for a placed joint (the default, see tcd.wild)
    anchors: Dict[int, int] = field(default_factory=dict)
    #: whether poses in this layout are always root-relative with the heading removed (the model's own)
    canonical: bool = False

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    def source_of(self, id32: int) -> Tuple[int, ...]:
        """The layout joints whose mean gives 32-skeleton joint ``id32`` (empty when the layout lacks it)."""
        if id32 in self.combined:
            return self.combined[id32]
        if id32 == 0 and self.pelvis_from:
            return self.pelvis_from
        return tuple(i for i, t in enumerate(self.to32) if t == id32)[:1]


def _h36m32() -> Layout:
    parents = tuple(int(p) for p in fk.skeleton()["parents"])
    return Layout("h36m32", NAMES32, parents, tuple(range(32)))


def _h36m22() -> Layout:
    # the model's joints, parented to their nearest model ancestor (-1 for the fixed root and hips)
    parents32 = fk.skeleton()["parents"]
    index = {j: i for i, j in enumerate(MODEL_IDS)}

    def parent(j: int) -> int:
        p = parents32[j]
        while p >= 0 and p not in index:
            p = parents32[p]
        return index.get(p, -1)

    return Layout(
        "h36m22", tuple(NAMES32[j] for j in MODEL_IDS), tuple(parent(j) for j in MODEL_IDS), MODEL_IDS, canonical=True
    )


# The arms as the layouts list them: side by side (h36m17, humaneva15) and in left / right pairs (smpl24, coco17).
_ARMS = ("left_shoulder", "left_elbow", "left_wrist", "right_shoulder", "right_elbow", "right_wrist")
_ARMS_PAIRED = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist")

_H36M17_IDS = tuple(fk.skeleton()["joints_h36m_17"])  # 0,1,2,3,6,7,8,12,13,14,15,17,18,19,25,26,27
H36M17 = Layout(
    "h36m17",
    (
        "pelvis",
        "right_hip",
        "right_knee",
        "right_ankle",
        "left_hip",
        "left_knee",
        "left_ankle",
        "spine",
        "thorax",
        "neck",
        "head",
        *_ARMS,
    ),
    (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 9, 8, 11, 12, 8, 14, 15),
    _H36M17_IDS,
)

SMPL24 = Layout(
    "smpl24",
    (
        "pelvis",
        "left_hip",
        "right_hip",
        "spine1",
        "left_knee",
        "right_knee",
        "spine2",
        "left_ankle",
        "right_ankle",
        "spine3",
        "left_foot",
        "right_foot",
        "neck",
        "left_collar",
        "right_collar",
        "head",
        *_ARMS_PAIRED,
        "left_hand",
        "right_hand",
    ),
    (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21),
    # SMPL's spine3 stands for the thorax, its feet for the toes, its hands for the hands; spine1, spine2 and
    # the collars have no model counterpart and are carried
    (0, 6, 1, None, 7, 2, None, 8, 3, 12, 9, 4, 13, None, None, 14, 17, 25, 18, 26, 19, 27, 22, 30),
)

COCO17 = Layout(
    "coco17",
    (
        "nose",
        "left_eye",
        "right_eye",
        "left_ear",
        "right_ear",
        *_ARMS_PAIRED,
        "left_hip",
        "right_hip",
        "left_knee",
        "right_knee",
        "left_ankle",
        "right_ankle",
    ),
    (-1, 0, 0, 1, 2, 0, 0, 5, 6, 7, 8, 5, 6, 11, 12, 13, 14),
    (None, None, None, None, None, 17, 25, 18, 26, 19, 27, 6, 1, 7, 2, 8, 3),
    # no neck and no head joint: the neck is the mid-point of the shoulders, the head that of the ears;
    # the face points are carried
    combined={13: (5, 6), 14: (3, 4)},
    pelvis_from=(11, 12),
    anchors={face: 14 for face in range(5)},  # nose, eyes and ears ride on the head
)

HUMANEVA15 = Layout(
    "humaneva15",
    (
        "pelvis",
        "thorax",
        *_ARMS,
        "left_hip",
        "left_knee",
        "left_ankle",
        "right_hip",
        "right_knee",
        "right_ankle",
        "head",
    ),
    (-1, 0, 1, 2, 3, 1, 5, 6, 0, 8, 9, 0, 11, 12, 1),
    # the thorax is where the shoulders meet (the 32-skeleton's 13, as h36m17's thorax); the head is the top of
    # the head (15, as h36m17's head)
    (0, 13, 17, 18, 19, 25, 26, 27, 6, 7, 8, 1, 2, 3, 15),
)

LAYOUTS: Dict[str, Layout] = {lay.name: lay for lay in (_h36m22(), _h36m32(), H36M17, SMPL24, COCO17, HUMANEVA15)}


def get_layout(name: object) -> Layout:
    """The layout called ``name`` (one of :data:`LAYOUTS`), else an InvalidInputError naming ``layout``."""
    if isinstance(name, Layout):
        return name
    return LAYOUTS[_checks.choice("layout", name, tuple(LAYOUTS))]
