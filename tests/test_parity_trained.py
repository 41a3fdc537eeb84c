"""Parity of the Rust engine with the PyTorch reference on the bundled, trained weights, in the regime
users run: real motion in (the bundled demo clip), whole chains, the same injected noise on both sides.

Why a second parity module: a random-init denoiser predicts eps = 0 exactly (the last projection starts at
zero), so a random-init chain is amplified noise (x_0 ~ 1e2 m) and the network's arithmetic hardly reaches
its output. A trained chain ends on a pose sequence of metre scale, shaped by the network.

Criteria (stated once, used throughout):
* tolerance relative to the output's scale: max |rust - torch| <= ``RTOL`` x max |torch| over the generated
  (unobserved) entries; observed entries come back bit for bit;
* the network's contribution, max |torch - torch with the network silenced| over the generated entries
  (the same chain and noise with the last projection zeroed, so eps_hat = 0), is at least
  ``CONTRIBUTION`` x the tolerance: the comparison above measures the network, not the noise;
* the chain ends near the real motion (``NEAR_MOTION_M``), which only a trained model does.

Observed on an AVX-512 Zen 4 with the bundled models (short and repair 3 x 32, long 4 x 64 since 2026-11-26), every
kernel path: relative differences 6.2e-8 .. 1.2e-6, output scale 0.90 .. 1.0 m, network contributions 0.03 .. 9.2 m
(0.03: the repaired observation of the cascade), mean distance to the clip 1.7 .. 4.9 cm (``pytest -s`` prints them).
The bundled HumanEva-I cascade (long model 5 x 32), every kernel path: 0.9e-6 .. 1.3e-6, scale 0.81 m, contribution
0.11 m, 1.8 cm from the window. The repair model around its repair fill (since the thirteenth session of 2026-11-27;
the engine computes the fill, PyTorch's ``prior_fill`` the reference's): 3.3e-7 .. 4.4e-7, contributions 8.8 .. 9.2 m,
4.2 .. 4.4 cm from the clip.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest

from conftest import import_torch

torch = import_torch("parity with the PyTorch reference")

import tcd  # noqa: E402
from fixtures_util import ALL_KERNELS, load_kernel  # noqa: E402
from tcd._demo import load_clip, occlusion_mask  # noqa: E402
from test_humaneva import HUMANEVA_FILE, needs_humaneva  # noqa: E402
from training import diffusion as D  # noqa: E402
from training.data.humaneva import humaneva_test_windows, load_humaneva  # noqa: E402
from training.export import load_model_dir  # noqa: E402
from training.model import prior_fill  # noqa: E402
from tcd import SamplerOptions  # noqa: E402

RTOL = 2e-5  # of the output's scale
CONTRIBUTION = 1e3  # the network's contribution over the tolerance, at least
NEAR_MOTION_M = 0.25  # mean |output - clip| over the generated entries, metres


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def bundled():
    """role -> (path, torch model, schedule, torch model with the network silenced)."""
    return trained_models(tcd.default_model_dir(), ("short", "long", "repair"))


@pytest.fixture(scope="module")
def bundled_humaneva():
    """The same for the bundled HumanEva-I model (its long model 5 x 32 since 2026-11-27)."""
    if not (tcd.humaneva_model_dir() / "long.safetensors").is_file():
        pytest.skip("no bundled HumanEva-I model in this build")
    return trained_models(tcd.humaneva_model_dir(), ("short", "long"))


def trained_models(d, roles):
    # each model conditioned on a fill with its fill attached: the forecasting models the prior, the repair model
    # its repair fill (training.export.load_model_dir)
    models = load_model_dir(d)
    return {
        role: (d / f"{role}.safetensors", models[role][0], models[role][1], silenced(models[role][0])) for role in roles
    }


def engine_observed(model, observed, mask):
    """What a single engine stage is given: the observation itself, or for a prior-conditioned model the
    observation with the prior's fill in its mask-0 entries (as tcd.engine.cascade_raw puts it there)."""
    if model.cfg.cond_fill != "prior":
        return observed
    return prior_fill(model.prior, torch.from_numpy(observed), torch.from_numpy(mask)).numpy()


@pytest.fixture(scope="module")
def clip():
    """(T, K) float32: the bundled demo clip (real motion, metres), frames in rows."""
    poses = load_clip()["poses"]
    return poses.reshape(len(poses), -1)


def silenced(model):
    """The same model with its last projection zeroed: eps_hat = 0 at every step."""
    z = copy.deepcopy(model)
    with torch.no_grad():
        last = z.diffmodel.output_projection2
        last.weight.zero_()
        if last.bias is not None:
            last.bias.zero_()
    return z


def load(path, kernel=None, monkeypatch=None):
    return tcd.engine.Denoiser.load(path) if kernel is None else load_kernel(path, kernel, monkeypatch)


def window(clip, start, length, observed_frames, occlude=False):
    """truth, observed, mask (1, K, length): the clip's frames, the first ``observed_frames`` observed (with
    the demo's leg and arm occlusion when ``occlude``), the rest generated."""
    truth = np.ascontiguousarray(clip[start : start + length].T[None], dtype=np.float32)
    assert truth.shape[-1] == length
    mask = np.zeros_like(truth)
    mask[..., :observed_frames] = 1
    if occlude:
        joints = occlusion_mask(observed_frames, load_clip()["joint_names"])  # (frames, J)
        mask[0, :, :observed_frames] = np.repeat(joints, 3, axis=1).T
    return truth, (truth * mask).astype(np.float32), mask


def check(got, want, silent, truth, mask, what):
    """The three criteria of the module docstring on (S, B, K, L) outputs (``got`` Rust, ``want`` PyTorch,
    ``silent`` PyTorch with the network silenced)."""
    gen = np.broadcast_to(mask == 0, want.shape)
    scale = float(np.abs(want[gen]).max())
    diff = float(np.abs(got - want)[gen].max())
    tol = RTOL * scale
    contribution = float(np.abs(want - silent)[gen].max())
    off_motion = float(np.abs(want - np.broadcast_to(truth, want.shape))[gen].mean())
    print(
        f"parity trained {what}: max abs diff {diff:.3g}, scale {scale:.3g} (rel {diff / scale:.3g}), "
        f"network contribution {contribution:.3g}, mean |out - clip| {off_motion:.3g} m"
    )
    assert diff <= tol, f"{what}: {diff:.3g} > {tol:.3g}"
    assert contribution >= CONTRIBUTION * tol, f"{what}: the network moved the output by {contribution:.3g} only"
    assert off_motion <= NEAR_MOTION_M, f"{what}: {off_motion:.3g} m from the clip: not a trained chain"
    obs = np.broadcast_to(mask == 1, got.shape)
    assert np.array_equal(got[obs], np.broadcast_to(want, got.shape)[obs])


def noise_for(den, sampler, steps, samples, rng):
    blocks = den.num_noise_blocks(sampler=SamplerOptions(sampler=sampler, num_inference_steps=steps))
    return rng.standard_normal((samples, blocks, 1, den.num_features, den.seq_len)).astype(np.float32)


# ------------------------------------------------------------------------------------ chains

CHAINS = [("ddpm", 10, 0.0), ("ddim", 10, 0.0), ("dpmpp2m", 10, 0.0)]


@pytest.mark.parametrize("role", ["short", "long"])
@pytest.mark.parametrize("sampler,steps,eta", CHAINS)
def test_chain_on_trained_weights(bundled, clip, role, sampler, steps, eta):
    """One stage: DDPM-10, DDIM-10 (eta 0) and DPM-Solver++(2M) 10 on each forecasting model."""
    path, model, sched, silent_model = bundled[role]
    den = load(path)
    obs_len = den.config["window"]["obs_len"]
    truth, observed, mask = window(clip, 20, den.seq_len, obs_len)
    noise = noise_for(den, sampler, steps, 2, np.random.default_rng(CHAINS.index((sampler, steps, eta))))
    kw = dict(sampler=sampler, num_inference_steps=steps, eta=eta, timestep_spacing="trailing")
    got = den.sample(engine_observed(model, observed, mask), mask, 2, noise=noise, sampler=SamplerOptions(**kw))
    args = (sched, torch.from_numpy(observed), torch.from_numpy(mask), 2)
    want = D.sample_many(model, *args, noise=torch.from_numpy(noise), **kw).numpy()
    silent = D.sample_many(silent_model, *args, noise=torch.from_numpy(noise), **kw).numpy()
    check(got, want, silent, truth, mask, f"{role} {sampler}-{steps}")


@pytest.mark.parametrize("kernel", ALL_KERNELS)
def test_chain_on_trained_weights_every_kernel(bundled, clip, kernel, monkeypatch):
    """DDIM-10 on the long-term model (the stage with the largest differences above) on each kernel path."""
    path, model, sched, silent_model = bundled["long"]
    den = load(path, kernel, monkeypatch)
    truth, observed, mask = window(clip, 40, den.seq_len, den.config["window"]["obs_len"])
    noise = noise_for(den, "ddim", 10, 1, np.random.default_rng(7))
    kw = dict(sampler="ddim", num_inference_steps=10, eta=0.0, timestep_spacing="trailing")
    got = den.sample(engine_observed(model, observed, mask), mask, 1, noise=noise, sampler=SamplerOptions(**kw))
    args = (sched, torch.from_numpy(observed), torch.from_numpy(mask), 1)
    want = D.sample_many(model, *args, noise=torch.from_numpy(noise), **kw).numpy()
    silent = D.sample_many(silent_model, *args, noise=torch.from_numpy(noise), **kw).numpy()
    check(got, want, silent, truth, mask, f"long ddim-10 kernel={kernel}")


# ------------------------------------------------------------------------------------ cascade / repair


def test_cascade_on_trained_weights(bundled, clip):
    """The whole cascade (DDPM-10, 2 samples) from an occluded observation: the short-term model repairs and
    extends it, the long-term model forecasts 1 s."""
    short, long = load(bundled["short"][0]), load(bundled["long"][0])
    truth, observed, mask = window(clip, 30, long.seq_len, short.config["window"]["obs_len"], occlude=True)
    check_cascade(bundled, tcd.default_model_dir(), truth, observed, mask, "cascade")


def test_cascade_on_trained_weights_with_the_default_sampler(bundled, clip):
    """The cascade with the bundled forecast's own sampler (tcd.load().sampling["forecast"]: one DDIM step and,
    where it says so, centred noise), 2 samples. The forecast only: one step moves the repaired frames too little
    from the prior's fill for the network-contribution criterion (the DDPM-10 test above checks a repair)."""
    short, long = load(bundled["short"][0]), load(bundled["long"][0])
    truth, observed, mask = window(clip, 30, long.seq_len, short.config["window"]["obs_len"], occlude=True)
    sampling = dataclasses.asdict(tcd.load().sampling["forecast"])
    check_cascade(
        bundled,
        tcd.default_model_dir(),
        truth,
        observed,
        mask,
        "cascade, default sampler",
        sampling=sampling,
        repaired=False,
    )


@needs_humaneva
@pytest.mark.parametrize("kernel", ALL_KERNELS)
def test_humaneva_cascade_on_trained_weights_every_kernel(bundled_humaneva, kernel, monkeypatch):
    """The bundled HumanEva-I cascade (DDPM-10, its default) on a Validate window, each kernel path."""
    w = humaneva_test_windows(load_humaneva(HUMANEVA_FILE, "Validate"))[40]  # (75, 14, 3) metres
    truth = np.ascontiguousarray(w.reshape(len(w), -1).T[None], dtype=np.float32)
    mask = np.zeros_like(truth)
    mask[..., :15] = 1
    mask[:, 6:12, 3:15] = 0  # both elbows and wrists hidden over the last 12 observed frames
    mask[:, 15:21, 3:15] = 0
    # the repaired frames are not checked: the short model moves them 3 mm from the prior's fill, too little for
    # the network-contribution criterion (the Human3.6M cascade above checks a repair)
    check_cascade(
        bundled_humaneva,
        tcd.humaneva_model_dir(),
        truth,
        (truth * mask).astype(np.float32),
        mask,
        f"humaneva cascade kernel={kernel}",
        kernel,
        monkeypatch,
        repaired=False,
    )


def check_cascade(
    models, directory, truth, observed, mask, what, kernel=None, monkeypatch=None, repaired=True, sampling=None
):
    """The cascade through the engine against training.diffusion.cascade, the same noise; ``truth`` etc. span the
    long model's window, of which the short model's observed frames are given; the forecast checked, and with
    ``repaired`` the repaired observation. ``sampling``: the sampler keywords (default DDPM over 10 steps)."""
    (sp, sm, ss, s_silent), (lp, lm, ls, l_silent) = models["short"], models["long"]
    short, long = load(sp, kernel, monkeypatch), load(lp, kernel, monkeypatch)
    o = short.config["window"]["obs_len"]
    observed, mask = observed[..., :o], mask[..., :o]
    rng = np.random.default_rng(11)
    kw = sampling or dict(sampler="ddpm", num_inference_steps=10, timestep_spacing="trailing")
    sampler, steps = kw["sampler"], kw["num_inference_steps"]
    noise_short, noise_long = noise_for(short, sampler, steps, 2, rng), noise_for(long, sampler, steps, 2, rng)
    prior = tcd.engine.Prior.load(directory / "prior.safetensors")
    got = tcd.engine.cascade_raw(
        short,
        long,
        observed,
        mask,
        num_samples=2,
        noise_short=noise_short,
        noise_long=noise_long,
        prior=prior,
        sampler=SamplerOptions(**kw),
    )

    def reference(short_model, long_model):
        return D.cascade(
            short_model,
            ss,
            long_model,
            ls,
            torch.from_numpy(observed),
            torch.from_numpy(mask),
            short_len=short.seq_len,
            long_len=long.seq_len,
            num_samples=2,
            noise_short=torch.from_numpy(noise_short),
            noise_long=torch.from_numpy(noise_long),
            **kw,
        )

    want, silent = reference(sm, lm), reference(s_silent, l_silent)
    future = np.zeros((1, long.num_features, long.seq_len - o), np.float32)  # every future entry generated
    check(
        got["samples"],
        want["samples"].numpy()[..., o:],
        silent["samples"].numpy()[..., o:],
        truth[..., o:],
        future,
        f"{what} {sampler}-{steps} forecast",
    )
    if repaired:
        check(
            got["repaired"][None],
            want["short_mean"].numpy()[None, ..., :o],
            silent["short_mean"].numpy()[None, ..., :o],
            truth[..., :o],
            mask,
            f"{what} {sampler}-{steps} repaired",
        )


@pytest.mark.parametrize("sampler", ["ddpm", "ddim"])
def test_repair_on_trained_weights(bundled, clip, sampler):
    """The repair model (the residual over its repair fill, which the engine computes, the 12-frame gap filled
    from the prior forecaster by the fill's gap fill) on the demo's leg and arm occlusion plus a 12-frame gap."""
    path, model, sched, silent_model = bundled["repair"]
    den = load(path)
    fill = tcd.engine.Prior.load(path.parent / "repair_fill.safetensors")
    forecaster = tcd.engine.Prior.load(path.parent / "prior.safetensors")  # its gap fill's (gap_fill "forecaster")
    truth, observed, mask = window(clip, 60, den.seq_len, den.seq_len, occlude=True)
    mask[..., 32:44] = 0
    observed = (truth * mask).astype(np.float32)
    noise = noise_for(den, sampler, 10, 2, np.random.default_rng(13))
    kw = dict(sampler=sampler, num_inference_steps=10, eta=0.0, timestep_spacing="trailing")
    got = tcd.engine.repair_raw(
        den, observed, mask, num_samples=2, noise=noise, fill=fill, forecaster=forecaster, sampler=SamplerOptions(**kw)
    )["mean"]

    def reference(m):
        return D.repair(
            m,
            sched,
            torch.from_numpy(observed),
            torch.from_numpy(mask),
            seq_len=den.seq_len,
            num_samples=2,
            noise=torch.from_numpy(noise),
            **kw,
        ).numpy()

    check(got[None], reference(model)[None], reference(silent_model)[None], truth, mask, f"repair {sampler}-10")
