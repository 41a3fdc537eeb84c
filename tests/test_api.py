"""The public Python API of `tcd`: reproducibility, invariants, units, masks, typed errors, weight-file
errors. Forecasts run DDIM with 1-3 steps on a tiny random-init model to stay fast."""

from __future__ import annotations

import dataclasses
import pydoc
import re
from pathlib import Path

import numpy as np
import pytest

import tcd

from conftest import import_torch
from fixtures_util import ALL_KERNELS, bad, config_of, copy_dir, poses, read_weights, with_config, write_weights
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tcd import SamplerOptions

FAST = dict(num_samples=2, sampler=SamplerOptions(sampler="ddim", num_inference_steps=3, eta=1.0))


@pytest.fixture()
def obs():
    return poses(np.random.default_rng(0))


# ------------------------------------------------------------------------------------ basics


def test_load_and_describe(tiny_model, tiny_model_dir):
    assert isinstance(tiny_model, tcd.TCD)
    assert (tiny_model.obs_len, tiny_model.horizon, tiny_model.num_joints) == (50, 25, 22)
    assert tiny_model.joint_names is not None and len(tiny_model.joint_names) == 22
    assert tiny_model.repair_model is None
    cfg = tiny_model.short.config
    assert cfg["role"] == "short" and cfg["window"] == {"obs_len": 50, "pred_len": 5, "seq_len": 55}
    d = tcd.engine.Denoiser.load(tiny_model_dir / "long.safetensors")
    assert (d.obs_len, d.seq_len, d.num_features, d.num_joints, d.role) == (55, 75, 66, 22, "long")
    assert d.config["model"]["channels"] == 16 and d.num_train_timesteps == 50
    d.config["model"]["channels"] = 0  # a copy: the model's config is not mutable from outside
    assert d.config["model"]["channels"] == 16
    assert isinstance(tcd.__version__, str) and tcd.__version__


def test_forecast_shapes_unbatched_and_batched(tiny_model, obs):
    f = tiny_model.forecast(obs, seed=1, **FAST)
    assert isinstance(f, tcd.Forecast) and f.seed == 1
    assert f.mean.shape == (25, 22, 3) and f.samples.shape == (2, 25, 22, 3) and f.repaired.shape == (50, 22, 3)
    assert f.mean.dtype == np.float32 and np.isfinite(f.samples).all() and np.isfinite(f.repaired).all()
    np.testing.assert_allclose(f.mean, f.samples.mean(axis=0), rtol=1e-5, atol=1e-5)
    batch = np.stack([obs, poses(np.random.default_rng(1))])
    fb = tiny_model.forecast(batch, seed=1, **FAST)
    assert fb.mean.shape == (2, 25, 22, 3) and fb.samples.shape == (2, 2, 25, 22, 3)
    assert fb.repaired.shape == (2, 50, 22, 3)
    # noise streams are per sequence: sequence 0 of a batch == the same sequence alone
    assert np.array_equal(fb.samples[:, 0], f.samples)
    assert np.array_equal(fb.repaired[0], f.repaired)


def test_one_length_rule(tiny_model, obs):
    """Without layout / fps as with them (tests/test_wild.py): a forecast conditions on the last obs_len frames,
    a shorter observation padded at the start with missing frames; ``repaired`` has the input's frames, those
    before the window as given. A repair takes at most one window, padded the same way."""
    kw = dict(FAST, seed=4)
    f = tiny_model.forecast(obs, **kw)
    longer = np.concatenate([poses(np.random.default_rng(5))[:9], obs])
    g = tiny_model.forecast(longer, **kw)
    assert np.array_equal(g.samples, f.samples) and np.array_equal(g.mean, f.mean)
    assert g.repaired.shape == (59, 22, 3) and np.array_equal(g.repaired[9:], f.repaired)
    assert np.array_equal(g.repaired[:9], longer[:9], equal_nan=True)
    padded = obs.copy()
    padded[:30] = np.nan
    for batch in (False, True):
        x, p = (obs[30:][None], padded[None]) if batch else (obs[30:], padded)
        short, full = tiny_model.forecast(x, **kw), tiny_model.forecast(p, **kw)
        assert short.mean.shape == full.mean.shape and np.array_equal(short.samples, full.samples)
        assert short.repaired.shape == x.shape and np.array_equal(short.repaired, full.repaired[..., 30:, :, :])
        r, rp = tiny_model.repair(x, **kw), tiny_model.repair(p, **kw)
        assert r.poses.shape == x.shape and np.array_equal(r.poses, rp.poses[..., 30:, :, :])
    one = tiny_model.forecast(obs[-1:], **kw)  # one frame: the rest is in-painted
    assert one.mean.shape == (25, 22, 3) and one.repaired.shape == (1, 22, 3)


def test_argument_types_match_their_checks():
    """The Literal types of the signatures list what the runtime checks accept."""
    import typing

    from numpy.typing import ArrayLike

    from tcd._interpolation import INTERPOLATIONS, Interpolation
    from tcd._poses import UNIT_SCALE, Units
    from tcd._model import FILLS, Fill

    assert typing.get_args(Units) == tuple(UNIT_SCALE)
    assert typing.get_args(Interpolation) == INTERPOLATIONS
    assert typing.get_args(Fill) == FILLS
    for call in (tcd.TCD.forecast, tcd.TCD.repair, tcd.TCD.predict):
        hints = typing.get_type_hints(call)
        assert hints["obs"] == ArrayLike and hints["mask"] == typing.Optional[ArrayLike] and hints["units"] == Units
    assert typing.get_type_hints(tcd.TCD.repair)["return"] is tcd.Repair
    assert typing.get_type_hints(tcd.repair)["return"] is tcd.Repair
    assert typing.get_type_hints(tcd.interpolate)["method"] == Interpolation
    assert typing.get_type_hints(tcd.engine.cascade_raw)["observed"] == ArrayLike
    assert typing.get_type_hints(tcd.engine.Prior.predict)["obs"] == ArrayLike


def test_module_level_calls_have_the_methods_signatures():
    """tcd.forecast / predict / repair take exactly what the bundled model's method takes (its signature less
    ``self``), and no call takes loose keywords: a misspelt or removed argument is a TypeError."""
    import inspect

    for name in ("forecast", "predict", "repair"):
        method = inspect.signature(getattr(tcd.TCD, name))
        function = inspect.signature(getattr(tcd, name))
        assert list(method.parameters)[0] == "self"
        assert function == method.replace(parameters=list(method.parameters.values())[1:]), name
        assert function.return_annotation == method.return_annotation
        for sig in (method, function):
            kinds = {p.kind for p in sig.parameters.values()}
            assert inspect.Parameter.VAR_KEYWORD not in kinds and inspect.Parameter.VAR_POSITIONAL not in kinds, name
            assert "capture" in sig.parameters and not {"layout", "fps", "up"} & set(sig.parameters), name
        assert getattr(tcd, name).__name__ == name
    forecast = inspect.signature(tcd.TCD.forecast).parameters
    assert "mode" in forecast and not {"tempo", "generator_share"} & set(forecast)
    for name in ("predict", "repair"):
        assert "mode" not in inspect.signature(getattr(tcd.TCD, name)).parameters


def test_mode_and_capture_are_objects(tiny_model, obs):
    """A forecast's ``mode`` is a tcd.Cascade, tcd.Mixture or tcd.Tempo and its ``capture`` a tcd.Capture: a bare
    pair, share, name or layout is an error naming the argument, on a model and through the module-level calls."""
    for mode in ((0.8, 1.2), 0.5, "cascade", tcd.Cascade, tcd.Capture("h36m22")):
        bad("mode", tiny_model.forecast, obs, mode=mode, **FAST)
    bad("mode", tcd.forecast, obs, mode=(0.8, 1.2), **FAST)
    for call in (tiny_model.forecast, tiny_model.repair, tcd.forecast, tcd.repair):
        bad("capture", call, obs, capture="coco17", **FAST)
    bad("capture", tcd.predict, obs, capture="coco17")
    bad("capture", tiny_model.forecast, obs, capture=tcd.Tempo(0.8, 1.25), **FAST)
    for mode in (tcd.Cascade(), tcd.Mixture(0), tcd.Tempo(1, 1)):  # each the cascade alone
        np.testing.assert_array_equal(
            tiny_model.forecast(obs, mode=mode, seed=3, **FAST).samples,
            tiny_model.forecast(obs, seed=3, **FAST).samples,
        )
    with pytest.raises(TypeError):
        tcd.forecast(obs, tempo=(0.8, 1.2))
    with pytest.raises(TypeError):
        tcd.repair(obs, layout="coco17")


def test_the_modes_and_the_capture_are_exported():
    assert {"Capture", "Cascade", "Mixture", "Tempo"} <= set(tcd.__all__)
    for cls in (tcd.Capture, tcd.Cascade, tcd.Mixture, tcd.Tempo):
        assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen  # type: ignore[attr-defined]
    assert tcd.Cascade() == tcd.Cascade() and tcd.Mixture(0.5) != tcd.Mixture(0.25)
    assert tcd.Cascade().describe() == "the cascade"
    assert "0.5" in tcd.Mixture(0.5).describe()


def test_engine_names_live_in_tcd_engine_only():
    """One home per name: the engine-level API in tcd.engine, not in tcd; the modules no document presents
    are private by name."""
    import importlib

    engine = {
        "Denoiser",
        "Prior",
        "Generator",
        "cascade_raw",
        "repair_raw",
        "seeded_noise",
        "supported_kernels",
        "STAGE_SHORT",
        "STAGE_LONG",
        "STAGE_GENERATOR",
    }
    assert set(tcd.engine.__all__) == engine and all(hasattr(tcd.engine, n) for n in engine)
    for name in engine:
        assert not hasattr(tcd, name), name
    assert {"engine", "Repair"} <= set(tcd.__all__) and all(hasattr(tcd, n) for n in tcd.__all__)
    for old in ("denoiser", "prior", "wild_calls", "poses", "resample", "progress", "files", "interpolation"):
        assert not hasattr(tcd, old), old
        with pytest.raises(ModuleNotFoundError):
            importlib.import_module(f"tcd.{old}")


def test_supported_kernels_and_default():
    ks = tcd.engine.supported_kernels()
    assert ks[0] == "portable" and set(ks) <= set(ALL_KERNELS)
    assert ks == [k for k in ALL_KERNELS if k in ks]


def test_forecast_times_follow_the_models_frame_rate(tiny_model, tiny_model_dir, tmp_path, obs):
    """Forecast.times are (k + 1) / fps; a model that records no frame rate gets None, not a made-up rate."""
    f = tiny_model.forecast(obs, seed=1, **FAST)
    np.testing.assert_allclose(f.times, np.arange(1, 26) / tiny_model.fps)
    d = copy_dir(tiny_model_dir, tmp_path / "no_fps")
    for role in ("short", "long"):
        tensors, meta = read_weights(d / f"{role}.safetensors")
        cfg = config_of(meta)
        cfg.get("data", {}).pop("fps", None)
        write_weights(d / f"{role}.safetensors", tensors, with_config(meta, cfg))
    m = tcd.load(d)
    assert m.fps is None and m.forecast(obs, seed=1, **FAST).times is None


def test_same_seed_identical_different_seed_differs(tiny_model, obs):
    a = tiny_model.forecast(obs, seed=7, **FAST)
    b = tiny_model.forecast(obs, seed=7, **FAST)
    c = tiny_model.forecast(obs, seed=8, **FAST)
    assert np.array_equal(a.samples, b.samples) and np.array_equal(a.repaired, b.repaired)
    assert not np.array_equal(a.samples, c.samples)
    assert not np.array_equal(a.repaired, c.repaired)


def test_seed_none_is_drawn_and_recorded(tiny_model, obs):
    a = tiny_model.forecast(obs, **FAST)
    b = tiny_model.forecast(obs, **FAST)
    assert isinstance(a.seed, int) and 0 <= a.seed < 2**64 and a.seed != b.seed
    again = tiny_model.forecast(obs, seed=a.seed, **FAST)
    assert np.array_equal(again.samples, a.samples)


def test_one_thread_equals_two_threads(tiny_model, obs):
    batch = np.stack([obs, poses(np.random.default_rng(3))])
    one = tiny_model.forecast(batch, seed=5, threads=1, **FAST)
    two = tiny_model.forecast(batch, seed=5, threads=2, **FAST)
    assert np.array_equal(one.samples, two.samples) and np.array_equal(one.repaired, two.repaired)
    threaded = tcd.load(tiny_model.path, threads=2).forecast(batch, seed=5, **FAST)
    assert np.array_equal(one.samples, threaded.samples)


def test_ddpm_default_runs_all_steps(tmp_path, obs):
    """The default sampler (no ``sampling.json``) is DDPM over every training step (a T = 10 model keeps this fast):
    num_inference_steps=T is the same thing, fewer steps are respaced DDPM, more are an error."""
    import_torch("writing a T = 10 model (training/export.py)")
    from training.diffusion import DiffusionConfig
    from training.export import random_init_dir

    m = tcd.load(random_init_dir(tmp_path / "t10", "tiny", seed=1, diff_cfg=DiffusionConfig(num_train_timesteps=10)))
    assert m.num_train_timesteps == 10
    a = m.forecast(obs, seed=2, num_samples=1)
    b = m.forecast(obs, seed=2, num_samples=1, sampler=SamplerOptions(num_inference_steps=10))
    c = m.forecast(obs, seed=2, num_samples=1, sampler=SamplerOptions(num_inference_steps=5))
    assert np.array_equal(a.samples, b.samples) and not np.array_equal(a.samples, c.samples)
    e = bad("num_inference_steps", m.forecast, obs, sampler=SamplerOptions(num_inference_steps=11))
    assert "1..10" in str(e)


def test_observed_entries_unchanged(tiny_model, obs):
    f = tiny_model.forecast(obs, seed=3, **FAST)
    seen = ~np.isnan(obs)
    assert (~seen).any() and seen.any()
    assert np.array_equal(f.repaired[seen], obs[seen])  # bit-identical
    assert np.isfinite(f.repaired[~seen]).all()
    # float64 input: float64 output, observed entries still bit-identical
    obs64 = obs.astype(np.float64) + 1e-9
    f64 = tiny_model.forecast(obs64, seed=3, **FAST)
    assert f64.mean.dtype == np.float64 and f64.repaired.dtype == np.float64
    assert np.array_equal(f64.repaired[seen], obs64[seen])


def test_units_mm_is_1000x_metres(tiny_model, obs):
    m = tiny_model.forecast(obs, seed=4, **FAST)
    mm = tiny_model.forecast(obs * 1000.0, seed=4, units="mm", **FAST)
    # float32 rounding of the unit conversion: 1e-4 relative, plus 1e-6 of the largest value (in mm)
    atol = 1e-6 * np.abs(mm.samples).max()
    np.testing.assert_allclose(mm.samples, 1000.0 * m.samples, rtol=1e-4, atol=atol)
    np.testing.assert_allclose(mm.mean, 1000.0 * m.mean, rtol=1e-4, atol=atol)
    np.testing.assert_allclose(mm.repaired, 1000.0 * m.repaired, rtol=1e-4, atol=atol)
    seen = ~np.isnan(obs)
    assert np.array_equal(mm.repaired[seen], (obs * 1000.0)[seen])
    assert not np.allclose(mm.samples, m.samples)  # really in other units


def test_joint_mask_equals_coordinate_mask(tiny_model, obs):
    rng = np.random.default_rng(9)
    joint_mask = (rng.random((50, 22)) > 0.3).astype(np.float32)
    full = np.repeat(joint_mask[..., None], 3, axis=-1)
    x = np.nan_to_num(obs, nan=0.5)
    a = tiny_model.forecast(x, joint_mask, seed=6, **FAST)
    b = tiny_model.forecast(x, full, seed=6, **FAST)
    c = tiny_model.forecast(x, full.astype(bool), seed=6, **FAST)
    assert np.array_equal(a.samples, b.samples) and np.array_equal(a.samples, c.samples)
    assert np.array_equal(a.repaired, b.repaired)


def test_nan_equals_mask(tiny_model, obs):
    missing = np.isnan(obs)
    mask = (~missing).astype(np.float32)
    filled = np.where(missing, np.float32(0.7), obs)  # values under mask 0 are ignored
    a = tiny_model.forecast(obs, seed=8, **FAST)
    b = tiny_model.forecast(filled, mask, seed=8, **FAST)
    c = tiny_model.forecast(obs, mask, seed=8, **FAST)  # NaN and mask together
    assert np.array_equal(a.samples, b.samples) and np.array_equal(a.samples, c.samples)
    assert np.array_equal(a.repaired, b.repaired)
    # a mask can also hide values that are present
    d = tiny_model.forecast(filled, np.ones_like(mask), seed=8, **FAST)
    assert not np.array_equal(a.samples, d.samples)


def test_repair(tiny_model, obs):
    kw = dict(num_samples=2, sampler=SamplerOptions(sampler="ddim", num_inference_steps=3))
    out = tiny_model.repair(obs, seed=1, **kw)
    assert isinstance(out, tcd.Repair) and out.seed == 1
    assert repr(out) == "Repair(poses=(50, 22, 3), seed=1)"
    r = out.poses
    seen = ~np.isnan(obs)
    assert r.shape == obs.shape and np.isfinite(r).all()
    assert np.array_equal(r[seen], obs[seen])
    again = tiny_model.repair(obs, seed=1, **kw).poses
    assert np.array_equal(r, again)
    batch = tiny_model.repair(obs[None], seed=1, **kw).poses
    assert batch.shape == (1, 50, 22, 3) and np.array_equal(batch[0], r)
    # seed=None draws one, recorded as Forecast.seed is: passing it back reproduces the result
    drawn = tiny_model.repair(obs, **kw)
    assert isinstance(drawn.seed, int) and 0 <= drawn.seed < 2**64
    assert np.array_equal(tiny_model.repair(obs, seed=drawn.seed, **kw).poses, drawn.poses)


def test_repair_uses_repair_model_when_present(tiny_model_dir, tmp_path, obs):
    d = copy_dir(tiny_model_dir, tmp_path / "with_repair")
    tensors, meta = read_weights(d / "short.safetensors")
    cfg = config_of(meta)
    cfg["role"], cfg["window"] = "repair", {"obs_len": 50, "pred_len": 0, "seq_len": 50}
    tensors = {k: (v * np.float32(1.5) if k.endswith("output_projection2.weight") else v) for k, v in tensors.items()}
    write_weights(d / "repair.safetensors", tensors, with_config(meta, cfg))
    m = tcd.load(d)
    assert m.repair_model is not None and m.repair_model.role == "repair"
    kw = dict(seed=1, num_samples=1, sampler=SamplerOptions(sampler="ddim", num_inference_steps=2))
    with_repair = m.repair(obs, **kw).poses
    without = tcd.load(tiny_model_dir).repair(obs, **kw).poses
    seen = ~np.isnan(obs)
    assert np.array_equal(with_repair[seen], without[seen])
    assert not np.array_equal(with_repair[~seen], without[~seen])


def test_dpmpp2m_forecast_and_repair(tiny_model, obs):
    """DPM-Solver++(2M) through the public API: reproducible, observed entries kept, one noise block."""
    kw = dict(seed=3, num_samples=2, sampler=SamplerOptions(sampler="dpmpp2m", num_inference_steps=3))
    f = tiny_model.forecast(obs, **kw)
    assert f.samples.shape == (2, 25, 22, 3) and np.isfinite(f.samples).all()
    assert np.array_equal(f.samples, tiny_model.forecast(obs, **kw).samples)
    assert not np.array_equal(f.samples, tiny_model.forecast(obs, **dict(kw, seed=4)).samples)
    r = tiny_model.repair(obs, **kw).poses
    seen = ~np.isnan(obs)
    assert np.array_equal(r[seen], obs[seen]) and np.isfinite(r).all()
    assert tiny_model.short.num_noise_blocks(sampler=SamplerOptions(sampler="dpmpp2m", num_inference_steps=3)) == 1
    assert tiny_model.short.timesteps(
        sampler=SamplerOptions(sampler="dpmpp2m", num_inference_steps=3)
    ) == tiny_model.short.timesteps(sampler=SamplerOptions(sampler="ddim", num_inference_steps=3))


# ------------------------------------------------------------------------------------ low level


def test_denoiser_forward_and_seeded_noise(tiny_model_dir):
    d = tcd.engine.Denoiser.load(tiny_model_dir / "short.safetensors")
    rng = np.random.default_rng(0)
    x = rng.standard_normal((2, 66, 55)).astype(np.float32)
    m = (rng.random((2, 66, 55)) < 0.5).astype(np.float32)
    eps = d.forward(x, x, m, 10)
    assert eps.shape == (2, 66, 55) and eps.dtype == np.float32 and np.isfinite(eps).all()
    assert np.array_equal(eps[1:], d.forward(x[1:], x[1:], m[1:], 10))  # per-sequence
    assert not np.array_equal(eps, d.forward(x, x, m, 11))
    # float64 / non-contiguous inputs are converted
    assert np.array_equal(eps, d.forward(x.astype(np.float64), np.asfortranarray(x), m, 10))
    obs, mask = x[:1] * m[:1], m[:1]
    kw = dict(sampler="ddim", num_inference_steps=4, eta=1.0)
    noise = tcd.engine.seeded_noise(
        5, tcd.engine.STAGE_SHORT, 3, d.num_noise_blocks(sampler=SamplerOptions(**kw)), 1, 66, 55
    )
    assert np.array_equal(
        d.sample(obs, mask, 3, seed=5, sampler=SamplerOptions(**kw)),
        d.sample(obs, mask, 3, noise=noise, sampler=SamplerOptions(**kw)),
    )
    assert (
        d.timesteps(sampler=SamplerOptions(**kw))
        == d.timesteps(sampler=SamplerOptions(sampler="ddim", num_inference_steps=4, timestep_spacing="trailing"))
        == [49, 37, 24, 11]
    )
    assert d.timesteps() == list(range(49, -1, -1))


def test_stream_ids_per_sequence(tiny_model_dir):
    """``sequences`` gives each sequence its own stream: a batch numbered [7, 2] equals sequence 0 alone
    on stream 7 and sequence 1 alone on stream 2, and the engine checks one id per sequence."""
    d = tcd.engine.Denoiser.load(tiny_model_dir / "short.safetensors")
    rng = np.random.default_rng(1)
    m = (rng.random((2, 66, 55)) < 0.5).astype(np.float32)
    x = rng.standard_normal((2, 66, 55)).astype(np.float32) * m
    kw = dict(seed=3, sampler=SamplerOptions(sampler="ddim", num_inference_steps=3))
    both = d.sample(x, m, 2, sequences=[7, 2], **kw)
    assert np.array_equal(both[:, :1], d.sample(x[:1], m[:1], 2, first_sequence=7, **kw))
    assert np.array_equal(both[:, 1:], d.sample(x[1:], m[1:], 2, sequences=np.array([2]), **kw))
    assert not np.array_equal(both, d.sample(x, m, 2, **kw))
    o = x[:, :, :50]
    mo = m[:, :, :50]
    rep = tcd.engine.repair_raw(d, o, mo, num_samples=2, sequences=[1, 0], **kw)
    assert np.array_equal(
        rep["samples"][:, :1], tcd.engine.repair_raw(d, o[:1], mo[:1], num_samples=2, first_sequence=1, **kw)["samples"]
    )
    assert np.array_equal(
        rep["samples"][:, 1:], tcd.engine.repair_raw(d, o[1:], mo[1:], num_samples=2, **kw)["samples"]
    )
    bad("sequences", d.sample, x, m, 1, sequences=[1], **kw)  # one id for two sequences: the engine says so
    bad("sequences", d.sample, x, m, 1, sequences=[1, -2], **kw)
    bad("sequences", d.sample, x, m, 1, sequences=[[1, 2]], **kw)
    bad("sequences", d.sample, x, m, 1, sequences=[1, 2], first_sequence=4, **kw)
    bad(
        "sequences",
        d.sample,
        x,
        m,
        1,
        noise=np.zeros((1, 4, 2, 66, 55), np.float32),
        sequences=[1, 2],
        sampler=SamplerOptions(sampler="ddim", num_inference_steps=3),
    )


# ------------------------------------------------------------------------------------ property tests


@settings(
    max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow]
)
@given(
    batch=st.sampled_from([None, 1, 2]),
    missing=st.floats(0.0, 0.9),
    seed=st.integers(0, 2**64 - 1),
    mask_style=st.sampled_from(["nan", "joint", "coord"]),
    units=st.sampled_from(["m", "mm"]),
    data_seed=st.integers(0, 1000),
)
def test_property_shapes_and_observed_unchanged(tiny_model, batch, missing, seed, mask_style, units, data_seed):
    rng = np.random.default_rng(data_seed)
    x = poses(rng, batch, missing=missing)
    if units == "mm":
        x = x * np.float32(1000.0)
    joint_seen = ~np.isnan(x[..., 0])
    if not joint_seen.reshape(1 if batch is None else batch, -1).any(axis=-1).all():
        x[..., 0, 0, :] = 0.1  # keep at least one observed joint per sequence
        joint_seen = ~np.isnan(x[..., 0])
    mask = None
    if mask_style == "joint":
        mask = joint_seen.astype(np.float32)
        x = np.where(np.isnan(x), np.float32(-7.0), x)
    elif mask_style == "coord":
        mask = np.repeat(joint_seen[..., None], 3, axis=-1).astype(np.float32)
        x = np.where(np.isnan(x), np.float32(3.0), x)
    f = tiny_model.forecast(
        x, mask, seed=seed, num_samples=1, sampler=SamplerOptions(sampler="ddim", num_inference_steps=1), units=units
    )
    lead = () if batch is None else (batch,)
    assert f.mean.shape == (*lead, 25, 22, 3) and f.samples.shape == (1, *lead, 25, 22, 3)
    assert f.repaired.shape == x.shape and f.seed == seed
    assert np.isfinite(f.samples).all() and np.isfinite(f.repaired).all()
    seen = np.repeat(joint_seen[..., None], 3, axis=-1)
    assert np.array_equal(f.repaired[seen], x[seen])


# ------------------------------------------------------------------------------------ stubs


def test_native_stub_matches_the_module():
    """python/tcd/_native.pyi agrees with the compiled module: names, signatures (positional or keyword),
    defaults, classes, ``__all__``, by mypy's stubtest on the installed package (issue 30's stub gate: it found
    ``Denoiser.forward``'s ``threads`` declared positional in the stub, keyword-only in the binding)."""
    import os
    import subprocess
    import sys

    pytest.importorskip("mypy")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    # run from / so that `tcd` is the installed package with its compiled module, not the source tree
    r = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "tcd._native"],
        cwd="/",
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_bundled_repair_model():
    """The bundled directory carries a dedicated repair model (50 + 0 frames) conditioned on its learned repair
    fill (a prior with anchor "window" over the window); it fills an occluded window of the bundled demo clip,
    observed entries unchanged, with at most 0.75 x the error of linear interpolation."""
    if not (tcd.default_model_dir() / "repair.safetensors").is_file():
        pytest.skip("no bundled repair model in this build")
    from tcd._demo import load_clip

    m = tcd.load()
    r = m.repair_model
    assert r is not None and r.role == "repair" and (r.obs_len, r.pred_len, r.seq_len) == (50, 0, 50)
    assert r.config["model"]["cond_fill"] == "prior" and r.config["model"]["target"] == "prior_residual"
    assert m.repair_fill is not None and m.repair_fill.anchor == "window" and m.repair_fill.obs_len == 50
    clip = load_clip()["poses"][:50]
    rng = np.random.default_rng(0)
    mask = rng.random(clip.shape[:2]) >= 0.3
    mask[20:30] = False  # 10 dropped frames
    out = m.repair(
        clip, mask, num_samples=5, sampler=SamplerOptions(num_inference_steps=10, sampler="ddpm"), seed=0
    ).poses
    np.testing.assert_array_equal(out[mask], clip[mask])
    err_mm = np.linalg.norm(out - clip, axis=-1)[~mask].mean() * 1000
    # Against linear interpolation on the same gaps: the bundled model around its repair fill, the 10 frames filled
    # from the prior forecaster (gap_fill), measured 22.0 vs 46.6 mm (0.47x; the natural cubic spline 25.1 mm;
    # without the gap fill 23.6, its first installment 23.6 too); the spline-conditioned
    # one before it 25.6 mm (0.55x; its first stage 25.3 mm); the GPU-trained linear-residual model 32.8 mm
    # (0.70x); the first CPU repair model 47.7 mm (1.02x, with DDIM-10 x 2); the short-term model's in-painting,
    # before there was a repair model, 128.8 mm.
    lin = tcd.interpolate(clip, mask, method="linear")
    lin_mm = np.linalg.norm(lin - clip, axis=-1)[~mask].mean() * 1000
    assert np.isfinite(err_mm) and err_mm <= 0.75 * lin_mm, (err_mm, lin_mm)

    # num_samples=0: the repair fill alone, what the chains above started from (tcd.engine.Prior.fill with the
    # prior forecaster filling the dropped frames, then the two in-betweeners), whatever the seed and sampler;
    # measured 20.5 mm here (21.6 before the in-betweeners; the mean of 5 samples above 21.1, 22.1 before)
    fill = m.repair(clip, mask, num_samples=0, seed=0).poses
    assert np.array_equal(
        m.repair(
            clip, mask, num_samples=0, seed=1, sampler=SamplerOptions(sampler="ddim", num_inference_steps=3)
        ).poses,
        fill,
    )
    keep = np.repeat(mask[..., None], 3, -1)
    flat = lambda a: np.ascontiguousarray(a, np.float32).reshape(1, 50, -1)  # noqa: E731
    want = m.repair_fill.fill(flat(np.where(keep, clip, 0.0)), flat(keep), forecaster=m.prior).reshape(clip.shape)
    assert np.array_equal(fill, want.astype(fill.dtype))
    np.testing.assert_array_equal(fill[mask], clip[mask])
    fill_mm = np.linalg.norm(fill - clip, axis=-1)[~mask].mean() * 1000
    assert fill_mm <= 0.75 * lin_mm, (fill_mm, lin_mm)


def test_repair_of_no_samples_needs_a_repair_fill(tiny_model, obs):
    """num_samples=0 (the repair fill alone) on a model without a repair fill is an InvalidInputError naming
    num_samples, in TCD.repair and in repair_raw; negative counts are refused as before."""
    for call in (
        lambda: tiny_model.repair(obs, num_samples=0, seed=0),
        lambda: tcd.engine.repair_raw(
            tiny_model.short,
            np.zeros((1, tiny_model.short.num_features, tiny_model.obs_len), np.float32),
            np.ones((1, tiny_model.short.num_features, tiny_model.obs_len), np.float32),
            num_samples=0,
            seed=0,
        ),
        lambda: tiny_model.repair(obs, num_samples=-1, seed=0),
    ):
        with pytest.raises(tcd.InvalidInputError) as ei:
            call()
        assert ei.value.argument == "num_samples", ei.value
    with pytest.raises(tcd.InvalidInputError, match="repair fill"):
        tiny_model.repair(obs, num_samples=0, seed=0)
    # forecasting and sampling still need at least one sample
    with pytest.raises(tcd.InvalidInputError, match="at least 1"):
        tiny_model.forecast(obs, num_samples=0, seed=0)


def test_the_sampler_and_its_defaults(tiny_model, obs):
    """A field left out takes SamplerOptions' default; an engine call without a sampler runs that default, and a
    TCD call without one its directory's (here, without ``sampling.json``, the same: tests/test_sampling_defaults.py
    has the directories' own); timesteps and num_noise_blocks read the same object."""
    defaults = dataclasses.asdict(tcd.SamplerOptions())
    assert defaults == {
        "sampler": "ddpm",
        "num_inference_steps": None,
        "eta": 0.0,
        "timestep_spacing": "trailing",
        "noise_coupling": "independent",
    }
    short = tiny_model.short
    assert short.timesteps() == short.timesteps(tcd.SamplerOptions(**defaults)) == list(range(49, -1, -1))
    assert short.num_noise_blocks() == 51
    o = SamplerOptions(sampler="ddim", num_inference_steps=3, eta=1.0)
    assert short.timesteps(o) == [49, 32, 16] and short.num_noise_blocks(sampler=o) == 4
    a = tiny_model.forecast(obs, num_samples=1, seed=4, sampler=SamplerOptions(num_inference_steps=3))
    b = tiny_model.forecast(
        obs, num_samples=1, seed=4, sampler=tiny_model.sampler_options("forecast", num_inference_steps=3)
    )
    assert np.array_equal(a.samples, b.samples)


def test_sampler_settings_have_one_form(tiny_model, obs, tmp_path):
    """One way in at every layer: ``sampler=``, a tcd.SamplerOptions. Loose sampler keywords are a TypeError
    (no catch-all takes them), anything else as ``sampler`` an InvalidInputError naming it, before any work; a
    bad field is refused when the object is made."""
    from tcd import _demo as demo
    from tcd._repair import RepairOptions

    d, long = tiny_model.short, tiny_model.long
    x, m = np.zeros((1, 66, 50), np.float32), np.ones((1, 66, 50), np.float32)
    calls = {
        "TCD.forecast": lambda **k: tiny_model.forecast(obs, **k),
        "TCD.repair": lambda **k: tiny_model.repair(obs, **k),
        "TCD.predict": lambda **k: tiny_model.predict(obs, **k),
        "Denoiser.sample": lambda **k: d.sample(np.zeros((1, 66, 55)), np.ones((1, 66, 55)), 1, seed=0, **k),
        "Denoiser.timesteps": d.timesteps,
        "Denoiser.num_noise_blocks": d.num_noise_blocks,
        "cascade_raw": lambda **k: tcd.engine.cascade_raw(d, long, x, m, seed=0, **k),
        "repair_raw": lambda **k: tcd.engine.repair_raw(d, x, m, seed=0, **k),
        "repair_file": lambda **k: tcd.repair_file(tmp_path / "in.npz", tmp_path / "out.npz", tiny_model, **k),
        "RepairOptions.make": lambda **k: RepairOptions.make(tiny_model, **k),
    }
    for name, call in calls.items():
        for key in ("num_inference_steps", "options"):
            with pytest.raises(TypeError, match=repr(key)):
                call(**{key: 3})
        if name != "TCD.predict":  # predict checks its model first (the tiny model has no prior)
            for value in ("ddim", {"sampler": "ddim"}):
                bad("sampler", call, sampler=value)
    with pytest.raises(TypeError):
        demo.run(tiny_model, quiet=True, num_inference_steps=3)
    assert not (tmp_path / "out.npz").exists()
    assert (
        RepairOptions.make(tiny_model, sampler=SamplerOptions(num_inference_steps=3)).sampling.num_inference_steps == 3
    )
    for kw, argument in (
        ({"sampler": "euler"}, "sampler"),
        ({"eta": 2.0}, "eta"),
        ({"num_inference_steps": 0}, "num_inference_steps"),
        ({"timestep_spacing": "x"}, "timestep_spacing"),
        ({"noise_coupling": "antithetic"}, "noise_coupling"),
    ):
        bad(argument, tcd.SamplerOptions, **kw)
    # more steps than the model was trained with: refused where the model samples
    bad("num_inference_steps", d.timesteps, SamplerOptions(num_inference_steps=51))


def test_sampler_options_are_checked_once_and_pickle(tiny_model, obs):
    """A SamplerOptions holds the engine's checked sampler from when it was made; pickled and copied it is made
    again from its fields (tcd repair --ray sends one to each worker) and samples the same."""
    import copy
    import pickle

    o = tcd.SamplerOptions(sampler="ddim", num_inference_steps=3, noise_coupling="centered")
    assert isinstance(o._engine, tcd._native.Sampler)
    for twin in (pickle.loads(pickle.dumps(o)), copy.deepcopy(o), dataclasses.replace(o)):
        assert twin == o and twin._engine is not o._engine
        a = tiny_model.forecast(obs, num_samples=2, seed=1, sampler=o).samples
        assert np.array_equal(a, tiny_model.forecast(obs, num_samples=2, seed=1, sampler=twin).samples)
    assert "_engine" not in repr(o) and "_engine" not in dataclasses.asdict(o)


def test_native_attributes_read_only_and_documented(tiny_model):
    """Denoiser's and Prior's attributes from the engine's model: the native values, read-only, each listed by
    help() with its type and text."""
    d = tiny_model.short
    names = (
        "path",
        "role",
        "num_features",
        "num_joints",
        "obs_len",
        "pred_len",
        "seq_len",
        "kernel",
        "num_train_timesteps",
    )
    text = pydoc.render_doc(tcd.engine.Denoiser, renderer=pydoc.plaintext)
    for name in names:
        assert getattr(d, name) == getattr(d._native, name)
        assert f"\n |  {name}\n |      {type(getattr(d, name)).__name__}: " in text, name
        with pytest.raises(AttributeError, match="read-only"):
            setattr(d, name, getattr(d, name))
    assert "int: Observed (conditioning) frames of the training window." in text
    text = pydoc.render_doc(tcd.engine.Prior, renderer=pydoc.plaintext)
    for name in ("path", "num_features", "num_joints", "obs_len", "chunk", "blocks", "kernel", "dct_matrix"):
        assert f"\n |  {name}\n |      " in text, name


def test_repair_package_holds_its_api_only():
    """tcd._repair's namespace is its __all__ (and its modules): no names kept under old homes."""
    import types

    import tcd._repair as br

    names = {n for n, v in vars(br).items() if not n.startswith("_") and not isinstance(v, types.ModuleType)}
    assert names - {"annotations"} == set(br.__all__)
    for old in ("cli", "CLI_USAGE", "add_subparser", "window_starts", "write_npz_atomic"):
        assert not hasattr(br, old), old


def test_every_module_without_an_underscore_is_listed_as_public():
    """A module of the package whose name has no leading underscore is public: docs/usage.md lists it in its
    "Public modules" table; every other module is private by name."""
    import pkgutil

    import tcd

    usage = (Path(__file__).resolve().parents[1] / "docs" / "usage.md").read_text()
    table = usage.split("## Public modules", 1)[1].split("\n## ", 1)[0]
    listed = set(re.findall(r"^\| `(tcd(?:\.[a-z_]+)*)` \|", table, re.M))
    public = {"tcd"} | {
        info.name
        for info in pkgutil.walk_packages(tcd.__path__, "tcd.")
        if not any(part.startswith("_") for part in info.name.split(".")[1:])
    }
    assert public == listed
