"""HumanEva-I loader and the DLow / GSPS stochastic-prediction test protocol.

Data: ``humaneva_i_15j_60hz.npz`` (the VideoPose3D ``data_3d_humaneva15`` positions), keys
``{Train|Validate}/{S1|S2|S3}/{action} chunk{n}``, float32 (T, 15, 3) metres at 60 Hz. The DLow
protocol trains on the ``Train/*`` subjects and tests on ``Validate/*``.

Protocol (DLow ``motion_pred/utils/dataset_humaneva.py``, ``dataset.py`` and ``eval.py``; GSPS and
MotionDiff use the same definitions):

* all 15 joints kept; joints 1..14 made relative to joint 0 (the root) and the root dropped:
  14 joints, 42 dimensions (global translation removed, global rotation kept);
* t_his = 15 observed, t_pred = 60 predicted frames (75 per window);
* test windows start at ``range(0, T - 75, t_his)``. The upper bound is exclusive as in DLow's
  ``iter_generator``: a chunk needs **more** than 75 frames to give a window, and the last window
  that would end exactly at the chunk's end is not used;
* three takes with a wrong head position are removed, as DLow does: ``Train/S3/Walking 1 chunk0``,
  ``Train/S3/Walking 1 chunk2`` (train) and ``Validate/S3/Walking 1 chunk4`` (test);
* multimodal ground truth: for each test window, the futures of all test windows whose last observed
  pose (flattened 42-dim root-relative pose at frame t_his - 1) lies at L2 distance < threshold
  (0.5 m) from this window's (strict inequality, as ``np.nonzero(pd < threshold)``); the window
  itself is always included (distance 0).

Training (``training.train`` and ``training.prior`` with ``"dataset": "humaneva"``): the chunks of the
Train split (the bad takes removed) in the model's space, joints 1..14 relative to the pelvis
(:func:`training_sequences`), every window of the model's length inside one chunk. The protocol has no
validation split: a model is scored on ``Validate`` only at the end (``training.evaluate``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from tcd.layouts import LAYOUTS

_HUMANEVA15 = LAYOUTS["humaneva15"]

HUMANEVA_FILE_NAME = "humaneva_i_15j_60hz.npz"
HUMANEVA_T_HIS = 15
HUMANEVA_T_PRED = 60
HUMANEVA_FPS = 60
HUMANEVA_NUM_JOINTS = 15

# The 15-joint HumanEva skeleton of VideoPose3D / DLow, the file's joint order (pelvis, thorax, lsho, lelb, lwri, rsho,
# relb, rwri, lhip, lkne, lank, rhip, rkne, rank, head; left/right are the subject's) and parents: the package's
# ``humaneva15`` layout, one definition.
HUMANEVA_JOINT_NAMES = _HUMANEVA15.joint_names
HUMANEVA_PARENTS = list(_HUMANEVA15.parents)
# The model's joints: joints 1..14 relative to the pelvis (the protocol's 42 dimensions).
HUMANEVA_MODEL_JOINT_NAMES = HUMANEVA_JOINT_NAMES[1:]
# The subjects of the Train split (S1, S2, S3), the only ones a model may be trained on.
HUMANEVA_TRAIN_SUBJECTS = (1, 2, 3)

# Takes DLow drops because of a wrong head position (``dataset_humaneva.py``).
HUMANEVA_EXCLUDED_TAKES = {
    "Train": ("Train/S3/Walking 1 chunk0", "Train/S3/Walking 1 chunk2"),
    "Validate": ("Validate/S3/Walking 1 chunk4",),
}


def load_humaneva(path, split: str = "Train", exclude_bad_takes: bool = True) -> dict[str, np.ndarray]:
    """Load the chunks of one split: ``{"Validate/S1/Box 1 chunk0": (T, 15, 3) float32 metres}``.

    ``split`` is ``"Train"`` (training subjects) or ``"Validate"`` (the test set of the protocol).
    Keys keep the file's order (DLow's iteration order). The takes in ``HUMANEVA_EXCLUDED_TAKES``
    are dropped unless ``exclude_bad_takes=False``. Raw absolute positions: see ``root_relative``.
    """
    if split not in ("Train", "Validate"):
        raise ValueError(f"split must be 'Train' or 'Validate', got {split!r}")
    excluded = set(HUMANEVA_EXCLUDED_TAKES[split]) if exclude_bad_takes else set()
    out: dict[str, np.ndarray] = {}
    with np.load(path) as data:
        for key in data.files:
            if not key.startswith(split + "/") or key in excluded:
                continue
            arr = np.asarray(data[key], dtype=np.float32)
            if arr.ndim != 3 or arr.shape[1:] != (HUMANEVA_NUM_JOINTS, 3):
                raise ValueError(f"{key}: expected (T, 15, 3), got {arr.shape}")
            out[key] = arr
    return out


def humaneva_file(path=None) -> Path:
    """The data file: ``path`` itself, ``path/humaneva_i_15j_60hz.npz`` for a directory, or (None) the
    shared data directory's copy (``$TCD_DATA_DIR/humaneva``, else ``../shared/data/humaneva``)."""
    if path is None:
        from .h36m import DEFAULT_DATA_ROOT

        path = DEFAULT_DATA_ROOT / "humaneva"
    path = Path(path)
    return path / HUMANEVA_FILE_NAME if path.is_dir() else path


def training_sequences(path=None, subjects=HUMANEVA_TRAIN_SUBJECTS) -> dict[str, np.ndarray]:
    """The Train split's chunks of ``subjects`` (ints among 1, 2, 3), bad takes removed, root-relative:
    ``{"Train/S1/Box 1 chunk1": (T, 14, 3) float32 metres}`` in the file's order (the model's space)."""
    subjects = tuple(int(s) for s in subjects)
    if not subjects or set(subjects) - set(HUMANEVA_TRAIN_SUBJECTS):
        raise ValueError(
            f"HumanEva-I training subjects must be among {list(HUMANEVA_TRAIN_SUBJECTS)} "
            f"(S1..S3 of the Train split), got {list(subjects)}"
        )
    wanted = {f"S{s}" for s in subjects}
    return {
        k: root_relative(v).astype(np.float32)
        for k, v in load_humaneva(humaneva_file(path), "Train").items()
        if k.split("/")[1] in wanted
    }


def training_actions(path=None, subjects=HUMANEVA_TRAIN_SUBJECTS) -> list[str]:
    """The action of each of :func:`training_sequences`' chunks, in its order ("Train/S1/Box 1 chunk1" -> "Box")."""
    return [k.split("/")[2].split()[0] for k in training_sequences(path, subjects)]


def root_relative(seq: np.ndarray) -> np.ndarray:
    """(..., 15, 3) -> (..., 14, 3): joints 1..14 minus joint 0; the root is dropped."""
    seq = np.asarray(seq)
    return seq[..., 1:, :] - seq[..., :1, :]


def window_starts(n_frames: int, t_total: int, step: int) -> range:
    """DLow's window starts: ``range(0, n_frames - t_total, step)`` (upper bound exclusive)."""
    return range(0, n_frames - t_total, step)


def protocol_window_index(
    data: dict[str, np.ndarray], t_his: int = HUMANEVA_T_HIS, t_pred: int = HUMANEVA_T_PRED, step: int | None = None
) -> list[tuple[str, int]]:
    """(chunk key, first frame) of every test window, in ``data``'s order: DLow's ``iter_generator(step=t_his)``
    (``step`` defaults to ``t_his``); chunks with at most ``t_his + t_pred`` frames give no window."""
    step = t_his if step is None else step
    if step <= 0:
        raise ValueError("step must be positive")
    return [(key, start) for key, seq in data.items() for start in window_starts(seq.shape[0], t_his + t_pred, step)]


def humaneva_test_windows(
    data: dict[str, np.ndarray], t_his: int = HUMANEVA_T_HIS, t_pred: int = HUMANEVA_T_PRED, step: int | None = None
) -> np.ndarray:
    """All test windows (:func:`protocol_window_index`), root-relative: (N, t_his + t_pred, 14, 3), in ``data``'s
    order."""
    t_total = t_his + t_pred
    windows = [
        root_relative(data[key][start : start + t_total])
        for key, start in protocol_window_index(data, t_his, t_pred, step)
    ]
    if not windows:
        return np.zeros((0, t_total, HUMANEVA_NUM_JOINTS - 1, 3), dtype=np.float32)
    return np.stack(windows)


def humaneva_test_actions(
    data: dict[str, np.ndarray], t_his: int = HUMANEVA_T_HIS, t_pred: int = HUMANEVA_T_PRED, step: int | None = None
) -> list[str]:
    """The action of each window :func:`humaneva_test_windows` gives, in its order: ``"Box"`` for a window of
    ``Validate/S1/Box 1 chunk0`` (Box, Gestures, Jog, ThrowCatch, Walking)."""
    return [key.split("/")[-1].split(" ")[0] for key, _ in protocol_window_index(data, t_his, t_pred, step)]


def multimodal_gt(windows: np.ndarray, t_his: int = HUMANEVA_T_HIS, threshold: float = 0.5) -> list[np.ndarray]:
    """DLow's ``get_multimodal_gt``: for each window i, ``(M_i, t_pred, D)`` futures of the windows whose
    last observed pose is within L2 distance ``< threshold`` of window i's (window i included).

    ``windows``: (N, T, J, 3) or (N, T, D). Distances are between flattened poses at frame
    ``t_his - 1``, computed in float64. Futures are frames ``t_his:`` flattened to D = 3 J.
    """
    windows = np.asarray(windows)
    n, t_total = windows.shape[:2]
    flat = windows.reshape(n, t_total, -1)
    start = flat[:, t_his - 1, :].astype(np.float64)
    # Exact pairwise distances (no Gram-matrix cancellation), row by row to bound memory.
    futures = flat[:, t_his:, :]
    out: list[np.ndarray] = []
    for i in range(n):
        dist = np.linalg.norm(start - start[i], axis=1)
        out.append(futures[np.nonzero(dist < threshold)[0]])
    return out


# ------------------------------------------------------------- Human3.6M retargeted to HumanEva-I's skeleton

#: Human3.6M subjects a HumanEva-I model may also learn from (``h36m_share``): the Human3.6M training subjects
#: of this project's own models; S5 stays out (it is Human3.6M's test subject).
H36M_EXTRA_SUBJECTS = (1, 6, 7, 8, 9, 11)


def check_h36m_share(share: float, dataset: str, where: str) -> None:
    """ValueError (naming ``where``) unless ``share`` is a fraction in [0, 1) and, when above 0, ``dataset`` is
    HumanEva-I: the one check of ``h36m_share`` for the prior's and the denoisers' configs and :func:`training_mix`."""
    if not 0.0 <= share < 1.0 or (share and dataset != "humaneva"):
        raise ValueError(
            f"{where}: h36m_share (the fraction of a HumanEva-I model's training windows taken from "
            f'Human3.6M) must be in [0, 1) and needs "dataset": "humaneva", got {share!r} '
            f"for {dataset!r}"
        )


def bone_lengths(seqs) -> np.ndarray:
    """(14,) the mean length of each bone (joint j to its parent, j = 1..14) over all frames of ``seqs``,
    (T, 15, 3) arrays in HumanEva-I's 15-joint order."""
    frames = np.concatenate([np.asarray(s, dtype=np.float64) for s in seqs])
    parents = HUMANEVA_PARENTS[1:]
    return np.linalg.norm(frames[:, 1:] - frames[:, parents], axis=-1).mean(axis=0)


def retarget(seq: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """(T, 15, 3) -> (T, 15, 3): the pose rebuilt from the root outwards, each bone along its direction in
    ``seq`` with the length ``lengths[j - 1]`` (HumanEva-I's joint order lists every parent before its child)."""
    seq = np.asarray(seq, dtype=np.float64)
    out = np.empty_like(seq)
    out[:, 0] = seq[:, 0]
    for j in range(1, HUMANEVA_NUM_JOINTS):
        p = HUMANEVA_PARENTS[j]
        bone = seq[:, j] - seq[:, p]
        out[:, j] = out[:, p] + lengths[j - 1] * bone / np.linalg.norm(bone, axis=-1, keepdims=True)
    return out


def resample(seq: np.ndarray, src_fps: float, dst_fps: float) -> np.ndarray:
    """(T, ...) sampled at ``src_fps`` -> the same motion at ``dst_fps`` (linear interpolation between frames),
    over the same span: frames at 0, 1 / dst_fps, ... up to the last source frame."""
    seq = np.asarray(seq)
    t = np.arange(int(np.floor((len(seq) - 1) * dst_fps / src_fps + 1e-9)) + 1) * (src_fps / dst_fps)
    i = np.minimum(np.floor(t).astype(np.int64), len(seq) - 2)
    w = (t - i).reshape((-1,) + (1,) * (seq.ndim - 1))
    return (1.0 - w) * seq[i] + w * seq[i + 1]


def h36m_as_humaneva(subjects=H36M_EXTRA_SUBJECTS, h36m_data=None, humaneva_path=None) -> dict[str, np.ndarray]:
    """Human3.6M's sequences of ``subjects`` in a HumanEva-I model's space: ``{"S1/walking_1": (T, 14, 3)
    float32 metres at 60 Hz}``.

    Forward kinematics of the exp-map data at its 50 Hz with the root's translation and rotation removed (as
    Human3.6M's own pipeline does: the body's frame, so no turning), the 15 joints HumanEva-I's layout stands
    for on the 32-joint skeleton (``tcd.layouts.HUMANEVA15``), Human3.6M's +y up turned to HumanEva-I's +z up
    (a proper rotation: left stays left), resampled to 60 Hz, every bone set to the mean length of the Train
    split's (Human3.6M's hips are twice as wide and its head a third shorter), then root-relative."""
    from tcd.layouts import HUMANEVA15

    from .h36m import DEFAULT_H36M_DIR, SOURCE_FPS, H36MSource, expmap_to_xyz32

    subjects = tuple(int(s) for s in subjects)
    if not subjects or set(subjects) - set(H36M_EXTRA_SUBJECTS):
        raise ValueError(
            f"Human3.6M subjects for a HumanEva-I model must be among {list(H36M_EXTRA_SUBJECTS)}, got {list(subjects)}"
        )
    lengths = bone_lengths(load_humaneva(humaneva_file(humaneva_path), "Train").values())
    source = H36MSource(h36m_data or DEFAULT_H36M_DIR)
    ids = list(HUMANEVA15.to32)
    out = {}
    for key in sorted(source.keys):
        subj, rest = key.split("/")
        if int(subj[1:]) not in subjects:
            continue
        action, sub = rest.rsplit("_", 1)
        xyz = expmap_to_xyz32(source.raw(int(subj[1:]), action, int(sub)), sample_rate=1)[:, ids] / 1000.0
        z_up = np.stack([xyz[..., 0], -xyz[..., 2], xyz[..., 1]], axis=-1)  # +90 degrees about x
        out[key] = root_relative(retarget(resample(z_up, SOURCE_FPS, HUMANEVA_FPS), lengths)).astype(np.float32)
    return out


def training_mix(
    h36m_share: float, window: int, path=None, subjects=HUMANEVA_TRAIN_SUBJECTS, h36m_data=None
) -> list[np.ndarray]:
    """HumanEva-I's training chunks (:func:`training_sequences`) and, when ``h36m_share`` > 0, Human3.6M's
    retargeted sequences (:func:`h36m_as_humaneva`), the chunks listed ``r`` times over so that a uniform draw
    of the windows of ``window`` frames comes from Human3.6M with probability ``h36m_share`` (as near as a
    whole ``r`` allows): the training loops draw windows uniformly and need no change."""
    target = list(training_sequences(path, subjects).values())
    check_h36m_share(h36m_share, "humaneva", "training_mix")
    if h36m_share == 0.0:
        return target
    extra = list(h36m_as_humaneva(H36M_EXTRA_SUBJECTS, h36m_data, path).values())
    count = lambda seqs: sum(max(len(s) - window + 1, 0) for s in seqs)  # noqa: E731
    n_target, n_extra = count(target), count(extra)
    if not n_target:
        raise ValueError(f"no HumanEva-I training window of {window} frames")
    r = max(1, round((1.0 - h36m_share) / h36m_share * n_extra / n_target))
    return target * r + extra


def mix_description(h36m_share: float, subjects=HUMANEVA_TRAIN_SUBJECTS) -> str:
    """The ``training_data`` line of a model's metadata for a HumanEva-I training mix."""
    line = f"HumanEva-I Train split, {','.join(f'S{s}' for s in subjects)} (60 Hz)"
    if h36m_share > 0.0:
        line += (
            f" + Human3.6M {','.join(f'S{s}' for s in H36M_EXTRA_SUBJECTS)} retargeted to its skeleton "
            f"({h36m_share:g} of the windows)"
        )
    return line
