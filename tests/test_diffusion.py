import math

import numpy as np
import pytest

from conftest import import_torch

torch = import_torch("the PyTorch reference's diffusion (training/diffusion.py)")

from training.diffusion import (  # noqa: E402
    DiffusionConfig,
    Schedule,
    cascade,
    dpmpp2m_coefficients,
    draw_noise,
    make_betas,
    masked_eps_loss,
    num_noise_blocks,
    q_sample,
    repair,
    sample,
    sample_many,
    step_pairs,
    training_loss,
)
from training.model import ModelConfig, TCDModel, randomize_output_layer  # noqa: E402

SCHED = Schedule(DiffusionConfig())
K = 66


@pytest.fixture(scope="module")
def tiny():
    torch.manual_seed(0)
    m = TCDModel(ModelConfig(channels=16, num_layers=2, num_heads=2, ffn_dim=16))
    randomize_output_layer(m, seed=1, std=0.1)
    return m.eval()


def window(B=2, L=12, obs_len=8, seed=0):
    g = torch.Generator().manual_seed(seed)
    x0 = torch.randn(B, K, L, generator=g)
    mask = torch.zeros(B, K, L)
    mask[..., :obs_len] = 1
    return x0, mask


class OracleEps(torch.nn.Module):
    """Predicts the exact noise for a known x0: eps = (x_t - sqrt(abar_t) x0) / sqrt(1 - abar_t)."""

    def __init__(self, x0):
        super().__init__()
        self.x0 = x0

    def forward(self, x, observed, mask, step):
        a = torch.as_tensor(SCHED.alphas_cumprod, dtype=torch.float64)[step].view(-1, 1, 1)
        return ((x.double() - a.sqrt() * self.x0.double()) / (1 - a).sqrt()).float()


def test_loss_ignores_conditioned_entries():
    eps, mask = torch.randn(2, K, 10), torch.zeros(2, K, 10)
    mask[..., :6] = 1
    eps_hat = torch.randn(2, K, 10)
    base = masked_eps_loss(eps, eps_hat, mask)
    changed = eps_hat.clone()
    changed[..., :6] += 100.0
    assert masked_eps_loss(eps, changed, mask) == base
    # normalised by the number of target entries
    assert base == pytest.approx(float(((eps - eps_hat)[..., 6:] ** 2).mean()), rel=1e-6)


def test_training_loss_gradient_is_zero_on_conditioned_outputs(tiny):
    x0, mask = window()
    eps_hat_holder = {}

    class Spy(torch.nn.Module):
        def forward(self, x, observed, mask, step):
            out = tiny(x, observed, mask, step)
            out.retain_grad()
            eps_hat_holder["out"] = out
            return out

    loss = training_loss(Spy(), SCHED, x0, mask, generator=torch.Generator().manual_seed(0))
    loss.backward()
    g = eps_hat_holder["out"].grad
    assert torch.all(g[..., :8] == 0) and g[..., 8:].abs().sum() > 0


def test_q_sample_formula():
    x0, eps = torch.ones(1, 1, 1), torch.full((1, 1, 1), 2.0)
    t = torch.tensor([10])
    a = SCHED.alphas_cumprod[10]
    assert q_sample(SCHED, x0, t, eps).item() == pytest.approx(math.sqrt(a) + 2 * math.sqrt(1 - a), rel=1e-6)


@pytest.mark.parametrize(
    "sampler,steps,eta",
    [
        ("ddpm", None, 0.0),
        ("ddim", 50, 0.0),
        ("ddim", 10, 0.0),
        ("ddim", 10, 1.0),
        ("ddpm", 10, 0.0),
        ("dpmpp2m", 5, 0.0),
        ("dpmpp2m", 10, 0.0),
        ("dpmpp2m", 20, 0.0),
        ("dpmpp2m", 50, 0.0),
    ],
)
def test_samplers_with_oracle_eps_recover_x0(sampler, steps, eta):
    x0, mask = window(B=3)
    obs = x0.clone()
    out = sample(
        OracleEps(x0),
        SCHED,
        obs,
        torch.zeros_like(mask),
        sampler=sampler,
        num_inference_steps=steps,
        eta=eta,
        generator=torch.Generator().manual_seed(0),
    )
    assert torch.allclose(out, x0, atol=2e-4)


def test_injected_noise_determinism_and_observed_unchanged(tiny):
    x0, mask = window()
    noise = draw_noise(50, x0.shape, torch.Generator().manual_seed(3))
    a = sample(tiny, SCHED, x0, mask, noise=noise)
    b = sample(tiny, SCHED, x0, mask, noise=noise.clone())
    assert torch.equal(a, b)
    assert torch.equal(a[..., :8], x0[..., :8])  # bit-identical observation
    c = sample(tiny, SCHED, x0, mask, noise=draw_noise(50, x0.shape, torch.Generator().manual_seed(4)))
    assert not torch.allclose(a[..., 8:], c[..., 8:])
    with pytest.raises(ValueError, match="noise must have shape"):
        sample(tiny, SCHED, x0, mask, noise=noise[:10])


def test_ddim_eta0_ignores_step_noise(tiny):
    x0, mask = window()
    n1 = draw_noise(10, x0.shape, torch.Generator().manual_seed(0))
    n2 = n1.clone()
    n2[1:] = torch.randn_like(n2[1:])
    kw = dict(sampler="ddim", num_inference_steps=10, eta=0.0)
    assert torch.equal(sample(tiny, SCHED, x0, mask, noise=n1, **kw), sample(tiny, SCHED, x0, mask, noise=n2, **kw))


def test_ddpm_first_step_by_hand():
    """One DDPM step with a constant eps prediction, checked against the written formula."""

    class Const(torch.nn.Module):
        def forward(self, x, o, m, step):
            return torch.full_like(x, 0.5)

    x0, mask = torch.zeros(1, 1, 1), torch.zeros(1, 1, 1)
    noise = torch.zeros(3, 1, 1, 1)
    noise[0], noise[1], noise[2] = 1.3, -0.7, 9.0  # the last z is never used
    T = SCHED.T
    sched1 = Schedule(DiffusionConfig())
    pairs = step_pairs(T, "ddpm", 2, "trailing")  # [(49, 24), (24, -1)]
    out = sample(Const(), sched1, x0, mask, sampler="ddpm", num_inference_steps=2, noise=noise)
    a49, a24 = SCHED.alphas_cumprod[49], SCHED.alphas_cumprod[24]
    beta = 1 - a49 / a24
    x = (1.3 - beta / math.sqrt(1 - a49) * 0.5) / math.sqrt(1 - beta)
    x += math.sqrt(beta * (1 - a24) / (1 - a49)) * -0.7
    x = (x - (1 - a24) / math.sqrt(1 - a24) * 0.5) / math.sqrt(a24)
    assert pairs == [(49, 24), (24, -1)]
    assert out.item() == pytest.approx(x, rel=1e-5)


def test_batched_chains_equal_sequential(tiny):
    x0, mask = window()
    noise = torch.randn(3, 6, *x0.shape, generator=torch.Generator().manual_seed(5))
    kw = dict(sampler="ddim", num_inference_steps=5, eta=1.0, noise=noise)
    a = sample_many(tiny, SCHED, x0, mask, 3, batch_chains=True, **kw)
    b = sample_many(tiny, SCHED, x0, mask, 3, batch_chains=False, **kw)
    assert a.shape == (3, 2, K, 12)
    assert torch.allclose(a, b, atol=1e-5)


def test_cascade_structure(tiny):
    obs, mask = window(B=2, L=8, obs_len=8)
    mask[0, :9, 2:5] = 0  # occlusion inside the observation
    g = torch.Generator().manual_seed(0)
    res = cascade(
        tiny,
        SCHED,
        tiny,
        SCHED,
        obs,
        mask,
        short_len=10,
        long_len=14,
        num_samples=3,
        generator=g,
        sampler="ddim",
        num_inference_steps=5,
    )
    short, mean, long = res["short_samples"], res["short_mean"], res["samples"]
    assert short.shape == (3, 2, K, 10) and mean.shape == (2, K, 10) and long.shape == (3, 2, K, 14)
    assert torch.allclose(mean, short.mean(0))
    for s in range(3):
        assert torch.equal(long[s, :, :, :10], mean)  # frames given to the long-term model
    vis = mask.bool()
    assert torch.equal(short[:, :, :, :8][:, vis], obs[vis].expand(3, -1))
    assert not torch.equal(long[0, ..., 10:], long[1, ..., 10:])


def test_repair_keeps_observed_and_fills_hidden(tiny):
    obs, mask = window(B=2, L=8, obs_len=8)
    mask[:, :6, 3:6] = 0
    out = repair(
        tiny,
        SCHED,
        obs * mask,
        mask,
        seq_len=10,
        num_samples=2,
        sampler="ddim",
        num_inference_steps=5,
        generator=torch.Generator().manual_seed(0),
    )
    assert out.shape == obs.shape
    assert torch.equal(out[mask.bool()], obs[mask.bool()])
    assert torch.all(out[~mask.bool()] != 0)


# ------------------------------------------------------------------------------------ DPM-Solver++(2M)


class Affine(torch.nn.Module):
    """A smooth, step-dependent eps prediction: eps = 0.3 x + 0.05 (t + 1) / T (computed in float64)."""

    def forward(self, x, observed, mask, step):
        return (0.3 * x.double() + 0.05 * (step.double().view(-1, 1, 1) + 1) / 50).float()


def dpmpp2m_by_hand(x, steps):
    """DPM-Solver++(2M) written out independently, in float64 scalars, in the form of Lu et al. 2022
    (Algorithm 2) / diffusers' midpoint update: x_t = (sigma_t/sigma_s) x - alpha_t (e^-h - 1) (D0 + D1/2),
    D0 = m0, D1 = (m0 - m1) / r0, r0 = h_prev / h; first order at step 0 and at the last step
    (sigma_t = 0: the update is x0_hat itself)."""
    ab = np.cumprod(1.0 - make_betas(DiffusionConfig()))
    ts = [int(v) for v in np.round(np.arange(50, 0, -50 / steps)) - 1]  # trailing
    alpha = lambda t: math.sqrt(ab[t])  # noqa: E731
    sigma = lambda t: math.sqrt(1 - ab[t])  # noqa: E731
    lam = lambda t: math.log(alpha(t) / sigma(t))  # noqa: E731
    m_prev, lam_prev = None, None
    for i, t in enumerate(ts):
        eps = 0.3 * x + 0.05 * (t + 1) / 50
        m0 = (x - sigma(t) * eps) / alpha(t)
        if i == len(ts) - 1:
            return m0
        s_next = ts[i + 1]
        h = lam(s_next) - lam(t)
        if m_prev is None:
            x = sigma(s_next) / sigma(t) * x - alpha(s_next) * (math.exp(-h) - 1) * m0
        else:
            r0 = (lam(t) - lam_prev) / h
            d1 = (m0 - m_prev) / r0
            x = (
                sigma(s_next) / sigma(t) * x
                - alpha(s_next) * (math.exp(-h) - 1) * m0
                - 0.5 * alpha(s_next) * (math.exp(-h) - 1) * d1
            )
        m_prev, lam_prev = m0, lam(t)


@pytest.mark.parametrize("steps", [1, 2, 3, 4, 10])
def test_dpmpp2m_matches_hand_derivation(steps):
    x_T = np.array([1.3, -0.4, 2.2])
    noise = torch.tensor(x_T, dtype=torch.float32).view(1, 1, 3, 1)  # one block: x_T
    zeros = torch.zeros(1, 3, 1)
    out = sample(Affine(), SCHED, zeros, zeros, sampler="dpmpp2m", num_inference_steps=steps, noise=noise)
    want = np.array([dpmpp2m_by_hand(v, steps) for v in x_T])
    np.testing.assert_allclose(out.view(-1).numpy(), want, rtol=2e-5, atol=2e-5)


def test_dpmpp2m_coefficients():
    c = dpmpp2m_coefficients(SCHED, step_pairs(50, "dpmpp2m", 5, "trailing"))
    assert [x["final"] for x in c] == [False] * 4 + [True]
    assert c[0]["w_prev"] == 0.0 and c[0]["w_cur"] == 1.0  # first order first
    for x in c[1:4]:
        assert x["w_cur"] + x["w_prev"] == pytest.approx(1.0, abs=1e-15)  # D extrapolates x0_hat
        assert x["w_prev"] < 0
    ab = SCHED.alphas_cumprod
    # first-order step == DDIM eta=0 (DPM-Solver++(1) is DDIM): cx x + c0 x0 = sqrt(ab') x0 + sqrt(1-ab') eps
    a, a_n = ab[49], ab[39]
    x, eps = 0.7, -1.1
    x0 = (x - math.sqrt(1 - a) * eps) / math.sqrt(a)
    assert c[0]["cx"] * x + c[0]["c0"] * x0 == pytest.approx(math.sqrt(a_n) * x0 + math.sqrt(1 - a_n) * eps, rel=1e-12)
    assert num_noise_blocks("dpmpp2m", 10) == 1 and num_noise_blocks("ddim", 10) == 11


def test_dpmpp2m_deterministic_and_one_noise_block(tiny):
    x0, mask = window()
    kw = dict(sampler="dpmpp2m", num_inference_steps=10)
    noise = draw_noise(0, x0.shape, torch.Generator().manual_seed(3))
    assert noise.shape == (1, *x0.shape)
    a = sample(tiny, SCHED, x0, mask, noise=noise, **kw)
    assert torch.equal(a, sample(tiny, SCHED, x0, mask, noise=noise.clone(), **kw))
    assert torch.equal(a[..., :8], x0[..., :8])
    # the same x_T drawn from a generator (one block) gives the same chain
    assert torch.equal(a, sample(tiny, SCHED, x0, mask, generator=torch.Generator().manual_seed(3), **kw))
    with pytest.raises(ValueError, match="noise must have shape"):
        sample(tiny, SCHED, x0, mask, noise=draw_noise(10, x0.shape), **kw)
    many = sample_many(tiny, SCHED, x0, mask, 2, noise=torch.stack([noise[0], noise[0]])[:, None], **kw)
    assert torch.allclose(many[0], a, atol=1e-5) and torch.allclose(many[1], a, atol=1e-5)
    seq = sample_many(
        tiny, SCHED, x0, mask, 2, noise=torch.stack([noise[0], noise[0]])[:, None], batch_chains=False, **kw
    )
    assert torch.allclose(many, seq, atol=1e-5)


def test_dpmpp2m_cascade_and_repair(tiny):
    obs, mask = window(B=2, L=8, obs_len=8)
    mask[:, :6, 3:6] = 0
    g = torch.Generator().manual_seed(0)
    res = cascade(
        tiny,
        SCHED,
        tiny,
        SCHED,
        obs,
        mask,
        short_len=10,
        long_len=14,
        num_samples=2,
        generator=g,
        sampler="dpmpp2m",
        num_inference_steps=5,
    )
    assert res["samples"].shape == (2, 2, K, 14) and torch.isfinite(res["samples"]).all()
    out = repair(
        tiny,
        SCHED,
        obs * mask,
        mask,
        seq_len=10,
        num_samples=2,
        sampler="dpmpp2m",
        num_inference_steps=5,
        generator=torch.Generator().manual_seed(0),
    )
    assert torch.equal(out[mask.bool()], obs[mask.bool()])
    assert torch.all(out[~mask.bool()] != 0)


@pytest.mark.parametrize("steps", [5, 10, 20])
def test_dpmpp2m_matches_diffusers_scheduler(steps):
    """Cross-check with diffusers' DPMSolverMultistepScheduler (optional: not a dependency)."""
    diffusers = pytest.importorskip("diffusers")
    sch = diffusers.DPMSolverMultistepScheduler(
        num_train_timesteps=50,
        trained_betas=make_betas(DiffusionConfig()).tolist(),
        algorithm_type="dpmsolver++",
        solver_order=2,
        lower_order_final=True,
        timestep_spacing="trailing",
        final_sigmas_type="zero",
        prediction_type="epsilon",
        thresholding=False,
    )
    sch.set_timesteps(steps)
    assert [int(t) for t in sch.timesteps] == [t for t, _ in step_pairs(50, "dpmpp2m", steps, "trailing")]
    model = Affine()
    x_T = torch.randn(1, 3, 4, generator=torch.Generator().manual_seed(7))
    x = x_T.clone()
    for t in sch.timesteps:
        eps = model(x, None, None, torch.full((1,), int(t)))
        x = sch.step(eps, t, x).prev_sample
    zeros = torch.zeros_like(x_T)
    ours = sample(model, SCHED, zeros, zeros, sampler="dpmpp2m", num_inference_steps=steps, noise=x_T[None])
    torch.testing.assert_close(ours, x.float(), rtol=1e-4, atol=1e-4)
