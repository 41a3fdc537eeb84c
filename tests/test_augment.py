"""training.augment: heading augmentation of training windows."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import import_torch

import_torch("training.augment is imported through the training package")
from training.augment import check_axis, rotate_about  # noqa: E402


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
