"""training.augment: heading and mirror augmentation of training windows."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import import_torch

import_torch("training.augment is imported through the training package")
from training.augment import check_axis, mirror, mirror_permutation, rotate_about  # noqa: E402


def test_rotation_about_the_vertical_keeps_heights_and_shapes():
    rng = np.random.default_rng(0)
    wins = rng.normal(size=(6, 5, 4, 3)).astype(np.float32)
    out = rotate_about(wins, "z", np.random.default_rng(1))
    np.testing.assert_array_equal(out[..., 2], wins[..., 2])                       # heights untouched
    d = lambda x: np.linalg.norm(x[:, :, :, None] - x[:, :, None], axis=-1)     # noqa: E731
    np.testing.assert_allclose(d(out), d(wins), atol=1e-5)                          # a rigid motion
    assert not np.allclose(out, wins)
    # one angle per window, the same for all its frames and joints
    theta = np.random.default_rng(1).uniform(0, 2 * np.pi, 6)
    c, s = np.cos(theta[1]), np.sin(theta[1])
    np.testing.assert_allclose(out[1, 3, 2, :2], [c * wins[1, 3, 2, 0] - s * wins[1, 3, 2, 1],
                                                  s * wins[1, 3, 2, 0] + c * wins[1, 3, 2, 1]], atol=1e-5)


def test_mirror_swaps_left_and_right_through_a_vertical_plane():
    names = ("thorax", "left_hand", "right_hand", "head")
    perm = mirror_permutation(names)
    np.testing.assert_array_equal(perm, [0, 2, 1, 3])
    rng = np.random.default_rng(0)
    wins = rng.normal(size=(4, 5, 4, 3)).astype(np.float32)
    which = np.array([True, False, True, False])
    out = mirror(wins, "z", perm, which)
    np.testing.assert_array_equal(out[~which], wins[~which])                       # the others untouched
    # z (vertical) and x kept, y negated; the left hand is where the right one was, reflected
    np.testing.assert_array_equal(out[0, :, 1], wins[0, :, 2] * np.array([1, -1, 1], np.float32))
    np.testing.assert_array_equal(out[0, :, 0], wins[0, :, 0] * np.array([1, -1, 1], np.float32))
    np.testing.assert_array_equal(mirror(out, "z", perm, which), wins)            # its own inverse
    d = lambda x: np.linalg.norm(x[:, :, :, None] - x[:, :, None], axis=-1)     # noqa: E731
    np.testing.assert_allclose(d(out[which])[:, :, perm][:, :, :, perm], d(wins[which]), atol=1e-6)  # relabelled
    with pytest.raises(ValueError, match="left_foot"):
        mirror_permutation(("left_foot", "right_hand", "left_hand"))


def test_prior_batches_mirror_and_need_the_vertical():
    from training.prior import PriorConfig, batch
    with pytest.raises(ValueError, match="mirror_prob"):
        PriorConfig(dataset="humaneva", subjects=(1, 2, 3), mirror_prob=0.5)
    rng = np.random.default_rng(0)
    frames = rng.normal(size=(200, 42)).astype(np.float32)
    base = dict(dataset="humaneva", subjects=(1, 2, 3), obs_len=15, chunk=15, batch_size=64, rotate_axis="z")
    plain = batch(PriorConfig(**base), frames, np.arange(170), 5).numpy().reshape(64, 30, 14, 3)
    mir = batch(PriorConfig(**base, mirror_prob=0.5), frames, np.arange(170), 5).numpy().reshape(64, 30, 14, 3)
    same = np.all(mir == plain, axis=(1, 2, 3))
    assert 16 < int((~same).sum()) < 48                   # about half of 64 mirrored
    # the same windows, the same headings: the mirrored ones are the plain ones mirrored
    from training.data.humaneva import HUMANEVA_MODEL_JOINT_NAMES
    perm = mirror_permutation(HUMANEVA_MODEL_JOINT_NAMES)
    np.testing.assert_array_equal(mirror(plain, "z", perm, ~same), mir)


def test_rotation_axis_is_checked():
    check_axis("", "cfg")
    check_axis("y", "cfg")
    with pytest.raises(ValueError, match="rotate_axis"):
        check_axis("up", "cfg")


def test_training_batches_turn_the_windows_and_keep_every_other_draw():
    """A diffusion run with rotate_axis draws the same windows, masks, steps and noise as without it; only the
    poses are turned (about z: heights equal, horizontal distances to the root kept)."""
    import torch
    from training.batches import BatchSource, Windows
    from training.train import TrainConfig
    rng = np.random.default_rng(0)
    seqs = [rng.normal(size=(40, 22, 3)).astype(np.float32) for _ in range(3)]
    wins = Windows(seqs, 12, 1)
    plain = TrainConfig(role="long", obs_len=8, pred_len=4, batch_size=5,
                        mask_mix=[["none", 1.0], ["random_joints", 1.0]])
    turned = TrainConfig(**{**plain.__dict__, "rotate_axis": "z"})
    a = BatchSource(plain, wins, 50, 10).batch(2, 3)
    b = BatchSource(turned, wins, 50, 10).batch(2, 3)
    for i in (2, 3, 4):                                   # mask, t, eps
        assert torch.equal(a[i], b[i])
    xa, xb = (x.reshape(5, 22, 3, 12) for x in (a[0], b[0]))   # (B, J, 3, L)
    assert torch.equal(xa[:, :, 2], xb[:, :, 2]) and not torch.allclose(xa, xb)
    torch.testing.assert_close(xa[:, :, :2].norm(dim=2), xb[:, :, :2].norm(dim=2))
    with pytest.raises(ValueError, match="rotate_axis"):
        TrainConfig(rotate_axis="vertical")
