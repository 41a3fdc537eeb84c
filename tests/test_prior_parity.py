"""Parity of the prior forecaster in the Rust engine (``tcd.engine.Prior``) with the PyTorch reference
(``training.prior_net.PriorNet.rollout``), on every kernel path this CPU supports, and the prior's export. The
binding's interface, which needs no torch, is tests/test_prior_engine.py.

Weights (the same file on both sides: the reference is loaded back from it with ``load_prior_file``):
* ``random``: 24 blocks (the bundled size), every weight a seeded normal of unit-gain scale
  (``training.prior_net.random_prior``): the trained init is Zero-Velocity (fc_out ~ 1e-8), which would test
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

import numpy as np
import pytest

from conftest import import_torch

torch = import_torch("parity with the PyTorch reference")

import tcd  # noqa: E402
import fixtures_util  # noqa: E402
from fixtures_util import ALL_KERNELS, read_weights, write_weights  # noqa: E402
from test_prior_engine import observations, synthetic_motion  # noqa: E402
from training import export, fileformat, prior_net  # noqa: E402
from training.prior import train  # noqa: E402
from training.prior_net import PriorConfig, dct_matrix  # noqa: E402

RTOL, ATOL = 1e-4, 1e-5
CONTRIBUTION = 1e3  # the network's contribution over ATOL, at least
HORIZONS = (10, 25, 17)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def random_file(tmp_path_factory):
    return prior_net.save_prior(
        tmp_path_factory.mktemp("prior_random") / "prior.safetensors", prior_net.random_prior(blocks=24, seed=0)
    )


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
    return out / fileformat.PRIOR_FILE


def bundled_file():
    f = tcd.default_model_dir() / fileformat.PRIOR_FILE
    if not f.is_file():
        pytest.skip(f"no bundled prior ({f})")
    return f


@pytest.fixture(params=["random", "trained", "bundled"])
def weights(request):
    """(path, torch reference loaded from the same file, name)."""
    path = {
        "random": lambda: request.getfixturevalue("random_file"),
        "trained": lambda: request.getfixturevalue("trained_file"),
        "bundled": bundled_file,
    }[request.param]()
    model, _ = prior_net.load_prior_file(path)
    return path, model, request.param


def load_kernel(path, kernel: str, monkeypatch) -> tcd.engine.Prior:
    """The prior at ``path`` on one kernel path (fixtures_util.load_kernel)."""
    return fixtures_util.load_kernel(path, kernel, monkeypatch, cls=tcd.engine.Prior)


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
        print(
            f"prior parity {name} {kernel} B={batch} H={horizon}: max abs diff {diff:.3g}, "
            f"max |torch| {np.abs(want).max():.3g}, contribution {contribution:.3g}"
        )
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=ATOL)
        assert contribution >= CONTRIBUTION * ATOL, contribution


def test_the_criterion_sees_a_small_change_of_one_weight(random_file, tmp_path):
    tensors, meta = read_weights(random_file)
    tensors["blocks.11.norm_weight"] = tensors["blocks.11.norm_weight"] * np.float32(1.001)
    prior = tcd.engine.Prior.load(write_weights(tmp_path / "prior.safetensors", tensors, meta))
    model, _ = prior_net.load_prior_file(random_file)
    obs = observations(3)
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(prior.predict(obs, 25), reference(model, obs, 25), rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("obs_len,chunk", [(50, 10), (12, 4), (25, 25), (7, 1)])
def test_dct_matrix_is_pytorchs_bit_for_bit(obs_len, chunk, tmp_path, monkeypatch):
    """The engine computes the DCT (no tensor in the file): its float32 matrix equals the reference's buffer,
    and a prior of another shape (K = 6, other obs_len and chunk) agrees with PyTorch too."""
    model = prior_net.random_prior(blocks=3, seed=obs_len, obs_len=obs_len, chunk=chunk, joints=2)
    path = prior_net.save_prior(tmp_path / "prior.safetensors", model)
    for kernel in tcd.engine.supported_kernels():
        prior = load_kernel(path, kernel, monkeypatch)
        want = torch.from_numpy(dct_matrix(obs_len)).float().numpy()
        assert prior.dct_matrix.dtype == np.float32 and np.array_equal(prior.dct_matrix, want)
        assert np.array_equal(model.dct.numpy(), want)
        obs = np.random.default_rng(0).normal(scale=0.3, size=(4, obs_len + 3, 6)).astype(np.float32)
        for horizon in (chunk, 3 * chunk + 1):
            np.testing.assert_allclose(
                prior.predict(obs, horizon), reference(model, obs, horizon), rtol=RTOL, atol=ATOL
            )


def test_export_cli_writes_the_directory_as_for_the_denoisers(trained_file):
    """``--prior`` writes prior.safetensors (the schema's config, the checkpoint's training record) and keeps
    model.json and SHA256SUMS consistent with the directory's files."""
    import hashlib
    import json

    d = trained_file.parent
    cfg = fileformat.read_config(trained_file)
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
    assert (out / fileformat.PRIOR_FILE).read_bytes() == trained_file.read_bytes()
    tensors, meta = read_weights(random_file)
    del tensors["fc_out.bias"]
    broken = tmp_path / "broken" / fileformat.PRIOR_FILE
    broken.parent.mkdir()
    write_weights(broken, tensors, meta)
    with pytest.raises(RuntimeError, match="fc_out.bias"):
        export.main(["--files", str(broken), "--out", str(out)])
    assert (out / fileformat.PRIOR_FILE).read_bytes() == trained_file.read_bytes()


@pytest.mark.parametrize("kernel", ALL_KERNELS)
def test_a_repair_fill_matches_pytorch(kernel, tmp_path, monkeypatch):
    """A prior with anchor "window" (the repair fill: 24 blocks over the 50-frame window, random weights of
    unit-gain scale) in the engine against ``PriorNet.forward``: its window corrected, within the criterion,
    the correction (the network's contribution over its input) large against it. It corrects its window and
    no other horizon."""
    model = prior_net.random_prior(blocks=24, seed=3, obs_len=50, chunk=50, anchor="window")
    path = prior_net.save_prior(tmp_path / fileformat.REPAIR_FILL_FILE, model)
    fill = load_kernel(path, kernel, monkeypatch)
    assert fill.anchor == "window" and fill.chunk == fill.obs_len == 50
    obs = observations(7)[:, -50:]
    got = fill.predict(obs, 50)
    with torch.no_grad():
        want = model(torch.from_numpy(np.ascontiguousarray(obs))).numpy()
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=ATOL)
    contribution = float(np.abs(want - obs).max())
    print(f"repair fill parity {kernel}: max abs diff {np.abs(got - want).max():.3g}, contribution {contribution:.3g}")
    assert contribution >= CONTRIBUTION * ATOL, contribution
    with pytest.raises(tcd.exceptions.InvalidInputError, match="does not forecast") as ei:
        fill.predict(obs, 10)
    assert ei.value.argument == "horizon"
