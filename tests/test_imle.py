"""The one-step sampler's IMLE loss (training.imle): which candidate it trains, the engine's candidate forwards
against PyTorch's, and the config's checks."""

from __future__ import annotations

import json
import pytest

from conftest import import_torch

torch = import_torch("IMLE training of the one-step sampler (training/)")

from training.diffusion import DiffusionConfig, Schedule, masked_eps_loss, training_loss  # noqa: E402
from training.export import build_config  # noqa: E402
from training.prior_net import random_prior  # noqa: E402
from training.imle import EngineSearch, imle_choose, imle_loss, torch_search  # noqa: E402
from training.model import ModelConfig, TCDModel, randomize_output_layer, to_target  # noqa: E402
from training.train import train_step  # noqa: E402
from training.train_config import TrainConfig  # noqa: E402

CFG = dict(
    channels=16,
    num_layers=1,
    num_heads=4,
    ffn_dim=16,
    dropout=0.0,
    cond_fill="prior",
    target="prior_residual",
    target_scale=10.0,
)
SCHED = Schedule(DiffusionConfig(prediction_type="sample"))


def model_and_window(B=3, L=75, given=55, seed=0):
    torch.manual_seed(seed)
    model = TCDModel(ModelConfig.from_dict(CFG), SCHED.T)
    randomize_output_layer(model, seed, std=0.2)  # the zero-initialised head would ignore the noise
    model.attach_prior(random_prior(blocks=2, seed=seed))
    g = torch.Generator().manual_seed(seed)
    x0 = torch.cumsum(torch.randn(B, 66, L, generator=g) * 0.01, dim=-1)
    mask = torch.zeros(B, 66, L)
    mask[..., :given] = 1.0
    return model, x0, mask


def one_step_samples(model, cand, x0, mask):
    """The IMLE target of windows x0 and the one-step sample of each candidate (S, B, K, L), computed one by one."""
    last = torch.full((x0.shape[0],), SCHED.T - 1)
    target = to_target(model.cfg, x0, x0, mask, model.prior)
    with torch.no_grad():
        return target, torch.stack([model(c, x0, mask, last) for c in cand])


def searched(model, x0, mask, cand, sched=SCHED, observed=None, **search):
    """imle_loss after a fresh imle_choose on the same arguments (``search``: its further options)."""
    choice = imle_choose(model, sched, x0, mask, cand, observed=observed, **search)
    return imle_loss(model, sched, x0, mask, cand, choice, observed=observed)


def test_imle_trains_each_windows_nearest_candidate():
    model, x0, mask = model_and_window()
    S, B = 4, x0.shape[0]
    cand = torch.randn(S, *x0.shape, generator=torch.Generator().manual_seed(1))
    target, outs = one_step_samples(model, cand, x0, mask)
    dist = (((outs - target) * (1 - mask)) ** 2).sum((2, 3))
    best = dist.argmin(0)
    expected = masked_eps_loss(target, outs[best, torch.arange(B)], mask)
    assert float(searched(model, x0, mask, cand).detach()) == pytest.approx(float(expected), rel=1e-5)
    # the nearest is what counts: putting it first and the others after changes nothing
    order = torch.stack(
        [torch.cat([best[b : b + 1], torch.tensor([s for s in range(S) if s != best[b]])]) for b in range(B)], 1
    )  # (S, B)
    moved = cand[order, torch.arange(B)]
    assert float(searched(model, x0, mask, moved).detach()) == pytest.approx(float(expected), rel=1e-5)
    # and a worse candidate alone gives a larger loss than the nearest
    worst = dist.argmax(0)
    alone = cand[worst, torch.arange(B)].unsqueeze(0)
    assert float(searched(model, x0, mask, alone).detach()) > float(expected)


@pytest.mark.parametrize("gap", [False, True])
def test_final_weight_adds_the_candidate_nearest_on_the_last_hidden_frame(gap):
    model, x0, mask = model_and_window()
    if gap:  # frames 55-64 hidden, the rest observed: the last hidden frame is 64, not 74
        mask[..., 65:] = 1.0
    S, B = 6, x0.shape[0]
    final = 64 if gap else 74
    cand = torch.randn(S, *x0.shape, generator=torch.Generator().manual_seed(7))
    target, outs = one_step_samples(model, cand, x0, mask)
    sq = ((outs - target) * (1 - mask)) ** 2
    best, final_best = sq.sum((2, 3)).argmin(0), sq[..., final].sum(2).argmin(0)
    assert (best != final_best).any()  # else the test could not tell the two terms apart
    expected = masked_eps_loss(target, outs[best, torch.arange(B)], mask) + 0.5 * masked_eps_loss(
        target, outs[final_best, torch.arange(B)], mask
    )
    got = searched(model, x0, mask, cand, final_weight=0.5)
    assert float(got.detach()) == pytest.approx(float(expected), rel=1e-5)


def test_further_targets_each_pull_their_nearest_candidate():
    """``others`` (imle_targets): each further future pulls its own nearest of the same samples; the loss is the
    mean over the targets, so copies of the window's own future change nothing."""
    model, x0, mask = model_and_window()
    cand = torch.randn(5, *x0.shape, generator=torch.Generator().manual_seed(11))
    alone = float(searched(model, x0, mask, cand).detach())
    copies = x0.expand(2, *x0.shape).clone()
    assert float(searched(model, x0, mask, cand, others=copies).detach()) == pytest.approx(alone, rel=1e-5)
    g = torch.Generator().manual_seed(12)
    others = x0 + torch.cumsum(torch.randn(2, *x0.shape, generator=g) * 0.02, dim=-1) * (1 - mask)
    each = [alone] + [float(searched(model, o, mask, cand, observed=x0).detach()) for o in others]
    got = float(searched(model, x0, mask, cand, others=others).detach())
    assert got == pytest.approx(sum(each) / 3, rel=1e-5)
    assert not got == pytest.approx(alone, rel=1e-3)  # the further futures are not the window's own
    with pytest.raises(ValueError, match="others must be"):
        searched(model, x0, mask, cand, others=x0)


@pytest.mark.parametrize("variant", ["own", "others", "final"])
def test_a_stored_choice_gives_the_loss_of_a_fresh_search_and_stays_as_chosen(variant):
    """imle_echo's split: a stored imle_choose result gives the loss of a fresh search; after the weights move, the
    stored choice still trains the candidates it chose (stale by design)."""
    model, x0, mask = model_and_window(seed=3)
    cand = torch.randn(6, *x0.shape, generator=torch.Generator().manual_seed(8))
    kw = {}
    if variant == "others":
        kw["others"] = x0 + torch.cumsum(
            torch.randn(2, *x0.shape, generator=torch.Generator().manual_seed(9)) * 0.02, dim=-1
        ) * (1 - mask)
    if variant == "final":
        kw["final_weight"] = 0.5
    choice = imle_choose(model, SCHED, x0, mask, cand, observed=x0, **kw)
    target, samples = one_step_samples(model, cand, x0, mask)
    hidden = 1 - mask
    assert torch.equal(choice.nearest[0], (((samples - target) * hidden) ** 2).sum((2, 3)).argmin(0))
    assert choice.nearest.shape == (3 if variant == "others" else 1, x0.shape[0])
    assert (choice.final is not None) == (variant == "final")
    fresh = searched(model, x0, mask, cand, observed=x0, **kw)
    stored = imle_loss(model, SCHED, x0, mask, cand, choice, observed=x0)
    assert float(stored.detach()) == pytest.approx(float(fresh.detach()), rel=1e-6)
    with torch.no_grad():  # move the weights: a fresh search may choose otherwise, the stored not
        for p in model.parameters():
            p.add_(torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())) * 0.3)
    again = imle_choose(model, SCHED, x0, mask, cand, observed=x0, **kw)
    B = x0.shape[0]
    last = torch.full((B,), SCHED.T - 1)
    by_hand = sum(
        masked_eps_loss(tm, model(cand[nm, torch.arange(B)], x0, mask, last), mask)
        for tm, nm in zip(choice.targets, choice.nearest)
    ) / len(choice.targets)
    if variant == "final":
        by_hand = by_hand + 0.5 * masked_eps_loss(
            choice.targets[0], model(cand[choice.final, torch.arange(B)], x0, mask, last), mask
        )
    got = imle_loss(model, SCHED, x0, mask, cand, choice, observed=x0)
    assert float(got.detach()) == pytest.approx(float(by_hand.detach()), rel=1e-6)
    assert not torch.equal(again.nearest, choice.nearest)  # the moved weights do choose otherwise


def test_imle_loss_gradient_reaches_the_weights():
    model, x0, mask = model_and_window()
    cand = torch.randn(3, *x0.shape, generator=torch.Generator().manual_seed(2))
    loss = searched(model, x0, mask, cand)
    loss.backward()
    grads = [p.grad for p in model.parameters() if p.requires_grad]
    assert all(g is not None for g in grads) and any(float(g.abs().sum()) > 0 for g in grads)


def test_engine_search_equals_torch_search():
    pytest.importorskip("tcd")
    model, x0, mask = model_and_window(B=2)
    cand = torch.randn(6, *x0.shape, generator=torch.Generator().manual_seed(3)).reshape(12, *x0.shape[1:])
    rows = torch.arange(12) % 2
    config = build_config("long", model.cfg, SCHED.cfg, 55, 20, {"training_data": "synthetic"})
    engine = EngineSearch(model, config, threads=1)(cand, x0, mask, rows, SCHED.T - 1)
    ref = torch_search(model, chunk=5)(cand, x0, mask, rows, SCHED.T - 1)
    hidden = (1 - mask[rows]).bool()
    assert torch.allclose(engine[hidden], ref[hidden], atol=1e-5, rtol=1e-4)
    # a changed weight reaches the engine on the next call (the weights are serialised per call)
    with torch.no_grad():
        model.diffmodel.output_projection2.bias += 0.5
    again = EngineSearch(model, config, threads=1)(cand, x0, mask, rows, SCHED.T - 1)
    assert torch.allclose(again[hidden], engine[hidden] + 0.5, atol=1e-4)


def test_imle_needs_x0_prediction_and_matching_candidates():
    model, x0, mask = model_and_window()
    with pytest.raises(ValueError, match="x0-predicting"):
        searched(model, x0, mask, torch.zeros(2, *x0.shape), sched=Schedule(DiffusionConfig(prediction_type="epsilon")))
    with pytest.raises(ValueError, match="candidates must be"):
        searched(model, x0, mask, torch.zeros(2, 1, 66, 75))


def test_config_checks_and_train_step_adds_the_imle_term(tmp_path):
    base = json.loads(
        json.dumps(
            {"role": "long", "obs_len": 55, "pred_len": 20, "model": CFG, "diffusion": {"prediction_type": "sample"}}
        )
    )
    with pytest.raises(ValueError, match="x0-predicting"):
        TrainConfig(**{**base, "diffusion": {}, "imle_samples": 4})
    with pytest.raises(ValueError, match="imle_samples, imle_weight and imle_final_weight"):
        TrainConfig(**{**base, "imle_samples": -1})
    with pytest.raises(ValueError, match="imle_samples, imle_weight and imle_final_weight"):
        TrainConfig(**{**base, "imle_samples": 4, "imle_weight": -0.5})
    with pytest.raises(ValueError, match="imle_samples, imle_weight and imle_final_weight"):
        TrainConfig(**{**base, "imle_samples": 4, "imle_final_weight": -1.0})
    with pytest.raises(ValueError, match="imle_final_weight .* needs imle_samples"):
        TrainConfig(**{**base, "imle_final_weight": 1.0})
    with pytest.raises(ValueError, match="imle_targets"):
        TrainConfig(**{**base, "imle_targets": 3})
    with pytest.raises(ValueError, match="imle_targets"):
        TrainConfig(**{**base, "imle_samples": 4, "imle_targets": 0})
    with pytest.raises(ValueError, match="imle_echo .* needs imle_samples"):
        TrainConfig(**{**base, "imle_echo": 2})
    with pytest.raises(ValueError, match="imle_echo"):
        TrainConfig(**{**base, "imle_samples": 4, "imle_echo": 0})
    TrainConfig(**{**base, "imle_samples": 4, "imle_echo": 3})  # with candidates: accepted
    TrainConfig(**{**base, "imle_samples": 4, "imle_targets": 3})  # with candidates: accepted
    TrainConfig(**{**base, "imle_samples": 4, "imle_final_weight": 1.0})  # with candidates: accepted
    TrainConfig(**{**base, "imle_samples": 4, "imle_weight": 0.5})  # x0-prediction: accepted
    model, x0, mask = model_and_window()
    t = torch.full((x0.shape[0],), 7)
    eps = torch.randn(x0.shape, generator=torch.Generator().manual_seed(4))
    cand = torch.randn(4, *x0.shape, generator=torch.Generator().manual_seed(5))
    plain = float(training_loss(model, SCHED, x0, mask, t=t, eps=eps, observed=x0).detach())
    extra = float(searched(model, x0, mask, cand, observed=x0).detach())
    opt = torch.optim.SGD(model.parameters(), lr=0.0)  # lr 0: the step reports the loss, weights stay
    got = float(train_step(model, opt, SCHED, (x0, x0, mask, t, eps, cand), False, imle_weight=0.5))
    assert got == pytest.approx(plain + 0.5 * extra, rel=1e-5)
    # the final-frame term reaches the IMLE loss through train_step
    with_final = float(searched(model, x0, mask, cand, observed=x0, final_weight=0.25).detach())
    assert with_final > extra
    got = float(
        train_step(model, opt, SCHED, (x0, x0, mask, t, eps, cand), False, imle_weight=0.5, imle_final_weight=0.25)
    )
    assert got == pytest.approx(plain + 0.5 * with_final, rel=1e-5)
    assert float(train_step(model, opt, SCHED, (x0, x0, mask, t, eps), False)) == pytest.approx(plain, rel=1e-5)
    # the further targets of imle_targets (the batch's seventh tensor) reach the IMLE loss through train_step
    others = x0 + torch.cumsum(torch.randn(2, *x0.shape, generator=torch.Generator().manual_seed(6)) * 0.02, dim=-1) * (
        1 - mask
    )
    with_others = float(searched(model, x0, mask, cand, observed=x0, others=others).detach())
    assert with_others != pytest.approx(extra, rel=1e-3)
    got = float(train_step(model, opt, SCHED, (x0, x0, mask, t, eps, cand, others), False, imle_weight=0.5))
    assert got == pytest.approx(plain + 0.5 * with_others, rel=1e-5)


@pytest.mark.slow
def test_training_with_imle_runs_through_the_engine_and_resumes_exactly(tmp_path):
    """``imle_samples`` in a train config: the candidates drawn by the batch source (after the batch's own draws,
    which stay those of the run without them), searched by the engine, and a resumed run lands on the same
    weights as an uninterrupted one."""
    pytest.importorskip("tcd")
    from test_train import synthetic_motion, tiny_cfg
    from training.batches import BatchSource, Windows
    from training.train import train

    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    cfg = tiny_cfg(epochs=2, steps_per_epoch=4, diffusion={"prediction_type": "sample"}, imle_samples=3)
    plain = tiny_cfg(epochs=2, steps_per_epoch=4, diffusion={"prediction_type": "sample"})
    wins = Windows(seqs["train"], 14, cfg.train_stride)
    a, b = BatchSource(cfg, wins, 50, 4).batch(1, 2), BatchSource(plain, wins, 50, 4).batch(1, 2)
    assert len(a) == 6 and len(b) == 5 and all(torch.equal(x, y) for x, y in zip(a, b))
    assert a[5].shape == (3, *a[0].shape)
    train(cfg, tmp_path / "full", sequences=seqs, log=lambda *a: None)
    train(cfg, tmp_path / "part", sequences=seqs, max_minutes=0.0, log=lambda *a: None)  # stops after one batch
    train(cfg, tmp_path / "part", sequences=seqs, resume=True, log=lambda *a: None)
    full = torch.load(tmp_path / "full" / "last.pt", weights_only=False)["model"]
    part = torch.load(tmp_path / "part" / "last.pt", weights_only=False)["model"]
    other = tmp_path / "plain"
    train(plain, other, sequences=seqs, log=lambda *a: None)
    without = torch.load(other / "last.pt", weights_only=False)["model"]
    assert all(torch.allclose(full[k], part[k], atol=1e-6) for k in full)
    assert any(not torch.allclose(full[k], without[k]) for k in full)  # the IMLE term changed the training


@pytest.mark.slow
def test_imle_echo_takes_that_many_optimizer_steps_per_batch_and_resumes_exactly(tmp_path):
    """``imle_echo`` 2: one search per batch, two optimizer steps on it (Adam's step count is twice the batches);
    a run stopped after one batch and resumed lands on the weights of an uninterrupted one."""
    pytest.importorskip("tcd")
    from test_train import synthetic_motion, tiny_cfg
    from training.train import train

    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    cfg = tiny_cfg(epochs=2, steps_per_epoch=3, diffusion={"prediction_type": "sample"}, imle_samples=3, imle_echo=2)
    train(cfg, tmp_path / "full", sequences=seqs, log=lambda *a: None)
    train(cfg, tmp_path / "part", sequences=seqs, max_minutes=0.0, log=lambda *a: None)  # stops after one batch
    train(cfg, tmp_path / "part", sequences=seqs, resume=True, log=lambda *a: None)
    full = torch.load(tmp_path / "full" / "last.pt", weights_only=False)
    part = torch.load(tmp_path / "part" / "last.pt", weights_only=False)
    assert {float(s["step"]) for s in full["optimizer"]["state"].values()} == {2.0 * 2 * 3}
    assert all(torch.allclose(full["model"][k], part["model"][k], atol=1e-6) for k in full["model"])
    once = tiny_cfg(epochs=2, steps_per_epoch=3, diffusion={"prediction_type": "sample"}, imle_samples=3)
    train(once, tmp_path / "once", sequences=seqs, log=lambda *a: None)
    single = torch.load(tmp_path / "once" / "last.pt", weights_only=False)
    assert {float(s["step"]) for s in single["optimizer"]["state"].values()} == {2.0 * 3}
