"""Tempo sampling (:mod:`tcd._tempo`): the observation replayed at each sample's tempo, the forecast read back on
the original clock, through ``TCD.forecast(mode=tcd.Tempo(lo, hi))`` and a model directory's ``sampling.json``
default."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import tcd
from fixtures_util import bad, poses
from tcd.exceptions import WeightsError
from tcd._tempo import check_tempo, tempi, tempo_forecast, unwarp_future, unwarp_history, warp
from tcd import SamplerOptions

K, T, H = 6, 15, 20


#: linear()'s default generator: one for the module, so successive calls draw different motions
_LINEAR_RNG = np.random.default_rng(0)


def linear(b: int, frames: np.ndarray, rng: np.random.Generator = _LINEAR_RNG):
    """(b, K, len(frames)) motion linear in time, each coordinate its own start and velocity."""
    start, vel = rng.normal(size=(b, K, 1)), rng.normal(size=(b, K, 1))
    return start + vel * frames, start, vel


def test_tempo_one_changes_nothing():
    x = np.random.default_rng(1).normal(size=(2, K, T))
    seen = (np.random.default_rng(2).random((2, K, T)) > 0.3).astype(np.float32)
    w, m = warp(x, seen, 1.0)
    assert np.array_equal(m, seen) and np.array_equal(w, np.where(seen > 0, x, 0.0))
    h, covered = unwarp_history(x, 1.0)
    assert np.array_equal(h, x) and covered.all()
    assert np.array_equal(unwarp_future(x[..., -1:], x, 1.0), x)


@pytest.mark.parametrize("s", [0.6, 0.8, 1.25, 1.6])
def test_linear_motion_warps_and_comes_back_exactly(s):
    """On motion linear in time every interpolation is exact: the warped observation moves at s times the
    velocity and ends where the observation ends; a forecast continuing it, read back, continues the original
    motion, up to frame s * H for s < 1, after which it holds."""
    x, start, vel = linear(3, np.arange(T, dtype=float))
    w, m = warp(x, np.ones_like(x), s)
    at = (T - 1) + s * (np.arange(T) - (T - 1))
    inside = at >= 0
    assert np.array_equal(m[..., ~inside], np.zeros_like(m[..., ~inside]))  # before frame 0: missing
    assert (m[..., inside] == 1).all()
    np.testing.assert_allclose(w[..., inside], (start + vel * at)[..., inside], atol=1e-12)
    # the forecast on the warped clock continues the warped motion: frame T - 1 + k is x at T - 1 + s k
    warped_future = start + vel * ((T - 1) + s * np.arange(1, H + 1))
    back = unwarp_future(w[..., -1:], warped_future, s)
    t = np.arange(1, H + 1)
    truth = start + vel * ((T - 1) + np.minimum(t, s * H))  # held after s * H
    np.testing.assert_allclose(back, truth, atol=1e-12)


def test_a_gap_stays_a_gap_after_warping():
    """An entry is observed only where both frames it reads are: a warped frame next to a gap is missing."""
    x = np.ones((1, K, T))
    seen = np.ones_like(x)
    seen[0, 2, 7] = 0.0
    _, m = warp(x, seen, 1.3)
    at = (T - 1) + 1.3 * (np.arange(T) - (T - 1))
    reads_7 = (np.floor(at) == 7) | ((np.floor(at) == 6) & (at > 6))
    assert (m[0, 2, reads_7] == 0).all() and reads_7.any()
    assert (m[0, [0, 1, 3, 4, 5]][:, at >= 0] == 1).all()


def test_tempo_forecast_reads_each_sample_back_on_its_own_clock():
    """With a forecaster that continues its observation's last velocity exactly (a stand-in for the cascade),
    every sample of linear motion is the motion's own continuation (held after s * H for s < 1); the repaired
    observation keeps the observed entries and fills a gap from the samples that cover it."""
    x, start, vel = linear(2, np.arange(T, dtype=float))
    seen = np.ones_like(x)
    seen[:, 1, 5] = 0.0
    calls = []

    def one(o, m, streams):  # per sequence: its last velocity continued; its repair: the missing entries linear too
        calls.append((o.shape, streams))
        v = o[..., -1:] - o[..., -2:-1]
        rep = np.where(m > 0, o, o[..., -1:] - v * (o.shape[-1] - 1 - np.arange(o.shape[-1])))
        return {"samples": (o[..., -1:] + v * np.arange(1, H + 1))[None], "repaired": rep}

    n = 5
    out = tempo_forecast(one, x, seen, n, (0.6, 1.6))
    assert calls == [((n * 2, K, T), [0, 5, 1, 6, 2, 7, 3, 8, 4, 9])]  # n * B; b * n + i
    assert out["samples"].shape == (n, 2, K, H) and out["mean"].shape == (2, K, H)
    t = np.arange(1, H + 1)
    for i, s in enumerate(tempi((0.6, 1.6), n)):
        np.testing.assert_allclose(out["samples"][i], start + vel * ((T - 1) + np.minimum(t, s * H)), atol=1e-9)
    np.testing.assert_allclose(out["mean"], out["samples"].mean(0))
    assert np.array_equal(out["repaired"][seen > 0], x[seen > 0])
    np.testing.assert_allclose(out["repaired"][:, 1, 5], x[:, 1, 5], atol=1e-9)


def test_tempi_are_geometric_and_include_both_ends():
    np.testing.assert_allclose(tempi((0.5, 2.0), 3), [0.5, 1.0, 2.0])
    assert tempi((0.6, 1.6), 1).tolist() == [1.0]


@pytest.mark.parametrize(
    "value", ["fast", (1.0,), (1.2, 2.0), (0.5, 0.9), (0.0, 1.0), (0.2, 1.5), (np.nan, 1.0), (1.0, True)]
)
def test_bad_tempo_is_an_error_naming_it(value):
    bad("tempo", check_tempo, value)


def test_check_tempo_takes_no_none():
    """None is no tempo range (a call without a mode takes the model's default, ``mode=None``)."""
    bad("tempo", check_tempo, None)


@pytest.mark.parametrize(
    "lo,hi", [(1.2, 2.0), (0.5, 0.9), (0.0, 1.0), (0.2, 1.5), (np.nan, 1.0), (1.0, True), ("fast", 1)]
)
def test_a_bad_tempo_mode_is_an_error_naming_it(lo, hi):
    bad("tempo", tcd.Tempo, lo, hi)


def test_tempo_mode_keeps_its_range_as_floats():
    t = tcd.Tempo(1, 2)
    assert (t.lo, t.hi) == (1.0, 2.0) and isinstance(t.lo, float) and isinstance(t.hi, float)
    assert t == tcd.Tempo(1.0, 2.0) and hash(t) == hash(tcd.Tempo(1.0, 2.0))
    assert t.describe() == "the cascade at tempi 1 to 2"


def test_forecast_with_tempo(tiny_model_dir):
    m = tcd.load(tiny_model_dir)
    assert m.forecast_mode == tcd.Cascade()
    obs = poses(np.random.default_rng(0), batch=2, missing=0.1)
    plain = m.forecast(obs, num_samples=4, seed=7, sampler=SamplerOptions(num_inference_steps=2))
    assert np.array_equal(
        plain.samples,
        m.forecast(
            obs, num_samples=4, seed=7, sampler=SamplerOptions(num_inference_steps=2), mode=tcd.Tempo(1, 1)
        ).samples,
    )
    a = m.forecast(obs, num_samples=4, seed=7, sampler=SamplerOptions(num_inference_steps=2), mode=tcd.Tempo(0.6, 1.6))
    b = m.forecast(obs, num_samples=4, seed=7, sampler=SamplerOptions(num_inference_steps=2), mode=tcd.Tempo(0.6, 1.6))
    assert a.samples.shape == plain.samples.shape and np.isfinite(a.samples).all()
    assert np.array_equal(a.samples, b.samples)  # seeded
    assert not np.allclose(a.samples, plain.samples)
    seen = np.isfinite(obs)
    np.testing.assert_allclose(a.repaired[seen], obs[seen], atol=1e-6)  # observed entries as given
    assert np.isfinite(a.repaired).all()
    # sequence b's samples do not depend on the batch's size or other sequences (streams b * n + i), as without
    # tempo sampling (stream b)
    alone = m.forecast(
        obs[:1], num_samples=4, seed=7, sampler=SamplerOptions(num_inference_steps=2), mode=tcd.Tempo(0.6, 1.6)
    )
    assert np.array_equal(alone.samples[:, 0], a.samples[:, 0])
    other = m.forecast(
        np.stack([obs[0], obs[0][::-1]]),
        num_samples=4,
        seed=7,
        sampler=SamplerOptions(num_inference_steps=2),
        mode=tcd.Tempo(0.6, 1.6),
    )
    assert np.array_equal(other.samples[:, 0], a.samples[:, 0])
    bad("tempo", tcd.Tempo, "fast", 1.6)
    bad("mode", m.forecast, obs, mode=(0.6, 1.6))  # a mode is a tcd.Tempo, not the pair
    with pytest.raises(TypeError, match="tempo"):
        m.forecast(obs, tempo=(0.6, 1.6))


def test_sampling_file_sets_the_default_tempo(tiny_model_dir, tmp_path):
    d = shutil.copytree(tiny_model_dir, tmp_path / "m")
    (d / "sampling.json").write_text(json.dumps({"why": "a test", "forecast_tempo": [0.7, 1.4]}))
    m = tcd.load(d)
    assert m.forecast_mode == tcd.Tempo(0.7, 1.4)
    obs = poses(np.random.default_rng(0), batch=2, missing=0.1)
    kw = dict(num_samples=3, seed=1, sampler=SamplerOptions(num_inference_steps=2))
    assert np.array_equal(m.forecast(obs, **kw).samples, m.forecast(obs, mode=tcd.Tempo(0.7, 1.4), **kw).samples)
    assert np.array_equal(
        m.forecast(obs, mode=tcd.Tempo(1, 1), **kw).samples, tcd.load(tiny_model_dir).forecast(obs, **kw).samples
    )
    assert np.array_equal(
        m.forecast(obs, mode=tcd.Cascade(), **kw).samples, tcd.load(tiny_model_dir).forecast(obs, **kw).samples
    )
    (d / "sampling.json").write_text(json.dumps({"forecast_tempo": [1.5, 2.0]}))
    with pytest.raises(WeightsError, match="forecast_tempo"):
        tcd.load(d)


def test_a_sampling_file_with_two_modes_is_a_weights_error(tiny_model_dir, tmp_path):
    """``"forecast_tempo"`` and ``"forecast_generator_share"`` name two default modes: a directory has one (even a
    share of 0 beside a tempo range)."""
    d = shutil.copytree(tiny_model_dir, tmp_path / "m")
    for share in (0.5, 0):
        (d / "sampling.json").write_text(json.dumps({"forecast_tempo": [0.7, 1.4], "forecast_generator_share": share}))
        with pytest.raises(WeightsError, match="forecast_tempo") as e:
            tcd.load(d)
        assert "forecast_generator_share" in str(e.value) and "sampling.json" in str(e.value)


def test_the_bundled_models_sample_no_tempi_by_default():
    """What the docs say (MODEL_CARD.md, "Tempo sampling": the samples' mean gets worse with it): the HumanEva-I
    model's default mode is its generator's mixture, the Human3.6M model's the cascade."""
    assert tcd.load(tcd.humaneva_model_dir()).forecast_mode == tcd.Mixture(0.5)
    assert tcd.load().forecast_mode == tcd.Cascade()


def test_command_line_tempo(tiny_model_dir, tmp_path, capsys):
    """``tcd forecast --tempo LO HI`` is the call's ``mode=tcd.Tempo(LO, HI)``; ``tcd info`` shows the default mode;
    a bad range is exit code 2 naming the flag, with nothing written."""
    from tcd._cli import main

    obs = poses(np.random.default_rng(0), batch=2, missing=0.1)
    src = tmp_path / "in.npz"
    np.savez(src, poses=obs)
    fast = ["--samples", "3", "--seed", "5", "--steps", "2", "--quiet", "--model", str(tiny_model_dir)]
    assert main(["forecast", str(src), "-o", str(tmp_path / "a.npz"), "--tempo", "0.7", "1.4", *fast]) == 0
    with np.load(tmp_path / "a.npz") as f:
        got = f["samples"]
    want = tcd.load(tiny_model_dir).forecast(
        obs, num_samples=3, seed=5, sampler=SamplerOptions(num_inference_steps=2), mode=tcd.Tempo(0.7, 1.4)
    )
    assert np.array_equal(got, want.samples)
    capsys.readouterr()
    assert main(["forecast", str(src), "-o", str(tmp_path / "b.npz"), "--tempo", "1.5", "2", *fast]) == 2
    assert "--tempo" in capsys.readouterr().err and not (tmp_path / "b.npz").exists()
    # --tempo and --generator-share name two modes: refused, naming both, nothing written
    assert (
        main(
            [
                "forecast",
                str(src),
                "-o",
                str(tmp_path / "c.npz"),
                "--tempo",
                "0.7",
                "1.4",
                "--generator-share",
                "0",
                *fast,
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "--tempo" in err and "--generator-share" in err and not (tmp_path / "c.npz").exists()
    assert main(["info", "--model", str(tiny_model_dir)]) == 0
    assert "default forecast mode: the cascade" in capsys.readouterr().out


def test_tempo_through_the_wild_path(tiny_model_dir):
    """Poses from the wild (``capture=tcd.Capture(layout, fps)``: resampled to the model's rate and back) take the
    same tempi: the samples come back in the caller's rate and shape, the observed frames as given."""
    m = tcd.load(tiny_model_dir)
    x = np.random.default_rng(0).normal(scale=0.3, size=(2, 60, 22, 3)).astype(np.float32)
    kw = dict(
        num_samples=3, seed=1, sampler=SamplerOptions(num_inference_steps=2), capture=tcd.Capture("h36m22", fps=50)
    )
    a, b = m.forecast(x, mode=tcd.Tempo(0.7, 1.4), **kw), m.forecast(x, **kw)
    assert a.samples.shape == b.samples.shape and np.isfinite(a.samples).all()
    assert not np.allclose(a.samples, b.samples)
    np.testing.assert_allclose(a.repaired, x, atol=1e-6)
