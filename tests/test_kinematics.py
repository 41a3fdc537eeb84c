import json

import numpy as np

from conftest import H36M_DIR, needs_h36m
from training.data import h36m
from training.data.kinematics import expmap_to_rotmat, fk_expmap


def test_rotmat_is_rodrigues():
    R = expmap_to_rotmat(np.array([0.0, 0.0, np.pi / 2]))
    assert np.allclose(R, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    rs = expmap_to_rotmat(np.random.default_rng(0).normal(size=(10, 3)))
    assert np.allclose(rs @ np.swapaxes(rs, -1, -2), np.eye(3), atol=1e-12)
    assert np.allclose(expmap_to_rotmat(np.zeros(3)), np.eye(3))


def test_fk_on_a_hand_made_chain():
    # root -> a (child of the root keeps its raw offset) -> b -> c, row-vector convention
    parents = [-1, 0, 1, 2]
    offsets = np.array([[0, 0, 0], [1.0, 0, 0], [0, 2.0, 0], [0, 3.0, 0]])
    e = np.zeros((1, 4, 3))
    e[0, 1] = [0, 0, np.pi / 2]  # rotate joint a by 90 degrees about z
    pos = fk_expmap(e, parents, offsets)[0]
    # b = offset_b @ R_a + p_a = [0,2,0] @ Rz(90) + [1,0,0]; the row vector y maps to +x
    assert np.allclose(pos[1], [1, 0, 0])
    assert np.allclose(pos[2], [1 + 2, 0, 0])
    assert np.allclose(pos[3], [1 + 5, 0, 0])
    # the root's own rotation has no effect (root stays at the origin, its children keep raw offsets)
    e[0, 0] = [0.3, -1.0, 2.0]
    assert np.allclose(fk_expmap(e, parents, offsets)[0], pos)


def test_bone_lengths_preserved_on_random_poses():
    sk = h36m.skeleton()
    e = np.random.default_rng(1).normal(scale=0.5, size=(4, 32, 3))
    pos = fk_expmap(e, sk["parents"], sk["offsets_mm"])
    for j in range(1, 32):
        p = sk["parents"][j]
        assert np.allclose(
            np.linalg.norm(pos[:, j] - pos[:, p], axis=-1), np.linalg.norm(sk["offsets_mm"][j]), atol=1e-9
        )


def test_model_joint_mapping_round_trip():
    sk = h36m.skeleton()
    xyz = fk_expmap(np.zeros((2, 32, 3)), sk["parents"], sk["offsets_mm"])
    m = h36m.xyz32_to_model(xyz)
    assert m.shape == (2, 22, 3)
    back = h36m.model_to_xyz32(m, xyz)
    assert np.allclose(back[:, h36m.joints_used()], xyz[:, h36m.joints_used()], atol=1e-3)
    for dst, src in sk["joints_copied_at_evaluation"].items():
        assert np.array_equal(back[:, dst], back[:, src])


@needs_h36m
def test_packaged_skeleton_equals_the_data_copy():
    shared = json.loads((H36M_DIR / "skeleton32.json").read_text())
    ours = h36m.skeleton()
    assert shared["parents"] == list(ours["parents"])
    assert np.array_equal(np.asarray(shared["offsets_mm"]), ours["offsets_mm"])
    assert shared["joints_used_22"] == h36m.joints_used()
