"""Parity of the Rust engine with the PyTorch reference for TCD models conditioned on the prior forecaster
(``cond_fill="prior"``, ``target="prior_residual"``) and for x0-prediction (``diffusion.prediction_type``
``"sample"``), through the public ``tcd`` API, on the same weights and the same injected noise.

Fixture: a seeded random-init ``tiny`` short (50 + 5) and long (55 + 20) pair with cond_fill prior / target
prior_residual / target_scale 10 and a random 3-block prior forecaster (``training.prior_net.random_prior``: every
weight random, its forecast a few tenths of a metre from the last pose), written twice with the same weights:
once epsilon-predicting, once x0-predicting. The reference is ``training.diffusion.cascade`` on the models
``training.export.load_model_dir`` reads back from the same directory (the prior attached to both).

Criteria (those of tests/test_parity.py): whole cascades agree within ``CHAIN_ATOL`` = 1e-4 (metres, absolute),
for ddpm, ddim (eta 1) and dpmpp2m, epsilon- and x0-prediction, on every kernel path this CPU supports, with an
observation that has missing entries (NaN for the engine, 0 with mask 0 for the reference). The tests also
check that what they compare carries the features: the prior's fill moves the long window's masked frames
by more than ``CONTRIBUTION`` x atol from the spline's held last frame, and the x0 reading of the same weights
differs from the epsilon reading by more than that too.

Observed on this AVX2 EPYC (portable and avx2 paths; ``pytest -s`` prints every comparison): largest
difference 2.9e-6 for epsilon-prediction (ddpm 1.9e-6, ddim 2.9e-6, dpmpp2m 2.9e-6; outputs up to 15.5 m:
a random-init eps-predictor's x0 grows as x_T / sqrt(alpha_bar)) and 2.7e-7 for x0-prediction (ddpm 2.5e-7,
ddim 2.7e-7, dpmpp2m 2.4e-7; outputs up to 1.2 m); the seeded x0 cascade through ``tcd.load`` 2.4e-7, the
exported trained pair 3.6e-7. The prior's fill moves the long window's masked frames up to 6.4 m from the
held last frame; the x0 and epsilon readings of the same weights differ by up to 15 m.
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from conftest import import_torch

torch = import_torch("parity with the PyTorch reference")

import tcd  # noqa: E402
from fixtures_util import ALL_KERNELS, bad, load_kernel, read_weights  # noqa: E402
from tcd.exceptions import InvalidInputError, WeightsError  # noqa: E402
from training import diffusion as D  # noqa: E402
from training import export, fileformat, prior_net  # noqa: E402
from training.diffusion import DiffusionConfig  # noqa: E402
from training.model import prior_fill  # noqa: E402
from tcd import SamplerOptions  # noqa: E402

CHAIN_ATOL = 1e-4  # model units (metres), the cascade criterion of tests/test_parity.py
CONTRIBUTION = 1e2  # what a feature changes, at least, over CHAIN_ATOL
OBS, LS, LL = 50, 55, 75
PREDICTIONS = ("epsilon", "sample")
SAMPLERS = [  # sampler, num_inference_steps, eta, num_samples
    ("ddpm", 10, 0.0, 2),
    ("ddim", 10, 1.0, 2),
    ("dpmpp2m", 10, 0.0, 2),
]
PRIOR_MODEL = {"cond_fill": "prior", "target": "prior_residual", "target_scale": 10.0}

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _make_dir(out, prediction: str):
    return export.random_init_dir(
        out,
        preset="tiny",
        seed=7,
        diff_cfg=DiffusionConfig(prediction_type=prediction),
        model=PRIOR_MODEL,
        prior_blocks=3,
    )


@pytest.fixture(scope="module")
def dirs(tmp_path_factory):
    """prediction type -> model directory (short, long, prior; the same weights in both)."""
    return {p: _make_dir(tmp_path_factory.mktemp(f"prior_cond_{p}") / "m", p) for p in PREDICTIONS}


def observation(seed: int, batch: int = 2, k: int = 66, missing: float = 0.3):
    """(engine observed with NaN at missing entries, reference observed with 0 there, mask), (B, K, OBS)."""
    rng = np.random.default_rng(seed)
    mask = (rng.random((batch, k, OBS)) >= missing).astype(np.float32)
    mask[0, :5, -3:] = 0  # a few coordinates missing over the last frames (the prior reads them)
    mask[-1, 6:9, :] = 0  # one joint never observed: its spline fill is 0
    values = rng.normal(scale=0.3, size=(batch, k, OBS)).astype(np.float32)
    ref = (values * mask).astype(np.float32)
    eng = np.where(mask == 1, values, np.nan).astype(np.float32)
    return eng, ref, mask


def noise_for(seed: int, sampler: str, steps: int, s: int, batch: int = 2, k: int = 66):
    rng = np.random.default_rng(seed)
    blocks = 1 if sampler == "dpmpp2m" else steps + 1
    return (
        rng.standard_normal((s, blocks, batch, k, LS)).astype(np.float32),
        rng.standard_normal((s, blocks, batch, k, LL)).astype(np.float32),
    )


@functools.lru_cache(maxsize=None)
def _torch_models(path: str):
    return export.load_model_dir(path)


def torch_cascade(d, observed, mask, s, noise_short, noise_long, **kw):
    models = _torch_models(str(d))
    (ms, ss, _), (ml, sl, _) = models["short"], models["long"]
    out = D.cascade(
        ms,
        ss,
        ml,
        sl,
        torch.from_numpy(observed),
        torch.from_numpy(mask),
        short_len=LS,
        long_len=LL,
        num_samples=s,
        noise_short=torch.from_numpy(noise_short),
        noise_long=torch.from_numpy(noise_long),
        **kw,
    )
    return {k: v.numpy() for k, v in out.items()}


@functools.lru_cache(maxsize=None)
def reference(d, prediction: str, sampler: str, steps: int, eta: float, s: int):
    """The PyTorch cascade of one case (the same for every kernel path), with its inputs."""
    eng, ref, mask = observation(300 + SAMPLERS.index((sampler, steps, eta, s)))
    ns, nl = noise_for(400 + SAMPLERS.index((sampler, steps, eta, s)), sampler, steps, s)
    kw = dict(sampler=sampler, num_inference_steps=steps, eta=eta, timestep_spacing="trailing")
    return eng, ref, mask, ns, nl, kw, torch_cascade(d, ref, mask, s, ns, nl, **kw)


def max_diff(a, b, what=""):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    d = float(np.abs(a - b).max())
    print(f"parity {what}: max abs diff {d:.3g}, max |torch| {np.abs(b).max():.3g}")
    return d


# ------------------------------------------------------------------------------------------- parity


@pytest.mark.parametrize("kernel", ALL_KERNELS)
@pytest.mark.parametrize("prediction", PREDICTIONS)
@pytest.mark.parametrize("sampler,steps,eta,s", SAMPLERS)
def test_cascade_matches_pytorch(dirs, prediction, sampler, steps, eta, s, kernel, monkeypatch):
    d = dirs[prediction]
    short = load_kernel(d / "short.safetensors", kernel, monkeypatch)
    long = load_kernel(d / "long.safetensors", kernel, monkeypatch)
    prior = load_kernel(d / fileformat.PRIOR_FILE, kernel, monkeypatch, cls=tcd.engine.Prior)
    assert short.config["diffusion"]["prediction_type"] == prediction
    eng, ref, mask, ns, nl, kw, want = reference(d, prediction, sampler, steps, eta, s)
    got = tcd.engine.cascade_raw(
        short, long, eng, mask, num_samples=s, noise_short=ns, noise_long=nl, prior=prior, sampler=SamplerOptions(**kw)
    )
    what = f"prior-conditioned cascade {prediction} {sampler} n={steps} eta={eta} S={s} kernel={kernel}"
    assert max_diff(got["short_mean"], want["short_mean"], what + " short_mean") <= CHAIN_ATOL
    assert max_diff(got["samples"], want["samples"][..., OBS:], what + " samples") <= CHAIN_ATOL
    assert max_diff(got["mean"], want["samples"][..., OBS:].mean(axis=0), what + " mean") <= CHAIN_ATOL
    assert max_diff(got["repaired"], want["short_mean"][..., :OBS], what + " repaired") <= CHAIN_ATOL
    sel = mask == 1
    assert np.array_equal(got["repaired"][sel], eng[sel])  # observed entries bit for bit
    assert np.isfinite(got["samples"]).all() and np.isfinite(got["repaired"]).all()


def test_the_comparison_sees_the_prior_and_the_prediction_type(dirs):
    """The prior's fill moves the long window's masked frames well away from the spline's held last frame,
    and the x0 reading of the same weights is another cascade: both features are in what is compared."""
    models = _torch_models(str(dirs["epsilon"]))
    long_model = models["long"][0]
    _, ref, mask, *_rest, want = reference(dirs["epsilon"], "epsilon", "ddim", 10, 1.0, 2)
    window = torch.from_numpy(np.concatenate([want["short_mean"], np.zeros((2, 66, LL - LS), np.float32)], -1))
    m_long = torch.cat([torch.ones(2, 66, LS), torch.zeros(2, 66, LL - LS)], -1)
    fill = prior_fill(long_model.prior, window, m_long).numpy()
    moved = float(np.abs(fill[..., LS:] - want["short_mean"][..., -1:]).max())
    print(f"prior fill: max |fill - last given frame| {moved:.3g}")
    assert moved > CONTRIBUTION * CHAIN_ATOL
    # the same weights: only the prediction type differs between the two directories
    for role in ("short", "long"):
        a, _ = read_weights(dirs["epsilon"] / f"{role}.safetensors")
        b, _ = read_weights(dirs["sample"] / f"{role}.safetensors")
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    x0 = reference(dirs["sample"], "sample", "ddim", 10, 1.0, 2)[-1]
    apart = float(np.abs(x0["samples"] - want["samples"]).max())
    print(f"x0 against epsilon reading of the same weights: max diff {apart:.3g}")
    assert apart > CONTRIBUTION * CHAIN_ATOL


# --------------------------------------------------------------------------------------- public API


def test_tcd_load_passes_the_prior_and_matches_pytorch_on_the_seeded_streams(dirs):
    """tcd.load(dir).forecast runs the cascade with the directory's prior (the seeded streams of
    cascade_raw), and PyTorch fed those streams agrees."""
    d = dirs["sample"]
    model = tcd.load(d)
    assert model.prior is not None
    eng, ref, mask = observation(11, batch=1)
    kw = dict(sampler="ddim", num_inference_steps=5, eta=1.0, timestep_spacing="trailing")
    poses = np.ascontiguousarray(eng[0].T.reshape(OBS, 22, 3))
    f = model.forecast(poses, num_samples=2, seed=21, sampler=SamplerOptions(**kw))
    raw = tcd.engine.cascade_raw(
        model.short, model.long, eng, mask, num_samples=2, seed=21, prior=model.prior, sampler=SamplerOptions(**kw)
    )
    assert np.array_equal(f.mean, raw["mean"][0].T.reshape(-1, 22, 3))
    ns = tcd.engine.seeded_noise(21, tcd.engine.STAGE_SHORT, 2, 6, 1, 66, LS)
    nl = tcd.engine.seeded_noise(21, tcd.engine.STAGE_LONG, 2, 6, 1, 66, LL)
    want = torch_cascade(d, ref, mask, 2, ns, nl, **kw)
    assert max_diff(raw["samples"], want["samples"][..., OBS:], "seeded prior-conditioned x0 cascade") <= CHAIN_ATOL


def test_errors_name_the_prior_and_the_missing_file(dirs, tmp_path):
    d = dirs["epsilon"]
    short, long = tcd.engine.Denoiser.load(d / "short.safetensors"), tcd.engine.Denoiser.load(d / "long.safetensors")
    prior = tcd.engine.Prior.load(d / fileformat.PRIOR_FILE)
    eng, _, mask = observation(5, batch=1)
    kw = dict(num_samples=1, seed=0, sampler=SamplerOptions(sampler="ddim", num_inference_steps=2))
    e = bad("prior", tcd.engine.cascade_raw, short, long, eng, mask, **kw)
    assert "cond_fill" in str(e) and "short-term" in str(e)
    bad("prior", tcd.engine.cascade_raw, short, long, eng, mask, prior="prior.safetensors", **kw)
    # a prior that reads the whole short window
    other = tmp_path / "p55.safetensors"
    prior_net.save_prior(other, prior_net.random_prior(blocks=1, obs_len=55, chunk=5))
    e = bad("prior", tcd.engine.cascade_raw, short, long, eng, mask, prior=tcd.engine.Prior.load(other), **kw)
    assert "obs_len = 55" in str(e)
    # repair runs a prior-conditioned model only with a repair fill (anchor "window"), never the forecaster
    for fill in (None, prior):
        e = bad(
            "fill",
            tcd.engine.repair_raw,
            short,
            eng,
            mask,
            num_samples=1,
            seed=0,
            sampler=SamplerOptions(sampler="ddim", num_inference_steps=2),
            fill=fill,
        )
        assert "repair fill" in str(e)
    # the low-level calls read the fill from `observed`: NaN there is refused
    m = np.concatenate([mask, np.zeros((1, 66, LS - OBS), np.float32)], -1)
    x = np.concatenate([eng, np.zeros((1, 66, LS - OBS), np.float32)], -1)
    bad("observed", short.sample, x, m, 1, seed=0, sampler=SamplerOptions(sampler="ddim", num_inference_steps=2))
    assert short.sample(
        np.nan_to_num(x), m, 1, seed=0, sampler=SamplerOptions(sampler="ddim", num_inference_steps=2)
    ).shape == (1, 1, 66, LS)
    assert tcd.engine.cascade_raw(short, long, eng, mask, prior=prior, **kw)["mean"].shape == (1, 66, 25)
    # a model directory without its prior: the weights error names the missing file
    bare = tmp_path / "bare"
    bare.mkdir()
    for role in ("short", "long"):
        (bare / f"{role}.safetensors").write_bytes((d / f"{role}.safetensors").read_bytes())
    with pytest.raises(WeightsError) as ei:
        tcd.load(bare)
    assert ei.value.path == str(bare / "prior.safetensors") and "prior.safetensors" in str(ei.value)
    assert "short-term and long-term" in str(ei.value)
    with pytest.raises(FileNotFoundError, match="prior.safetensors"):
        export.load_model_dir(bare)
    # the user-facing repair of a directory without a repair model uses the short model: refused too
    with pytest.raises(InvalidInputError, match="prior"):
        tcd.load(d).repair(
            np.nan_to_num(eng[0].T.reshape(OBS, 22, 3)),
            seed=0,
            num_samples=1,
            sampler=SamplerOptions(sampler="ddim", num_inference_steps=2),
        )


# ------------------------------------------------------------------------------------------- export


def test_export_writes_and_restores_prior_conditioning_and_x0_prediction(tmp_path):
    """``python -m training.export --checkpoint`` of a cond_fill='prior', prediction_type='sample' run writes
    both into the tcd_config; load_model_file / load_model_dir restore them and attach the directory's prior;
    the engine reads them."""
    from test_train import synthetic_motion, tiny_cfg
    from training.train import train

    prior_file = prior_net.save_prior(
        tmp_path / "prior.safetensors", prior_net.random_prior(blocks=2, obs_len=8, chunk=2, seed=3)
    )
    seqs = {"train": synthetic_motion(4, T=40, seed=0), "val": synthetic_motion(2, T=40, seed=1)}
    out = tmp_path / "out"
    for role, (o, p) in (("short", (10, 4)), ("long", (14, 6))):
        cfg = tiny_cfg(
            role=role,
            obs_len=o,
            pred_len=p,
            epochs=1,
            steps_per_epoch=2,
            model={**tiny_cfg().model, **PRIOR_MODEL},
            diffusion={"prediction_type": "sample"},
            prior=str(prior_file),
        )
        train(cfg, tmp_path / role, sequences=seqs, log=lambda *a: None)
        assert export.main(["--checkpoint", str(tmp_path / role / "last.pt"), "--out", str(out)]) == 0
    assert export.main(["--files", str(prior_file), "--out", str(out)]) == 0
    for role in ("short", "long"):
        meta = json.loads(read_weights(out / f"{role}.safetensors")[1][fileformat.CONFIG_KEY])
        assert meta["model"]["cond_fill"] == "prior" and meta["model"]["target"] == "prior_residual"
        assert meta["model"]["target_scale"] == 10.0
        assert meta["diffusion"]["prediction_type"] == "sample"
        model, sched, cfg = export.load_model_file(out / f"{role}.safetensors")
        assert model.cfg.cond_fill == "prior" and model.cfg.target == "prior_residual"
        assert sched.cfg.prediction_type == "sample" and model.prior is None
    models = export.load_model_dir(out)
    assert all(m.prior is not None and m.prior.cfg.obs_len == 8 for m, _, _ in models.values())
    assert json.loads((out / "model.json").read_text())["short"]["diffusion"]["prediction_type"] == "sample"
    # the engine reads the same and forecasts with the directory's prior; the reference agrees
    model = tcd.load(out)
    assert model.short.config["model"]["cond_fill"] == "prior" and model.prior.obs_len == 8
    eng, ref, mask = (a[:, :, :10] for a in observation(13, batch=1))
    kw = dict(sampler="dpmpp2m", num_inference_steps=5, timestep_spacing="trailing")
    ns = np.random.default_rng(1).standard_normal((1, 1, 1, 66, 14)).astype(np.float32)
    nl = np.random.default_rng(2).standard_normal((1, 1, 1, 66, 20)).astype(np.float32)
    got = tcd.engine.cascade_raw(
        model.short,
        model.long,
        eng,
        mask,
        num_samples=1,
        noise_short=ns,
        noise_long=nl,
        prior=model.prior,
        sampler=SamplerOptions(**kw),
    )
    (ms, ss, _), (ml, sl, _) = models["short"], models["long"]
    want = D.cascade(
        ms,
        ss,
        ml,
        sl,
        torch.from_numpy(ref),
        torch.from_numpy(mask),
        short_len=14,
        long_len=20,
        num_samples=1,
        noise_short=torch.from_numpy(ns),
        noise_long=torch.from_numpy(nl),
        **kw,
    )
    assert max_diff(got["samples"], want["samples"].numpy()[..., 10:], "exported trained pair") <= CHAIN_ATOL
