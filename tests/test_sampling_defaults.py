"""A model directory's own sampler defaults (``sampling.json``, :attr:`tcd.TCD.sampling`): what every layer
runs when a call names no sampler, how a call's keywords override them, and the errors of a bad file."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest

import tcd
from fixtures_util import poses
from tcd import SamplerOptions
from tcd._cli import main
from tcd.exceptions import WeightsError

DDIM2 = {"sampler": "ddim", "num_inference_steps": 2, "eta": 1.0}


@pytest.fixture()
def model_dir(tiny_model_dir, tmp_path):
    """The tiny model with ``sampling.json``: forecasts with DDIM-2 (eta 1), repairs with DDPM-3."""
    d = shutil.copytree(tiny_model_dir, tmp_path / "m")
    (d / "sampling.json").write_text(
        json.dumps({"why": "a test", "forecast": DDIM2, "repair": {"num_inference_steps": 3}})
    )
    return d


@pytest.fixture()
def obs():
    return poses(np.random.default_rng(0), missing=0.1)


def test_build_over_defaults():
    d = SamplerOptions(**DDIM2)
    assert SamplerOptions.build(d) == d
    assert SamplerOptions.build(d, num_inference_steps=5) == SamplerOptions("ddim", 5, 1.0)
    assert SamplerOptions.build(d, sampler="ddim", eta=0.0) == SamplerOptions("ddim", 2, 0.0)
    # another sampler: the defaults' steps and eta belong to DDIM-2, not to it
    assert SamplerOptions.build(d, sampler="ddpm") == SamplerOptions()
    assert SamplerOptions.build(d, sampler="dpmpp2m", num_inference_steps=4) == SamplerOptions("dpmpp2m", 4)
    assert SamplerOptions.build(None, num_inference_steps=4) == SamplerOptions(num_inference_steps=4)


def test_a_directory_may_centre_its_forecast_noise(model_dir, obs):
    """``"noise_coupling": "centered"`` in sampling.json: forecasts centre their noise unless a call says otherwise;
    naming another sampler drops it with the default's other fields; `tcd info` says so."""
    (model_dir / "sampling.json").write_text(json.dumps({"forecast": dict(DDIM2, noise_coupling="centered")}))
    m = tcd.load(model_dir)
    assert m.sampling["forecast"].noise_coupling == "centered"
    a = m.forecast(obs, num_samples=3, seed=3)
    assert np.array_equal(
        a.samples,
        m.forecast(obs, num_samples=3, seed=3, sampler=SamplerOptions(**DDIM2, noise_coupling="centered")).samples,
    )
    assert not np.array_equal(
        a.samples,
        m.forecast(
            obs, num_samples=3, seed=3, sampler=m.sampler_options("forecast", noise_coupling="independent")
        ).samples,
    )
    assert SamplerOptions.build(m.sampling["forecast"], sampler="ddpm").noise_coupling == "independent"
    assert m.sampling["forecast"].describe(50) == "ddim, 2 steps (eta 1, trailing spacing, centred noise)"


def test_load_reads_the_defaults(model_dir, tiny_model_dir, obs):
    m = tcd.load(model_dir)
    assert m.sampling == {"forecast": SamplerOptions(**DDIM2), "repair": SamplerOptions(num_inference_steps=3)}
    assert tcd.load(tiny_model_dir).sampling == {"forecast": SamplerOptions(), "repair": SamplerOptions()}
    a = m.forecast(obs, num_samples=2, seed=3)
    assert np.array_equal(a.samples, m.forecast(obs, num_samples=2, seed=3, sampler=SamplerOptions(**DDIM2)).samples)
    assert not np.array_equal(
        a.samples,
        m.forecast(obs, num_samples=2, seed=3, sampler=SamplerOptions(sampler="ddim", num_inference_steps=3)).samples,
    )
    # sampler_options changes the fields it names only; the repair's default is the repair's
    assert np.array_equal(
        m.forecast(obs, num_samples=2, seed=3, sampler=m.sampler_options("forecast", eta=0.0)).samples,
        m.forecast(obs, num_samples=2, seed=3, sampler=SamplerOptions(**dict(DDIM2, eta=0.0))).samples,
    )
    r = m.repair(obs, num_samples=2, seed=3).poses
    assert np.array_equal(
        r, m.repair(obs, num_samples=2, seed=3, sampler=SamplerOptions(sampler="ddpm", num_inference_steps=3)).poses
    )


def test_cli_and_repair_file_use_the_model_defaults(model_dir, obs, tmp_path, capsys):
    inp = tmp_path / "in.npz"
    np.savez(inp, poses=obs)
    m = tcd.load(model_dir)
    assert (
        main(
            [
                "forecast",
                str(inp),
                "-o",
                str(tmp_path / "f.npz"),
                "--model",
                str(model_dir),
                "--seed",
                "4",
                "--samples",
                "2",
            ]
        )
        == 0
    )
    with np.load(tmp_path / "f.npz") as f:
        assert np.array_equal(
            f["samples"], m.forecast(obs, num_samples=2, seed=4, sampler=SamplerOptions(**DDIM2)).samples
        )
    assert (
        main(
            [
                "forecast",
                str(inp),
                "-o",
                str(tmp_path / "g.npz"),
                "--model",
                str(model_dir),
                "--seed",
                "4",
                "--samples",
                "2",
                "--eta",
                "0",
            ]
        )
        == 0
    )
    with np.load(tmp_path / "g.npz") as f:
        assert np.array_equal(
            f["samples"], m.forecast(obs, num_samples=2, seed=4, sampler=SamplerOptions(**dict(DDIM2, eta=0.0))).samples
        )
    s = tcd.repair_file(inp, tmp_path / "r.npz", m, num_samples=2)
    assert s["status"] == "repaired"
    with np.load(tmp_path / "r.npz", allow_pickle=False) as f:
        prov = json.loads(str(f["provenance"]))
    assert prov["sampler"] == "ddpm" and prov["steps"] == 3
    capsys.readouterr()
    assert main(["info", "--model", str(model_dir)]) == 0
    out = capsys.readouterr().out
    assert "default sampler, forecast: ddim, 2 steps (eta 1, trailing spacing)" in out
    assert "default sampler, repair: ddpm, 3 steps (trailing spacing)" in out
    assert main(["info", "--model", str(model_dir), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["sampling"]["forecast"] == dataclasses.asdict(SamplerOptions(**DDIM2))


@pytest.mark.parametrize(
    "text, says",
    [
        ("{", "not a readable JSON file"),
        ("[1]", "expected an object of tasks"),
        ('{"predict": {}}', "unknown key 'predict'"),
        ('{"forecast": {"steps": 2}}', "'steps'"),
        ('{"forecast": {"sampler": "euler"}}', "sampler"),
        ('{"forecast": {"num_inference_steps": 0}}', "num_inference_steps"),
        ('{"forecast": "ddim"}', "expected an object of sampler settings"),
    ],
)
def test_bad_sampling_file_is_a_weights_error(tiny_model_dir, tmp_path, text, says):
    d = shutil.copytree(tiny_model_dir, tmp_path / "m")
    (d / "sampling.json").write_text(text)
    with pytest.raises(WeightsError, match="sampling.json") as e:
        tcd.load(d)
    assert says in str(e.value)


def test_too_many_default_steps_fail_at_the_call(tiny_model_dir, tmp_path, obs):
    """The step count is checked against the model where the model samples, naming the argument."""
    d = shutil.copytree(tiny_model_dir, tmp_path / "m")
    (d / "sampling.json").write_text('{"forecast": {"sampler": "ddim", "num_inference_steps": 51}}')
    m = tcd.load(d)
    with pytest.raises(tcd.exceptions.InvalidInputError, match="num_inference_steps"):
        m.forecast(obs, num_samples=1, seed=0)
