"""pytest-benchmark timings of the public Python calls, on the bundled model and the bundled demo clip.

    python -m pytest benches/test_python_calls.py --benchmark-enable            # measure
    python -m pytest benches/test_python_calls.py --benchmark-enable --benchmark-json out.json

The test suite collects this file with benchmarking disabled (``--benchmark-disable`` in pyproject's
pytest ``addopts``): each call then runs once, as a smoke test that the benchmarked calls work and give
well-formed results. No timing is asserted anywhere. ``--benchmark-enable`` turns the timing on.

What is timed (2 threads unless stated; the bundled reduced model, 3 layers x 32 channels):

* ``tcd.load()`` of the bundled model (reads and checks the weight files);
* one denoiser forward at L = 75 (the long-term model, batch 1);
* ``forecast``: the paper's setting (5 samples x DDPM-50, both stages), the fast one (1 sample, DDIM-10) and
  5 samples with the model's default sampler (``sampling.json``: one DDIM step for the bundled model; issue 29's
  goal: under 0.3 s on 2 cores);
* ``repair`` of one 50-frame window with 40 % of the joint-frames occluded (DDPM-50, 5 samples);
* ``tcd.repair_file`` of a 500-frame sequence (20 s at 25 fps) with gaps, DDIM-10, 1 sample.

The forecasts, 2026-11-26 (AMD EPYC Zen 4, 2 cores, the other core busy with a training run;
``benches/results/python_calls_forecast.json``, ``-k forecast --benchmark-enable --benchmark-json ...``): median
130 ms for 5 samples with the bundled model's default sampler (one DDIM step), 245 ms for DDIM-10 x 1, 4,791 ms for
DDPM-50 x 5 (37 x the default).
"""

from __future__ import annotations

import numpy as np
import pytest

import tcd
from tcd._demo import load_clip
from tcd import SamplerOptions

pytest.importorskip("pytest_benchmark")


@pytest.fixture(scope="module")
def model():
    return tcd.load(threads=2)


@pytest.fixture(scope="module")
def clip():
    return load_clip()["poses"]


def _occluded(poses: np.ndarray, rate: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    mask = rng.random(poses.shape[:2]) >= rate
    mask[-1] = True  # the last observed frame stays whole
    return poses, mask


def test_load(benchmark):
    m = benchmark(tcd.load)
    assert m.obs_len == 50


def test_forward_long_L75(benchmark, model):
    den = model.long
    k, length = den.num_features, den.seq_len
    rng = np.random.default_rng(0)
    noisy = rng.standard_normal((1, k, length)).astype(np.float32)
    observed = rng.normal(scale=0.3, size=(1, k, length)).astype(np.float32)
    mask = np.zeros((1, k, length), np.float32)
    mask[..., :55] = 1
    eps = benchmark(den.forward, noisy, observed, mask, 25)
    assert eps.shape == (1, k, length) and np.isfinite(eps).all()


@pytest.mark.parametrize("samples,steps,sampler", [(5, None, "ddpm"), (1, 10, "ddim")], ids=["ddpm50x5", "ddim10x1"])
def test_forecast(benchmark, model, clip, samples, steps, sampler):
    obs = clip[: model.obs_len]
    o = model.sampler_options("forecast", sampler=sampler, num_inference_steps=steps)
    fc = benchmark(model.forecast, obs, num_samples=samples, sampler=o, seed=0)
    assert fc.mean.shape == (model.horizon, model.num_joints, 3) and np.isfinite(fc.mean).all()


def test_forecast_default_sampler(benchmark, model, clip):
    obs = clip[: model.obs_len]
    fc = benchmark(model.forecast, obs, num_samples=5, seed=0)
    assert fc.samples.shape == (5, model.horizon, model.num_joints, 3) and np.isfinite(fc.samples).all()


def test_repair_window(benchmark, model, clip):
    obs, mask = _occluded(clip[: model.obs_len], 0.4, seed=1)
    out = benchmark(model.repair, obs, mask, seed=0).poses
    assert out.shape == obs.shape and np.isfinite(out).all()
    np.testing.assert_array_equal(out[mask], obs[mask])


def test_repair_file_500_frames(benchmark, model, clip, tmp_path):
    reps = -(-500 // len(clip))
    poses = np.concatenate([clip] * reps)[:500].copy()
    poses[100:120] = np.nan  # a dropped stretch
    poses[200:300, 0:4] = np.nan  # a leg occluded for 4 s
    src = tmp_path / "seq.npz"
    np.savez(src, poses=poses)

    def run():
        return tcd.repair_file(
            src,
            tmp_path / "out.npz",
            model,
            num_samples=1,
            sampler=SamplerOptions(num_inference_steps=10, sampler="ddim"),
            overwrite=True,
        )

    benchmark(run)
    with np.load(tmp_path / "out.npz") as f:
        out = f["poses"]
    assert out.shape == poses.shape and np.isfinite(out).all()
    seen = ~np.isnan(poses)
    np.testing.assert_array_equal(out[seen], poses[seen])
