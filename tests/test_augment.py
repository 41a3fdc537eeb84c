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
