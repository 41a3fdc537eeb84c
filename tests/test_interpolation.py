"""`tcd.interpolate`: the engine's fills of missing values along time, checked against outside oracles
(numpy's `interp`, scipy's natural `CubicSpline`) and bit for bit against the PyTorch reference fills the
models are trained with (`training.model.linear_fill` / `spline_fill`; that comparison needs torch)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

import tcd
from conftest import import_torch
from fixtures_util import bad, poses


def gappy(seed: int = 0, batch: int | None = 3) -> np.ndarray:
    """Smooth random motion (metres) with 30 % of joints missing and one block of missing frames."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2, 40)[:, None, None]
    x = rng.normal(scale=0.3, size=(batch or 1, 1, 5, 3)) + 0.1 * np.sin(3 * t + rng.normal(size=(5, 3)))
    x = x.astype(np.float32)
    miss = rng.random(x.shape[:3]) < 0.3
    miss[:, 10:16] = True
    x[miss] = np.nan
    return x if batch else x[0]


def per_row(x: np.ndarray, fn) -> np.ndarray:
    """``fn(frames seen, values seen, all frames)`` for every (sequence, joint, coordinate) row of x."""
    out = x.astype(np.float64).copy()
    frames = np.arange(x.shape[1])
    for b in range(x.shape[0]):
        for j in range(x.shape[2]):
            for c in range(3):
                seen = ~np.isnan(x[b, :, j, c])
                if seen.any() and not seen.all():
                    out[b, ~seen, j, c] = fn(frames[seen], x[b, seen, j, c].astype(np.float64), frames[~seen])
    return out


def test_linear_equals_numpy_interp():
    x = gappy()
    want = per_row(x, lambda f, y, at: np.interp(at, f, y))  # np.interp holds the end values, as we do
    np.testing.assert_allclose(tcd.interpolate(x), want, rtol=1e-6, atol=1e-7)


def test_spline_equals_scipy_natural_cubic_spline():
    x = gappy(1)

    def natural(f, y, at):
        if len(f) < 2:
            return np.full(len(at), y[0])
        return CubicSpline(f, y, bc_type="natural")(np.clip(at, f[0], f[-1]))  # held outside the knots

    np.testing.assert_allclose(tcd.interpolate(x, method="spline"), per_row(x, natural), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("method", ["linear", "spline"])
def test_equals_the_training_fills_bit_for_bit(method):
    torch = import_torch("the PyTorch reference fills (training/model.py)")
    from training import model

    reference = getattr(model, f"{method}_fill")
    x = gappy(2)
    rows = torch.from_numpy(np.nan_to_num(x).transpose(0, 2, 3, 1).copy())  # (B, J, 3, T)
    mask = torch.from_numpy((~np.isnan(x)).transpose(0, 2, 3, 1).astype(np.float32).copy())
    want = reference(rows, mask).numpy().transpose(0, 3, 1, 2)
    got = tcd.interpolate(x, method=method)
    ok = ~np.isnan(got)  # rows never observed: NaN here, 0 in the conditioning channel
    np.testing.assert_array_equal(got[ok], want[ok])
    assert np.all(want[~ok] == 0)


def test_observed_values_dtype_and_unobserved_rows():
    x = gappy(3, batch=None).astype(np.float64)
    x[:, 2, 1] = np.nan  # one coordinate never observed
    out = tcd.interpolate(x)
    assert out.dtype == np.float64 and out.shape == x.shape
    seen = ~np.isnan(x)
    np.testing.assert_array_equal(out[seen], x[seen])  # bit for bit, not rounded to float32
    assert np.isnan(out[:, 2, 1]).all() and np.isnan(out).sum() == len(x)
    assert tcd.interpolate(np.ones((4, 2, 3), np.int64)).dtype == np.float64


def test_mask_equals_nan():
    x = gappy(4)
    joint_mask = (~np.isnan(x[..., 0])).astype(np.float32)
    filled_in = np.where(np.isnan(x), 123.0, x)  # values under mask 0 are never read
    np.testing.assert_array_equal(
        tcd.interpolate(filled_in, joint_mask, method="spline"), tcd.interpolate(x, method="spline")
    )


def test_bad_input():
    x = poses(np.random.default_rng(0))
    bad("method", tcd.interpolate, x, method="cubic")
    bad("method", tcd.interpolate, x, method=3)
    bad("poses", tcd.interpolate, x[..., :2])
    bad("poses", tcd.interpolate, np.full((5, 2, 3), np.nan))
    bad("mask", tcd.interpolate, x, np.ones((3, 3)))
    bad("mask", tcd.interpolate, x, np.full(x.shape[:2], 0.5))
