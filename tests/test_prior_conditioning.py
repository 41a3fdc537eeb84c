"""Training side of TCD models around the prior forecaster (issue 29): cond_fill "prior" with target
"prior_residual", and x0-prediction (prediction_type "sample"). The engine's parity with these is in
tests/test_prior_conditioned_parity.py."""

from __future__ import annotations

import math

import pytest

from conftest import import_torch

torch = import_torch("training around the prior forecaster (training/)")

from training.diffusion import (  # noqa: E402
    DiffusionConfig,
    Schedule,
    predicted_noise,
    q_sample,
    sample_many,
    training_loss,
)
from training.prior_net import random_prior  # noqa: E402
from training.model import ModelConfig, TCDModel, prior_fill, spline_fill, to_target  # noqa: E402
from training.train import load_prior  # noqa: E402
from training.train_config import TrainConfig  # noqa: E402

PRIOR_CFG = dict(
    channels=16,
    num_layers=1,
    num_heads=4,
    ffn_dim=16,
    dropout=0.0,
    cond_fill="prior",
    target="prior_residual",
    target_scale=10.0,
)


def window(B=3, L=75, given=55, seed=0):
    g = torch.Generator().manual_seed(seed)
    x0 = torch.cumsum(torch.randn(B, 66, L, generator=g) * 0.01, dim=-1)
    mask = torch.zeros(B, 66, L)
    mask[..., :given] = 1.0
    mask[0, 5:9, 10:20] = 0.0  # occluded observation entries
    return x0, mask


def prior_net(seed=0):
    return random_prior(blocks=2, seed=seed)


def test_prior_fill_is_spline_then_rollout_and_keeps_observed():
    prior = prior_net()
    x0, mask = window()
    observed = torch.where(mask > 0.5, x0, torch.full_like(x0, float("nan")))
    fill = prior_fill(prior, observed, mask)
    n_obs = prior.cfg.obs_len
    assert torch.equal(fill[mask > 0.5], x0[mask > 0.5])
    assert torch.equal(fill[..., :n_obs], spline_fill(observed[..., :n_obs], mask[..., :n_obs]))
    with torch.no_grad():
        future = prior.rollout(fill[..., :n_obs].transpose(1, 2), 25).transpose(1, 2)
    free = mask[..., n_obs:] < 0.5
    assert torch.equal(fill[..., n_obs:][free], future[..., : fill.shape[-1] - n_obs][free])
    assert torch.isfinite(fill).all()


def test_prior_target_and_fill_go_together_and_need_a_prior():
    with pytest.raises(ValueError, match="go together"):
        ModelConfig.from_dict({**PRIOR_CFG, "cond_fill": "spline"})
    with pytest.raises(ValueError, match="go together"):
        ModelConfig.from_dict({**PRIOR_CFG, "target": "absolute"})
    model = TCDModel(ModelConfig.from_dict(PRIOR_CFG))
    x0, mask = window()
    with pytest.raises(ValueError, match="attach_prior"):
        model(x0, x0, mask, 3)
    with pytest.raises(ValueError, match="needs 'prior'"):
        load_prior("")
    with pytest.raises(FileNotFoundError, match="prior"):
        load_prior("/nonexistent/prior.safetensors")


def test_the_prior_is_frozen_and_outside_the_state_dict():
    model = TCDModel(ModelConfig.from_dict(PRIOR_CFG))
    keys = set(model.state_dict())
    prior = prior_net()
    model.attach_prior(prior)
    assert set(model.state_dict()) == keys
    assert not any(p.requires_grad for p in prior.parameters())
    assert all(p is not q for p in model.parameters() for q in prior.parameters())


def test_predicted_noise_inverts_the_forward_process():
    sched = Schedule(DiffusionConfig(prediction_type="sample"))
    x0, _ = window()
    eps = torch.randn(x0.shape, generator=torch.Generator().manual_seed(1))
    for t in (0, 10, 49):
        xt = q_sample(sched, x0, torch.full((x0.shape[0],), t), eps)
        back = predicted_noise(sched, x0, xt, t)
        tol = 1e-3 if t == 0 else 1e-4  # 1/sqrt(1 - abar_0) is large: float32 rounding of xt shows
        assert torch.allclose(back, eps, atol=tol), (t, float((back - eps).abs().max()))
    assert predicted_noise(Schedule(DiffusionConfig()), x0, x0 * 0, 5) is x0  # epsilon: the output itself


def test_x0_prediction_starts_at_the_prior():
    """A fresh x0-predicting model whose last layer outputs exactly 0 samples the prior's fill: the
    diffusion around the prior starts from the prior's accuracy (epsilon-prediction does not)."""
    prior = prior_net()
    x0, mask = window()
    observed = x0 * mask
    fill = prior_fill(prior, observed, mask)
    for pt, close in (("sample", True), ("epsilon", False)):
        model = TCDModel(ModelConfig.from_dict(PRIOR_CFG))
        model.attach_prior(prior)
        torch.nn.init.zeros_(model.diffmodel.output_projection2.bias)
        sched = Schedule(DiffusionConfig(prediction_type=pt))
        out = sample_many(
            model.eval(),
            sched,
            observed,
            mask,
            2,
            sampler="ddim",
            num_inference_steps=10,
            generator=torch.Generator().manual_seed(0),
        )
        err = float((out - fill).abs().max())
        assert (err < 1e-4) == close, (pt, err)


def test_x0_loss_is_on_the_clean_target():
    prior = prior_net()
    model = TCDModel(ModelConfig.from_dict(PRIOR_CFG))
    model.attach_prior(prior)
    torch.nn.init.zeros_(model.diffmodel.output_projection2.bias)
    x0, mask = window()
    sched = Schedule(DiffusionConfig(prediction_type="sample"))
    t = torch.full((x0.shape[0],), 7)
    loss = training_loss(model, sched, x0, mask, t=t, observed=x0 * mask)
    target = to_target(model.cfg, x0, x0 * mask, mask, prior)  # the network outputs 0: the loss is the target's
    free = 1.0 - mask
    expect = ((target * free) ** 2).sum() / free.sum()
    assert math.isclose(float(loss.detach()), float(expect), rel_tol=1e-5)


def test_train_config_prior_trains_a_step(tmp_path):
    from training.prior_net import save_prior

    prior = prior_net()
    path = save_prior(tmp_path / "prior.safetensors", prior)
    seqs = [torch.cumsum(torch.randn(120, 22, 3) * 0.01, 0).numpy() for _ in range(2)]
    cfg = TrainConfig(
        role="long",
        obs_len=55,
        pred_len=20,
        model=PRIOR_CFG,
        diffusion={"prediction_type": "sample"},
        batch_size=2,
        epochs=1,
        steps_per_epoch=2,
        val_every=1,
        val_timesteps=2,
        val_max_windows=2,
        prior=str(path),
    )
    from training.train import train

    res = train(cfg, tmp_path / "run", sequences={"train": seqs, "val": seqs}, log=lambda *a: None)
    assert res is not None
    ck = torch.load(tmp_path / "run" / "last.pt", weights_only=False)
    assert not any(k.startswith("prior") or "._prior" in k for k in ck["model"])
