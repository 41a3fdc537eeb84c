"""Parity of the Rust engine (through the `tcd` binding) with the PyTorch reference in `training/`, on
the same random-init weights and the same injected noise.

Criteria (stated once, used throughout):
* one forward: ``assert_allclose(rtol=1e-4, atol=1e-5)``;
* whole chains and the cascade: max |rust - torch| <= 1e-4 in model units (metres), absolute.
  A random-init denoiser predicts eps ~ 0, so x_0 ~ x_T / sqrt(alpha_bar) reaches ~1e2 and float32
  rounding grows with it (observed: ~2e-7 relative, 5e-5 absolute at most), which the absolute bound
  still covers.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import import_torch

torch = import_torch("parity with the PyTorch reference")

import tcd  # noqa: E402
from fixtures_util import ALL_KERNELS, load_kernel, make_model_dir  # noqa: E402
from training import diffusion as D  # noqa: E402
from training.export import load_model_file  # noqa: E402
from tcd import SamplerOptions  # noqa: E402

CHAIN_ATOL = 1e-4  # model units (metres)
OBS_LEN = 50  # observed frames of the cascade


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def tiny(tiny_model_dir):
    """role -> (rust Denoiser, torch model, schedule)."""
    out = {}
    for role in ("short", "long"):
        path = tiny_model_dir / f"{role}.safetensors"
        model, sched, _ = load_model_file(path)
        out[role] = (tcd.engine.Denoiser.load(path), model, sched)
    return out


def observation(rng, b, k, length, obs_frames, missing=0.2):
    """observed / mask (B, K, L): the first obs_frames frames observed except a random fraction."""
    mask = np.zeros((b, k, length), np.float32)
    mask[:, :, :obs_frames] = rng.random((b, k, obs_frames)) >= missing
    observed = (rng.normal(scale=0.3, size=(b, k, length)) * mask).astype(np.float32)
    return observed, mask


def max_diff(a, b, what=""):
    """max |a - b|; printed with the largest |b| (see them with `pytest -s`)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    d = float(np.abs(a - b).max())
    print(
        f"parity {what}: max abs diff {d:.3g}, max |torch| {np.abs(b).max():.3g}, "
        f"max rel diff {d / max(np.abs(b).max(), 1e-30):.3g}"
    )
    return d


def chain_close(got, want, what):
    """The chain criterion of the module docstring."""
    d = max_diff(got, want, what)
    return d <= CHAIN_ATOL


def torch_forward(model, noisy, observed, mask, step):
    with torch.no_grad():
        t = torch.full((noisy.shape[0],), step, dtype=torch.long)
        return model(torch.from_numpy(noisy), torch.from_numpy(observed), torch.from_numpy(mask), t).numpy()


# ------------------------------------------------------------------------------------ forward

MASKS = ["forecast", "random", "none_observed", "all_observed"]


def make_mask(kind, rng, b, k, length):
    if kind == "forecast":
        m = np.zeros((b, k, length), np.float32)
        m[:, :, :OBS_LEN] = 1
        return m
    if kind == "random":
        return (rng.random((b, k, length)) < 0.5).astype(np.float32)
    if kind == "none_observed":
        return np.zeros((b, k, length), np.float32)
    return np.ones((b, k, length), np.float32)


@pytest.mark.parametrize("step", [0, 1, 17, 49])
@pytest.mark.parametrize("mask_kind", MASKS)
def test_forward_tiny(tiny, step, mask_kind):
    den, model, _ = tiny["short"]
    rng = np.random.default_rng(step * 7 + MASKS.index(mask_kind))
    b, k, length = 2, den.num_features, den.seq_len
    noisy = rng.standard_normal((b, k, length)).astype(np.float32)
    observed = rng.normal(scale=0.3, size=(b, k, length)).astype(np.float32)
    mask = make_mask(mask_kind, rng, b, k, length)
    got = den.forward(noisy, observed, mask, step)
    want = torch_forward(model, noisy, observed, mask, step)
    assert got.shape == want.shape == (b, k, length) and got.dtype == np.float32
    assert np.abs(want).max() > 1e-3  # a non-trivial output (the random last conv is non-zero)
    max_diff(got, want, f"forward tiny step={step} mask={mask_kind}")
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)


def test_forward_tiny_long_model(tiny):
    den, model, _ = tiny["long"]
    rng = np.random.default_rng(11)
    b, k, length = 1, den.num_features, den.seq_len
    assert length == 75
    noisy = rng.standard_normal((b, k, length)).astype(np.float32)
    observed = rng.normal(scale=0.3, size=(b, k, length)).astype(np.float32)
    mask = make_mask("forecast", rng, b, k, length)
    got, want = den.forward(noisy, observed, mask, 30), torch_forward(model, noisy, observed, mask, 30)
    max_diff(got, want, "forward tiny long L=75")
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)


def test_forward_full_size(tmp_path_factory):
    """One forward of the paper-size denoiser (C = 64, 12 blocks, 8 heads) at K = 66, L = 75."""
    d = make_model_dir(tmp_path_factory.mktemp("parity_full"), "full", seed=1)
    path = d / "long.safetensors"
    den = tcd.engine.Denoiser.load(path)
    model, _, cfg = load_model_file(path)
    assert cfg["model"]["channels"] == 64 and cfg["model"]["num_layers"] == 12
    rng = np.random.default_rng(5)
    b, k, length = 1, den.num_features, den.seq_len
    assert (k, length) == (66, 75)
    noisy = rng.standard_normal((b, k, length)).astype(np.float32)
    observed = rng.normal(scale=0.3, size=(b, k, length)).astype(np.float32)
    mask = make_mask("random", rng, b, k, length)
    got, want = den.forward(noisy, observed, mask, 23), torch_forward(model, noisy, observed, mask, 23)
    assert np.abs(want).max() > 1e-3
    max_diff(got, want, "forward full-size K=66 L=75")
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)


# ------------------------------------------------------------------------------- every kernel path


@pytest.fixture(scope="module")
def reduced_dir(tmp_path_factory):
    """The bundled model's size (3 layers x 32 channels, 4 heads of 8): the shapes the fast kernels tile."""
    return make_model_dir(tmp_path_factory.mktemp("parity_reduced"), "reduced", seed=8)


@pytest.mark.parametrize("kernel", ALL_KERNELS)
@pytest.mark.parametrize("size", ["tiny", "reduced"])
def test_forward_every_kernel(tiny_model_dir, reduced_dir, size, kernel, monkeypatch):
    """Each kernel path this CPU supports (the portable one forced) against PyTorch, both roles."""
    d = tiny_model_dir if size == "tiny" else reduced_dir
    for role, step in (("short", 3), ("long", 41)):
        path = d / f"{role}.safetensors"
        den = load_kernel(path, kernel, monkeypatch)
        model, _, _ = load_model_file(path)
        rng = np.random.default_rng(ALL_KERNELS.index(kernel) * 10 + step)
        b, k, length = 2, den.num_features, den.seq_len
        noisy = rng.standard_normal((b, k, length)).astype(np.float32)
        observed = rng.normal(scale=0.3, size=(b, k, length)).astype(np.float32)
        mask = make_mask("random", rng, b, k, length)
        got, want = den.forward(noisy, observed, mask, step), torch_forward(model, noisy, observed, mask, step)
        max_diff(got, want, f"forward {size} {role} kernel={kernel}")
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)


@pytest.mark.slow
@pytest.mark.parametrize("kernel", ALL_KERNELS)
def test_cascade_every_kernel(reduced_dir, kernel, monkeypatch):
    """A whole DDPM-10 cascade (2 samples) per kernel path, injected noise, against PyTorch."""
    short = load_kernel(reduced_dir / "short.safetensors", kernel, monkeypatch)
    long = load_kernel(reduced_dir / "long.safetensors", kernel, monkeypatch)
    ms, ss, _ = load_model_file(reduced_dir / "short.safetensors")
    ml, sl, _ = load_model_file(reduced_dir / "long.safetensors")
    rng = np.random.default_rng(200 + ALL_KERNELS.index(kernel))
    k, s = short.num_features, 2
    observed, mask = observation(rng, 1, k, OBS_LEN, OBS_LEN)
    kw = dict(sampler="ddpm", num_inference_steps=10, timestep_spacing="trailing")
    ns = rng.standard_normal((s, 11, 1, k, short.seq_len)).astype(np.float32)
    nl = rng.standard_normal((s, 11, 1, k, long.seq_len)).astype(np.float32)
    got = tcd.engine.cascade_raw(
        short, long, observed, mask, num_samples=s, noise_short=ns, noise_long=nl, sampler=SamplerOptions(**kw)
    )
    want = D.cascade(
        ms,
        ss,
        ml,
        sl,
        torch.from_numpy(observed),
        torch.from_numpy(mask),
        short_len=short.seq_len,
        long_len=long.seq_len,
        num_samples=s,
        noise_short=torch.from_numpy(ns),
        noise_long=torch.from_numpy(nl),
        **kw,
    )
    what = f"cascade reduced kernel={kernel}"
    assert chain_close(got["short_mean"], want["short_mean"].numpy(), what + " short_mean")
    assert chain_close(got["samples"], want["samples"].numpy()[..., OBS_LEN:], what + " samples")


# ------------------------------------------------------------------------------------ chains

CHAINS = [
    # sampler, num_inference_steps, eta, timestep_spacing, num_samples
    ("ddpm", None, 0.0, "trailing", 2),  # the reference: all 50 steps
    ("ddpm", 10, 0.0, "trailing", 1),  # respaced DDPM
    ("ddim", 10, 0.0, "trailing", 1),
    ("ddim", 10, 1.0, "trailing", 1),
    ("ddim", 10, 0.0, "leading", 1),
    ("ddim", 10, 1.0, "leading", 1),
    ("ddim", 10, 0.0, "linspace", 1),
    ("ddim", 7, 0.5, "linspace", 2),
    ("dpmpp2m", 5, 0.0, "trailing", 1),  # DPM-Solver++(2M): one noise block (x_T)
    ("dpmpp2m", 10, 0.0, "trailing", 2),
    ("dpmpp2m", 20, 0.0, "trailing", 1),
    ("dpmpp2m", 10, 0.0, "linspace", 1),
]


@pytest.mark.parametrize("sampler,steps,eta,spacing,num_samples", CHAINS)
def test_chain_injected_noise(tiny, sampler, steps, eta, spacing, num_samples):
    den, model, sched = tiny["short"]
    rng = np.random.default_rng(100 + CHAINS.index((sampler, steps, eta, spacing, num_samples)))
    b, k, length = 1, den.num_features, den.seq_len
    observed, mask = observation(rng, b, k, length, OBS_LEN)
    kw = dict(sampler=sampler, num_inference_steps=steps, eta=eta, timestep_spacing=spacing)
    assert den.timesteps(sampler=SamplerOptions(**kw)) == [t for t, _ in D.step_pairs(50, sampler, steps, spacing)]
    blocks = den.num_noise_blocks(sampler=SamplerOptions(**kw))
    noise = rng.standard_normal((num_samples, blocks, b, k, length)).astype(np.float32)
    got = den.sample(observed, mask, num_samples, noise=noise, sampler=SamplerOptions(**kw))
    want = D.sample_many(
        model,
        sched,
        torch.from_numpy(observed),
        torch.from_numpy(mask),
        num_samples,
        noise=torch.from_numpy(noise),
        **kw,
    ).numpy()
    assert got.shape == want.shape == (num_samples, b, k, length)
    assert np.abs(want).max() > 1.0  # the chain really moved
    assert chain_close(got, want, f"chain {sampler} n={steps} eta={eta} {spacing} S={num_samples}")
    # observed entries come back bit for bit
    sel = np.broadcast_to(mask == 1, got.shape)
    assert np.array_equal(got[sel], np.broadcast_to(observed, got.shape)[sel])


def test_seeded_noise_matches_torch_fed_the_same_streams(tiny):
    """The seeded path consumes exactly `tcd.engine.seeded_noise`: PyTorch fed that array agrees."""
    den, model, sched = tiny["short"]
    rng = np.random.default_rng(21)
    b, k, length, s = 2, den.num_features, den.seq_len, 2
    observed, mask = observation(rng, b, k, length, OBS_LEN)
    kw = dict(sampler="ddim", num_inference_steps=8, eta=1.0, timestep_spacing="trailing")
    blocks = den.num_noise_blocks(sampler=SamplerOptions(**kw))
    noise = tcd.engine.seeded_noise(1234, tcd.engine.STAGE_SHORT, s, blocks, b, k, length)
    assert noise.shape == (s, blocks, b, k, length) and noise.dtype == np.float32
    assert abs(float(noise.mean())) < 0.05 and abs(float(noise.std()) - 1) < 0.05
    seeded = den.sample(observed, mask, s, seed=1234, sampler=SamplerOptions(**kw))
    assert np.array_equal(seeded, den.sample(observed, mask, s, noise=noise, sampler=SamplerOptions(**kw)))
    want = D.sample_many(
        model, sched, torch.from_numpy(observed), torch.from_numpy(mask), s, noise=torch.from_numpy(noise), **kw
    ).numpy()
    assert chain_close(seeded, want, "seeded chain ddim n=8 eta=1")


# ------------------------------------------------------------------------------------ cascade / repair


def torch_cascade(tiny, observed, mask, s, noise_short, noise_long, **kw):
    _, ms, ss = tiny["short"]
    _, ml, sl = tiny["long"]
    return D.cascade(
        ms,
        ss,
        ml,
        sl,
        torch.from_numpy(observed),
        torch.from_numpy(mask),
        short_len=55,
        long_len=75,
        num_samples=s,
        noise_short=torch.from_numpy(noise_short),
        noise_long=torch.from_numpy(noise_long),
        **kw,
    )


@pytest.mark.parametrize("sampler,steps,eta,s", [("ddpm", None, 0.0, 1), ("ddim", 10, 1.0, 2), ("dpmpp2m", 10, 0.0, 2)])
def test_cascade_injected_noise(tiny, sampler, steps, eta, s):
    short, long = tiny["short"][0], tiny["long"][0]
    rng = np.random.default_rng(31)
    b, k = 1, short.num_features
    observed, mask = observation(rng, b, k, OBS_LEN, OBS_LEN, missing=0.3)
    kw = dict(sampler=sampler, num_inference_steps=steps, eta=eta, timestep_spacing="trailing")
    n_s, n_l = short.num_noise_blocks(sampler=SamplerOptions(**kw)), long.num_noise_blocks(sampler=SamplerOptions(**kw))
    noise_short = rng.standard_normal((s, n_s, b, k, short.seq_len)).astype(np.float32)
    noise_long = rng.standard_normal((s, n_l, b, k, long.seq_len)).astype(np.float32)
    got = tcd.engine.cascade_raw(
        short,
        long,
        observed,
        mask,
        num_samples=s,
        noise_short=noise_short,
        noise_long=noise_long,
        sampler=SamplerOptions(**kw),
    )
    want = torch_cascade(tiny, observed, mask, s, noise_short, noise_long, **kw)
    samples = want["samples"].numpy()
    assert got["samples"].shape == (s, b, k, 25) and got["mean"].shape == (b, k, 25)
    assert got["repaired"].shape == (b, k, OBS_LEN) and got["short_mean"].shape == (b, k, 55)
    what = f"cascade {sampler} n={steps} eta={eta} S={s}"
    assert chain_close(got["short_mean"], want["short_mean"], what + " short_mean")
    assert chain_close(got["samples"], samples[..., OBS_LEN:], what + " samples")
    assert chain_close(got["mean"], samples[..., OBS_LEN:].mean(axis=0), what + " mean")
    assert chain_close(got["repaired"], want["short_mean"].numpy()[..., :OBS_LEN], what + " repaired")
    assert np.abs(samples).max() > 1.0
    sel = mask == 1
    assert np.array_equal(got["repaired"][sel], observed[sel])


def test_cascade_seeded_matches_torch_fed_the_same_streams(tiny):
    short, long = tiny["short"][0], tiny["long"][0]
    rng = np.random.default_rng(41)
    b, k, s = 2, short.num_features, 1
    observed, mask = observation(rng, b, k, OBS_LEN, OBS_LEN)
    kw = dict(sampler="ddim", num_inference_steps=5, eta=1.0, timestep_spacing="trailing")
    n = short.num_noise_blocks(sampler=SamplerOptions(**kw))
    noise_short = tcd.engine.seeded_noise(99, tcd.engine.STAGE_SHORT, s, n, b, k, short.seq_len)
    noise_long = tcd.engine.seeded_noise(99, tcd.engine.STAGE_LONG, s, n, b, k, long.seq_len)
    got = tcd.engine.cascade_raw(short, long, observed, mask, num_samples=s, seed=99, sampler=SamplerOptions(**kw))
    want = torch_cascade(tiny, observed, mask, s, noise_short, noise_long, **kw)
    assert chain_close(got["samples"], want["samples"].numpy()[..., OBS_LEN:], "seeded cascade ddim n=5 eta=1")


@pytest.mark.parametrize("sampler,steps,eta", [("ddim", 1, 0.0), ("ddpm", 10, 0.0), ("ddim", 5, 1.0)])
def test_centred_noise_cascade_matches_torch(tiny, sampler, steps, eta):
    """noise_coupling="centered": the engine centres each sequence's x_T (training.diffusion.couple_noise) in both
    stages, injected or seeded, and agrees with PyTorch fed the raw streams with the same coupling."""
    short, long = tiny["short"][0], tiny["long"][0]
    rng = np.random.default_rng(43)
    b, k, s = 2, short.num_features, 3
    observed, mask = observation(rng, b, k, OBS_LEN, OBS_LEN, missing=0.3)
    kw = dict(
        sampler=sampler, num_inference_steps=steps, eta=eta, timestep_spacing="trailing", noise_coupling="centered"
    )
    n = short.num_noise_blocks(sampler=SamplerOptions(**kw))
    noise_short = tcd.engine.seeded_noise(5, tcd.engine.STAGE_SHORT, s, n, b, k, short.seq_len)
    noise_long = tcd.engine.seeded_noise(5, tcd.engine.STAGE_LONG, s, n, b, k, long.seq_len)
    got = tcd.engine.cascade_raw(short, long, observed, mask, num_samples=s, seed=5, sampler=SamplerOptions(**kw))
    injected = tcd.engine.cascade_raw(
        short,
        long,
        observed,
        mask,
        num_samples=s,
        noise_short=noise_short,
        noise_long=noise_long,
        sampler=SamplerOptions(**kw),
    )
    assert all(np.array_equal(got[key], injected[key]) for key in got)
    want = torch_cascade(tiny, observed, mask, s, noise_short, noise_long, **kw)
    what = f"centred cascade {sampler} n={steps} eta={eta}"
    assert chain_close(got["short_mean"], want["short_mean"], what + " short_mean")
    assert chain_close(got["samples"], want["samples"].numpy()[..., OBS_LEN:], what + " samples")
    independent = tcd.engine.cascade_raw(
        short,
        long,
        observed,
        mask,
        num_samples=s,
        seed=5,
        sampler=SamplerOptions(**{**kw, "noise_coupling": "independent"}),
    )
    assert not np.allclose(independent["samples"], got["samples"])  # the coupling changes what is sampled
    # the twin's coupling: x_T of each sequence sums to zero, each rescaled to unit variance; z's untouched
    coupled = D.couple_noise(torch.from_numpy(noise_long), "centered").numpy()
    assert np.abs(coupled[:, 0].sum(axis=0)).max() < 1e-5
    assert np.array_equal(coupled[:, 1:], noise_long[:, 1:])
    assert abs(float(coupled[:, 0].std()) - 1) < 0.05
    assert D.couple_noise(torch.from_numpy(noise_long[:1]), "centered").numpy().tobytes() == noise_long[:1].tobytes()


def test_repair_injected_noise(tiny):
    den, model, sched = tiny["short"]
    rng = np.random.default_rng(51)
    b, k, s = 1, den.num_features, 2
    observed, mask = observation(rng, b, k, OBS_LEN, OBS_LEN, missing=0.4)
    kw = dict(sampler="ddim", num_inference_steps=10, eta=0.0, timestep_spacing="trailing")
    noise = rng.standard_normal((s, 11, b, k, den.seq_len)).astype(np.float32)
    got = tcd.engine.repair_raw(den, observed, mask, num_samples=s, noise=noise, sampler=SamplerOptions(**kw))
    want = D.repair(
        model,
        sched,
        torch.from_numpy(observed),
        torch.from_numpy(mask),
        seq_len=den.seq_len,
        num_samples=s,
        noise=torch.from_numpy(noise),
        **kw,
    ).numpy()
    assert chain_close(got["mean"], want, "repair ddim n=10")
    sel = mask == 1
    assert np.array_equal(got["mean"][sel], observed[sel])
    assert not np.array_equal(got["mean"][~sel], observed[~sel])  # the gaps were filled


def test_dpmpp2m_noise_blocks_seeded_and_repair(tiny):
    """dpmpp2m consumes x_T only: one noise block; the seeded path equals `seeded_noise` with one block
    and PyTorch fed it; repair agrees with the reference."""
    den, model, sched = tiny["short"]
    assert den.num_noise_blocks(sampler=SamplerOptions(sampler="dpmpp2m", num_inference_steps=10)) == 1
    assert den.num_noise_blocks(sampler=SamplerOptions(sampler="ddim", num_inference_steps=10)) == 11
    rng = np.random.default_rng(61)
    b, k, s = 2, den.num_features, 2
    observed, mask = observation(rng, b, k, den.seq_len, OBS_LEN)
    kw = dict(sampler="dpmpp2m", num_inference_steps=10, timestep_spacing="trailing")
    noise = tcd.engine.seeded_noise(77, tcd.engine.STAGE_SHORT, s, 1, b, k, den.seq_len)
    seeded = den.sample(observed, mask, s, seed=77, sampler=SamplerOptions(**kw))
    assert np.array_equal(seeded, den.sample(observed, mask, s, noise=noise, sampler=SamplerOptions(**kw)))
    want = D.sample_many(
        model, sched, torch.from_numpy(observed), torch.from_numpy(mask), s, noise=torch.from_numpy(noise), **kw
    ).numpy()
    assert chain_close(seeded, want, "seeded chain dpmpp2m n=10")
    with pytest.raises(tcd.InvalidInputError, match="noise"):
        den.sample(
            observed, mask, s, noise=np.zeros((s, 11, b, k, den.seq_len), np.float32), sampler=SamplerOptions(**kw)
        )
    obs, m = observation(rng, 1, k, OBS_LEN, OBS_LEN, missing=0.4)
    rnoise = rng.standard_normal((s, 1, 1, k, den.seq_len)).astype(np.float32)
    got = tcd.engine.repair_raw(den, obs, m, num_samples=s, noise=rnoise, sampler=SamplerOptions(**kw))
    want = D.repair(
        model,
        sched,
        torch.from_numpy(obs),
        torch.from_numpy(m),
        seq_len=den.seq_len,
        num_samples=s,
        noise=torch.from_numpy(rnoise),
        **kw,
    ).numpy()
    assert chain_close(got["mean"], want, "repair dpmpp2m n=10")
    sel = m == 1
    assert np.array_equal(got["mean"][sel], obs[sel])


# ------------------------------------------------------------------------- interpolated conditioning


def tiny_repair(tmp_path_factory, name: str, seed: int, over: dict):
    """A tiny repair model (50 + 0 frames) with the model-config overrides ``over``, each checked in both
    the PyTorch and the Rust configuration: (rust Denoiser, torch model, schedule)."""
    d = make_model_dir(tmp_path_factory.mktemp(name), "tiny", seed=seed, repair=over)
    path = d / "repair.safetensors"
    model, sched, _ = load_model_file(path)
    den = tcd.engine.Denoiser.load(path)
    for key, value in over.items():
        assert getattr(model.cfg, key) == value and den.config["model"][key] == value, key
    return den, model, sched


@pytest.fixture(scope="module")
def tiny_linear(tmp_path_factory):
    """A repair model with cond_fill = "linear"."""
    return tiny_repair(tmp_path_factory, "parity_linear", 5, {"cond_fill": "linear"})


@pytest.mark.parametrize("mask_kind", ["random", "gaps", "none_observed", "all_observed"])
@pytest.mark.parametrize("fill,seed", [("linear", 71), ("spline", 171)])
def test_forward_cond_fill(request, fill, seed, mask_kind):
    """The interpolated observed channel (linear or spline fill; rows with 0, 1, 2 and many observed frames;
    leading, inner and trailing gaps): same numbers in Rust and PyTorch; masked observed entries (NaN here)
    are never read."""
    den, model, _ = request.getfixturevalue({"linear": "tiny_linear", "spline": "tiny_spline"}[fill])
    rng = np.random.default_rng(seed + len(mask_kind))
    b, k, length = 2, den.num_features, den.seq_len
    noisy = rng.standard_normal((b, k, length)).astype(np.float32)
    observed = rng.normal(scale=0.3, size=(b, k, length)).astype(np.float32)
    if mask_kind == "gaps":
        mask = np.ones((b, k, length), np.float32)
        mask[:, :, :3] = mask[:, :, 20:31] = mask[:, :, 45:] = 0
        mask[:, 0] = 0
        mask[:, 0, 7] = 1  # one observed frame: held
        mask[:, 1] = 0
        mask[:, 1, [4, 30]] = 1  # two: a straight line between them
    else:
        mask = make_mask(mask_kind, rng, b, k, length)
    got = den.forward(noisy, np.where(mask > 0, observed, np.nan).astype(np.float32), mask, 13)
    want = torch_forward(model, noisy, observed, mask, 13)
    max_diff(got, want, f"forward cond_fill={fill} mask={mask_kind}")
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)


def test_repair_cond_fill_linear_injected_noise(tiny_linear):
    den, model, sched = tiny_linear
    rng = np.random.default_rng(81)
    b, k, s = 2, den.num_features, 2
    observed, mask = observation(rng, b, k, OBS_LEN, OBS_LEN, missing=0.4)
    kw = dict(sampler="ddpm", num_inference_steps=10, timestep_spacing="trailing")
    noise = rng.standard_normal((s, 11, b, k, den.seq_len)).astype(np.float32)
    got = tcd.engine.repair_raw(den, observed, mask, num_samples=s, noise=noise, sampler=SamplerOptions(**kw))
    want = D.repair(
        model,
        sched,
        torch.from_numpy(observed),
        torch.from_numpy(mask),
        seq_len=den.seq_len,
        num_samples=s,
        noise=torch.from_numpy(noise),
        **kw,
    ).numpy()
    assert chain_close(got["mean"], want, "repair cond_fill=linear ddpm n=10")
    sel = mask == 1
    assert np.array_equal(got["mean"][sel], observed[sel])


@pytest.fixture(scope="module")
def tiny_residual(tmp_path_factory):
    """A repair model that diffuses 5 x the residual over the linear fill."""
    return tiny_repair(
        tmp_path_factory,
        "parity_residual",
        6,
        {"cond_fill": "linear", "target": "linear_residual", "target_scale": 5.0},
    )


@pytest.fixture(scope="module")
def tiny_spline(tmp_path_factory):
    """A repair model conditioned on the natural cubic spline fill and diffusing 20 x the residual over it."""
    return tiny_repair(
        tmp_path_factory, "parity_spline", 8, {"cond_fill": "spline", "target": "spline_residual", "target_scale": 20.0}
    )


@pytest.mark.parametrize(
    "fill,sampler,steps",
    [
        ("linear", "ddpm", 10),
        ("linear", "ddim", 5),
        ("linear", "dpmpp2m", 5),
        ("spline", "ddpm", 10),
        ("spline", "ddim", 5),
    ],
)
def test_repair_residual_injected_noise(request, fill, sampler, steps):
    """target = linear_residual / spline_residual: the chain runs on the scaled residual and is mapped back
    onto the fill before the observation is merged, identically in Rust and PyTorch; observed entries are
    returned bit for bit."""
    from training.model import FILLS

    den, model, sched = request.getfixturevalue({"linear": "tiny_residual", "spline": "tiny_spline"}[fill])
    seed, atol = {"linear": (91, 1e-3), "spline": (191, 1e-4)}[fill]
    rng = np.random.default_rng(seed + steps)
    b, k, s = 2, den.num_features, 2
    observed, mask = observation(rng, b, k, OBS_LEN, OBS_LEN, missing=0.4)
    mask[0, :, 10:25] = 0  # a long gap, all joints
    kw = dict(sampler=sampler, num_inference_steps=steps, timestep_spacing="trailing")
    blocks = 1 if sampler == "dpmpp2m" else steps + 1
    noise = rng.standard_normal((s, blocks, b, k, den.seq_len)).astype(np.float32)
    got = tcd.engine.repair_raw(den, observed, mask, num_samples=s, noise=noise, sampler=SamplerOptions(**kw))
    want = D.repair(
        model,
        sched,
        torch.from_numpy(observed),
        torch.from_numpy(mask),
        seq_len=den.seq_len,
        num_samples=s,
        noise=torch.from_numpy(noise),
        **kw,
    ).numpy()
    assert chain_close(got["mean"], want, f"repair target={fill}_residual {sampler} n={steps}")
    sel = mask == 1
    assert np.array_equal(got["mean"][sel], observed[sel])
    # the chain's residual is not negligible, so the comparison above exercises the mapping back
    base = FILLS[fill](torch.from_numpy(observed), torch.from_numpy(mask)).numpy()
    assert not np.allclose(got["mean"], base, atol=atol)


# ------------------------------------------------------------------------- a repair model around its fill


@pytest.fixture(scope="module")
def fill_repair_dir(tmp_path_factory):
    """A repair model conditioned on its repair fill (cond_fill "prior": a 4-block prior with anchor "window"
    over the 50-frame window, random like the model) and diffusing 10 x the residual over it."""
    return make_model_dir(
        tmp_path_factory.mktemp("parity_repair_fill"),
        "tiny",
        seed=9,
        repair={"cond_fill": "prior", "target": "prior_residual", "target_scale": 10.0},
    )


@pytest.mark.parametrize("kernel", ALL_KERNELS)
@pytest.mark.parametrize("sampler,steps", [("ddpm", 10), ("ddim", 1)])
def test_repair_around_a_repair_fill_every_kernel(fill_repair_dir, sampler, steps, kernel, monkeypatch):
    """The engine fills the masked entries once with the repair fill's correction of the spline
    (``training.model.prior_fill``) and runs the chain on the residual over it, as PyTorch does, on each
    kernel path; observed entries come back bit for bit, and the fill is neither the spline nor ignored."""
    from training.prior_net import load_prior_file
    from training.model import prior_fill, spline_fill

    den = load_kernel(fill_repair_dir / "repair.safetensors", kernel, monkeypatch)
    fill = load_kernel(fill_repair_dir / "repair_fill.safetensors", kernel, monkeypatch, cls=tcd.engine.Prior)
    assert fill.anchor == "window" and fill.obs_len == fill.chunk == den.seq_len
    model, sched, _ = load_model_file(fill_repair_dir / "repair.safetensors")
    model.attach_prior(load_prior_file(fill_repair_dir / "repair_fill.safetensors")[0])
    rng = np.random.default_rng(300 + steps + ALL_KERNELS.index(kernel))
    b, k, s = 2, den.num_features, 2
    observed, mask = observation(rng, b, k, OBS_LEN, OBS_LEN, missing=0.4)
    mask[0, :, 10:25] = 0  # a long gap, all joints
    kw = dict(sampler=sampler, num_inference_steps=steps, timestep_spacing="trailing")
    noise = rng.standard_normal((s, steps + 1, b, k, den.seq_len)).astype(np.float32)
    got = tcd.engine.repair_raw(
        den, observed, mask, num_samples=s, noise=noise, fill=fill, sampler=SamplerOptions(**kw)
    )
    want = D.repair(
        model,
        sched,
        torch.from_numpy(observed),
        torch.from_numpy(mask),
        seq_len=den.seq_len,
        num_samples=s,
        noise=torch.from_numpy(noise),
        **kw,
    ).numpy()
    assert chain_close(got["mean"], want, f"repair around its fill, {sampler} n={steps}, {kernel}")
    sel = mask == 1
    assert np.array_equal(got["mean"][sel], observed[sel])
    obs_t, mask_t = torch.from_numpy(observed), torch.from_numpy(mask)
    base = prior_fill(model.prior, obs_t, mask_t).numpy()
    assert not np.allclose(base, spline_fill(obs_t, mask_t).numpy(), atol=1e-3)  # the fill corrects the spline
    assert not np.allclose(got["mean"], base, atol=1e-4)  # and the chain adds to it
    # without its fill the call is refused, naming it
    with pytest.raises(tcd.exceptions.InvalidInputError, match="repair fill") as ei:
        tcd.engine.repair_raw(den, observed, mask, num_samples=s, noise=noise, sampler=SamplerOptions(**kw))
    assert ei.value.argument == "fill"


@pytest.fixture(scope="module")
def gap_fill_repair_dir(fill_repair_dir, tmp_path_factory):
    """``fill_repair_dir`` with a random prior forecaster (``prior.safetensors``, 4 blocks) and its repair fill
    set to fill whole-frame gaps with it (``gap_fill: "forecaster"``; the same weights)."""
    import shutil

    from training.export import write_model_json
    from training.prior_net import build_prior_config, load_prior_file, random_prior
    from training.fileformat import PRIOR_FILE, REPAIR_FILL_FILE, save_model_file

    d = tmp_path_factory.mktemp("parity_gap_fill") / "model"
    shutil.copytree(fill_repair_dir, d)
    fill, cfg = load_prior_file(d / REPAIR_FILL_FILE)
    fill.cfg.gap_fill = "forecaster"
    save_model_file(d / REPAIR_FILL_FILE, fill, build_prior_config(fill, cfg["data"]))
    forecaster = random_prior(blocks=4, seed=31)
    save_model_file(d / PRIOR_FILE, forecaster, build_prior_config(forecaster, cfg["data"]))
    write_model_json(d)
    return d


def gap_observation(rng, k):
    """Three 50-frame observations with whole-frame gaps: frames 10-24 of the first, 0-5 of the second, 44-49
    and 20 of the third (every other frame keeps 60 % of its entries)."""
    observed, mask = observation(rng, 3, k, OBS_LEN, OBS_LEN, missing=0.4)
    for b, frames in ((0, slice(10, 25)), (1, slice(0, 6)), (2, slice(44, 50)), (2, slice(20, 21))):
        mask[b, :, frames] = 0
        observed[b, :, frames] = 0
    return observed, mask


@pytest.mark.parametrize("kernel", ALL_KERNELS)
@pytest.mark.parametrize("sampler,steps", [("ddpm", 10), ("ddim", 1)])
def test_repair_around_a_gap_filling_repair_fill_every_kernel(gap_fill_repair_dir, sampler, steps, kernel, monkeypatch):
    """A repair fill with ``gap_fill: "forecaster"``: the engine fills the window's whole-frame gaps from the
    prior forecaster, forward and backward (``training.model.fill_gaps``), after the fill's correction of the
    spline, as PyTorch does, on each kernel path; the gaps (and only they) differ from the plain fill, and the
    repair around them from the plain fill's; without the forecaster the call is refused, naming it."""
    from training.prior_net import load_prior_file
    from training.model import prior_fill, whole_frame_gaps

    d = gap_fill_repair_dir
    den = load_kernel(d / "repair.safetensors", kernel, monkeypatch)
    fill = load_kernel(d / "repair_fill.safetensors", kernel, monkeypatch, cls=tcd.engine.Prior)
    forecaster = load_kernel(d / "prior.safetensors", kernel, monkeypatch, cls=tcd.engine.Prior)
    assert fill.gap_fill == "forecaster" and forecaster.gap_fill == "none"
    model, sched, _ = load_model_file(d / "repair.safetensors")
    gapped = load_prior_file(d / "repair_fill.safetensors")[0]  # its forecaster attached, from beside it
    rng = np.random.default_rng(500 + steps + ALL_KERNELS.index(kernel))
    observed, mask = gap_observation(rng, den.num_features)
    obs_t, mask_t = torch.from_numpy(observed), torch.from_numpy(mask)
    assert whole_frame_gaps(mask_t) == [(0, 10, 25), (1, 0, 6), (2, 20, 21), (2, 44, 50)]
    s = 2
    kw = dict(sampler=sampler, num_inference_steps=steps, timestep_spacing="trailing")
    noise = rng.standard_normal((s, steps + 1, 3, den.num_features, den.seq_len)).astype(np.float32)
    got = tcd.engine.repair_raw(
        den, observed, mask, num_samples=s, noise=noise, fill=fill, forecaster=forecaster, sampler=SamplerOptions(**kw)
    )["mean"]
    want = {}
    for name, gap_fill in (("gaps", "forecaster"), ("plain", "none")):
        gapped.cfg.gap_fill = gap_fill
        model.attach_prior(gapped)
        want[name] = D.repair(
            model,
            sched,
            obs_t,
            mask_t,
            seq_len=den.seq_len,
            num_samples=s,
            noise=torch.from_numpy(noise),
            **kw,
        ).numpy()
        want[name + " fill"] = prior_fill(gapped, obs_t, mask_t).numpy()
    assert chain_close(got, want["gaps"], f"repair around a gap-filling fill, {sampler} n={steps}, {kernel}")
    in_gap = np.zeros(mask.shape, bool)
    for b, start, end in whole_frame_gaps(mask_t):
        in_gap[b, :, start:end] = True
    fill_diff = np.abs(want["gaps fill"] - want["plain fill"])
    assert fill_diff[in_gap].min() > 0 and np.array_equal(want["gaps fill"][~in_gap], want["plain fill"][~in_gap])
    assert np.abs(got - want["plain"])[in_gap].mean() > 1e-3  # the gap fill changed the repair
    # the fill itself as the engine gives it (tcd.engine.Prior.fill, frame-major), with and without the forecaster
    btk = lambda a: np.ascontiguousarray(a.transpose(0, 2, 1))  # noqa: E731
    np.testing.assert_allclose(
        fill.fill(btk(observed), btk(mask), forecaster=forecaster), btk(want["gaps fill"]), rtol=0, atol=1e-5
    )
    with pytest.raises(tcd.exceptions.InvalidInputError, match="prior forecaster"):
        fill.fill(btk(observed), btk(mask))
    with pytest.raises(tcd.exceptions.InvalidInputError, match="prior forecaster") as ei:
        tcd.engine.repair_raw(den, observed, mask, num_samples=s, noise=noise, fill=fill, sampler=SamplerOptions(**kw))
    assert ei.value.argument == "forecaster"


@pytest.fixture(scope="module")
def inbetween_repair_dir(gap_fill_repair_dir, tmp_path_factory):
    """``gap_fill_repair_dir`` with both in-betweeners in its repair fill (``training.export.set_inbetween``): random
    kernels (N(0, 0.05)) for whole-frame gaps of 1 to 15 frames with 4 context frames each side, and for a
    coordinate's runs of 1 to 3 hidden frames with 2."""
    import shutil

    from training.export import set_inbetween
    from training.inbetween import kernel_width, save_kernels

    d = tmp_path_factory.mktemp("parity_inbetween") / "model"
    shutil.copytree(gap_fill_repair_dir, d)
    rng = np.random.default_rng(41)
    kernels = {n: (0.05 * rng.standard_normal((n, kernel_width(n, 4)))).astype(np.float32) for n in range(1, 16)}
    save_kernels(d / "kernels.npz", kernels, 4, {"random": True})
    set_inbetween(d, d / "kernels.npz")
    joints = {n: (0.05 * rng.standard_normal((n, kernel_width(n, 2)))).astype(np.float32) for n in range(1, 4)}
    save_kernels(d / "joint_kernels.npz", joints, 2, {"random": True})
    set_inbetween(d, d / "joint_kernels.npz", "joint_inbetween")
    return d


@pytest.mark.parametrize("kernel", ALL_KERNELS)
def test_repair_fill_with_an_in_betweener_every_kernel(inbetween_repair_dir, kernel, monkeypatch):
    """A gap-filling repair fill with both in-betweeners (``training.inbetween``): the engine corrects each
    whole-frame gap of a length it has a kernel for after the gap fill, and each run of a coordinate's hidden
    frames outside them, as PyTorch does (``training.model.prior_fill``), on each kernel path: in the fill
    (``tcd.engine.Prior.fill``), the fill alone (``num_samples=0``) and the repair around it; observed entries
    never change, the gaps' frames and the short runs' do."""
    from training.prior_net import load_prior_file
    from training.model import prior_fill, whole_frame_gaps

    d = inbetween_repair_dir
    den = load_kernel(d / "repair.safetensors", kernel, monkeypatch)
    fill = load_kernel(d / "repair_fill.safetensors", kernel, monkeypatch, cls=tcd.engine.Prior)
    forecaster = load_kernel(d / "prior.safetensors", kernel, monkeypatch, cls=tcd.engine.Prior)
    model, sched, _ = load_model_file(d / "repair.safetensors")
    twin = load_prior_file(d / "repair_fill.safetensors")[0]
    assert (twin.cfg.inbetween_context, twin.cfg.inbetween_max_gap) == (4, 15)
    assert (twin.cfg.joint_inbetween_context, twin.cfg.joint_inbetween_max_gap) == (2, 3)
    rng = np.random.default_rng(700 + ALL_KERNELS.index(kernel))
    observed, mask = gap_observation(rng, den.num_features)
    obs_t, mask_t = torch.from_numpy(observed), torch.from_numpy(mask)
    want = prior_fill(twin, obs_t, mask_t).numpy()
    twin.cfg.inbetween_max_gap = twin.cfg.joint_inbetween_max_gap = 0
    without = prior_fill(twin, obs_t, mask_t).numpy()  # the same fill, no in-betweener
    twin.cfg.inbetween_max_gap, twin.cfg.joint_inbetween_max_gap = 15, 3
    in_gap = np.zeros(mask.shape, bool)
    for b, start, end in whole_frame_gaps(mask_t):
        in_gap[b, :, start:end] = True
    changed = want != without
    assert np.abs(want - without)[in_gap].min() > 0 and not changed[mask > 0.5].any()
    assert changed[(mask <= 0.5) & ~in_gap].mean() > 0.3  # many short runs of hidden entries
    btk = lambda a: np.ascontiguousarray(a.transpose(0, 2, 1))  # noqa: E731
    np.testing.assert_allclose(fill.fill(btk(observed), btk(mask), forecaster=forecaster), btk(want), rtol=0, atol=1e-5)
    alone = tcd.engine.repair_raw(den, observed, mask, num_samples=0, seed=0, fill=fill, forecaster=forecaster)
    np.testing.assert_allclose(alone["mean"], want, rtol=0, atol=1e-5)
    assert alone["samples"].shape == (0, 3, den.num_features, OBS_LEN)
    s, kw = 2, dict(sampler="ddim", num_inference_steps=1, timestep_spacing="trailing")
    noise = rng.standard_normal((s, 2, 3, den.num_features, den.seq_len)).astype(np.float32)
    got = tcd.engine.repair_raw(
        den, observed, mask, num_samples=s, noise=noise, fill=fill, forecaster=forecaster, sampler=SamplerOptions(**kw)
    )["mean"]
    model.attach_prior(twin)
    ref = D.repair(
        model, sched, obs_t, mask_t, seq_len=den.seq_len, num_samples=s, noise=torch.from_numpy(noise), **kw
    ).numpy()
    assert chain_close(got, ref, f"repair around a fill with an in-betweener, {kernel}")


def assert_repairs_as_the_engine(m, poses, **fills):
    """``TCD.repair`` of ``poses`` (T, 22, 3, NaN hidden) is ``tcd.engine.repair_raw`` of the directory's repair
    model given ``fills`` (its ``fill`` and ``forecaster`` keywords), bit for bit."""
    kw = dict(num_samples=2, seed=4, sampler=SamplerOptions(sampler="ddim", num_inference_steps=1))
    engine = lambda a: np.ascontiguousarray(a.reshape(1, OBS_LEN, 66).transpose(0, 2, 1))  # noqa: E731
    want = tcd.engine.repair_raw(
        m.repair_model, engine(np.nan_to_num(poses)), engine((~np.isnan(poses)).astype(np.float32)), **fills, **kw
    )["mean"]
    np.testing.assert_array_equal(engine(m.repair(poses, **kw).poses), want)


def assert_refused_without(d, tmp_path, name):
    """A copy of the model directory ``d`` without the file ``name`` does not load; the error names the file."""
    import shutil

    bare = tmp_path / "bare"
    shutil.copytree(d, bare)
    (bare / name).unlink()
    with pytest.raises(tcd.exceptions.WeightsError, match=name) as ei:
        tcd.load(bare)
    assert ei.value.path == str(bare / name)


def test_a_model_directory_repairs_with_its_gap_filling_fill(gap_fill_repair_dir, tmp_path):
    """``tcd.load`` gives a repair fill with ``gap_fill: "forecaster"`` the directory's prior forecaster in every
    repair (``TCD.repair`` against ``repair_raw`` with both); a directory without ``prior.safetensors`` is
    refused, the error naming it."""
    m = tcd.load(gap_fill_repair_dir)
    assert m.repair_fill.gap_fill == "forecaster" and m.prior is not None
    poses = np.random.default_rng(6).normal(scale=0.3, size=(OBS_LEN, 22, 3)).astype(np.float32)
    poses[10:20] = np.nan
    assert_repairs_as_the_engine(m, poses, fill=m.repair_fill, forecaster=m.prior)
    assert_refused_without(gap_fill_repair_dir, tmp_path, "prior.safetensors")


def test_a_model_directory_repairs_with_its_repair_fill(fill_repair_dir, tmp_path):
    """``tcd.load`` opens ``repair_fill.safetensors`` beside a repair model conditioned on it and every
    repair of the directory runs with it (here ``TCD.repair`` against ``repair_raw`` with the fill); without
    the file the directory is refused, the error naming it."""
    m = tcd.load(fill_repair_dir)
    assert m.repair_fill is not None and m.repair_fill.anchor == "window"
    assert "repair_fill.safetensors" in m.file_sha256
    poses = np.random.default_rng(5).normal(scale=0.3, size=(OBS_LEN, 22, 3)).astype(np.float32)
    poses[10:20, 3:9] = np.nan
    assert_repairs_as_the_engine(m, poses, fill=m.repair_fill)
    assert_refused_without(fill_repair_dir, tmp_path, "repair_fill.safetensors")
