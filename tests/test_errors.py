"""Bad input and broken weight files: every refusal is a typed error (InvalidInputError or WeightsError,
both ValueError and TcdError) naming the argument or the file, raised before anything is computed."""

from __future__ import annotations

import math

import numpy as np
import pytest

import tcd
from tcd import _native
from tcd.exceptions import TcdError, WeightsError

from fixtures_util import bad, config_of, copy_dir, poses, read_weights, with_config, write_weights
from tcd import SamplerOptions


@pytest.fixture()
def obs():
    return poses(np.random.default_rng(0))


# ------------------------------------------------------------------------------------ bad input


def test_bad_obs(tiny_model, obs):
    e = bad("obs", tiny_model.forecast, obs[0])  # rank 2
    assert "(T, J, 3) or (B, T, J, 3)" in str(e) and "(22, 3)" in str(e)
    bad("obs", tiny_model.forecast, obs[None, None])  # rank 5
    e = bad("obs", tiny_model.forecast, obs[:, :21])  # joints
    assert "21 joints" in str(e) and "J = 22" in str(e)
    bad("obs", tiny_model.forecast, obs[..., :2])  # coordinates
    e = bad("obs", tiny_model.repair, np.concatenate([obs, obs[:1]]))  # a repair: one window at most
    assert "at most the model's window (50 frames)" in str(e) and "51 frames" in str(e)
    assert "tcd.repair_file" in str(e)
    e = bad("obs", tiny_model.forecast, np.concatenate([obs, np.full_like(obs, np.nan)]))  # nothing in its window
    assert "last 50 frames" in str(e) and "every value missing there" in str(e)
    e = bad(
        "obs",
        tiny_model.forecast,
        np.stack([np.concatenate([obs[:25], obs]), np.concatenate([obs[:25], np.full_like(obs, np.nan)])]),
    )
    assert "sequence 1 of `obs`" in str(e)
    x = obs.copy()
    x[3, 4, 1] = np.inf
    e = bad("obs", tiny_model.forecast, x)
    assert "inf" in str(e) and "(3, 4, 1)" in str(e)
    x[3, 4, 1] = -np.inf
    bad("obs", tiny_model.forecast, x)
    bad("obs", tiny_model.forecast, np.full((50, 22, 3), "a"))
    bad("obs", tiny_model.forecast, np.zeros((0, 50, 22, 3), np.float32))
    e = bad("obs", tiny_model.forecast, np.nan_to_num(obs) > 0)  # booleans are not coordinates
    assert "dtype bool" in str(e)
    bad("obs", tiny_model.forecast, obs.astype(np.complex64))


def test_poses_not_in_the_declared_units(tiny_model, obs):
    """Poses must measure like a person in the declared units (median distance of the observed joints from
    their frame's centroid within 0.01-3 m); otherwise `units` is named with the unit that fits."""
    for call in (tiny_model.forecast, tiny_model.repair):
        e = bad("units", call, obs * 1000)  # millimetres given as metres
        assert "pass units='mm'" in str(e)
        e = bad("units", call, obs, units="mm")  # metres given as millimetres
        assert "pass units='m'" in str(e)
        e = bad("units", call, obs * 1e30)
        assert "no supported unit fits" in str(e)
    spread = tcd._poses.spread_m(obs[None], ~np.isnan(obs[None]), "m")
    assert 0.1 < spread < 1.0  # the test poses: a person's size
    tiny_model.forecast(
        obs + 250.0, num_samples=1, sampler=SamplerOptions(num_inference_steps=1, sampler="ddim"), seed=0
    )  # far away: fine
    tiny_model.forecast(
        np.zeros((50, 22, 3)), num_samples=1, sampler=SamplerOptions(num_inference_steps=1, sampler="ddim"), seed=0
    )


def test_bad_mask(tiny_model, obs):
    x = np.nan_to_num(obs)
    ones = np.ones((50, 22, 3), np.float32)
    m = ones.copy()
    m[1, 2, 0] = 0.5
    e = bad("mask", tiny_model.forecast, x, m)
    assert "0.5" in str(e)
    for v in (2.0, -1.0, np.nan):
        m = ones.copy()
        m[0, 0, 0] = v
        bad("mask", tiny_model.forecast, x, m)
    bad("mask", tiny_model.forecast, x, np.ones((50, 22, 2)))
    bad("mask", tiny_model.forecast, x, np.ones((49, 22)))
    bad("mask", tiny_model.forecast, x, np.ones((1, 50, 22, 3)))
    # NaN where the mask says observed
    e = bad("obs", tiny_model.forecast, obs, ones)
    assert "NaN" in str(e) and "mask" in str(e)


def test_all_missing_is_an_error(tiny_model, obs):
    e = bad("obs", tiny_model.forecast, np.full_like(obs, np.nan))
    assert "every value is missing" in str(e)
    bad("mask", tiny_model.forecast, np.nan_to_num(obs), np.zeros((50, 22)))
    batch = np.stack([obs, np.full_like(obs, np.nan)])
    e = bad("obs", tiny_model.forecast, batch)
    assert "sequence 1" in str(e)
    bad("obs", tiny_model.repair, np.full_like(obs, np.nan))


@pytest.mark.parametrize(
    "argument,kwargs",
    [
        ("num_samples", {"num_samples": 0}),
        ("num_samples", {"num_samples": -2}),
        ("num_samples", {"num_samples": 1.5}),
        ("num_samples", {"num_samples": True}),
        ("num_samples", {"num_samples": 2**70}),  # beyond the binding's 64 bits: still a typed error
        ("num_inference_steps", {"num_inference_steps": 0}),
        ("num_inference_steps", {"num_inference_steps": -1}),
        ("num_inference_steps", {"num_inference_steps": 51}),
        ("num_inference_steps", {"num_inference_steps": 10.0}),
        ("sampler", {"sampler": "euler"}),
        ("sampler", {"sampler": None}),
        ("timestep_spacing", {"timestep_spacing": "middle"}),
        ("noise_coupling", {"noise_coupling": "antithetic"}),
        ("units", {"units": "inch"}),
        ("eta", {"eta": -0.1}),
        ("eta", {"eta": 1.5}),
        ("eta", {"eta": math.nan}),
        ("eta", {"eta": "0"}),
        ("seed", {"seed": -1}),
        ("seed", {"seed": 2**64}),
        ("seed", {"seed": 1.0}),
        ("seed", {"seed": 2**130}),
        ("threads", {"threads": 0}),
        ("threads", {"threads": 10**6}),
    ],
)
def test_bad_options(tiny_model, obs, argument, kwargs):
    """Each bad setting is an error naming it: a sampler field when the tcd.SamplerOptions is made (its step count
    against the model when the model samples), the others when the call is made."""
    import dataclasses

    if set(kwargs) <= {f.name for f in dataclasses.fields(tcd.SamplerOptions)}:
        for call in (tiny_model.forecast, tiny_model.repair):
            bad(argument, lambda call=call: call(obs, sampler=tcd.SamplerOptions(**kwargs)))
        return
    bad(argument, tiny_model.forecast, obs, **kwargs)
    bad(argument, tiny_model.repair, obs, **kwargs)


@pytest.mark.parametrize(
    "argument,make",
    [
        ("tempo", lambda: tcd.Tempo(1.2, 2.0)),
        ("tempo", lambda: tcd.Tempo(0.2, 1.5)),
        ("share", lambda: tcd.Mixture(1.5)),
        ("share", lambda: tcd.Mixture("half")),
        ("layout", lambda: tcd.Capture("openpose25")),
        ("fps", lambda: tcd.Capture("coco17", fps=0)),
        ("up", lambda: tcd.Capture("coco17", up="w")),
    ],
)
def test_bad_modes_and_captures_are_refused_when_made(argument, make):
    bad(argument, make)


def test_a_mode_or_capture_of_another_type_is_an_error_naming_it(tiny_model, obs):
    bad("mode", tiny_model.forecast, obs, mode=(0.8, 1.2))
    bad("mode", tiny_model.forecast, obs, mode={"mode": "cascade"})
    for call in (tiny_model.forecast, tiny_model.repair):
        bad("capture", call, obs, capture="coco17")
        bad("capture", call, obs, capture=("coco17", 25))
    with pytest.raises(TypeError, match="mode"):
        tiny_model.repair(obs, mode=tcd.Cascade())


def test_the_sampler_is_an_options_object(tiny_model, obs):
    """A call's sampler is a tcd.SamplerOptions: a name alone, a dict or loose sampler keywords are refused,
    the error naming ``sampler`` and showing how to make one."""
    e = bad("sampler", tiny_model.forecast, obs, sampler="ddim")
    assert "tcd.SamplerOptions(sampler='ddim')" in str(e)
    bad("sampler", tiny_model.repair, obs, sampler={"sampler": "ddim"})
    bad("sampler", tiny_model.short.timesteps, "ddpm")
    with pytest.raises(TypeError, match="num_inference_steps"):
        tiny_model.forecast(obs, num_inference_steps=3)


def test_settings_kept_for_later_are_checked_when_given(tiny_model_dir):
    """A thread count given to tcd.load, and tcd repair's options, are refused at once with the engine's rules
    (tcd._repair.RepairOptions is checked before any file is read)."""
    bad("threads", tcd.load, tiny_model_dir, threads=0)
    bad("threads", tcd.load, tiny_model_dir, threads=2000)
    m = tcd.load(tiny_model_dir)
    from tcd._repair import RepairOptions

    bad("seed", RepairOptions.make, m, seed=-1)
    bad("num_samples", RepairOptions.make, m, num_samples=0)
    bad("threads", RepairOptions.make, m, threads=0)


def test_bad_low_level_arguments(tiny_model_dir):
    d = tcd.engine.Denoiser.load(tiny_model_dir / "short.safetensors")
    x = np.zeros((1, 66, 55), np.float32)
    m = np.ones_like(x)
    bad("noisy", d.forward, np.zeros((66, 55), np.float32), x[0], m[0], 0)
    bad("noisy", d.forward, np.zeros((1, 65, 55), np.float32), x, m, 0)
    bad("observed", d.forward, x, x[:, :, :54], m, 0)
    bad("mask", d.forward, x, x, m[:, :, :54], 0)
    m2 = m.copy()
    m2[0, 0, 0] = 0.25
    bad("mask", d.forward, x, x, m2, 0)
    bad("step", d.forward, x, x, m, 50)
    bad("step", d.forward, x, x, m, -1)
    nan_obs = x.copy()
    nan_obs[0, 1, 2] = np.nan
    bad("observed", d.forward, x, nan_obs, m, 0)
    bad("noise", d.sample, x, m, 1, noise=np.zeros((1, 50, 1, 66, 55), np.float32))  # needs 51 blocks
    bad("noise", d.sample, x, m, 1, noise=np.zeros((1, 51, 1, 66, 55), np.float32), seed=1)
    bad("seed", d.sample, x, m, 1)
    bad("num_samples", d.sample, x, m, 0, seed=1)
    bad("num_samples", d.sample, x, m, 10**9, seed=1)  # refused up front, not a failed allocation
    bad("noise_short", tcd.engine.cascade_raw, d, d, x[:, :, :50], m[:, :, :50], seed=1, noise_short=np.zeros(3))
    bad("observed", tcd.engine.cascade_raw, d, d, x[:, :, :49], m[:, :, :49], seed=1)
    bad("long", tcd.engine.cascade_raw, d, d, x[:, :, :50], m[:, :, :50], seed=1)  # short model as long model


@pytest.mark.parametrize(
    "argument,kwargs",
    [
        ("num_samples", {"num_samples": 0}),
        ("num_samples", {"num_samples": -1}),
        ("num_inference_steps", {"num_inference_steps": 0}),
        ("num_inference_steps", {"num_inference_steps": 51}),
        ("sampler", {"sampler": "euler"}),
        ("timestep_spacing", {"timestep_spacing": "middle"}),
        ("noise_coupling", {"noise_coupling": "antithetic"}),
        ("eta", {"eta": 2.0}),
        ("eta", {"eta": math.nan}),
        ("threads", {"threads": 0}),
        ("threads", {"threads": 10**6}),
        ("seed", {}),
        ("seed", {"seed": -1}),
        ("seed", {"seed": 2**64}),
        ("first_sequence", {"first_sequence": -1}),
        ("num_samples", {"num_samples": 2**40}),
    ],
)
def test_native_errors_are_typed(tiny_model_dir, argument, kwargs):
    """The binding's own checks and the engine's errors (bypassing the Python layer) map onto
    tcd.exceptions too."""
    import dataclasses
    import types

    d = _native.Denoiser.load(str(tiny_model_dir / "short.safetensors"))
    x = np.zeros((1, 66, 55), np.float32)
    kw = dict(kwargs)
    if argument != "seed":
        kw.setdefault("seed", 1)
    n = kw.pop("num_samples", 1)
    # the sampler fields straight to the engine's sampler (tcd.SamplerOptions checks its Python types first)
    fields = [kw.pop(f.name, f.default) for f in dataclasses.fields(tcd.SamplerOptions)]
    if argument in {f.name for f in dataclasses.fields(tcd.SamplerOptions)} and argument != "num_inference_steps":
        bad(argument, _native.Sampler, *fields)
        return
    try:
        sampler = types.SimpleNamespace(_engine=_native.Sampler(*fields))
    except tcd.InvalidInputError as e:  # 0 steps: refused by the sampler itself; 51: by the model, below
        assert e.argument == argument
        return
    streams = {"seed": None, "first_sequence": 0, "sequences": None, "threads": None}
    streams.update(kw)
    call = {"observed": x, "mask": np.ones_like(x), "num_samples": n, "options": sampler}
    bad(argument, d.sample, {**call, "streams": streams, "progress": None})


def test_native_engine_error_mapping(tiny_model_dir):
    d = _native.Denoiser.load(str(tiny_model_dir / "short.safetensors"))
    x = np.zeros((1, 66, 55), np.float32)
    m = np.ones_like(x)
    m[0, 0, 0] = 0.5
    bad("mask", d.forward, x, x, m, 0)  # raised by tcd-core's validation
    with pytest.raises(FileNotFoundError):
        _native.Denoiser.load(str(tiny_model_dir / "nope.safetensors"))
    with pytest.raises(WeightsError):
        _native.Denoiser.from_bytes(b"\x00" * 16, "garbage")


# ------------------------------------------------------------------------------------ loading


def test_load_without_bundled_model_explains(tmp_path, monkeypatch):
    import tcd._directory
    import tcd._model

    monkeypatch.setattr(tcd._directory, "bundled_model_dir", lambda name: tmp_path)  # an installation without weights
    monkeypatch.setattr(tcd._model, "_default", None)
    with pytest.raises(FileNotFoundError, match="'h36m' is not bundled"):
        tcd.load()
    with pytest.raises(FileNotFoundError, match="pass a model directory"):
        tcd.forecast(np.zeros((50, 22, 3), np.float32))


def test_bundled_model_forecasts():
    if not (tcd.default_model_dir() / "short.safetensors").is_file():
        pytest.skip("no bundled model in this build")
    obs = np.zeros((50, 22, 3), np.float32)
    f = tcd.forecast(obs, num_samples=1, sampler=SamplerOptions(num_inference_steps=2, sampler="ddim"), seed=0)
    assert f.mean.shape == (25, 22, 3) and np.isfinite(f.mean).all()
    assert tcd.load().sha256 is not None


def test_load_missing_paths(tmp_path, tiny_model_dir):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        tcd.load(tmp_path / "nowhere")
    with pytest.raises(NotADirectoryError):
        tcd.load(tiny_model_dir / "short.safetensors")
    d = copy_dir(tiny_model_dir, tmp_path / "no_long")
    (d / "long.safetensors").unlink()
    with pytest.raises(FileNotFoundError, match="long.safetensors"):
        tcd.load(d)
    with pytest.raises(FileNotFoundError):
        tcd.engine.Denoiser.load(tmp_path / "missing.safetensors")
    with pytest.raises(WeightsError, match="is a directory"):  # a directory is not a weight file
        tcd.engine.Denoiser.load(tmp_path)
    bad("path", tcd.load, 42)


def broken_dir(tiny_model_dir, tmp_path, name, edit):
    """A copy of the model directory whose short.safetensors was changed by edit(path)."""
    d = copy_dir(tiny_model_dir, tmp_path / name)
    edit(d / "short.safetensors")
    return d


def truncate(path):
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def drop_tensor(path):
    tensors, meta = read_weights(path)
    del tensors["diffmodel.residual_layers.1.mid_projection.bias"]
    write_weights(path, tensors, meta)


def add_tensor(path):
    tensors, meta = read_weights(path)
    tensors["diffmodel.extra.weight"] = np.zeros((4, 4), np.float32)
    write_weights(path, tensors, meta)


def config_disagrees(path):
    tensors, meta = read_weights(path)
    cfg = config_of(meta)
    cfg["model"]["channels"] = 32  # the tensors are C = 16
    write_weights(path, tensors, with_config(meta, cfg))


def wrong_layer_count(path):
    tensors, meta = read_weights(path)
    cfg = config_of(meta)
    cfg["model"]["num_layers"] = 3
    write_weights(path, tensors, with_config(meta, cfg))


def wrong_dtype(path):
    tensors, meta = read_weights(path)
    tensors["embed_layer.weight"] = tensors["embed_layer.weight"].astype(np.float64)
    write_weights(path, tensors, meta)


def no_metadata(path):
    tensors, _ = read_weights(path)
    write_weights(path, tensors, {})


def bad_json(path):
    tensors, meta = read_weights(path)
    write_weights(path, tensors, {**meta, "tcd_config": "{not json"})


def garbage(path):
    path.write_bytes(b"this is not a safetensors file at all")


def nan_weight(path):
    tensors, meta = read_weights(path)
    w = tensors["diffmodel.diffusion_embedding.projection2.weight"].copy()
    w.flat[5] = np.nan  # one NaN: it used to load, and forecasts came back finite and wrong
    tensors["diffmodel.diffusion_embedding.projection2.weight"] = w
    write_weights(path, tensors, meta)


def inf_weight(path):
    tensors, meta = read_weights(path)
    w = tensors["embed_layer.weight"].copy()
    w.flat[0] = -np.inf
    tensors["embed_layer.weight"] = w
    write_weights(path, tensors, meta)


@pytest.mark.parametrize(
    "edit,needle",
    [
        (truncate, "truncated or corrupt"),
        (drop_tensor, "lacks the tensor `diffmodel.residual_layers.1.mid_projection.bias`"),
        (add_tensor, "diffmodel.extra.weight"),
        (config_disagrees, "shape"),
        (wrong_layer_count, "lacks the tensor"),
        (wrong_dtype, "F32"),
        (no_metadata, "tcd_config"),
        (bad_json, "could not be parsed"),
        (garbage, "not a valid safetensors file"),
        (nan_weight, r"`diffmodel.diffusion_embedding.projection2.weight` .* holds NaN at flat index 5"),
        (inf_weight, r"`embed_layer.weight` .* holds -inf at flat index 0"),
    ],
)
def test_weights_errors(tiny_model_dir, tmp_path, edit, needle):
    d = broken_dir(tiny_model_dir, tmp_path, edit.__name__, edit)
    with pytest.raises(WeightsError, match=needle) as ei:
        tcd.engine.Denoiser.load(d / "short.safetensors")
    assert isinstance(ei.value, ValueError) and isinstance(ei.value, TcdError)
    assert ei.value.path is not None and ei.value.path.endswith("short.safetensors")
    with pytest.raises(WeightsError):
        tcd.load(d)


def test_model_dir_whose_files_disagree(tiny_model_dir, tmp_path):
    d = copy_dir(tiny_model_dir, tmp_path / "swapped")
    (d / "long.safetensors").write_bytes((d / "short.safetensors").read_bytes())
    with pytest.raises(WeightsError, match="obs_len"):
        tcd.load(d)
