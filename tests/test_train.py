import json

import numpy as np
import pytest

from conftest import import_torch

torch = import_torch("training (training/train.py)")

from training.diffusion import DiffusionConfig, Schedule  # noqa: E402
from training.model import ModelConfig, TCDModel  # noqa: E402
from training.batches import Windows, make_batch  # noqa: E402
from training.train import learning_rate, train, validation_loss  # noqa: E402
from training.train_config import TrainConfig  # noqa: E402


def synthetic_motion(n_seq=6, T=60, J=22, seed=0):
    """Smooth periodic 'motion': each coordinate a sinusoid with its own phase and frequency."""
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None, None] / 25.0
    out = []
    for _ in range(n_seq):
        amp = rng.uniform(0.05, 0.2, size=(1, J, 3))
        freq = rng.uniform(0.3, 1.0, size=(1, J, 3))
        phase = rng.uniform(0, 2 * np.pi, size=(1, J, 3))
        base = rng.normal(scale=0.3, size=(1, J, 3))
        out.append((base + amp * np.sin(2 * np.pi * freq * t + phase)).astype(np.float32))
    return out


def tiny_cfg(**kw):
    d = dict(
        role="short",
        obs_len=10,
        pred_len=4,
        batch_size=8,
        epochs=3,
        steps_per_epoch=20,
        val_every=1,
        val_timesteps=5,
        val_max_windows=16,
        train_stride=2,
        val_stride=7,
        lr=3e-3,
        model={"channels": 16, "num_layers": 2, "num_heads": 2, "ffn_dim": 16, "dropout": 0.0},
    )
    d.update(kw)
    return TrainConfig(**d)


def test_make_batch_masks_and_targets():
    wins = np.stack(synthetic_motion(n_seq=4, T=14))
    cfg = tiny_cfg(mask_mix=[["random_leg_arm", 1.0]])
    x0, obs, mask = make_batch(cfg, wins, np.random.default_rng(0))
    assert x0.shape == obs.shape == mask.shape == (4, 66, 14)
    assert torch.all(mask[..., 10:] == 0)
    assert 0 < float(mask[..., :10].mean()) < 1  # some occlusion in the observation
    assert torch.all(obs[mask == 0] == 0)
    assert torch.equal(x0[mask == 1], obs[mask == 1])  # no noise pattern: visible = clean


def test_mask_mix_entries_may_carry_a_rate():
    wins = np.stack(synthetic_motion(n_seq=64, T=14))
    hidden = {}
    for rate in (0.1, 0.9):
        cfg = tiny_cfg(mask_mix=[["random_joints", 1.0, rate]])
        _, _, mask = make_batch(cfg, wins, np.random.default_rng(1))
        hidden[rate] = 1.0 - float(mask[..., :10].mean())
    assert abs(hidden[0.1] - 0.1) < 0.05 and abs(hidden[0.9] - 0.9) < 0.05, hidden
    cfg = tiny_cfg(mask_mix=[["random_joints", 1.0, [0.3, 0.5]]])
    _, _, mask = make_batch(cfg, wins, np.random.default_rng(2))
    assert 0.25 < 1.0 - float(mask[..., :10].mean()) < 0.55
    with pytest.raises(ValueError, match="mask_mix entry"):
        make_batch(tiny_cfg(mask_mix=[["random_joints"]]), wins, np.random.default_rng(0))


@pytest.mark.slow
def test_short_cpu_training_lowers_the_loss(tmp_path):
    seqs = {"train": synthetic_motion(6, seed=0), "val": synthetic_motion(2, seed=1)}
    cfg = tiny_cfg(epochs=2, steps_per_epoch=25, val_every=2)
    # validation loss of the same seeded model before any update
    torch.manual_seed(cfg.seed)
    untrained = TCDModel(ModelConfig.from_dict(cfg.model))
    before = validation_loss(
        untrained, Schedule(DiffusionConfig()), cfg, Windows(seqs["val"], 14, cfg.val_stride), "cpu"
    )
    res = train(cfg, tmp_path, sequences=seqs, log=lambda *a: None)
    after = [h["val_loss"] for h in res["history"] if "val_loss" in h]
    assert len(after) == 1
    assert after[-1] < 0.6 * before, (before, after)
    assert (tmp_path / "best.pt").is_file() and (tmp_path / "last.pt").is_file()


@pytest.mark.slow
def test_resume_continues_exactly(tmp_path):
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    cfg = tiny_cfg(epochs=2, steps_per_epoch=6)
    train(cfg, tmp_path / "full", sequences=seqs, log=lambda *a: None)
    # same run interrupted after the first epoch (max_minutes=0 stops at the first batch of epoch 0,
    # so emulate an interruption by training one epoch with the same config and then resuming)
    part = tmp_path / "part"
    cfg1 = tiny_cfg(epochs=2, steps_per_epoch=6)
    train(cfg1, part, sequences=seqs, max_minutes=0.0, log=lambda *a: None)  # stops after one batch
    train(cfg1, part, sequences=seqs, resume=True, log=lambda *a: None)
    a = torch.load(tmp_path / "full" / "last.pt", weights_only=False)["model"]
    b = torch.load(part / "last.pt", weights_only=False)["model"]
    for k in a:
        assert torch.allclose(a[k], b[k], atol=1e-6), k


@pytest.mark.slow
def test_dataloader_workers_draw_the_same_batches(tmp_path):
    """workers > 0 draws each batch (rows, masks, t, noise) in worker processes from the same seeds:
    the trained weights are bitwise those of the in-process run."""
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    cfg = tiny_cfg(
        epochs=2,
        steps_per_epoch=5,
        val_every=2,
        mask_mix=[["random_leg_arm", 1.0, 0.4], ["random_joints", 1.0, [0.1, 0.4]]],
    )
    train(cfg, tmp_path / "serial", sequences=seqs, log=lambda *a: None)
    train(cfg, tmp_path / "workers", sequences=seqs, workers=2, log=lambda *a: None)
    a = torch.load(tmp_path / "serial" / "last.pt", weights_only=False)["model"]
    b = torch.load(tmp_path / "workers" / "last.pt", weights_only=False)["model"]
    for k in a:
        assert torch.equal(a[k], b[k]), k


def test_resume_refuses_another_config(tmp_path):
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    train(tiny_cfg(epochs=1, steps_per_epoch=2), tmp_path, sequences=seqs, log=lambda *a: None)
    with pytest.raises(ValueError, match="another config"):
        train(
            tiny_cfg(epochs=1, steps_per_epoch=2, lr=1e-4), tmp_path, sequences=seqs, resume=True, log=lambda *a: None
        )


REMOVED_AT_DEFAULTS = {"batches": "host", "ema_probe_decays": [], "choose_average": False}


def test_removed_keys_at_their_inert_values_are_dropped_and_otherwise_refused(tmp_path):
    """Configs and checkpoints written before the GPU-call tooling was removed hold "batches",
    "ema_probe_decays" and "choose_average": at the values that did nothing they load and resume as
    before; any other value is refused, naming the key and the git tag that has the code."""
    from dataclasses import asdict
    from training.train_config import REMOVED_KEYS

    assert REMOVED_KEYS == REMOVED_AT_DEFAULTS
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    cfg = tiny_cfg(epochs=1, steps_per_epoch=2)
    old, plain = tmp_path / "old.json", tmp_path / "plain.json"
    old.write_text(json.dumps({**asdict(cfg), **REMOVED_AT_DEFAULTS}))
    plain.write_text(json.dumps(asdict(cfg)))
    assert TrainConfig.load(old) == TrainConfig.load(plain)
    train(cfg, tmp_path / "run", sequences=seqs, max_minutes=0.0, log=lambda *a: None)  # stops after one batch
    last = tmp_path / "run" / "last.pt"
    ck = torch.load(last, weights_only=False)
    ck["train_config"] = {**ck["train_config"], **REMOVED_AT_DEFAULTS}
    torch.save(ck, last)
    assert train(cfg, tmp_path / "run", sequences=seqs, resume=True, log=lambda *a: None)["epoch"] == 1
    for key, value in (("batches", "device"), ("ema_probe_decays", [0.99]), ("choose_average", True)):
        old.write_text(json.dumps({**asdict(cfg), key: value}))
        with pytest.raises(ValueError, match=f"{key}.*gpu-workflow-before-removal"):
            TrainConfig.load(old)
        ck["train_config"] = {**ck["train_config"], **REMOVED_AT_DEFAULTS, key: value}
        torch.save(ck, last)
        with pytest.raises(ValueError, match=key):
            train(cfg, tmp_path / "run", sequences=seqs, resume=True, log=lambda *a: None)


def test_config_files_load(tmp_path):
    """The configs the tests train from, and every trainer stage's config of every recipe, load as their
    trainer's (a recipe's stage names its warm start apart, as ``from``)."""
    from pathlib import Path
    from training.prior_net import PriorConfig
    from training.recipe_file import all_recipes

    files = sorted((Path(__file__).parents[1] / "training" / "configs").glob("*.json"))
    configs = [json.loads(p.read_text()) for p in files]
    trainer = ["prior" if p.stem.startswith("humaneva_prior") else "train" for p in files]
    for r in all_recipes().values():
        for s in r.stages:
            if s.run in ("train", "prior"):
                configs.append({k: v for k, v in s.config.items() if not (isinstance(v, str) and "{" in v)})
                trainer.append(s.run)
    assert len(configs) > 5
    for d, run in zip(configs, trainer, strict=True):
        path = tmp_path / "c.json"
        path.write_text(json.dumps(d))
        if run == "prior":
            assert PriorConfig.load(path).blocks >= 1
        else:
            assert TrainConfig.load(path).role in ("short", "long", "repair")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"role": "short", "learning_rate": 1}))
    with pytest.raises(ValueError, match="learning_rate"):
        TrainConfig.load(bad)


def test_sequences_load_from_a_data_cache(tmp_path):
    """--data may name a cache in --write-cache's layout (float16 ``{split}/{key}`` arrays): each split's
    sequences, in key order, as float32."""
    from training.train import load_sequences

    seqs = {"train": synthetic_motion(3, seed=0), "val": synthetic_motion(2, seed=1)}
    cache = tmp_path / "h36m_model_cache_test.npz"
    np.savez(
        cache, **{f"{split}/{i:02d}": q.astype(np.float16) for split, qs in seqs.items() for i, q in enumerate(qs)}
    )
    for split, qs in seqs.items():
        got = load_sequences(tiny_cfg(), str(cache), split)
        assert len(got) == len(qs) and all(g.dtype == np.float32 for g in got)
        assert all(np.array_equal(g, q.astype(np.float16).astype(np.float32)) for g, q in zip(got, qs))


def test_windows_index():
    w = Windows([np.zeros((10, 22, 3)), np.zeros((4, 22, 3))], length=5, stride=2)
    assert len(w) == 3 and w.gather(np.array([2])).shape == (1, 5, 22, 3)


def test_learning_rate_is_the_papers_multistep_schedule_with_a_warm_up():
    cfg = tiny_cfg(epochs=20, lr=1e-3, milestones=(0.75, 0.9))
    model = torch.nn.Linear(2, 2)
    opt = torch.optim.SGD(model.parameters(), lr=cfg.lr)
    ref = torch.optim.lr_scheduler.MultiStepLR(opt, milestones=[15, 18], gamma=0.1)
    for epoch in range(cfg.epochs):
        for b in range(3):
            assert learning_rate(cfg, epoch * 3 + b, 3) == pytest.approx(opt.param_groups[0]["lr"], rel=1e-12)
        opt.step()
        ref.step()
    warm = tiny_cfg(epochs=20, lr=1e-3, warmup_steps=4)
    assert [learning_rate(warm, s, 3) for s in range(5)] == pytest.approx([2.5e-4, 5e-4, 7.5e-4, 1e-3, 1e-3])


def test_bad_train_config_values_are_refused():
    for kw, word in (({"ema_decay": 1.0}, "ema_decay"), ({"warmup_steps": -1}, "warmup_steps")):
        with pytest.raises(ValueError, match=word):
            tiny_cfg(**kw)


def test_reset_output_head_restarts_only_the_last_layer_of_a_warm_start(tmp_path):
    """reset_output_head (a warm start whose prediction_type changes): every weight as the warm start's but the
    last 1x1 conv, whose weight and bias restart at zero; refused without init_from."""
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    train(tiny_cfg(epochs=1, steps_per_epoch=4), tmp_path / "eps", sequences=seqs, log=lambda *a: None)
    start = torch.load(tmp_path / "eps" / "last.pt", weights_only=False)["model"]
    head = "diffmodel.output_projection2.weight"
    assert start[head].abs().sum() > 0  # trained away from its zero init
    for reset in (False, True):  # lr 0: the weights stay where they start
        cfg = tiny_cfg(
            epochs=1,
            steps_per_epoch=1,
            lr=0.0,
            init_from=str(tmp_path / "eps" / "last.pt"),
            diffusion={"prediction_type": "sample"},
            reset_output_head=reset,
        )
        train(cfg, tmp_path / f"x0_{reset}", sequences=seqs, log=lambda *a: None)
        got = torch.load(tmp_path / f"x0_{reset}" / "last.pt", weights_only=False)["model"]
        for k in start:
            if reset and k.startswith("diffmodel.output_projection2."):
                assert not got[k].any(), k
            else:
                assert torch.equal(got[k], start[k]), k
    with pytest.raises(ValueError, match="reset_output_head.*init_from"):
        tiny_cfg(reset_output_head=True)


def test_a_warm_start_into_a_wider_config_is_widened(tmp_path):
    """A config twice as wide as its init_from (channels and ffn_dim): train widens the warm start with
    training.widen (seeded by the config's seed) and starts from exactly those weights (lr 0 keeps them)."""
    from training.model import ModelConfig
    from training.widen import widen_state

    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    train(tiny_cfg(epochs=1, steps_per_epoch=2), tmp_path / "narrow", sequences=seqs, log=lambda *a: None)
    ck = torch.load(tmp_path / "narrow" / "last.pt", weights_only=False)
    lines = []
    wide = {"channels": 32, "num_layers": 2, "num_heads": 2, "ffn_dim": 32, "dropout": 0.0}
    cfg = tiny_cfg(
        epochs=1, steps_per_epoch=1, lr=0.0, seed=7, init_from=str(tmp_path / "narrow" / "last.pt"), model=wide
    )
    train(cfg, tmp_path / "wide", sequences=seqs, log=lines.append)
    assert any("widened 2 x to 32 channels" in line for line in lines)
    got = torch.load(tmp_path / "wide" / "last.pt", weights_only=False)["model"]
    want = widen_state(ck["model"], ModelConfig.from_dict(ck["model_config"]), 2, seed=7)
    assert sorted(got) == sorted(want) and all(torch.equal(got[k], want[k]) for k in want)


@pytest.mark.slow
def test_ema_weights_are_validated_resumed_and_exported(tmp_path):
    from training.export import export_checkpoint, load_model_file

    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    cfg = tiny_cfg(epochs=2, steps_per_epoch=6, ema_decay=0.9)
    train(cfg, tmp_path / "full", sequences=seqs, log=lambda *a: None)
    part = tmp_path / "part"
    train(cfg, part, sequences=seqs, max_minutes=0.0, log=lambda *a: None)
    train(cfg, part, sequences=seqs, resume=True, log=lambda *a: None)
    full = torch.load(tmp_path / "full" / "last.pt", weights_only=False)
    resumed = torch.load(part / "last.pt", weights_only=False)
    best = torch.load(tmp_path / "full" / "best.pt", weights_only=False)
    assert "optimizer" not in best and best["ema"].keys() == full["ema"].keys()  # best.pt: the weights only
    assert full["ema_n"] == resumed["ema_n"] == 12
    key = "diffmodel.residual_layers.0.mid_projection.weight"
    assert not torch.allclose(full["ema"][key], full["model"][key])  # an average, not the last weights
    for k in full["ema"]:
        assert torch.allclose(full["ema"][k], resumed["ema"][k], atol=1e-6), k
    path = export_checkpoint(tmp_path / "full" / "last.pt", tmp_path / "export")
    exported, _, meta = load_model_file(path)
    assert torch.equal(exported.state_dict()[key], full["ema"][key])
    assert meta["training"]["weights"] == "ema"
    # the validation loss recorded is the EMA weights' loss
    ema_model = TCDModel(ModelConfig.from_dict(cfg.model))
    ema_model.load_state_dict(full["ema"])
    v = validation_loss(ema_model, Schedule(DiffusionConfig()), cfg, Windows(seqs["val"], 14, cfg.val_stride), "cpu")
    assert full["history"][-1]["val_loss"] == pytest.approx(v, rel=1e-6)


def test_compile_failure_falls_back_to_eager_training(tmp_path, monkeypatch):
    def broken(*a, **k):
        raise RuntimeError("no compiler here")

    monkeypatch.setattr(torch, "compile", broken)
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    lines = []
    res = train(tiny_cfg(epochs=1, steps_per_epoch=3, compile=True), tmp_path, sequences=seqs, log=lines.append)
    assert res["epoch"] == 1
    message = "torch.compile failed (RuntimeError: no compiler here); training eagerly"
    assert any(message in line for line in lines), lines


def test_the_compiled_forward_is_compiled_once(tmp_path, monkeypatch):
    """With ``compile``, the warm-up call before training compiles the graph the training steps use: a
    recompilation at the first step is an error here (Dynamo's eager backend, so no compiler is needed). The
    warm-up once passed one tensor as x, observed and mask; Dynamo guards on aliasing, and the first real
    step compiled everything again."""
    import functools

    monkeypatch.setattr(torch, "compile", functools.partial(torch.compile, backend="eager"))
    monkeypatch.setattr(torch._dynamo.config, "error_on_recompile", True)
    torch._dynamo.reset()
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    lines = []
    res = train(tiny_cfg(epochs=1, steps_per_epoch=3, compile=True), tmp_path, sequences=seqs, log=lines.append)
    torch._dynamo.reset()
    assert res["epoch"] == 1
    assert not any("torch.compile failed" in line for line in lines), lines


def test_training_stops_at_the_deadline(tmp_path):
    """train(deadline=) (--stop-at): a wall-clock stop, counted whatever set-up and compiling took: a
    deadline already past stops after the first batch, validated and resumable, like max_minutes=0."""
    import time

    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    cfg = tiny_cfg(epochs=2, steps_per_epoch=4)
    res = train(cfg, tmp_path / "r", sequences=seqs, deadline=time.time() - 1, log=lambda *a: None)
    assert (res["epoch"], res["batch"]) == (0, 1) and res["history"][-1]["stopped"] == "max-minutes"
    assert train(cfg, tmp_path / "r", sequences=seqs, resume=True, log=lambda *a: None)["epoch"] == 2
