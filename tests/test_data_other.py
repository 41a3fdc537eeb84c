"""Tests of the AMASS, CMU and HumanEva loaders (training/data/{amass,cmu,humaneva}.py).

Data-free tests use small hand-made inputs. Tests on the real data (../shared/data, or the folder
named by TCD_DATA_DIR) skip when it is absent.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from conftest import DATA, needs_data
from training.data.amass import (
    JOINTS_AMASS_18,
    amass_sample_step,
    iter_windows,
    load_amass_file,
    load_smpl_skeleton,
)
from training.data.cmu import (
    CMU_JOINTS_USED_LTD,
    CMU_OFFSETS,
    CMU_PARENTS,
    expmap_to_positions_cmu,
    load_cmu_npz,
)
from training.data.humaneva import (
    humaneva_test_windows,
    load_humaneva,
    multimodal_gt,
    root_relative,
)
from training.data.kinematics import fk_axis_angle

AMASS_DIR = DATA / "amass_samples"
SKELETON = AMASS_DIR / "smpl_skeleton.npz"
CMU_FILE = DATA / "cmu" / "cmu_expmap_train.npz"
HUMANEVA_FILE = DATA / "humaneva" / "humaneva_i_15j_60hz.npz"

needs_amass = needs_data("amass_samples/smpl_skeleton.npz")
needs_cmu = needs_data("cmu/cmu_expmap_train.npz")
needs_humaneva = needs_data("humaneva/humaneva_i_15j_60hz.npz")

# SMPL-H kinematic tree (52 joints), used to build synthetic skeleton files.
SMPLH_PARENTS = np.array(
    [
        -1,
        0,
        0,
        0,
        1,
        2,
        3,
        4,
        5,
        6,
        7,
        8,
        9,
        9,
        9,
        12,
        13,
        14,
        16,
        17,
        18,
        19,
        20,
        22,
        23,
        20,
        25,
        26,
        20,
        28,
        29,
        20,
        31,
        32,
        20,
        34,
        35,
        21,
        37,
        38,
        21,
        40,
        41,
        21,
        43,
        44,
        21,
        46,
        47,
        21,
        49,
        50,
    ],
    dtype=np.int32,
)


def rot_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# --------------------------------------------------------------------------------------------------
# generic helpers


def test_fk_axis_angle_three_joint_chain():
    rest = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    parents = [-1, 0, 1]
    pose = np.zeros((3, 3, 3))
    pose[1, 1] = [0.0, 0.0, math.pi / 2]  # frame 1: elbow (joint 1) +90 deg about z
    pose[2, 0] = [0.0, 0.0, math.pi / 2]  # frame 2: root +90 deg about z
    out = fk_axis_angle(pose, rest, parents)
    np.testing.assert_allclose(out[0], rest, atol=1e-12)
    np.testing.assert_allclose(out[1], [[0, 0, 0], [1, 0, 0], [1, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(out[2], [[0, 0, 0], [0, 1, 0], [0, 2, 0]], atol=1e-12)


def test_iter_windows_counts_and_content():
    seq = np.arange(10)[:, None, None] * np.ones((10, 2, 3))
    wins = list(iter_windows(seq, 4, 3))
    assert [w[0, 0, 0] for w in wins] == [0, 3, 6]  # 6 + 4 = 10 fits exactly
    assert all(w.shape == (4, 2, 3) for w in wins)
    assert len(list(iter_windows(seq, 10, 1))) == 1
    assert len(list(iter_windows(seq, 11, 1))) == 0
    assert len(list(iter_windows(seq, 1, 1))) == 10


# --------------------------------------------------------------------------------------------------
# AMASS


def _write_skeleton(path: Path, rng) -> np.ndarray:
    rest = rng.normal(scale=0.3, size=(52, 3))
    rest[0] = [0.01, -0.2, 0.03]
    np.savez(path, p3d0=rest[None].astype(np.float32), parents=SMPLH_PARENTS)
    return rest.astype(np.float32).astype(np.float64)


@pytest.mark.parametrize(
    "framerate,fps,step",
    [(120.0, 25, 4), (120.00004577636719, 25, 4), (60.0, 25, 2), (100.0, 25, 4), (250.0, 25, 10), (30.0, 25, 1)],
)
def test_amass_sample_step(framerate, fps, step):
    assert amass_sample_step(framerate, fps) == step


def test_amass_zero_pose_gives_rest_skeleton(tmp_path):
    rng = np.random.default_rng(0)
    rest = _write_skeleton(tmp_path / "skel.npz", rng)
    T = 25
    poses = np.zeros((T, 156))
    poses[:, :3] = rng.normal(size=(T, 3))  # root orientation: must be ignored
    trans = rng.normal(size=(T, 3))  # translation: must be ignored
    np.savez(tmp_path / "seq.npz", poses=poses, trans=trans, mocap_framerate=np.float64(120.0))
    out = load_amass_file(tmp_path / "seq.npz", tmp_path / "skel.npz")
    assert out.shape == (7, 18, 3)  # frames 0, 4, ..., 24
    np.testing.assert_allclose(out, np.broadcast_to(rest[4:22], out.shape), atol=1e-6)


def test_amass_downsampling_picks_every_nth_frame(tmp_path):
    rng = np.random.default_rng(1)
    rest = _write_skeleton(tmp_path / "skel.npz", rng)
    T = 13
    poses = np.zeros((T, 156))
    angles = np.arange(T) * 0.1
    poses[:, 3 * 1 + 2] = angles  # left hip (joint 1): rotation about z growing with the frame index
    np.savez(tmp_path / "seq.npz", poses=poses, mocap_framerate=np.float64(60.0))
    out = load_amass_file(tmp_path / "seq.npz", tmp_path / "skel.npz", fps=25)  # step 2
    assert out.shape == (7, 18, 3)
    for k, frame in enumerate(range(0, T, 2)):
        R = rot_z(math.degrees(angles[frame]))
        knee = rest[1] + R @ (rest[4] - rest[1])  # joint 4 -> output 0
        ankle = rest[1] + R @ (rest[7] - rest[1])  # joint 7 -> output 3
        np.testing.assert_allclose(out[k, 0], knee, atol=1e-9)
        np.testing.assert_allclose(out[k, 3], ankle, atol=1e-9)
        np.testing.assert_allclose(out[k, 1], rest[5], atol=1e-9)  # right knee untouched


@needs_amass
def test_amass_real_skeleton_and_joint_names():
    rest, parents = load_smpl_skeleton(SKELETON)
    assert rest.shape == (52, 3) and parents.shape == (52,)
    np.testing.assert_array_equal(parents, SMPLH_PARENTS)
    for name, j in zip(JOINTS_AMASS_18, range(4, 22)):
        if name.startswith("left_"):
            assert rest[j, 0] > 0.02, name
        elif name.startswith("right_"):
            assert rest[j, 0] < -0.02, name
        else:
            assert abs(rest[j, 0]) < 0.02, name
    assert rest[15, 1] > rest[12, 1] > rest[9, 1] > rest[0, 1] > rest[4, 1] > rest[7, 1]  # head .. ankle


@needs_amass
@pytest.mark.parametrize("name", ["amass_sample_amassrepo", "amass_sample_hbp", "dmpl_sample_amassrepo"])
def test_amass_real_sample_bone_lengths(name):
    path = AMASS_DIR / f"{name}.npz"
    if not path.exists():
        pytest.skip(f"{path} not found")
    rest, parents = load_smpl_skeleton(SKELETON)
    with np.load(path) as d:
        n_frames = d["poses"].shape[0]
    out = load_amass_file(path, SKELETON)
    assert out.shape == (math.ceil(n_frames / 4), 18, 3)
    assert np.isfinite(out).all()
    checked = 0
    for j in range(4, 22):
        p = parents[j]
        if 4 <= p < 22:
            lengths = np.linalg.norm(out[:, j - 4] - out[:, p - 4], axis=-1)
            np.testing.assert_allclose(lengths, np.linalg.norm(rest[j] - rest[p]), atol=1e-6)
            checked += 1
    assert checked == 15  # all but joints 4, 5, 6 (parents 1, 2, 3 not kept)
    assert out.std(axis=0).max() > 0.01  # the sample does move


# --------------------------------------------------------------------------------------------------
# CMU


def _zero_pose_positions() -> np.ndarray:
    pos = np.zeros((38, 3))
    for j in range(1, 38):
        pos[j] = pos[CMU_PARENTS[j]] + CMU_OFFSETS[j]
    return pos


def test_cmu_skeleton_constants():
    assert CMU_PARENTS.shape == (38,) and CMU_OFFSETS.shape == (38, 3)
    assert CMU_PARENTS[0] == -1
    assert all(0 <= CMU_PARENTS[j] < j for j in range(1, 38))
    # Spot checks against LTD's _some_variables_cmu (70 x the ASF values).
    np.testing.assert_allclose(CMU_OFFSETS[3], [70 * 2.5972, -70 * 7.13576, 0.0])
    np.testing.assert_allclose(CMU_OFFSETS[37], [-70 * 0.59786, 0.0, 70 * 0.59786])
    assert list(CMU_PARENTS[[20, 27, 29, 36]]) == [15, 23, 15, 32]
    assert len(CMU_JOINTS_USED_LTD) == 25
    # Thigh and shin lengths (units ~ mm): about half a metre each.
    assert 450 < np.linalg.norm(CMU_OFFSETS[3]) < 600 and 450 < np.linalg.norm(CMU_OFFSETS[4]) < 600


def test_cmu_zero_pose_and_root_ignored():
    rng = np.random.default_rng(2)
    seq = np.zeros((11, 117), dtype=np.float32)
    seq[:, 0:6] = rng.normal(size=(11, 6)) * 10  # root position and rotation: zeroed by the loader
    out = expmap_to_positions_cmu(seq)
    assert out.shape == (6, 38, 3)  # frames 0, 2, ..., 10
    np.testing.assert_allclose(out, np.broadcast_to(_zero_pose_positions(), out.shape), atol=1e-9)
    assert expmap_to_positions_cmu(seq, sample_rate=1).shape == (11, 38, 3)


def test_cmu_expmap_column_convention():
    # Triplet j lives at columns 3 + 3j. Rotating joint 1 (the parent of joint 2) by +90 deg about z
    # moves joint 2 to offset_2 @ Rz (row-vector convention): (x, y, z) -> (y, -x, z).
    seq = np.zeros((1, 117))
    seq[0, 3 + 3 * 1 + 2] = math.pi / 2
    out = expmap_to_positions_cmu(seq, sample_rate=1)[0]
    ox, oy, oz = CMU_OFFSETS[2]
    np.testing.assert_allclose(out[2], [oy, -ox, oz], atol=1e-9)
    ref = _zero_pose_positions()
    np.testing.assert_allclose(out[7:], ref[7:], atol=1e-9)  # other leg, spine and arms unchanged
    # The same rotation on joint 2's own triplet moves its children but not joint 2.
    seq2 = np.zeros((1, 117))
    seq2[0, 3 + 3 * 2 + 2] = math.pi / 2
    out2 = expmap_to_positions_cmu(seq2, sample_rate=1)[0]
    np.testing.assert_allclose(out2[2], ref[2], atol=1e-9)
    ox3, oy3, oz3 = CMU_OFFSETS[3]
    np.testing.assert_allclose(out2[3], ref[2] + [oy3, -ox3, oz3], atol=1e-9)


def test_cmu_load_npz_roundtrip(tmp_path):
    a = np.random.default_rng(3).normal(size=(5, 117)).astype(np.float32)
    np.savez(tmp_path / "c.npz", **{"walking/walking_1": a, "running/running_2": a[:3]})
    d = load_cmu_npz(tmp_path / "c.npz")
    assert list(d) == ["walking/walking_1", "running/running_2"]
    assert d["running/running_2"].dtype == np.float32 and d["running/running_2"].shape == (3, 117)
    np.savez(tmp_path / "bad.npz", x=np.zeros((4, 99), dtype=np.float32))
    with pytest.raises(ValueError):
        load_cmu_npz(tmp_path / "bad.npz")


@needs_cmu
def test_cmu_real_bone_lengths():
    data = load_cmu_npz(CMU_FILE)
    assert len(data) >= 30
    assert all(k.split("/")[0] in k.split("/")[1] for k in data)
    bone = np.linalg.norm(CMU_OFFSETS[1:], axis=1)
    for key, seq in data.items():
        assert seq.dtype == np.float32 and seq.shape[1] == 117
        pos = expmap_to_positions_cmu(seq)
        assert pos.shape == ((seq.shape[0] + 1) // 2, 38, 3)
        assert np.isfinite(pos).all(), key
        lengths = np.linalg.norm(pos[:, 1:] - pos[:, CMU_PARENTS[1:]], axis=-1)
        np.testing.assert_allclose(lengths, np.broadcast_to(bone, lengths.shape), atol=1e-6, err_msg=key)
        np.testing.assert_allclose(pos[:, 0], 0.0)
    # The motion is not degenerate: the wrists move by decimetres over a sequence.
    pos = expmap_to_positions_cmu(data["walking/walking_1"])
    assert pos[:, CMU_JOINTS_USED_LTD].std(axis=0).max() > 50


# --------------------------------------------------------------------------------------------------
# HumanEva


def _chunks(lengths, seed=4):
    rng = np.random.default_rng(seed)
    return {
        f"Validate/S1/Box 1 chunk{i}": rng.normal(size=(n, 15, 3)).astype(np.float32) for i, n in enumerate(lengths)
    }


def test_humaneva_window_counts_and_root_relative():
    data = _chunks([74, 75, 76, 120, 200])
    w = humaneva_test_windows(data)
    # DLow: starts in range(0, T - 75, 15) -> 0, 0, 1, 3, 9 windows
    assert w.shape == (13, 75, 14, 3)
    seqs = list(data.values())
    np.testing.assert_allclose(w[0], seqs[2][0:75, 1:] - seqs[2][0:75, :1], atol=1e-6)
    np.testing.assert_allclose(w[3], seqs[3][30:105, 1:] - seqs[3][30:105, :1], atol=1e-6)
    np.testing.assert_allclose(w[-1], seqs[4][120:195, 1:] - seqs[4][120:195, :1], atol=1e-6)
    assert humaneva_test_windows(data, step=30).shape[0] == 0 + 0 + 1 + 2 + 5
    assert humaneva_test_windows(data, t_his=10, t_pred=20).shape == (5 + 5 + 5 + 9 + 17, 30, 14, 3)
    assert humaneva_test_windows(_chunks([30, 60])).shape == (0, 75, 14, 3)
    assert root_relative(np.zeros((2, 15, 3))).shape == (2, 14, 3)


def test_multimodal_gt_threshold_and_self():
    n, t_his, t_pred = 5, 3, 4
    rng = np.random.default_rng(5)
    windows = rng.normal(size=(n, t_his + t_pred, 2, 3))
    offsets = [0.0, 0.3, 0.6, 2.0, 2.5]  # last observed pose = offset on one coordinate, 0 elsewhere
    windows[:, t_his - 1] = 0.0
    for i, o in enumerate(offsets):
        windows[i, t_his - 1, 0, 0] = o
    mm = multimodal_gt(windows, t_his, threshold=0.5)
    expected = [[0, 1], [0, 1, 2], [1, 2], [3], [4]]  # 2.0 vs 2.5 is exactly 0.5: excluded (strict <)
    assert len(mm) == n
    flat = windows.reshape(n, t_his + t_pred, -1)
    for i, members in enumerate(expected):
        assert mm[i].shape == (len(members), t_pred, 6)
        np.testing.assert_array_equal(mm[i], flat[members, t_his:])
        assert any(np.array_equal(f, flat[i, t_his:]) for f in mm[i])  # the window itself
    assert [m.shape[0] for m in multimodal_gt(windows, t_his, threshold=10.0)] == [5] * 5


def test_load_humaneva_split_and_exclusions(tmp_path):
    rng = np.random.default_rng(6)
    arrays = {
        k: rng.normal(size=(80, 15, 3)).astype(np.float32)
        for k in [
            "Train/S1/Walking 1 chunk0",
            "Train/S3/Walking 1 chunk0",
            "Train/S3/Walking 1 chunk2",
            "Validate/S1/Jog 1 chunk0",
            "Validate/S3/Walking 1 chunk4",
            "Validate/S3/Walking 1 chunk2",
        ]
    }
    np.savez(tmp_path / "he.npz", **arrays)
    assert list(load_humaneva(tmp_path / "he.npz", "Train")) == ["Train/S1/Walking 1 chunk0"]
    assert list(load_humaneva(tmp_path / "he.npz", "Validate")) == [
        "Validate/S1/Jog 1 chunk0",
        "Validate/S3/Walking 1 chunk2",
    ]
    assert len(load_humaneva(tmp_path / "he.npz", "Validate", exclude_bad_takes=False)) == 3
    with pytest.raises(ValueError):
        load_humaneva(tmp_path / "he.npz", "Test")


@needs_humaneva
def test_humaneva_real_protocol():
    test = load_humaneva(HUMANEVA_FILE, "Validate")
    train = load_humaneva(HUMANEVA_FILE, "Train")
    assert "Validate/S3/Walking 1 chunk4" not in test and "Train/S3/Walking 1 chunk0" not in train
    assert all(k.startswith("Validate/") for k in test) and all(k.startswith("Train/") for k in train)
    w = humaneva_test_windows(test)
    expected_n = sum(max(0, math.ceil((v.shape[0] - 75) / 15)) for v in test.values())
    assert w.shape == (expected_n, 75, 14, 3) and expected_n > 100
    # root-relative: a body is about 1-2 m tall, so every joint lies within 1.5 m of the root
    assert np.abs(w).max() < 1.5
    mm = multimodal_gt(w, 15, threshold=0.5)
    flat = w.reshape(len(w), 75, 42)
    for i in range(len(w)):
        assert mm[i].ndim == 3 and mm[i].shape[1:] == (60, 42)
        assert any(np.array_equal(f, flat[i, 15:]) for f in mm[i])
    sizes = np.array([m.shape[0] for m in mm])
    assert sizes.min() >= 1 and sizes.max() > 1  # some windows do have several futures
