"""The channels-last training forward (training/channels_last.py) computes the reference forward
(training/model.py, which the Rust engine is checked against) on the same parameters."""

import pytest

from conftest import import_torch

torch = import_torch("the channels-last training forward (training/channels_last.py)")

from training.channels_last import ChannelsLast  # noqa: E402
from training.export import PRESETS  # noqa: E402
from training.model import TCDModel, randomize_output_layer  # noqa: E402
from dataclasses import replace  # noqa: E402


def inputs(B, K, L, seed=0):
    g = torch.Generator().manual_seed(seed)
    noisy = torch.randn(B, K, L, generator=g)
    observed = torch.randn(B, K, L, generator=g) * 0.3
    mask = (torch.rand(B, K, L, generator=g) < 0.6).float()
    mask[..., L - 5 :] = 0.0  # a future to predict
    step = torch.randint(0, 50, (B,), generator=g)
    return noisy, observed, mask, step


def model(cfg, seed=0):
    torch.manual_seed(seed)
    m = TCDModel(cfg).eval()
    randomize_output_layer(m, seed=seed, std=0.5)  # the zero-initialised last conv would make both outputs its bias
    return m


@pytest.mark.parametrize("preset", sorted(PRESETS))
@pytest.mark.parametrize("L", [55, 75])
def test_equals_the_reference_forward_at_every_preset(preset, L):
    m = model(PRESETS[preset])
    noisy, observed, mask, step = inputs(2, m.cfg.num_features, L)
    with torch.no_grad():
        ref = m(noisy, observed, mask, step)
        out = ChannelsLast(m)(noisy, observed, mask, step)
    assert out.shape == ref.shape == (2, m.cfg.num_features, L)
    assert float(ref.abs().max()) > 0.1  # a real signal to compare
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("fill", ["zero", "linear", "spline"])
def test_equals_the_reference_with_every_cond_fill_and_a_shared_step(fill):
    m = model(replace(PRESETS["tiny"], cond_fill=fill), seed=1)
    noisy, observed, mask, _ = inputs(3, m.cfg.num_features, 50, seed=1)
    with torch.no_grad():
        for step in (7, torch.tensor([49])):  # one step broadcast over the batch
            torch.testing.assert_close(
                ChannelsLast(m)(noisy, observed, mask, step), m(noisy, observed, mask, step), rtol=1e-5, atol=1e-5
            )


def test_gradients_equal_the_reference():
    m = model(PRESETS["tiny"], seed=2)
    noisy, observed, mask, step = inputs(2, m.cfg.num_features, 20, seed=2)
    grads = []
    for fwd in (m, ChannelsLast(m)):
        m.zero_grad()
        fwd(noisy, observed, mask, step).square().mean().backward()
        grads.append({n: p.grad.clone() for n, p in m.named_parameters()})
    for name in grads[0]:
        torch.testing.assert_close(grads[1][name], grads[0][name], rtol=1e-4, atol=1e-6, msg=name)


def test_dropout_is_active_in_training_mode_only():
    m = model(replace(PRESETS["tiny"], dropout=0.5), seed=3)
    fast = ChannelsLast(m)
    noisy, observed, mask, step = inputs(2, m.cfg.num_features, 20, seed=3)
    with torch.no_grad():
        a, b = fast(noisy, observed, mask, step), fast(noisy, observed, mask, step)
        assert torch.equal(a, b)
        fast.train()
        c, d = fast(noisy, observed, mask, step), fast(noisy, observed, mask, step)
    assert not torch.allclose(c, d)


def test_state_dict_is_the_models():
    m = model(PRESETS["tiny"])
    fast = ChannelsLast(m)
    assert sorted(fast.model.state_dict()) == sorted(m.state_dict())
    assert sum(p.numel() for p in fast.parameters()) == sum(p.numel() for p in m.parameters())
