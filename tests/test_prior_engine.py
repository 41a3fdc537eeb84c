"""The prior forecaster's interface in the engine (``tcd.engine.Prior``): its description, results that do not
depend on threads, batching or the caller's thread, the frames it reads, bad arguments and bad files; on the
committed 2-block random prior (tests/fixtures/tiny_prior.safetensors, ``training.prior_net.random_prior(blocks=2,
seed=0)``: every weight shapes the output). No torch: its parity with the PyTorch reference is
tests/test_prior_parity.py."""

from __future__ import annotations

import shutil
import threading
from pathlib import Path

import numpy as np
import pytest

import tcd
from conftest import FIXTURES
from fixtures_util import bad, read_weights, write_weights
from tcd.exceptions import InvalidInputError, WeightsError


def synthetic_motion(seed: int, sequences: int = 12, frames: int = 160, k: int = 66) -> np.ndarray:
    """(S, T, K) float32: smooth motion, metres: per coordinate a sum of two sinusoids around an offset."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[None, :, None] / 25.0
    f = rng.uniform(0.2, 1.5, (sequences, 2, 1, k))
    ph = rng.uniform(0, 2 * np.pi, (sequences, 2, 1, k))
    amp = rng.uniform(0.02, 0.2, (sequences, 2, 1, k))
    x = rng.normal(scale=0.3, size=(sequences, 1, k)) + (amp * np.sin(2 * np.pi * f * t[:, None] + ph)).sum(1)
    return x.astype(np.float32)


def observations(batch: int, frames: int = 60) -> np.ndarray:
    """(B, T, K) float32 metres: real motion (the bundled demo clip) for the first windows, synthetic after."""
    from tcd._demo import load_clip

    clip = load_clip()["poses"]
    clip = clip.reshape(len(clip), -1).astype(np.float32)
    wins = [clip[s : s + frames] for s in range(0, len(clip) - frames + 1, 23)][:batch]
    wins += list(synthetic_motion(2, sequences=batch - len(wins), frames=frames)) if batch > len(wins) else []
    return np.ascontiguousarray(np.stack(wins))


@pytest.fixture(scope="module")
def random_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("prior_random")
    return Path(shutil.copyfile(FIXTURES / "tiny_prior.safetensors", d / "prior.safetensors"))


@pytest.fixture(scope="module")
def prior(random_file):
    return tcd.engine.Prior.load(random_file)


def test_description(prior, random_file):
    cfg = prior.config
    assert cfg["role"] == "prior" and cfg["model"]["blocks"] == prior.blocks == 2
    assert (prior.num_features, prior.num_joints, prior.obs_len, prior.chunk) == (66, 22, 50, 10)
    assert prior.path == str(random_file) and prior.kernel in tcd.engine.supported_kernels()
    assert "Prior(" in repr(prior) and "blocks=2" in repr(prior)
    assert tcd.engine.Prior.from_bytes(random_file.read_bytes()).predict(observations(1), 3).shape == (1, 3, 66)


def test_results_do_not_depend_on_threads_batch_or_caller_thread(prior):
    obs = observations(9)
    one = prior.predict(obs, 25, threads=1)
    assert np.array_equal(one, prior.predict(obs, 25, threads=2))
    assert np.array_equal(one, prior.predict(obs, 25))
    assert np.array_equal(one[4:5], prior.predict(obs[4:5], 25, threads=2))
    assert np.array_equal(one, prior.predict(obs.astype(np.float64), 25))  # converted to float32
    assert np.array_equal(one, prior.predict(np.asfortranarray(obs), 25))  # any memory order
    results = [None] * 4

    def run(i):
        results[i] = prior.predict(obs, 25, threads=1)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(np.array_equal(r, one) for r in results)


def test_only_the_last_obs_len_frames_are_read(prior):
    obs = observations(2, frames=80)
    want = prior.predict(obs[:, -50:], 12)
    early = obs.copy()
    early[:, :30] = np.nan
    assert np.array_equal(prior.predict(early, 12), want)


def test_bad_arguments(prior):
    obs = observations(2)
    bad("obs", prior.predict, obs[0], 10)  # not (B, T, K)
    bad("obs", prior.predict, obs[:, :49], 10)  # fewer than obs_len frames
    bad("obs", prior.predict, obs[..., :60], 10)  # K
    bad("obs", prior.predict, obs[:0], 10)  # B = 0
    bad("obs", prior.predict, np.array([["a"]]), 10)
    for h in (0, -3):
        bad("horizon", prior.predict, obs, h)
    bad("horizon", prior.predict, obs, 2**40)  # the output would not fit
    bad("horizon", prior.predict, obs, 2.5)
    bad("horizon", prior.predict, obs, True)
    bad("threads", prior.predict, obs, 10, threads=0)
    nan = obs.copy()
    nan[1, -1, 5] = np.nan
    e = bad("obs", prior.predict, nan, 10)
    assert "finite" in str(e) and str(1 * 60 * 66 + 59 * 66 + 5) in str(e)


def test_fill_is_the_spline_then_the_rollout(prior):
    """``Prior.fill`` of a forecaster (what a model conditioned on it sees): given entries back bit for bit, the
    hidden ones of the first obs_len frames the engine's natural cubic spline through each row's given frames
    (``tcd.interpolate``), the frames after them the rollout from those filled frames; never reading hidden
    entries; bad arguments named."""
    obs = observations(2, frames=60)
    mask = np.ones_like(obs)
    mask[0, 20:30] = 0
    mask[1, 3:9, 7] = 0
    mask[:, 50:] = 0
    hidden = np.where(mask > 0, obs, np.nan).astype(np.float32)
    got = prior.fill(np.nan_to_num(hidden), mask)
    assert np.array_equal(got[mask > 0], obs[mask > 0])
    spline = tcd.interpolate(hidden[:, :50].reshape(2, 50, 22, 3), method="spline").reshape(2, 50, 66)
    np.testing.assert_array_equal(got[:, :50], spline)
    np.testing.assert_array_equal(got[:, 50:], prior.predict(got[:, :50], 10))
    assert np.array_equal(prior.fill(np.where(mask > 0, obs, 7.0).astype(np.float32), mask), got)
    bad("observed", prior.fill, obs[..., :60], mask[..., :60])  # K
    bad("observed", prior.fill, obs[0], mask[0])  # not (B, T, K)
    bad("mask", prior.fill, obs, mask[:, :59])
    m2 = mask.copy()
    m2[0, 0, 0] = 0.5
    bad("mask", prior.fill, obs, m2)
    bad("length", prior.fill, obs[:, :50], mask[:, :50])  # a forecaster rolls out after obs_len
    bad("forecaster", prior.fill, obs, mask, forecaster=object())
    bad("threads", prior.fill, obs, mask, threads=0)


def test_bad_files(prior, random_file, tmp_path):
    with pytest.raises(FileNotFoundError):
        tcd.engine.Prior.load(tmp_path / "none.safetensors")
    with pytest.raises(WeightsError):
        tcd.engine.Prior.load(tmp_path)
    (tmp_path / "cut.safetensors").write_bytes(random_file.read_bytes()[:1000])
    with pytest.raises(WeightsError) as e:
        tcd.engine.Prior.load(tmp_path / "cut.safetensors")
    assert e.value.path == str(tmp_path / "cut.safetensors")
    tensors, meta = read_weights(random_file)
    tensors["fc_in.weight"] = tensors["fc_in.weight"].copy()
    tensors["fc_in.weight"][3, 4] = np.inf
    with pytest.raises(WeightsError, match="fc_in.weight"):
        tcd.engine.Prior.load(write_weights(tmp_path / "inf.safetensors", tensors, meta))
    tensors, meta = read_weights(random_file)
    tensors["blocks.0.fc.weight"] = tensors["blocks.0.fc.weight"][:, :40]
    with pytest.raises(WeightsError, match=r"blocks\.0\.fc\.weight.*\[50, 40\].*\[50, 50\]"):
        tcd.engine.Prior.load(write_weights(tmp_path / "shape.safetensors", tensors, meta))
    with pytest.raises(TypeError):
        tcd.engine.Prior(object())
    assert isinstance(InvalidInputError("m", "a"), ValueError)
