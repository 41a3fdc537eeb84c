"""Parity of the MLP sample generator in the Rust engine (``tcd.engine.Generator``) with the PyTorch reference
(``training.generator.Generator``), on every kernel path this CPU supports, and its export. The model-level
mixture (``tcd.TCD.forecast``'s ``mode=tcd.Mixture(share)``), which needs no torch, is tests/test_generator_engine.py.

Weights (the same file on both sides: the reference is loaded back from it with ``load_generator_file``):
* ``random``: the bundled size (3 x 768, z 64, 20 coefficients), PyTorch's default init of the hidden layers and
  a seeded normal head of std 8/sqrt(hidden) (the trained init's zero head would be the prior, testing nothing):
  the samples lie up to a few tenths of a metre from the prior's forecast (``pytest -s`` prints it);
* ``bundled``: ``python/tcd/weights_humaneva/generator.safetensors`` and the Setting-A model's
  ``python/tcd/weights_h36m_stochastic/generator.safetensors`` where the package has them (skipped otherwise),
  trained with IMLE by ``training/generator_imle.py``.
Inputs: windows of the bundled demo clip of the model's layout (real motion: 15 HumanEva-I frames, 25 Setting-A
frames) and the bundled prior's forecast of them; the noise z (S, B, 64) injected, the same array on both sides.

Criteria (stated once, used throughout):
* every value: ``assert_allclose(rtol=1e-4, atol=1e-5)`` (metres), the prior's and the denoiser's tolerance;
* the network's contribution, max |torch - the prior's forecast|, is at least ``CONTRIBUTION`` x atol: the
  comparison measures the network;
* a perturbation of one head bias by 1e-3 (0.13 mm on every frame of one coordinate) fails the criterion (the test
  can fail).
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import import_torch

torch = import_torch("parity with the PyTorch reference")

import tcd  # noqa: E402
from fixtures_util import ALL_KERNELS, load_kernel, read_weights, write_weights  # noqa: E402
from training.fileformat import humaneva_data_meta  # noqa: E402
from training.generator import Generator, load_generator_file, save_generator  # noqa: E402

RTOL, ATOL = 1e-4, 1e-5
CONTRIBUTION = 100
ROOT = Path(__file__).resolve().parents[1]
BUNDLED = tcd.humaneva_model_dir() / "generator.safetensors"
SETTING_A = tcd.humaneva_model_dir().with_name("weights_h36m_stochastic")


def random_generator(seed: int = 0, hidden: int = 768, layers: int = 3) -> Generator:
    torch.manual_seed(seed)
    g = Generator(42, hidden, layers, 64, 20)
    with torch.no_grad():
        g.head.weight.normal_(0.0, 8.0 / math.sqrt(hidden))
        g.head.bias.normal_(0.0, 0.01)
    return g.eval()


def clip_inputs(clip_path: Path, model_dir: Path, obs_len: int, horizon: int):
    """(obs (7, obs_len, K), the directory's prior's forecast (7, horizon, K)) float32 metres from a demo clip."""
    from tcd import _demo as demo

    clip = demo.load_clip(clip_path)["poses"]
    clip = clip.reshape(len(clip), -1).astype(np.float32)
    starts = np.linspace(0, len(clip) - obs_len, 7).astype(int)
    obs = np.ascontiguousarray(np.stack([clip[s : s + obs_len] for s in starts]))
    return obs, tcd.engine.Prior.load(model_dir / "prior.safetensors").predict(obs, horizon)


@pytest.fixture(scope="module")
def inputs():
    """(obs (7, 15, 42), the bundled prior's forecast (7, 60, 42)) float32 metres, from the HumanEva-I demo clip."""
    from tcd import _demo as demo

    return clip_inputs(demo.HUMANEVA_CLIP_PATH, tcd.humaneva_model_dir(), 15, 60)


@pytest.fixture(scope="module")
def random_file(tmp_path_factory):
    return save_generator(
        tmp_path_factory.mktemp("gen") / "generator.safetensors",
        random_generator(),
        humaneva_data_meta("none (random init)"),
        {"random_init": True},
    )


def reference(path: Path, obs: np.ndarray, prior: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The PyTorch generator loaded from ``path``: (S, B, 60, 42) for z (S, B, Z)."""
    gen, _ = load_generator_file(path)
    with torch.no_grad():
        out = gen(torch.from_numpy(obs), torch.from_numpy(prior), torch.from_numpy(z).transpose(0, 1))
    return out.transpose(0, 1).numpy()


def check(path: Path, kernel: str, monkeypatch, inputs, samples: int = 5) -> None:
    obs, prior = inputs
    z = np.random.default_rng(1).standard_normal((samples, len(obs), 64)).astype(np.float32)
    engine = load_kernel(path, kernel, monkeypatch, tcd.engine.Generator).sample(obs, prior, samples, noise=z)
    ref = reference(path, obs, prior, z)
    assert engine.shape == ref.shape == (samples, *prior.shape) and engine.dtype == np.float32
    contribution = np.abs(ref - prior[None]).max()
    print(
        f"{path.name} [{kernel}]: max |engine - torch| {np.abs(engine - ref).max():.2e}, "
        f"contribution {contribution:.3f} m"
    )
    assert contribution >= CONTRIBUTION * ATOL
    np.testing.assert_allclose(engine, ref, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("kernel", ALL_KERNELS)
def test_random_weights_match_pytorch(random_file, kernel, monkeypatch, inputs):
    check(random_file, kernel, monkeypatch, inputs)


@pytest.mark.parametrize("kernel", ALL_KERNELS)
def test_bundled_weights_match_pytorch(kernel, monkeypatch, inputs):
    if not BUNDLED.is_file():
        pytest.skip("no bundled HumanEva-I generator in this build")
    check(BUNDLED, kernel, monkeypatch, inputs, samples=8)


@pytest.mark.parametrize("kernel", ALL_KERNELS)
def test_bundled_setting_a_weights_match_pytorch(kernel, monkeypatch):
    """The Setting-A model's generator (16 joints, 25 -> 100 frames) on its own clip and prior."""
    from tcd import _demo as demo

    if not (SETTING_A / "generator.safetensors").is_file():
        pytest.skip("no bundled Setting-A generator in this build")
    inputs = clip_inputs(demo.SETTING_A_CLIP_PATH, SETTING_A, 25, 100)
    check(SETTING_A / "generator.safetensors", kernel, monkeypatch, inputs, samples=8)


def test_a_perturbed_head_bias_fails_the_criterion(random_file, tmp_path, inputs):
    """The criterion can fail: the engine on a file whose head.bias[0] (the first coordinate's DC coefficient) moved
    by 1e-3, against the reference of the original."""
    tensors, meta = read_weights(random_file)
    tensors["head.bias"] = tensors["head.bias"].copy()
    tensors["head.bias"][0] += 1e-3
    moved = write_weights(tmp_path / "generator.safetensors", tensors, meta)
    obs, prior = inputs
    z = np.random.default_rng(1).standard_normal((5, len(obs), 64)).astype(np.float32)
    engine = tcd.engine.Generator.load(moved).sample(obs, prior, 5, noise=z)
    assert not np.allclose(engine, reference(random_file, obs, prior, z), rtol=RTOL, atol=ATOL)


def test_seeded_noise_is_the_generator_stream(random_file, inputs):
    """A seeded call draws z from the engine's streams of stage STAGE_GENERATOR (``tcd.engine.seeded_noise``
    materialises them), so the PyTorch reference reproduces it from that array."""
    obs, prior = inputs
    gen = tcd.engine.Generator.load(random_file)
    z = tcd.engine.seeded_noise(11, tcd.engine.STAGE_GENERATOR, 4, 1, len(obs), 64, 1).reshape(4, len(obs), 64)
    seeded = gen.sample(obs, prior, 4, seed=11)
    np.testing.assert_array_equal(seeded, gen.sample(obs, prior, 4, noise=z))
    np.testing.assert_allclose(seeded, reference(random_file, obs, prior, z), rtol=RTOL, atol=ATOL)


def test_export_round_trip_and_cli(tmp_path):
    """``save_generator`` / ``load_generator_file`` keep every weight; ``python -m training.generator`` writes a
    bench state dict as a file the engine loads, its config in the metadata."""
    g = random_generator(seed=3, hidden=32, layers=2)
    loaded, cfg = load_generator_file(save_generator(tmp_path / "g.safetensors", g, humaneva_data_meta()))
    assert cfg["role"] == "generator" and cfg["model"] == {
        "num_joints": 14,
        "coords": 3,
        "num_features": 42,
        "obs_len": 15,
        "pred_len": 60,
        "hidden": 32,
        "layers": 2,
        "z_dim": 64,
        "coefs": 20,
    }
    for (name, a), (_, b) in zip(g.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(a, b), name
    torch.save(g.state_dict(), tmp_path / "state.pt")
    subprocess.run(
        [
            sys.executable,
            "-m",
            "training.generator",
            "--state-dict",
            str(tmp_path / "state.pt"),
            "--out",
            str(tmp_path / "dir"),
            "--hidden",
            "32",
            "--layers",
            "2",
            "--description",
            "a test",
        ],
        cwd=ROOT,
        check=True,
        capture_output=True,
    )
    e = tcd.engine.Generator.load(tmp_path / "dir" / "generator.safetensors")
    assert (e.hidden, e.layers, e.z_dim, e.coefs, e.pred_len, e.obs_len) == (32, 2, 64, 20, 60, 15)
    assert e.config["training"]["description"] == "a test"
    shutil.rmtree(tmp_path / "dir")


def test_a_setting_a_generator_exports_for_its_protocol(tmp_path):
    """``python -m training.generator --protocol h36m-a``: Setting-A's 16 joints, 25 -> 100 frames and its data block
    (50 Hz), into a model directory whose summary and checksums it rewrites: with the prior beside it, a generator
    directory that ``tcd.load`` opens (25 -> 100 frames, the generator alone); an unknown protocol is refused by
    name."""
    from training.fileformat import save_model_file, setting_a_data_meta
    from training.prior_net import build_prior_config, random_prior

    d = tmp_path / "dir"
    d.mkdir()
    prior = random_prior(blocks=2, seed=1, obs_len=25, chunk=25, joints=16)
    save_model_file(d / "prior.safetensors", prior, build_prior_config(prior, setting_a_data_meta()))
    g = Generator(48, 32, 2, 64, 20, obs_len=25, pred_len=100)
    torch.save(g.state_dict(), tmp_path / "state.pt")
    argv = [sys.executable, "-m", "training.generator", "--state-dict", str(tmp_path / "state.pt")]
    argv += ["--out", str(d), "--hidden", "32", "--layers", "2"]
    subprocess.run(argv + ["--protocol", "h36m-a"], cwd=ROOT, check=True, capture_output=True)
    e = tcd.engine.Generator.load(d / "generator.safetensors")
    assert (e.num_joints, e.obs_len, e.pred_len) == (16, 25, 100)
    assert (e.config["data"]["dataset"], e.config["data"]["fps"]) == ("h36m-setting-a", 50.0)
    assert set(json.loads((d / "model.json").read_text())) == {"prior", "generator"}
    assert "generator.safetensors" in (d / "SHA256SUMS").read_text()
    m = tcd.load(d)
    assert (m.obs_len, m.horizon, m.num_joints, m.fps, m.forecast_mode) == (25, 100, 16, 50.0, tcd.Mixture(1.0))
    assert m.forecast(np.zeros((25, 16, 3), np.float32), num_samples=50, seed=0).samples.shape == (50, 100, 16, 3)
    bad = subprocess.run(argv + ["--protocol", "h36m-b"], cwd=ROOT, capture_output=True, text=True)
    assert bad.returncode != 0 and "'h36m-b' is not a stochastic protocol" in bad.stderr
