"""training.widen: a trained denoiser made wider (channels and feed-forward width x factor) computing the same."""

from __future__ import annotations

import json

import pytest

from conftest import import_torch

torch = import_torch("the PyTorch reference model (training/model.py)")

from training.diffusion import DiffusionConfig  # noqa: E402
from training.export import build_config  # noqa: E402
from training.fileformat import CONFIG_KEY  # noqa: E402
from training.model import ModelConfig, TCDModel, condition, randomize_output_layer  # noqa: E402
from training.widen import widen_state, widen_to, widened_config  # noqa: E402


def narrow_model(channels=16, heads=2, ffn=8, layers=2, seed=0, **kw):
    torch.manual_seed(seed)
    cfg = ModelConfig(
        num_joints=4, channels=channels, num_layers=layers, num_heads=heads, ffn_dim=ffn, dropout=0.0, **kw
    )
    model = TCDModel(cfg).eval()
    randomize_output_layer(model, seed=seed, std=0.5)  # the zero-initialised head would hide every other weight
    return model


def inputs(B=3, K=12, L=9, seed=1):
    g = torch.Generator().manual_seed(seed)
    noisy, observed = torch.randn(B, K, L, generator=g), torch.randn(B, K, L, generator=g)
    mask = (torch.rand(B, K, L, generator=g) < 0.5).float()
    return noisy, observed, mask, torch.tensor([3, 17, 49])[:B]


@pytest.mark.parametrize("channels,heads,ffn,factor", [(16, 2, 8, 2), (12, 3, 12, 3), (8, 1, 16, 2)])
def test_the_wide_model_computes_what_the_narrow_one_computes(channels, heads, ffn, factor):
    narrow = narrow_model(channels, heads, ffn)
    wide_cfg = widened_config(narrow.cfg, factor)
    assert (wide_cfg.channels, wide_cfg.ffn_dim, wide_cfg.num_heads) == (channels * factor, ffn * factor, heads)
    wide = TCDModel(wide_cfg).eval()
    wide.load_state_dict(widen_state(narrow.state_dict(), narrow.cfg, factor, seed=4), strict=True)
    want = narrow(*inputs())
    assert want.abs().mean() > 1e-2  # a non-trivial function
    torch.testing.assert_close(wide(*inputs()), want, rtol=1e-5, atol=2e-6)


def test_the_copies_share_their_narrow_weight_unevenly_and_part_after_a_step():
    """Exact copies would get the same gradients and stay copies: the layers that read them split each narrow
    weight among the copies by seeded shares (summing to it), so one optimiser step sets the copies apart."""
    narrow = narrow_model()
    C = narrow.cfg.channels
    state = widen_state(narrow.state_dict(), narrow.cfg, 2, seed=5)
    key = "diffmodel.output_projection1.weight"
    w, w0 = state[key][..., 0], narrow.state_dict()[key][..., 0]
    torch.testing.assert_close(w[:C, :C] + w[:C, C:], w0)  # the shares of each weight sum to it
    assert not torch.allclose(w[:C, :C], w[:C, C:])  # and differ between the copies
    again = widen_state(narrow.state_dict(), narrow.cfg, 2, seed=5)
    assert all(torch.equal(state[k], again[k]) for k in state)  # seeded
    wide = TCDModel(widened_config(narrow.cfg, 2))
    wide.load_state_dict(state)
    inp = "diffmodel.input_projection.weight"
    assert torch.equal(wide.state_dict()[inp][:C], wide.state_dict()[inp][C:])  # the producer's rows: copies
    opt = torch.optim.SGD(wide.parameters(), lr=0.1)
    wide(*inputs()).square().sum().backward()
    opt.step()
    assert not torch.allclose(wide.state_dict()[inp][:C], wide.state_dict()[inp][C:])


def test_widen_to_widens_only_by_a_whole_factor_of_both_widths():
    narrow = narrow_model(16, 2, 8)
    state = narrow.state_dict()
    same, f = widen_to(narrow.cfg, state)
    assert f == 1 and same is state
    wide, f = widen_to(widened_config(narrow.cfg, 2), state, seed=3)
    assert f == 2 and all(torch.equal(wide[k], v) for k, v in widen_state(state, narrow.cfg, 2, seed=3).items())
    with pytest.raises(ValueError, match="same factor"):
        widen_to(ModelConfig.from_dict({**narrow.cfg.to_dict(), "channels": 32, "ffn_dim": 8}), state)
    odd = ModelConfig.from_dict({**narrow.cfg.to_dict(), "channels": 24, "ffn_dim": 12})
    assert widen_to(odd, state)[1] == 1  # not a whole factor: the load reports it
    with pytest.raises(ValueError, match="multiple of num_heads"):
        widen_state(narrow_model(12, 3, 8).state_dict(), ModelConfig(channels=12, num_heads=5), 2)
    with pytest.raises(ValueError, match="integer >= 1"):
        widened_config(narrow.cfg, 0)


def test_the_engine_runs_the_widened_weights_as_the_narrow_model():
    """The Rust engine reads the wider head dimension from the config: its forward of the widened weights equals
    PyTorch's forward of the narrow model (the bundled HumanEva-I long model widened 2 x gave the protocol's numbers
    to 3e-7 m: docs/training.md)."""
    pytest.importorskip("tcd")
    from safetensors.torch import save
    from tcd.engine import Denoiser

    narrow = narrow_model(16, 2, 16)
    wide_cfg = widened_config(narrow.cfg, 2)
    config = build_config("long", wide_cfg, DiffusionConfig(prediction_type="sample"), 5, 4, {"training_data": "x"})
    tensors = {k: v.contiguous() for k, v in widen_state(narrow.state_dict(), narrow.cfg, 2, seed=1).items()}
    net = Denoiser.from_bytes(save(tensors, metadata={CONFIG_KEY: json.dumps(config)}), "widened")
    noisy, observed, mask, _ = inputs(B=2, K=12, L=9)
    mask[..., :5] = 1.0
    mask[..., 5:] = 0.0
    with torch.no_grad():
        want = narrow(noisy, observed, mask, torch.tensor([49, 49]))
        cond = condition(narrow.cfg, observed, mask, narrow.prior)
    got = net.forward(noisy.numpy(), cond.numpy(), mask.numpy(), 49, threads=1)
    hidden = (1 - mask).bool()
    assert torch.allclose(torch.from_numpy(got)[hidden], want[hidden], atol=1e-5, rtol=1e-4)
