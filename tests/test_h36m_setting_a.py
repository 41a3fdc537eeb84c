"""Human3.6M Setting-A's data (training.data.h36m_setting_a): the world rotation integrated from the root's
increments, 16 root-relative joints in metres, DLow's test windows, and Zero-Velocity on them."""

import numpy as np
import pytest
from conftest import H36M_DIR, needs_h36m

from training.data import h36m_setting_a as A
from training.data.kinematics import expmap_to_rotmat


def test_world_rotation_integrates_the_root_increments():
    step = np.array([0.0, 0.1, 0.0])  # the same turn about the vertical every frame
    rows = np.zeros((4, 99))
    rows[:, 3:6] = step
    r = A.world_rotations(rows[:, 3:6])
    one = expmap_to_rotmat(step[None])[0]
    assert np.allclose(r[0], one) and np.allclose(r[3], np.linalg.matrix_power(one, 4))


def test_positions_are_16_root_relative_joints_in_the_world_rotation():
    rows = np.zeros((3, 99))
    rows[:, 0:3] = [100.0, 200.0, 300.0]  # the translation is removed
    still = A.setting_a_positions(rows)
    assert still.shape == (3, 16, 3) and np.allclose(still[0], still[2])
    rows[1:, 3:6] = [0.0, np.pi / 2, 0.0]  # a quarter turn at frame 1, another at frame 2
    turned = A.setting_a_positions(rows)
    # the body keeps its shape (its distances to the pelvis) and turns with the root
    assert np.allclose(np.linalg.norm(turned, axis=2), np.linalg.norm(still, axis=2))
    assert not np.allclose(turned[1], still[1]) and np.allclose(
        turned[2] @ expmap_to_rotmat(rows[2:3, 3:6])[0].T, turned[1]
    )
    with pytest.raises(ValueError, match="99 values"):
        A.setting_a_positions(np.zeros((3, 98)))


@needs_h36m
def test_the_test_windows_and_zero_velocity_on_them():
    """S9 and S11 give 4,313 windows of 125 frames; Zero-Velocity on them scores ADE 0.563 / FDE 0.834 (the L2 norm
    of the flattened 48-dim pose), our protocol's reference numbers."""
    windows, actions = A.setting_a_test_windows(A.setting_a_sequences(data_dir=H36M_DIR))
    assert windows.shape == (4313, 125, 16, 3) and len(actions) == 4313 and "walking" in actions
    flat = windows.reshape(len(windows), 125, 48)
    zv = np.repeat(flat[:, A.SETTING_A_T_HIS - 1 : A.SETTING_A_T_HIS], A.SETTING_A_T_PRED, axis=1)
    err = np.linalg.norm(zv - flat[:, A.SETTING_A_T_HIS :], axis=2)
    assert err.mean() == pytest.approx(0.563, abs=5e-4) and err[:, -1].mean() == pytest.approx(0.834, abs=5e-4)
    with pytest.raises(FileNotFoundError, match="subjects"):
        A.setting_a_sequences(subjects=(99,), data_dir=H36M_DIR)
