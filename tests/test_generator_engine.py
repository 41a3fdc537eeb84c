"""The MLP sample generator in the engine and the API (no torch): ``tcd.engine.Generator`` (its description,
seeded streams that depend neither on threads nor on the batch, bad arguments and files) and the mixture of
:meth:`tcd.TCD.forecast` (``mode=tcd.Mixture(share)``: the cascade's samples, then the generator's). On a small random
generator (2 x 32) written here with safetensors' numpy API into a copy of the committed tiny HumanEva-I model
(tests/fixtures/tiny_humaneva_model, with its random prior). Parity with the PyTorch reference:
tests/test_generator_parity.py."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import tcd
from conftest import FIXTURES
from fixtures_util import bad, read_weights, write_weights
from tcd.exceptions import InvalidInputError, WeightsError
from tcd import SamplerOptions

K, OBS, P, Z, C = 42, 15, 60, 64, 20


def write_generator(path: Path, hidden: int = 32, layers: int = 2, seed: int = 0, **model) -> Path:
    """A random generator file: normal weights of unit-gain scale, the head's scaled so that the samples lie a few
    tenths of a metre from the prior's forecast."""
    rng = np.random.default_rng(seed)
    m = {
        "num_joints": 14,
        "coords": 3,
        "num_features": K,
        "obs_len": OBS,
        "pred_len": P,
        "hidden": hidden,
        "layers": layers,
        "z_dim": Z,
        "coefs": C,
        **model,
    }
    tensors, width = {}, m["obs_len"] * m["num_features"] + m["coefs"] * m["num_features"] + m["z_dim"]
    for i in range(layers):
        tensors[f"layers.{i}.weight"] = rng.normal(0, 1 / np.sqrt(width), (hidden, width)).astype(np.float32)
        tensors[f"layers.{i}.bias"] = rng.normal(0, 0.1, hidden).astype(np.float32)
        width = hidden
    tensors["head.weight"] = rng.normal(0, 0.3 / np.sqrt(hidden), (m["coefs"] * m["num_features"], hidden))
    tensors["head.bias"] = rng.normal(0, 0.01, m["coefs"] * m["num_features"])
    cfg = {
        "format_version": 1,
        "role": "generator",
        "model": m,
        "data": json.loads((FIXTURES / "tiny_humaneva_model" / "model.json").read_text())["prior"]["data"],
        "training": {"random_init": True},
    }
    return write_weights(path, {k: v.astype(np.float32) for k, v in tensors.items()}, {"tcd_config": json.dumps(cfg)})


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory) -> Path:
    d = Path(shutil.copytree(FIXTURES / "tiny_humaneva_model", tmp_path_factory.mktemp("gen_model") / "m"))
    write_generator(d / "generator.safetensors")
    return d


@pytest.fixture(scope="module")
def model(model_dir):
    return tcd.load(model_dir)


def observation(batch: int = 3) -> np.ndarray:
    """(B, 15, 14, 3) float32 metres: windows of the bundled HumanEva-I demo clip."""
    from tcd import _demo as demo

    clip = demo.load_clip(demo.HUMANEVA_CLIP_PATH)["poses"].astype(np.float32)
    return np.stack([clip[s : s + OBS] for s in range(0, 20 * batch, 20)])


def test_description(model, model_dir):
    g = model.generator
    assert isinstance(g, tcd.engine.Generator) and model.forecast_mode == tcd.Cascade()
    assert (g.num_features, g.num_joints, g.obs_len, g.pred_len, g.hidden, g.layers, g.z_dim, g.coefs) == (
        K,
        14,
        OBS,
        P,
        32,
        2,
        Z,
        C,
    )
    assert g.config["role"] == "generator" and model.config["generator"] == g.config
    assert g.path == str(model_dir / "generator.safetensors") and "generator=True" in repr(model)
    assert "Generator(" in repr(g)


def test_seeded_samples_do_not_depend_on_threads_or_the_batch(model):
    g, prior = model.generator, model.prior
    obs = observation(3).reshape(3, OBS, K)
    fc = prior.predict(obs, P)
    a = g.sample(obs, fc, 4, seed=7, threads=1)
    assert a.shape == (4, 3, P, K) and a.dtype == np.float32 and np.isfinite(a).all()
    np.testing.assert_array_equal(a, g.sample(obs, fc, 4, seed=7, threads=2))
    np.testing.assert_array_equal(a[:, 2:], g.sample(obs[2:], fc[2:], 4, seed=7, first_sequence=2))
    np.testing.assert_array_equal(a[:, [2, 0]], g.sample(obs[[2, 0]], fc[[2, 0]], 4, seed=7, sequences=[2, 0]))
    assert np.abs(a - fc[None]).max() > 0.05 and np.ptp(a, axis=0).max() > 0.01  # the network moves them
    b = g.sample(obs, fc, 4, seed=8)
    assert not np.array_equal(a, b)
    longer = np.concatenate([np.zeros((3, 5, K), np.float32), obs], axis=1)  # its last 15 frames read
    np.testing.assert_array_equal(a, g.sample(longer, fc, 4, seed=7))


def test_bad_arguments(model):
    g = model.generator
    obs = observation(2).reshape(2, OBS, K)
    fc = model.prior.predict(obs, P)
    bad("obs", g.sample, obs[:, :, :30], fc, 2, seed=0)
    bad("obs", g.sample, obs[:, :10], fc, 2, seed=0)
    nan = obs.copy()
    nan[1, -1, 4] = np.nan
    bad("obs", g.sample, nan, fc, 2, seed=0)
    bad("prior", g.sample, obs, fc[:, :59], 2, seed=0)
    bad("prior", g.sample, obs, fc[:1], 2, seed=0)
    bad("num_samples", g.sample, obs, fc, 0, seed=0)
    bad("noise", g.sample, obs, fc, 2, noise=np.zeros((2, 2, Z - 1), np.float32))
    with pytest.raises(InvalidInputError):
        g.sample(obs, fc, 2)  # neither noise nor seed
    with pytest.raises(InvalidInputError):
        g.sample(obs, fc, 2, seed=0, noise=np.zeros((2, 2, Z), np.float32))


def test_bad_files(model_dir, tmp_path):
    f = model_dir / "generator.safetensors"
    with pytest.raises(WeightsError):  # a prior's file is no generator
        tcd.engine.Generator.load(model_dir / "prior.safetensors")
    with pytest.raises(WeightsError):  # nor a generator's a prior
        tcd.engine.Prior.load(f)
    tensors, meta = read_weights(f)
    del tensors["head.bias"]
    with pytest.raises(WeightsError, match="head.bias"):
        tcd.engine.Generator.load(write_weights(tmp_path / "g.safetensors", tensors, meta))
    with pytest.raises(WeightsError, match="coefs"):
        tcd.engine.Generator.load(write_generator(tmp_path / "c.safetensors", coefs=61))


def test_forecast_mixture_is_the_cascade_then_the_generator(model):
    """``tcd.Mixture(0.5)`` of 6 samples: the first 3 are the cascade's alone with 3 samples (the same seed),
    the last 3 the generator's of the observation and the prior's forecast of it (seeded alike); the mean is
    theirs; the default (the directory's share, 0 here) is the cascade alone."""
    obs = observation(2)
    kw = dict(seed=5, sampler=SamplerOptions(sampler="ddim", num_inference_steps=1))
    mixed = model.forecast(obs, num_samples=6, mode=tcd.Mixture(0.5), **kw)
    cascade = model.forecast(obs, num_samples=3, **kw)
    assert mixed.samples.shape == (6, 2, P, 14, 3)
    np.testing.assert_array_equal(mixed.samples[:3], cascade.samples)
    np.testing.assert_array_equal(mixed.repaired, cascade.repaired)
    x = obs.reshape(2, OBS, K)
    drawn = model.generator.sample(x, model.prior.predict(x, P), 3, seed=5).reshape(3, 2, P, 14, 3)
    np.testing.assert_allclose(mixed.samples[3:], drawn, rtol=0, atol=1e-7)
    np.testing.assert_allclose(mixed.mean, mixed.samples.mean(axis=0), rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(
        model.forecast(obs, num_samples=3, mode=tcd.Mixture(0), **kw).samples, cascade.samples
    )
    np.testing.assert_array_equal(model.forecast(obs, num_samples=3, mode=tcd.Cascade(), **kw).samples, cascade.samples)
    every = model.forecast(obs, num_samples=3, mode=tcd.Mixture(1.0), **kw)  # no cascade: the observation kept
    np.testing.assert_allclose(every.samples, drawn, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(every.repaired, obs)
    odd = model.forecast(obs, num_samples=5, mode=tcd.Mixture(0.5), **kw)  # floor(2.5) = 2 from the generator
    np.testing.assert_array_equal(odd.samples[:3], cascade.samples)


def test_the_share_from_sampling_json_and_bad_shares(model_dir, tmp_path):
    d = Path(shutil.copytree(model_dir, tmp_path / "m"))
    (d / "sampling.json").write_text(json.dumps({"forecast_generator_share": 0.5}))
    m = tcd.load(d)
    assert m.forecast_mode == tcd.Mixture(0.5)
    obs = observation(1)
    kw = dict(seed=1, sampler=SamplerOptions(sampler="ddim", num_inference_steps=1))
    np.testing.assert_array_equal(
        m.forecast(obs, num_samples=4, **kw).samples,
        m.forecast(obs, num_samples=4, mode=tcd.Mixture(0.5), **kw).samples,
    )
    for share in (1.5, -0.1, "half", True, np.nan, None):
        bad("share", tcd.Mixture, share)
    bad("mode", m.forecast, obs, mode=0.5)  # a share is a tcd.Mixture
    with pytest.raises(TypeError, match="generator_share"):
        m.forecast(obs, generator_share=0.5)
    # a mode replaces the directory's default mode: tempo sampling of the cascade alone on a model whose default
    # mixes in the generator, the same samples as on the model without that default
    tempo = m.forecast(obs, num_samples=4, mode=tcd.Tempo(0.8, 1.25), **kw)
    plain = tcd.load(model_dir)
    assert plain.forecast_mode == tcd.Cascade()
    np.testing.assert_array_equal(
        tempo.samples, plain.forecast(obs, num_samples=4, mode=tcd.Tempo(0.8, 1.25), **kw).samples
    )
    np.testing.assert_array_equal(
        m.forecast(obs, num_samples=4, mode=tcd.Tempo(1, 1), **kw).samples,
        plain.forecast(obs, num_samples=4, **kw).samples,
    )
    np.testing.assert_array_equal(
        m.forecast(obs, num_samples=4, mode=tcd.Cascade(), **kw).samples,
        plain.forecast(obs, num_samples=4, **kw).samples,
    )
    (d / "sampling.json").write_text(json.dumps({"forecast_generator_share": 2}))
    with pytest.raises(WeightsError, match="forecast_generator_share"):
        tcd.load(d)
    (d / "sampling.json").write_text(json.dumps({"forecast_generator_share": 0.5}))
    (d / "generator.safetensors").unlink()
    with pytest.raises(WeightsError, match="generator"):
        tcd.load(d)
    (d / "sampling.json").unlink()
    none = tcd.load(d)
    assert none.generator is None and none.forecast_mode == tcd.Cascade()
    e = bad("mode", none.forecast, obs, mode=tcd.Mixture(0.5))
    assert "generator" in str(e)
    # any share above 0, even one that draws no sample here (floor(2 * 0.1) = 0)
    bad("mode", none.forecast, obs, num_samples=2, mode=tcd.Mixture(0.1), **kw)
    np.testing.assert_array_equal(  # a share of 0 is the cascade
        none.forecast(obs, num_samples=2, mode=tcd.Mixture(0), **kw).samples,
        none.forecast(obs, num_samples=2, **kw).samples,
    )


def test_a_generator_that_does_not_fit_the_model_is_refused(model_dir, tmp_path):
    d = Path(shutil.copytree(model_dir, tmp_path / "m"))
    write_generator(d / "generator.safetensors", pred_len=50)
    with pytest.raises(WeightsError, match="pred_len"):
        tcd.load(d)
    write_generator(d / "generator.safetensors", num_joints=15, num_features=45)
    with pytest.raises(WeightsError, match="num_features"):
        tcd.load(d)


def test_the_constructor_takes_a_mode(model):
    """``TCD(..., mode=...)`` is the default :attr:`TCD.forecast_mode` (the cascade without one), checked when the
    model is made: a mode object, a mixture only with a generator; the old keywords are gone."""
    parts = dict(prior=model.prior, generator=model.generator)
    assert tcd.TCD(model.short, model.long, **parts).forecast_mode == tcd.Cascade()
    mixed = tcd.TCD(model.short, model.long, mode=tcd.Mixture(0.5), **parts)
    assert mixed.forecast_mode == tcd.Mixture(0.5)
    obs = observation(1)
    kw = dict(num_samples=4, seed=2, sampler=SamplerOptions(sampler="ddim", num_inference_steps=1))
    np.testing.assert_array_equal(
        mixed.forecast(obs, **kw).samples, model.forecast(obs, mode=tcd.Mixture(0.5), **kw).samples
    )
    assert tcd.TCD(model.short, model.long, mode=tcd.Tempo(0.8, 1.25), **parts).forecast_mode == tcd.Tempo(0.8, 1.25)
    bad("mode", tcd.TCD, model.short, model.long, mode=(0.8, 1.25), **parts)
    bad("mode", tcd.TCD, model.short, model.long, mode=0.5, **parts)
    with pytest.raises(WeightsError, match="generator"):
        tcd.TCD(model.short, model.long, prior=model.prior, mode=tcd.Mixture(0.5))
    for old in ({"forecast_tempo": (0.8, 1.25)}, {"generator_share": 0.5}):
        with pytest.raises(TypeError):
            tcd.TCD(model.short, model.long, **parts, **old)


def test_command_line_generator_share(model_dir, tmp_path, capsys):
    """``tcd forecast --generator-share F`` is the call's ``mode=tcd.Mixture(F)``; a bad share, a share on a model
    without a generator and a share with --tempo are exit code 2 naming the flag, with nothing written."""
    from tcd._cli import main

    src = tmp_path / "in.npz"
    np.savez(src, poses=observation(2))
    fast = ["--samples", "4", "--seed", "3", "--sampler", "ddim", "--steps", "1", "--quiet"]
    assert (
        main(
            [
                "forecast",
                str(src),
                "-o",
                str(tmp_path / "a.npz"),
                "--generator-share",
                "0.5",
                "--model",
                str(model_dir),
                *fast,
            ]
        )
        == 0
    )
    want = tcd.load(model_dir).forecast(
        observation(2),
        num_samples=4,
        seed=3,
        sampler=SamplerOptions(sampler="ddim", num_inference_steps=1),
        mode=tcd.Mixture(0.5),
    )
    with np.load(tmp_path / "a.npz") as f:
        np.testing.assert_array_equal(f["samples"], want.samples)
    capsys.readouterr()
    assert (
        main(
            [
                "forecast",
                str(src),
                "-o",
                str(tmp_path / "b.npz"),
                "--generator-share",
                "1.5",
                "--model",
                str(model_dir),
                *fast,
            ]
        )
        == 2
    )
    assert "--generator-share" in capsys.readouterr().err and not (tmp_path / "b.npz").exists()
    plain = Path(shutil.copytree(model_dir, tmp_path / "plain"))
    (plain / "generator.safetensors").unlink()
    assert (
        main(
            [
                "forecast",
                str(src),
                "-o",
                str(tmp_path / "c.npz"),
                "--generator-share",
                "0.5",
                "--model",
                str(plain),
                *fast,
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "--generator-share" in err and "generator" in err and not (tmp_path / "c.npz").exists()
    argv = ["forecast", str(src), "-o", str(tmp_path / "d.npz"), "--generator-share", "0.5", "--tempo", "0.8", "1.25"]
    assert main([*argv, "--model", str(model_dir), *fast]) == 2
    err = capsys.readouterr().err
    assert "--tempo" in err and "--generator-share" in err and not (tmp_path / "d.npz").exists()


@pytest.fixture(scope="module")
def generator_dir(model_dir, tmp_path_factory) -> Path:
    """A generator directory: the generator and its prior, no cascade (as the bundled Setting-A model)."""
    d = tmp_path_factory.mktemp("generator_dir") / "g"
    d.mkdir()
    for name in ("generator.safetensors", "prior.safetensors"):
        shutil.copy(model_dir / name, d / name)
    return d


def test_a_generator_directory_forecasts_with_the_generator_alone(model, generator_dir):
    """Without the cascade, a directory's forecasts are its generator's samples around its prior (``Mixture(1)``,
    its default): the same samples as ``Mixture(1)`` on a directory that has the cascade too; its window is the
    generator's, and its point forecast the prior's."""
    g = tcd.load(generator_dir)
    assert g.short is None and g.long is None and g.forecast_mode == tcd.Mixture(1.0)
    assert (g.obs_len, g.horizon, g.num_joints) == (OBS, P, K // 3) and g.num_train_timesteps is None
    assert g.fps == model.fps and g.joint_names == model.joint_names and set(g.config) == {"prior", "generator"}
    obs = observation(2)
    f = g.forecast(obs, num_samples=6, seed=4)
    want = model.forecast(obs, num_samples=6, seed=4, mode=tcd.Mixture(1.0))
    np.testing.assert_array_equal(f.samples, want.samples)
    np.testing.assert_array_equal(f.mean, want.mean)
    assert f.samples.shape == (6, 2, P, K // 3, 3)
    np.testing.assert_array_equal(g.predict(obs).mean, model.predict(obs).mean)
    assert "generator=True" in repr(g)


def test_a_generator_directory_refuses_what_needs_the_cascade(generator_dir, tmp_path):
    g = tcd.load(generator_dir)
    obs = observation(1)
    for mode in (tcd.Cascade(), tcd.Mixture(0.5), tcd.Tempo(0.8, 1.25)):
        assert "no" in str(bad("mode", g.forecast, obs, num_samples=4, seed=0, mode=mode))
    with pytest.raises(FileNotFoundError, match="cannot repair"):
        g.repair(obs)
    holed = obs.copy()
    holed[0, 3:5, 2] = np.nan
    with pytest.raises(FileNotFoundError, match="cannot repair"):
        g.predict(holed, fill="model")
    assert np.isfinite(g.predict(holed).mean).all()  # fill="auto": the spline
    d = Path(shutil.copytree(generator_dir, tmp_path / "g"))
    (d / "sampling.json").write_text(json.dumps({"forecast_generator_share": 0.5}))
    with pytest.raises(WeightsError, match="no cascade"):
        tcd.load(d)
    (d / "sampling.json").write_text(json.dumps({"forecast_generator_share": 1.0}))
    assert tcd.load(d).forecast_mode == tcd.Mixture(1.0)
    (d / "prior.safetensors").unlink()
    with pytest.raises(WeightsError, match="prior.safetensors is missing"):
        tcd.load(d)
    shutil.copy(FIXTURES / "tiny_humaneva_model" / "short.safetensors", d / "short.safetensors")
    with pytest.raises(FileNotFoundError, match="long.safetensors"):
        tcd.load(d)


def test_tcd_info_describes_a_generator_directory(generator_dir, capsys):
    from tcd._cli import main

    assert main(["info", "--model", str(generator_dir)]) == 0
    out = capsys.readouterr().out
    assert "short: none" in out and "long: none" in out and "generator: MLP" in out
    assert "default sampler" not in out and "the generator" in out
