"""Parity of the prior forecaster in the Rust engine (``tcd.engine.Prior``) with the PyTorch reference
(``training.prior.PriorNet.rollout``), on every kernel path this CPU supports, and the binding's interface.

Weights (the same file on both sides: the reference is loaded back from it with ``load_prior_file``):
* ``random``: 24 blocks (the bundled size), every weight a seeded normal of unit-gain scale
  (``training.export.random_prior``): the trained init is Zero-Velocity (fc_out ~ 1e-8), which would test
  nothing; here the forecast moves about a metre away from the last pose;
* ``trained``: a 4-block prior trained 40 iterations on synthetic motion in the test (Adam at 1e-2 from the
  Zero-Velocity init), exported through the CLI (``python -m training.export --prior``);
* ``bundled``: ``python/tcd/weights/prior.safetensors`` where the package has one (skipped otherwise).

Criteria (stated once, used throughout):
* every value: ``assert_allclose(rtol=1e-4, atol=1e-5)`` (metres), the denoiser forward's tolerance, on
  horizons 10 (one forward), 25 (the cascade's, three chunks) and 17 (no multiple of the chunk), batches of
  1 and 7, inputs longer than ``obs_len`` (the last 50 frames are read);
* the network's contribution, max |torch - the last observed pose| (what the network adds to
  Zero-Velocity), is at least ``CONTRIBUTION`` x atol: the comparison measures the network;
* a perturbation of one layer-norm weight by 1e-3 fails the criterion (the test can fail).

Observed on this AVX2 EPYC (portable and avx2 paths; ``pytest -s`` prints them): random weights max abs
difference 1.9e-6 at outputs up to 2.7 m (contributions 1.05 m and more); trained on synthetic motion
3.0e-7 (contributions 0.065 m and more); a copy of runs/prior/last.pt at the end of the bundled run (24
blocks, 9,000 iterations; the same inputs) 4.3e-6 at horizon 25 and 1.0e-6 at 10 (contribution 0.69 m).
Against a float64 forward the engine is off by 0.8-1.1e-6 in one forward (PyTorch: 3.6e-7; the engine's
GEMMs add their terms in order),
and the rollout compounds it (5.5e-6 at 25 frames; PyTorch 1.3e-6). The DCT matrix the engine computes
equals PyTorch's float32 matrix bit for bit.
"""
from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

import tcd
import fixtures_util
from fixtures_util import ALL_KERNELS, bad, read_weights, write_weights
from tcd.exceptions import InvalidInputError, WeightsError
from training import export
from training.prior import PriorConfig, dct_matrix, train

RTOL, ATOL = 1e-4, 1e-5
CONTRIBUTION = 1e3     # the network's contribution over ATOL, at least
HORIZONS = (10, 25, 17)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def synthetic_motion(seed: int, sequences: int = 12, frames: int = 160, k: int = 66) -> np.ndarray:
    """(S, T, K) float32: smooth motion, metres: per coordinate a sum of two sinusoids around an offset."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[None, :, None] / 25.0
    f = rng.uniform(0.2, 1.5, (sequences, 2, 1, k))
    ph = rng.uniform(0, 2 * np.pi, (sequences, 2, 1, k))
    amp = rng.uniform(0.02, 0.2, (sequences, 2, 1, k))
    x = rng.normal(scale=0.3, size=(sequences, 1, k)) + (amp * np.sin(2 * np.pi * f * t[:, None] + ph)).sum(1)
    return x.astype(np.float32)


@pytest.fixture(scope="module")
def random_file(tmp_path_factory):
    return export.save_prior(tmp_path_factory.mktemp("prior_random") / "prior.safetensors",
                             export.random_prior(blocks=24, seed=0))


@pytest.fixture(scope="module")
def trained_file(tmp_path_factory):
    """A few dozen training iterations on synthetic motion, exported by the CLI into a model directory."""
    d = tmp_path_factory.mktemp("prior_trained")
    seqs = synthetic_motion(1)
    frames = seqs.reshape(-1, seqs.shape[-1])
    L = 50 + 10
    starts = np.concatenate([i * seqs.shape[1] + np.arange(seqs.shape[1] - L + 1) for i in range(len(seqs))])
    cfg = PriorConfig(blocks=4, iterations=40, batch_size=32, lr=1e-2, lr_final=1e-2)
    torch.manual_seed(0)
    train(cfg, d / "run", frames=(frames, starts), log=lambda m: None)
    out = d / "model"
    assert export.main(["--prior", str(d / "run" / "last.pt"), "--out", str(out)]) == 0
    return out / export.PRIOR_FILE


def bundled_file():
    f = tcd.default_model_dir() / export.PRIOR_FILE
    if not f.is_file():
        pytest.skip(f"no bundled prior ({f})")
    return f


@pytest.fixture(params=["random", "trained", "bundled"])
def weights(request):
    """(path, torch reference loaded from the same file, name)."""
    path = {"random": lambda: request.getfixturevalue("random_file"),
            "trained": lambda: request.getfixturevalue("trained_file"), "bundled": bundled_file}[request.param]()
    model, _ = export.load_prior_file(path)
    return path, model, request.param


def load_kernel(path, kernel: str, monkeypatch) -> tcd.engine.Prior:
    """The prior at ``path`` on one kernel path (fixtures_util.load_kernel)."""
    return fixtures_util.load_kernel(path, kernel, monkeypatch, cls=tcd.engine.Prior)


def observations(batch: int, frames: int = 60) -> np.ndarray:
    """(B, T, K) float32 metres: real motion (the bundled demo clip) for the first windows, synthetic after."""
    from tcd.demo import load_clip
    clip = load_clip()["poses"]
    clip = clip.reshape(len(clip), -1).astype(np.float32)
    wins = [clip[s:s + frames] for s in range(0, len(clip) - frames + 1, 23)][:batch]
    wins += list(synthetic_motion(2, sequences=batch - len(wins), frames=frames)) if batch > len(wins) else []
    return np.ascontiguousarray(np.stack(wins))


def reference(model, obs: np.ndarray, horizon: int) -> np.ndarray:
    with torch.no_grad():
        return model.rollout(torch.from_numpy(obs), horizon).numpy()


@pytest.mark.parametrize("kernel", ALL_KERNELS)
@pytest.mark.parametrize("batch", [1, 7])
def test_predict_matches_pytorch(weights, kernel, batch, monkeypatch):
    path, model, name = weights
    prior = load_kernel(path, kernel, monkeypatch)
    obs = observations(batch)
    for horizon in HORIZONS:
        got = prior.predict(obs, horizon)
        want = reference(model, obs, horizon)
        assert got.shape == want.shape == (batch, horizon, 66) and got.dtype == np.float32
        diff = float(np.abs(got.astype(np.float64) - want).max())
        contribution = float(np.abs(want - obs[:, -1:]).max())
        print(f"prior parity {name} {kernel} B={batch} H={horizon}: max abs diff {diff:.3g}, "
              f"max |torch| {np.abs(want).max():.3g}, contribution {contribution:.3g}")
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=ATOL)
        assert contribution >= CONTRIBUTION * ATOL, contribution


def test_the_criterion_sees_a_small_change_of_one_weight(random_file, tmp_path):
    tensors, meta = read_weights(random_file)
    tensors["blocks.11.norm_weight"] = tensors["blocks.11.norm_weight"] * np.float32(1.001)
    prior = tcd.engine.Prior.load(write_weights(tmp_path / "prior.safetensors", tensors, meta))
    model, _ = export.load_prior_file(random_file)
    obs = observations(3)
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(prior.predict(obs, 25), reference(model, obs, 25), rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("obs_len,chunk", [(50, 10), (12, 4), (25, 25), (7, 1)])
def test_dct_matrix_is_pytorchs_bit_for_bit(obs_len, chunk, tmp_path, monkeypatch):
    """The engine computes the DCT (no tensor in the file): its float32 matrix equals the reference's buffer,
    and a prior of another shape (K = 6, other obs_len and chunk) agrees with PyTorch too."""
    model = export.random_prior(blocks=3, seed=obs_len, obs_len=obs_len, chunk=chunk, joints=2)
    path = export.save_prior(tmp_path / "prior.safetensors", model)
    for kernel in tcd.engine.supported_kernels():
        prior = load_kernel(path, kernel, monkeypatch)
        want = torch.from_numpy(dct_matrix(obs_len)).float().numpy()
        assert prior.dct_matrix.dtype == np.float32 and np.array_equal(prior.dct_matrix, want)
        assert np.array_equal(model.dct.numpy(), want)
        obs = np.random.default_rng(0).normal(scale=0.3, size=(4, obs_len + 3, 6)).astype(np.float32)
        for horizon in (chunk, 3 * chunk + 1):
            np.testing.assert_allclose(prior.predict(obs, horizon), reference(model, obs, horizon),
                                       rtol=RTOL, atol=ATOL)


# ------------------------------------------------------------------------------- the interface

@pytest.fixture(scope="module")
def prior(random_file):
    return tcd.engine.Prior.load(random_file)


def test_description(prior, random_file):
    cfg = prior.config
    assert cfg["role"] == "prior" and cfg["model"]["blocks"] == prior.blocks == 24
    assert (prior.num_features, prior.num_joints, prior.obs_len, prior.chunk) == (66, 22, 50, 10)
    assert prior.path == str(random_file) and prior.kernel in tcd.engine.supported_kernels()
    assert "Prior(" in repr(prior) and "blocks=24" in repr(prior)
    assert tcd.engine.Prior.from_bytes(random_file.read_bytes()).predict(observations(1), 3).shape == (1, 3, 66)


def test_results_do_not_depend_on_threads_batch_or_caller_thread(prior):
    obs = observations(9)
    one = prior.predict(obs, 25, threads=1)
    assert np.array_equal(one, prior.predict(obs, 25, threads=2))
    assert np.array_equal(one, prior.predict(obs, 25))
    assert np.array_equal(one[4:5], prior.predict(obs[4:5], 25, threads=2))
    assert np.array_equal(one, prior.predict(obs.astype(np.float64), 25))            # converted to float32
    assert np.array_equal(one, prior.predict(np.asfortranarray(obs), 25))              # any memory order
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
    bad("obs", prior.predict, obs[0], 10)                              # not (B, T, K)
    bad("obs", prior.predict, obs[:, :49], 10)                         # fewer than obs_len frames
    bad("obs", prior.predict, obs[..., :60], 10)                       # K
    bad("obs", prior.predict, obs[:0], 10)                             # B = 0
    bad("obs", prior.predict, np.array([["a"]]), 10)
    for h in (0, -3):
        bad("horizon", prior.predict, obs, h)
    bad("horizon", prior.predict, obs, 2**40)                          # the output would not fit
    bad("horizon", prior.predict, obs, 2.5)
    bad("horizon", prior.predict, obs, True)
    bad("threads", prior.predict, obs, 10, threads=0)
    nan = obs.copy()
    nan[1, -1, 5] = np.nan
    e = bad("obs", prior.predict, nan, 10)
    assert "finite" in str(e) and str(1 * 60 * 66 + 59 * 66 + 5) in str(e)


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


def test_export_cli_writes_the_directory_as_for_the_denoisers(trained_file):
    """``--prior`` writes prior.safetensors (the schema's config, the checkpoint's training record) and keeps
    model.json and SHA256SUMS consistent with the directory's files."""
    import hashlib
    import json
    d = trained_file.parent
    cfg = export.read_config(trained_file)
    assert cfg["role"] == "prior" and cfg["training"]["iteration"] == 40
    assert cfg["training"]["train_config"]["blocks"] == 4 and cfg["data"]["training_data"].startswith("Human3.6M S1,S6")
    assert json.loads((d / "model.json").read_text())["prior"] == cfg
    sums = dict(reversed(line.split()) for line in (d / "SHA256SUMS").read_text().splitlines())
    assert sums == {"prior.safetensors": hashlib.sha256(trained_file.read_bytes()).hexdigest()}


def test_export_files_adopts_a_prior_file_after_loading_it(trained_file, random_file, tmp_path):
    """``--files prior.safetensors`` (how exported weights replace the bundled ones) checks the file loads
    strictly first."""
    out = tmp_path / "adopted"
    assert export.main(["--files", str(trained_file), "--out", str(out)]) == 0
    assert (out / export.PRIOR_FILE).read_bytes() == trained_file.read_bytes()
    tensors, meta = read_weights(random_file)
    del tensors["fc_out.bias"]
    broken = tmp_path / "broken" / export.PRIOR_FILE
    broken.parent.mkdir()
    write_weights(broken, tensors, meta)
    with pytest.raises(RuntimeError, match="fc_out.bias"):
        export.main(["--files", str(broken), "--out", str(out)])
    assert (out / export.PRIOR_FILE).read_bytes() == trained_file.read_bytes()
