"""TCD.predict / tcd.predict / `tcd forecast --point` (issue 28, part 4): the prior's point forecast with the
inputs of `forecast`, and repair-then-predict for observations with missing entries."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

import tcd
from tcd._cli import main as cli
from conftest import FIXTURES
from tcd.exceptions import InvalidInputError


@pytest.fixture(scope="module")
def model_dir(tiny_model_dir, tmp_path_factory):
    """The tiny cascade plus a prior with random (non-trivial) weights: the committed
    tests/fixtures/tiny_prior.safetensors (``training.prior_net.random_prior(blocks=2, seed=0)``)."""
    d = tmp_path_factory.mktemp("with_prior") / "m"
    shutil.copytree(tiny_model_dir, d)
    shutil.copyfile(FIXTURES / "tiny_prior.safetensors", d / "prior.safetensors")
    return d


@pytest.fixture(scope="module")
def model(model_dir):
    return tcd.load(model_dir)


def clip(batch: int = 0) -> np.ndarray:
    """Human-scale motion in the model's layout: the demo clip's first 50 frames (metres)."""
    poses = np.load(tcd.default_model_dir().parent / "data" / "demo_walking.npz")["poses"].astype(np.float32)
    if not batch:
        return poses[:50]
    return np.stack([poses[i * 5 : i * 5 + 50] for i in range(batch)])


def test_clean_observation_goes_to_the_prior_as_given(model):
    obs = clip()
    f = model.predict(obs)
    assert f.samples is None and f.mean.shape == (25, 22, 3) and f.times.shape == (25,)
    direct = model.prior.predict(obs.reshape(1, 50, 66), 25)[0].reshape(25, 22, 3)
    np.testing.assert_array_equal(f.mean, direct)
    np.testing.assert_array_equal(f.repaired, obs)
    assert np.abs(f.mean - obs[-1]).max() > 0.01  # the network moves the poses: not Zero-Velocity
    assert "samples=None" in repr(f)


def test_batches_and_units(model):
    obs = clip(batch=3)
    f = model.predict(obs)
    assert f.mean.shape == (3, 25, 22, 3)
    np.testing.assert_array_equal(f.mean[1], model.predict(obs[1]).mean)
    mm = model.predict(obs * 1000.0, units="mm")
    np.testing.assert_allclose(mm.mean, f.mean * 1000.0, rtol=1e-5, atol=1e-3)


def test_missing_entries_are_filled_before_the_prior(model):
    obs = clip()
    obs[20:25, 3] = np.nan
    obs[40:45] = np.nan
    spline = model.predict(obs, fill="spline")
    filled = tcd.interpolate(obs, method="spline")
    np.testing.assert_allclose(spline.repaired, filled, atol=1e-6)
    direct = model.prior.predict(filled.reshape(1, 50, 66).astype(np.float32), 25)[0].reshape(25, 22, 3)
    np.testing.assert_allclose(spline.mean, direct, atol=1e-5)
    # the tiny model directory has no repair model: auto is the spline
    np.testing.assert_array_equal(model.predict(obs, fill="auto").mean, spline.mean)
    # "model": the short-term model fills (seeded); observed entries come back as given
    a, b = model.predict(obs, fill="model", seed=7), model.predict(obs, fill="model", seed=7)
    np.testing.assert_array_equal(a.mean, b.mean)
    assert a.seed == 7
    seen = ~np.isnan(obs)
    np.testing.assert_array_equal(a.repaired[seen], obs[seen])
    assert not np.allclose(a.repaired, spline.repaired)


def test_the_length_rule_of_forecast(model):
    """Any length, as TCD.forecast: the last obs_len frames, a shorter observation padded with missing frames."""
    obs = clip()
    longer = np.concatenate([clip(batch=2)[1][:7], obs])
    f, g = model.predict(obs), model.predict(longer)
    np.testing.assert_array_equal(g.mean, f.mean)
    np.testing.assert_array_equal(g.repaired, np.concatenate([longer[:7], f.repaired]))
    padded = obs.copy()
    padded[:20] = np.nan
    for fill in ("spline", "model"):
        short, full = model.predict(obs[20:], fill=fill, seed=2), model.predict(padded, fill=fill, seed=2)
        np.testing.assert_array_equal(short.mean, full.mean)
        np.testing.assert_array_equal(short.repaired, full.repaired[20:])


def test_bad_fill_and_unfillable_joints(model):
    with pytest.raises(InvalidInputError) as e:
        model.predict(clip(), fill="cubic")
    assert e.value.argument == "fill"
    obs = clip()
    obs[:, 5] = np.nan  # joint 5 never observed: nothing to interpolate from
    with pytest.raises(InvalidInputError, match="never observed") as e:
        model.predict(obs, fill="linear")
    assert e.value.argument == "obs"
    assert np.isfinite(model.predict(obs, fill="model", seed=0).mean).all()


def test_a_directory_without_prior(tiny_model):
    with pytest.raises(FileNotFoundError, match="prior.safetensors"):
        tiny_model.predict(clip())


def test_other_frame_rates_and_layouts(model):
    obs = clip()
    f = model.predict(obs[::2], capture=tcd.Capture("h36m22", fps=12.5))  # half the model's rate: resampled both ways
    assert f.samples is None and f.mean.shape == (12, 22, 3)
    np.testing.assert_allclose(f.times, np.arange(1, 13) / 12.5)


def test_the_capture_is_a_capture_object(model):
    obs = clip()
    with pytest.raises(InvalidInputError) as e:
        model.predict(obs, capture="coco17")
    assert e.value.argument == "capture" and "`capture`" in str(e.value)
    with pytest.raises(TypeError, match="fps"):
        model.predict(obs[::2], fps=12.5)


def test_cli_point_forecast(model_dir, tmp_path, tiny_model_dir):
    np.savez(tmp_path / "in.npz", poses=clip(batch=2))
    assert (
        cli(
            [
                "forecast",
                str(tmp_path / "in.npz"),
                "-o",
                str(tmp_path / "out.npz"),
                "--model",
                str(model_dir),
                "--point",
                "--quiet",
            ]
        )
        == 0
    )
    with np.load(tmp_path / "out.npz") as z:
        assert "samples" not in z.files and z["mean"].shape == (2, 25, 22, 3)
        np.testing.assert_array_equal(z["mean"], tcd.load(model_dir).predict(clip(batch=2)).mean)
    assert (
        cli(
            [
                "forecast",
                str(tmp_path / "in.npz"),
                "-o",
                str(tmp_path / "o2.npz"),
                "--model",
                str(tiny_model_dir),
                "--point",
                "--quiet",
            ]
        )
        == 2
    )
    assert not (tmp_path / "o2.npz").exists()
