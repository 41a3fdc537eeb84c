import math

import numpy as np
import pytest

from conftest import import_torch

torch = import_torch("the PyTorch reference model (training/model.py)")

from torch import nn  # noqa: E402

from training.model import (  # noqa: E402
    ModelConfig,
    TCDModel,
    count_parameters,
    frame_embedding,
    load_grown,
    randomize_output_layer,
    step_embedding_table,
)


def expected_keys(n_layers):
    keys = ["embed_layer.weight"]
    for p in (
        "diffusion_embedding.projection1",
        "diffusion_embedding.projection2",
        "input_projection",
        "output_projection1",
        "output_projection2",
    ):
        keys += [f"diffmodel.{p}.weight", f"diffmodel.{p}.bias"]
    for i in range(n_layers):
        pre = f"diffmodel.residual_layers.{i}"
        for p in ("diffusion_projection", "cond_projection", "mid_projection", "output_projection"):
            keys += [f"{pre}.{p}.weight", f"{pre}.{p}.bias"]
        for tr in ("time_layer", "feature_layer"):
            lp = f"{pre}.{tr}.layers.0"
            keys += [
                f"{lp}.self_attn.in_proj_weight",
                f"{lp}.self_attn.in_proj_bias",
                f"{lp}.self_attn.out_proj.weight",
                f"{lp}.self_attn.out_proj.bias",
            ]
            for p in ("linear1", "linear2", "norm1", "norm2"):
                keys += [f"{lp}.{p}.weight", f"{lp}.{p}.bias"]
    return keys


def test_state_dict_keys_and_shapes_match_spec_10_1():
    m = TCDModel(ModelConfig())
    sd = m.state_dict()
    assert sorted(sd) == sorted(expected_keys(12))
    assert sd["embed_layer.weight"].shape == (66, 16)
    assert sd["diffmodel.input_projection.weight"].shape == (64, 2, 1)
    assert sd["diffmodel.output_projection2.weight"].shape == (1, 64, 1)
    assert sd["diffmodel.residual_layers.3.cond_projection.weight"].shape == (128, 145, 1)
    assert sd["diffmodel.residual_layers.3.time_layer.layers.0.self_attn.in_proj_weight"].shape == (192, 64)
    assert torch.all(sd["diffmodel.output_projection2.weight"] == 0)  # reference init


def test_parameter_count_matches_layer_sizes():
    # spec 1.5: about 1.167 M for H36M, 94,016 per residual block
    full = TCDModel(ModelConfig())
    block = sum(p.numel() for p in full.diffmodel.residual_layers[0].parameters())
    assert block == 94_016
    assert count_parameters(full) == 1_166_689
    assert count_parameters(TCDModel(ModelConfig(num_joints=18, num_layers=4))) == pytest.approx(0.41e6, rel=0.02)


def test_conv1x1_equals_conv1d():
    m = TCDModel(ModelConfig(channels=16, num_layers=1, num_heads=2, ffn_dim=16))
    conv = m.diffmodel.residual_layers[0].mid_projection
    x = torch.randn(3, 16, 40)
    ref = nn.functional.conv1d(x, conv.weight, conv.bias)
    assert torch.allclose(conv(x), ref, atol=1e-6)


def test_embeddings_follow_the_formulas():
    table = step_embedding_table(50, 128)
    t, j = 7, 5
    f = 10.0 ** (4.0 * j / 63)
    assert table[t, j].item() == pytest.approx(math.sin(t * f), abs=1e-4)
    assert table[t, 64 + j].item() == pytest.approx(math.cos(t * f), abs=1e-4)
    pe = frame_embedding(75, 128)
    pos, i = 30, 3
    assert pe[pos, 2 * i].item() == pytest.approx(math.sin(pos / 10000 ** (2 * i / 128)), abs=1e-5)
    assert pe[pos, 2 * i + 1].item() == pytest.approx(math.cos(pos / 10000 ** (2 * i / 128)), abs=1e-5)


def test_side_info_layout():
    m = TCDModel(ModelConfig(channels=16, num_layers=1, num_heads=2, ffn_dim=16))
    mask = (torch.rand(2, 66, 9) > 0.5).float()
    side = m.side_info(mask)
    assert side.shape == (2, 145, 66, 9)
    assert torch.equal(side[:, 144], mask)
    assert torch.equal(side[0, 128:144, 5, 3], m.embed_layer.weight[5])
    assert torch.equal(side[1, :128, 10, 4], frame_embedding(9, 128)[4])


def test_forward_uses_mask_and_ignores_hidden_observations():
    torch.manual_seed(0)
    m = TCDModel(ModelConfig(channels=16, num_layers=2, num_heads=2, ffn_dim=16)).eval()
    nn.init.normal_(m.diffmodel.output_projection2.weight, std=0.1)
    x, obs = torch.randn(1, 66, 12), torch.randn(1, 66, 12)
    mask = torch.zeros(1, 66, 12)
    mask[..., :8] = 1
    y = m(x, obs, mask, 10)
    assert y.shape == (1, 66, 12) and y.abs().mean() > 1e-3
    obs2 = obs.clone()
    obs2[..., 8:] += 5.0  # values under mask 0 are not seen
    x2 = x.clone()
    x2[..., :8] += 5.0  # noisy values under mask 1 are not seen
    assert torch.equal(m(x2, obs2, mask, 10), y)
    assert not torch.allclose(m(x, obs, mask, 11), y)  # the step matters


def _np_fill(values, mask):
    """np.interp per row: the same rule (hold at the ends, zero on a row with nothing observed)."""
    out = np.zeros_like(values, dtype=np.float64)
    idx = np.arange(values.shape[-1])
    for r in np.ndindex(values.shape[:-1]):
        m = mask[r] > 0.5
        out[r] = np.interp(idx, idx[m], values[r][m]) if m.any() else 0.0
    return out


@pytest.mark.parametrize("seed", range(3))
def test_spline_fill_is_the_natural_cubic_spline_and_ignores_hidden_values(seed):
    """spline_fill: scipy's natural cubic spline between the first and last observed frames, linear_fill's
    rule outside them and on rows with fewer than 2 observed frames; observed entries bit-identical."""
    from training.model import linear_fill, spline_fill

    rng = np.random.default_rng(seed)
    x = rng.normal(size=(3, 9, 30)).cumsum(-1).astype(np.float32)
    m = (rng.random(x.shape) < [0.3, 0.6, 0.9][seed]).astype(np.float32)
    m[0, 0] = 0.0
    m[0, 1] = 0.0
    m[0, 1, 12] = 1.0  # one observed frame: held
    m[0, 2] = 0.0
    m[0, 2, [3, 20]] = 1.0  # two: the straight line between them
    x_nan = np.where(m > 0, x, np.nan).astype(np.float32)
    got = spline_fill(torch.from_numpy(x_nan), torch.from_numpy(m)).numpy()
    lin = linear_fill(torch.from_numpy(x_nan), torch.from_numpy(m)).numpy()
    assert np.isfinite(got).all()
    np.testing.assert_array_equal(got[m > 0], x[m > 0])
    np.testing.assert_array_equal(got[0, :2], lin[0, :2])
    np.testing.assert_allclose(got[0, 2], lin[0, 2], atol=1e-6)
    interpolate = pytest.importorskip("scipy.interpolate")
    for i in range(3):
        for k in range(9):
            seen = m[i, k] > 0
            if seen.sum() < 2:
                continue
            f = np.flatnonzero(seen)
            frames = np.arange(30)
            inside = (frames > f[0]) & (frames < f[-1]) & ~seen
            ref = interpolate.CubicSpline(f, x[i, k, seen].astype(np.float64), bc_type="natural")(frames)
            np.testing.assert_allclose(got[i, k, inside], ref[inside], rtol=0, atol=2e-6)
            np.testing.assert_array_equal(got[i, k, ~inside & ~seen], lin[i, k, ~inside & ~seen])


@pytest.mark.parametrize("seed", range(4))
def test_linear_fill_matches_np_interp_and_ignores_hidden_values(seed):
    from training.model import linear_fill

    rng = np.random.default_rng(seed)
    x = rng.normal(size=(3, 7, 20)).astype(np.float32)
    m = (rng.random(x.shape) < [0.0, 0.2, 0.6][seed % 3]).astype(np.float32)
    m[0, 0] = 0.0
    m[0, 1] = 0.0
    m[0, 1, 19] = 1.0  # only the last frame: held backwards
    m[0, 2] = 0.0
    m[0, 2, 0] = 1.0  # only the first: held forwards
    x_nan = np.where(m > 0, x, np.nan).astype(np.float32)
    got = linear_fill(torch.from_numpy(x_nan), torch.from_numpy(m)).numpy()
    assert np.isfinite(got).all()
    np.testing.assert_array_equal(got[m > 0], x[m > 0])  # observed: bit-identical
    np.testing.assert_allclose(got, _np_fill(x, m), rtol=0, atol=1e-6)
    assert (got[0, 0] == 0).all() and (got[0, 1] == x[0, 1, 19]).all() and (got[0, 2] == x[0, 2, 0]).all()


def test_cond_fill_linear_changes_the_input_and_is_validated():
    torch.manual_seed(0)
    zero = TCDModel(ModelConfig(channels=16, num_layers=1, num_heads=2, ffn_dim=16))
    lin = TCDModel(ModelConfig(channels=16, num_layers=1, num_heads=2, ffn_dim=16, cond_fill="linear"))
    lin.load_state_dict(zero.state_dict())
    nn.init.normal_(zero.diffmodel.output_projection2.weight)
    lin.load_state_dict(zero.state_dict())
    zero.eval(), lin.eval()
    K, L = 66, 12
    noisy, obs = torch.randn(1, K, L), torch.randn(1, K, L)
    mask = torch.ones(1, K, L)
    with torch.no_grad():
        assert torch.equal(zero(noisy, obs, mask, 3), lin(noisy, obs, mask, 3))  # nothing to fill
        mask[..., 4:8] = 0
        assert not torch.allclose(zero(noisy, obs, mask, 3), lin(noisy, obs, mask, 3))
    with pytest.raises(ValueError, match="cond_fill"):
        ModelConfig.from_dict({"cond_fill": "cubic"})


def test_linear_residual_target_round_trips_and_is_validated():
    from training import diffusion as D
    from training.model import from_target, linear_fill, to_target

    cfg = ModelConfig(
        channels=16,
        num_layers=1,
        num_heads=2,
        ffn_dim=16,
        cond_fill="linear",
        target="linear_residual",
        target_scale=5.0,
    )
    torch.manual_seed(1)
    x0 = torch.randn(2, 66, 12)
    mask = (torch.rand(2, 66, 12) > 0.4).float()
    r = to_target(cfg, x0, x0, mask)
    assert torch.equal(r[mask > 0], torch.zeros_like(r[mask > 0]))  # observed entries: no residual
    torch.testing.assert_close(r, (x0 - linear_fill(x0, mask)) * 5.0)
    torch.testing.assert_close(from_target(cfg, r, x0, mask), x0, rtol=0, atol=1e-6)
    absolute = ModelConfig(channels=16, num_layers=1, num_heads=2, ffn_dim=16)
    assert to_target(absolute, x0, x0, mask) is x0 and from_target(absolute, r, x0, mask) is r
    # the training loss noises the residual: with a model that reads its noisy input back, eps-hat = x_t
    # differs between the targets exactly by how q_sample moved the data
    model = TCDModel(cfg).eval()
    sched = D.Schedule(D.DiffusionConfig())
    t, eps = torch.full((2,), 49), torch.randn(2, 66, 12)
    seen = {}
    model.forward = lambda xt, obs, m, step: seen.setdefault("xt", xt) * 0
    D.training_loss(model, sched, x0, mask, t=t, eps=eps)
    torch.testing.assert_close(seen["xt"], D.q_sample(sched, r, t, eps))
    for bad in ({"target": "residual"}, {"target_scale": 0.0}, {"target_scale": float("nan")}):
        with pytest.raises(ValueError, match="target"):
            ModelConfig.from_dict(bad)


def test_a_grown_model_starts_as_the_function_of_the_smaller_one():
    """training.model.load_grown: 2 layers -> 4, the new ones last; the same outputs to float rounding, the new
    layers' output projections zero but trainable (their gradient is not zero), and every other mismatch refused."""
    small_cfg = ModelConfig(num_joints=4, channels=16, num_layers=2, num_heads=2, ffn_dim=16)
    torch.manual_seed(0)
    small = TCDModel(small_cfg).eval()
    randomize_output_layer(small, seed=1, std=0.5)
    big = TCDModel(ModelConfig.from_dict({**small_cfg.to_dict(), "num_layers": 4})).eval()
    assert load_grown(big, small.state_dict()) == 2
    g = torch.Generator().manual_seed(2)
    noisy, observed = torch.randn(3, 12, 9, generator=g), torch.randn(3, 12, 9, generator=g)
    mask = (torch.rand(3, 12, 9, generator=g) < 0.5).float()
    step = torch.tensor([3, 17, 40])
    want = small(noisy, observed, mask, step)
    assert want.abs().mean() > 1e-2  # a non-trivial function
    torch.testing.assert_close(big(noisy, observed, mask, step), want, rtol=1e-5, atol=1e-6)
    assert all(torch.all(layer.output_projection.weight == 0) for layer in big.diffmodel.residual_layers[2:])
    big(noisy, observed, mask, step).square().sum().backward()
    assert big.diffmodel.residual_layers[3].output_projection.weight.grad.abs().sum() > 0
    # the same depth loads unchanged (no rescaling)
    same = TCDModel(small_cfg)
    assert load_grown(same, small.state_dict()) == 0
    torch.testing.assert_close(same.eval()(noisy, observed, mask, step), want)
    with pytest.raises(ValueError, match="grow, not shrink"):
        load_grown(TCDModel(ModelConfig.from_dict({**small_cfg.to_dict(), "num_layers": 1})), small.state_dict())
    with pytest.raises(ValueError, match="does not fit"):
        wider = ModelConfig.from_dict({**small_cfg.to_dict(), "channels": 32, "ffn_dim": 32})
        load_grown(TCDModel(wider), small.state_dict())
    state = dict(small.state_dict())
    state.pop("embed_layer.weight")
    with pytest.raises(ValueError, match="missing.*embed_layer"):
        load_grown(TCDModel(small_cfg), state)
