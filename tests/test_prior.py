"""The prior forecaster's PyTorch reference (training/prior.py): the DCT, the untrained network (Zero-
Velocity), rollout, the loss, config checks, and resumable training (a stopped and resumed run equals an
uninterrupted one)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import import_torch

torch = import_torch("the prior forecaster's PyTorch reference (training/prior.py)")

from training.prior import (  # noqa: E402
    batch,
    hidden_loss,
    load,
    load_grown,
    loss_fn,
    repair_batch,
    train,
    validation_windows,
    window_loss,
)
from training.prior_net import PriorConfig, PriorNet, dct_matrix  # noqa: E402


def synthetic_frames(n_frames: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Smooth random motion (n_frames, 66) and every window start of 60 frames."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames)[:, None] / 25.0
    frames = (0.3 * np.sin(2 * np.pi * rng.uniform(0.2, 1.5, 66) * t + rng.uniform(0, 6, 66))).astype(np.float32)
    return frames, np.arange(n_frames - 60 + 1)


def test_dct_is_orthonormal():
    m = dct_matrix(50)
    np.testing.assert_allclose(m @ m.T, np.eye(50), atol=1e-12)
    assert np.allclose(m[0], m[0, 0])  # row 0 is the mean


def test_untrained_network_is_zero_velocity_and_rolls_out():
    cfg = PriorConfig(blocks=3)
    torch.manual_seed(0)
    net = PriorNet(cfg)
    obs = torch.randn(4, 50, 66)
    out = net.rollout(obs, 25)
    assert out.shape == (4, 25, 66)
    torch.testing.assert_close(out, obs[:, -1:].expand(4, 25, 66), atol=1e-5, rtol=0)


def test_rollout_feeds_back_its_chunks():
    cfg = PriorConfig(blocks=2, chunk=10)
    torch.manual_seed(0)
    net = PriorNet(cfg)
    with torch.no_grad():
        for p in net.parameters():
            p.normal_(0, 0.05)
    obs = torch.randn(2, 60, 66)
    first = net(obs[:, -50:])
    second = net(torch.cat([obs[:, -40:], first], dim=1))
    out = net.rollout(obs, 23)
    torch.testing.assert_close(out[:, :10], first)
    torch.testing.assert_close(out[:, 10:20], second)
    assert out.shape == (2, 23, 66)


def test_loss_is_joint_distance_plus_velocity():
    target = torch.zeros(1, 2, 66)
    pred = torch.zeros(1, 2, 66)
    pred[0, 1, :3] = torch.tensor([3.0, 4.0, 0.0])  # one joint 5 away in frame 1
    pos = 5.0 / 44  # mean over 2 frames x 22 joints
    vel = 5.0 / 22  # one velocity of 22
    assert loss_fn(pred, target, 0.0).item() == pytest.approx(pos)
    assert loss_fn(pred, target, 1.0).item() == pytest.approx(pos + vel)


def test_batch_is_a_pure_function_and_flips():
    frames, starts = synthetic_frames()
    cfg = PriorConfig(batch_size=64, flip_prob=0.5)
    a, b = batch(cfg, frames, starts, 7), batch(cfg, frames, starts, 7)
    assert torch.equal(a, b) and a.shape == (64, 60, 66)
    assert not torch.equal(a, batch(cfg, frames, starts, 8))
    # every window is a run of consecutive frames, forwards or reversed
    f = torch.from_numpy(frames)
    fwd = rev = 0
    for w in a:
        i = int(torch.argmin(((f - w[0]) ** 2).sum(1)))
        if i + 60 <= len(f) and torch.equal(w, f[i : i + 60]):
            fwd += 1
        elif i - 59 >= 0 and torch.equal(w, f[i - 59 : i + 1].flip(0)):
            rev += 1
    assert fwd + rev == 64 and fwd > 10 and rev > 10


def test_batch_observation_noise():
    """obs_noise_prob of the windows get N(0, obs_noise_mm^2) on their observed frames only; the others, and every
    window's target frames, are the windows of the same config without noise, bit for bit."""
    frames, starts = synthetic_frames()
    clean_cfg = PriorConfig(batch_size=256, flip_prob=0.5)
    cfg = PriorConfig(batch_size=256, flip_prob=0.5, obs_noise_mm=25.0, obs_noise_prob=0.5)
    clean, noisy = batch(clean_cfg, frames, starts, 3), batch(cfg, frames, starts, 3)
    assert torch.equal(noisy[:, 50:], clean[:, 50:])
    d = (noisy[:, :50] - clean[:, :50]).double()
    hit = d.abs().amax(dim=(1, 2)) > 0
    assert 90 < int(hit.sum()) < 166  # about half of 256
    assert d[hit].std().item() == pytest.approx(0.025, rel=0.02)


@pytest.mark.parametrize(
    "field,value",
    [
        ("chunk", 0),
        ("blocks", 0),
        ("flip_prob", 1.5),
        ("chunk", 60),
        ("obs_noise_mm", -1.0),
        ("obs_noise_mm", float("nan")),
        ("obs_noise_prob", 1.5),
        ("loss_frames", -1),
    ],
)
def test_config_rejects_bad_values(field, value):
    with pytest.raises(ValueError, match=field):
        PriorConfig(**{field: value})


def test_unknown_config_key_is_named(tmp_path):
    p = tmp_path / "c.json"
    p.write_text('{"blocks": 2, "block": 3}')
    with pytest.raises(ValueError, match="block"):
        PriorConfig.load(p)


def test_resumed_training_equals_uninterrupted(tmp_path):
    torch.set_num_threads(1)
    frames = synthetic_frames()
    cfg = PriorConfig(blocks=2, batch_size=16, iterations=6, lr_decay_at=0.5)
    whole = train(cfg, tmp_path / "whole", frames=frames, log=lambda m: None)
    assert whole["done"]
    # the same run stopped after its first iteration (max_minutes=0) and resumed
    part = train(cfg, tmp_path / "part", frames=frames, max_minutes=0.0, log=lambda m: None)
    assert part["iteration"] == 1 and not part["done"]
    done = train(cfg, tmp_path / "part", frames=frames, resume=True, log=lambda m: None)
    assert done["iteration"] == 6
    a = torch.load(tmp_path / "whole" / "last.pt", weights_only=False)["model"]
    b = torch.load(tmp_path / "part" / "last.pt", weights_only=False)["model"]
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0, msg=k)
    with pytest.raises(ValueError, match="another config"):
        train(
            PriorConfig(blocks=3, batch_size=16, iterations=6),
            tmp_path / "part",
            frames=frames,
            resume=True,
            log=lambda m: None,
        )


def test_training_lowers_the_loss(tmp_path):
    torch.set_num_threads(1)
    frames = synthetic_frames()
    cfg = PriorConfig(blocks=2, batch_size=32, iterations=150, lr=3e-3)
    held_out = batch(cfg, *frames, 10_000)  # an iteration the run never draws

    def loss_of(net):
        with torch.no_grad():
            return loss_fn(net(held_out[:, :50]), held_out[:, 50:], 1.0).item()

    torch.manual_seed(cfg.seed)
    before = loss_of(PriorNet(cfg))  # the run's initial weights: Zero-Velocity
    train(cfg, tmp_path, frames=frames, log=lambda m: None)
    after = loss_of(load(tmp_path / "last.pt"))
    assert after < 0.7 * before, (before, after)


def test_loss_frames_trains_on_the_rolled_out_horizon(tmp_path):
    """loss_frames = 20 with chunks of 10: windows of obs_len + 20 frames, and training is Adam on the loss of the
    two chunks rolled out (the second predicted from the first), computed here by hand; not the one-chunk loss."""
    torch.set_num_threads(1)
    frames, starts = synthetic_frames()
    starts = starts[:-10]  # every window of 70 frames
    cfg = PriorConfig(blocks=2, batch_size=8, iterations=3, lr=1e-2, lr_decay_at=1.0, loss_frames=20)
    assert batch(cfg, frames, starts, 0).shape == (8, 70, 66)
    train(cfg, tmp_path, frames=(frames, starts), log=lambda m: None)
    got = torch.load(tmp_path / "last.pt", weights_only=False)["model"]

    def by_hand(horizon: int) -> dict:
        torch.manual_seed(cfg.seed)
        net = PriorNet(cfg)
        opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        for it in range(cfg.iterations):
            wins = batch(cfg, frames, starts, it)
            loss_fn(net.rollout(wins[:, :50], horizon), wins[:, 50 : 50 + horizon], cfg.velocity_weight).backward()
            opt.step()
            opt.zero_grad(set_to_none=True)
        return net.state_dict()

    for k, v in by_hand(20).items():
        torch.testing.assert_close(got[k], v, rtol=1e-5, atol=1e-6, msg=k)
    one_chunk = by_hand(10)
    assert any(not torch.allclose(got[k], v, rtol=1e-5, atol=1e-6) for k, v in one_chunk.items())


def test_schedule_may_change_only_where_the_run_so_far_is_the_same(tmp_path):
    torch.set_num_threads(1)
    frames = synthetic_frames()
    long = PriorConfig(blocks=2, batch_size=16, iterations=12, lr_decay_at=0.5)  # decays at 6
    short = PriorConfig(blocks=2, batch_size=16, iterations=8, lr_decay_at=0.5)  # decays at 4
    train(short, tmp_path / "short", frames=frames, log=lambda m: None)
    # 3 iterations of a schedule that never decays, resumed as the short one: the same first 3 rates
    part = train(
        PriorConfig(blocks=2, batch_size=16, iterations=3, lr_decay_at=1.0),
        tmp_path / "p3",
        frames=frames,
        log=lambda m: None,
    )
    assert part["done"]
    done = train(short, tmp_path / "p3", frames=frames, resume=True, log=lambda m: None)
    assert done["iteration"] == 8
    a = torch.load(tmp_path / "short" / "last.pt", weights_only=False)["model"]
    b = torch.load(tmp_path / "p3" / "last.pt", weights_only=False)["model"]
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0, msg=k)
    # the long run's iterations 4 and 5 had lr 3e-4, the short schedule's lr_final: refused
    train(long, tmp_path / "six", frames=frames, log=lambda m: None)
    with pytest.raises(ValueError, match="another config"):
        train(short, tmp_path / "six", frames=frames, resume=True, log=lambda m: None)


def test_a_deeper_prior_grows_from_a_shallower_one(tmp_path):
    """init_from a prior with fewer blocks: the extra blocks start as identities, so the grown network computes
    the same forecast, and its first training step moves them; a shallower config is refused."""
    torch.set_num_threads(1)
    frames = synthetic_frames()
    small = PriorConfig(blocks=2, batch_size=16, iterations=3)
    train(small, tmp_path / "small", frames=frames, log=lambda m: None)
    net2 = load(tmp_path / "small" / "last.pt")
    ck = torch.load(tmp_path / "small" / "last.pt", weights_only=False)
    net4 = PriorNet(PriorConfig(blocks=4))
    assert load_grown(net4, ck["model"]) == 2
    obs = torch.from_numpy(np.stack([frames[0][i : i + 50] for i in (0, 77)]))
    with torch.no_grad():
        torch.testing.assert_close(net4.eval().rollout(obs, 25), net2.rollout(obs, 25), rtol=0, atol=1e-6)
    big = PriorConfig(blocks=4, batch_size=16, iterations=1, init_from=str(tmp_path / "small" / "last.pt"))
    train(big, tmp_path / "big", frames=frames, log=lambda m: None)
    grown = torch.load(tmp_path / "big" / "last.pt", weights_only=False)["model"]
    assert grown["blocks.3.norm_weight"].abs().max() > 0  # the new blocks learn
    with pytest.raises(ValueError, match="grow, not shrink"):
        load_grown(PriorNet(PriorConfig(blocks=1)), ck["model"])
    with pytest.raises(ValueError, match="does not fit"):
        load_grown(
            PriorNet(PriorConfig(blocks=4, dataset="humaneva", subjects=(1, 2, 3), obs_len=15, chunk=15)), ck["model"]
        )


REPAIR_MIX = (("random_joints", 1.0, 0.4), ("consecutive_frames", 1.0, 0.2))


def repair_fill_config(**over) -> PriorConfig:
    return PriorConfig(
        **{
            "obs_len": 50,
            "chunk": 50,
            "blocks": 2,
            "batch_size": 16,
            "anchor": "window",
            "mask_mix": REPAIR_MIX,
            "velocity_weight": 0.0,
            **over,
        }
    )


@pytest.mark.parametrize(
    "over,match",
    [
        ({"chunk": 10}, "chunk must equal obs_len"),
        ({"loss_frames": 20}, "loss_frames be 0"),
        ({"mask_mix": (("no_such_mask", 1.0),)}, "no_such_mask"),
        ({"obs_noise_prob": 0.5, "obs_noise_mm": 25.0}, "flips and rotations only"),
        ({"anchor": "first"}, "anchor must be one of"),
        ({"gap_fill": "linear"}, "gap_fill must be one of"),
        ({"dataset": "humaneva", "subjects": (1, 2, 3)}, "trains on Human3.6M"),
    ],
)
def test_repair_fill_config_rejects_what_it_cannot_train(over, match):
    with pytest.raises(ValueError, match=match):
        repair_fill_config(**over)
    with pytest.raises(ValueError, match="mask_mix is for anchor"):
        PriorConfig(mask_mix=REPAIR_MIX)
    with pytest.raises(ValueError, match="gap_fill is for a repair fill"):
        PriorConfig(gap_fill="forecaster")


def test_a_repair_fill_corrects_the_spline_of_its_masked_windows(tmp_path):
    """anchor "window": the output is the input window plus the network's (the untrained network returns
    the spline it is given); the training input is the spline through each window's observed entries under a
    mask of the mix (observed entries exact), a pure function of (seed, iteration); the loss covers the hidden
    joints only; training lowers it below the spline's on windows the run never draws; and the exported file
    is ``repair_fill.safetensors``, a prior with anchor "window"."""
    from training import export, fileformat, prior_net
    from training.model import spline_fill

    torch.set_num_threads(1)
    frames, starts = synthetic_frames()
    cfg = repair_fill_config()
    wins = batch(cfg, frames, starts, 10_000)
    assert wins.shape == (16, 50, 66)
    filled, joint_mask = repair_batch(cfg, wins, 10_000)
    again, mask_again = repair_batch(cfg, wins, 10_000)
    assert torch.equal(filled, again) and torch.equal(joint_mask, mask_again)
    assert 0.05 < float(1 - joint_mask.mean()) < 0.6  # some joints hidden, most seen
    mk = joint_mask.repeat_interleave(3, -1).transpose(1, 2)
    torch.testing.assert_close(filled, spline_fill(wins.transpose(1, 2), mk).transpose(1, 2))
    seen = mk.transpose(1, 2) > 0.5
    assert torch.equal(filled[seen], wins[seen])
    torch.manual_seed(cfg.seed)
    fresh = PriorNet(cfg)
    with torch.no_grad():
        torch.testing.assert_close(fresh(filled), filled, atol=1e-6, rtol=0)  # fc_out ~ 0: the spline itself
    # the loss is over the hidden joints: an error on seen joints only costs nothing
    off = wins + 1.0 * seen
    assert hidden_loss(off, wins, joint_mask).item() == 0.0
    # learnable: 66 coordinates mixed from 3 sinusoids, so the seen joints of a frame say where the hidden
    # ones are; 300 iterations at 1e-3 (3e-3 oscillates) take the hidden-joint error to about 0.67 x the spline's
    rng = np.random.default_rng(1)
    t = np.arange(400)[:, None] / 25.0
    latent = np.sin(2 * np.pi * rng.uniform(0.2, 1.5, 3) * t + rng.uniform(0, 6, 3))
    mixed = (0.3 * latent @ rng.normal(size=(3, 66)) / np.sqrt(3)).astype(np.float32), np.arange(400 - 50 + 1)
    cfg = repair_fill_config(iterations=300, lr=1e-3, lr_final=1e-3, mask_mix=(("random_joints", 1.0, 0.4),))
    wins = batch(cfg, *mixed, 10_000)
    filled, joint_mask = repair_batch(cfg, wins, 10_000)
    train(cfg, tmp_path / "run", frames=mixed, log=lambda m: None)
    with torch.no_grad():
        spline_loss = hidden_loss(filled, wins, joint_mask).item()
        trained_loss = hidden_loss(load(tmp_path / "run" / "last.pt")(filled), wins, joint_mask).item()
    assert trained_loss < 0.8 * spline_loss, (spline_loss, trained_loss)
    assert export.main(["--prior", str(tmp_path / "run" / "last.pt"), "--out", str(tmp_path / "model")]) == 0
    path = tmp_path / "model" / fileformat.REPAIR_FILL_FILE
    assert fileformat.read_config(path)["model"]["anchor"] == "window"
    assert not (tmp_path / "model" / fileformat.PRIOR_FILE).exists()
    model, _ = prior_net.load_prior_file(path)
    assert model.cfg.anchor == "window"
    with pytest.raises(ValueError, match="does not forecast"):
        model.rollout(wins, 10)


def test_validation_keeps_the_best_weights(tmp_path):
    """val_every: the loss on the held-out subjects' fixed windows every val_every iterations, in the history;
    best.pt holds the weights (and iteration) of the lowest, which the exporter records; the held-out subjects
    cannot be trained on."""
    from training import export, fileformat

    torch.set_num_threads(1)
    frames, held_out = synthetic_frames(), synthetic_frames(seed=1)
    cfg = repair_fill_config(
        iterations=40, lr=1e-2, lr_final=1e-2, val_subjects=(11,), val_every=10, val_windows=32, subjects=(1, 6)
    )
    train(cfg, tmp_path, frames=frames, val_frames=held_out, log=lambda m: None)
    history = torch.load(tmp_path / "last.pt", weights_only=False)["history"]
    vals = {h["iteration"]: h["val"] for h in history if "val" in h}
    assert sorted(vals) == [10, 20, 30, 40]
    best = torch.load(tmp_path / "best.pt", weights_only=False)
    assert best["iteration"] == min(vals, key=vals.get)
    vcfg, val = validation_windows(cfg, frames=held_out)
    net = load(tmp_path / "best.pt")
    with torch.no_grad():
        assert window_loss(vcfg, net, net, val, 0).item() == pytest.approx(vals[best["iteration"]], rel=1e-6)
    export.export_prior(tmp_path / "best.pt", tmp_path / "model")
    meta = fileformat.read_config(tmp_path / "model" / fileformat.REPAIR_FILL_FILE)["training"]
    assert meta["iteration"] == best["iteration"] and meta["val"] == pytest.approx(vals[best["iteration"]])
    with pytest.raises(ValueError, match="held out"):
        repair_fill_config(val_subjects=(1,), subjects=(1, 6))
    with pytest.raises(ValueError, match="needs val_subjects"):
        repair_fill_config(val_every=10)


def test_log_window_loss_weighs_every_window_alike():
    """window_loss "log_window": the mean over the windows with a hidden joint of the log of each one's mean
    hidden-joint distance (a window hiding nothing is left out); "pooled", the mean over every hidden joint. A
    window ten times further off adds log 10 to its term, whatever its size."""
    B, L, J = 3, 4, 2
    target = torch.zeros(B, L, 3 * J)
    joint_mask = torch.ones(B, L, J)
    joint_mask[0, 0, 0] = 0.0  # window 0: one hidden joint, 1 mm off
    joint_mask[1, :2, :] = 0.0  # window 1: four hidden joints, 10 mm off; window 2: none
    pred = target.clone()
    pred[0, 0, 0] = 0.001
    pred[1, :2, 1::3] = 0.010
    pred[2] += 5.0  # all seen: costs nothing
    pooled = hidden_loss(pred, target, joint_mask).item()
    assert pooled == pytest.approx((0.001 + 4 * 0.010) / 5, rel=1e-5)
    logw = hidden_loss(pred, target, joint_mask, "log_window").item()
    assert logw == pytest.approx((np.log(0.001 + 1e-6) + np.log(0.010 + 1e-6)) / 2, rel=1e-5)
    with pytest.raises(ValueError, match="window_loss must be one of"):
        repair_fill_config(window_loss="mean")
    with pytest.raises(ValueError, match="for a repair fill"):
        PriorConfig(window_loss="log_window")


def test_validation_on_separate_patterns_is_their_geometric_mean(tmp_path):
    """val_mask_mix: every validation window under each pattern in turn, scored by the geometric mean of the
    patterns' pooled hidden-joint errors (so the few-mm occlusions count as much as a gap of many frames); what
    best.pt is chosen on; the entries are checked like mask_mix's."""
    from dataclasses import replace
    from training.prior import validation_loss

    torch.set_num_threads(1)
    frames, held_out = synthetic_frames(), synthetic_frames(seed=1)
    patterns = (("random_leg_arm", 1.0, 0.4), ("consecutive_frames", 1.0, 0.2))
    cfg = repair_fill_config(
        iterations=20,
        lr=1e-2,
        lr_final=1e-2,
        val_subjects=(11,),
        val_every=10,
        val_windows=32,
        subjects=(1, 6),
        val_mask_mix=patterns,
        window_loss="log_window",
    )
    train(cfg, tmp_path, frames=frames, val_frames=held_out, log=lambda m: None)
    history = torch.load(tmp_path / "last.pt", weights_only=False)["history"]
    vals = {h["iteration"]: h["val"] for h in history if "val" in h}
    vcfg, val = validation_windows(cfg, frames=held_out)
    net = load(tmp_path / "last.pt")
    with torch.no_grad():
        each = [
            window_loss(replace(vcfg, mask_mix=(p,), window_loss="pooled"), net, net, val, 0).item() for p in patterns
        ]
        assert validation_loss(vcfg, net, val) == pytest.approx(np.sqrt(each[0] * each[1]), rel=1e-6)
    assert vals[20] == pytest.approx(np.sqrt(each[0] * each[1]), rel=1e-6)
    assert each[1] > 2 * each[0]  # the whole-frame gap is the larger error, not the larger say
    assert json.loads(json.dumps(load(tmp_path / "last.pt").cfg.val_mask_mix)) == json.loads(json.dumps(patterns))
    with pytest.raises(ValueError, match="no_such_mask"):
        repair_fill_config(val_mask_mix=(("no_such_mask", 1.0),))
    with pytest.raises(ValueError, match="for a repair fill"):
        PriorConfig(val_mask_mix=patterns)
