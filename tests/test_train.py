import json

import numpy as np
import pytest
import torch

from training.diffusion import DiffusionConfig, Schedule
from training.model import ModelConfig, TCDModel
from training.batches import Windows, make_batch
from training.train import TrainConfig, learning_rate, train, validation_loss


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
    d = dict(role="short", obs_len=10, pred_len=4, batch_size=8, epochs=3, steps_per_epoch=20, val_every=1,
             val_timesteps=5, val_max_windows=16, train_stride=2, val_stride=7, lr=3e-3,
             model={"channels": 16, "num_layers": 2, "num_heads": 2, "ffn_dim": 16, "dropout": 0.0})
    d.update(kw)
    return TrainConfig(**d)


def test_make_batch_masks_and_targets():
    wins = np.stack(synthetic_motion(n_seq=4, T=14))
    cfg = tiny_cfg(mask_mix=[["random_leg_arm", 1.0]])
    x0, obs, mask = make_batch(cfg, wins, np.random.default_rng(0))
    assert x0.shape == obs.shape == mask.shape == (4, 66, 14)
    assert torch.all(mask[..., 10:] == 0)
    assert 0 < float(mask[..., :10].mean()) < 1                      # some occlusion in the observation
    assert torch.all(obs[mask == 0] == 0)
    assert torch.equal(x0[mask == 1], obs[mask == 1])                 # no noise pattern: visible = clean


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
    before = validation_loss(untrained, Schedule(DiffusionConfig()), cfg, Windows(seqs["val"], 14, cfg.val_stride), "cpu")
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
    train(cfg1, part, sequences=seqs, max_minutes=0.0, log=lambda *a: None)   # stops after one batch
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
    cfg = tiny_cfg(epochs=2, steps_per_epoch=5, val_every=2,
                   mask_mix=[["random_leg_arm", 1.0, 0.4], ["random_joints", 1.0, [0.1, 0.4]]])
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
        train(tiny_cfg(epochs=1, steps_per_epoch=2, lr=1e-4), tmp_path, sequences=seqs, resume=True, log=lambda *a: None)


def test_config_files_load(tmp_path):
    from pathlib import Path
    from training.prior import PriorConfig
    for p in sorted((Path(__file__).parents[1] / "training" / "configs").glob("*.json")):
        if p.name.startswith("prior") or p.name.endswith("_prior.json"):   # the prior forecaster's (training.prior)
            assert PriorConfig.load(p).blocks >= 1
            continue
        cfg = TrainConfig.load(p)
        assert cfg.role in ("short", "long", "repair")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"role": "short", "learning_rate": 1}))
    with pytest.raises(ValueError, match="learning_rate"):
        TrainConfig.load(bad)


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
    for kw, word in (({"batches": "gpu"}, "batches"), ({"ema_decay": 1.0}, "ema_decay"),
                     ({"warmup_steps": -1}, "warmup_steps")):
        with pytest.raises(ValueError, match=word):
            tiny_cfg(**kw)


@pytest.mark.slow
def test_device_batches_train_resume_exactly_and_lower_the_loss(tmp_path):
    """batches="device" (everything drawn on the device; here the CPU): a pure function of (seed, epoch,
    batch), so an interrupted and resumed run ends with the weights of an uninterrupted one."""
    seqs = {"train": synthetic_motion(6, seed=0), "val": synthetic_motion(2, seed=1)}
    cfg = tiny_cfg(epochs=2, steps_per_epoch=25, val_every=2, batches="device",
                   mask_mix=[["none", 1.0], ["random_leg_arm", 1.0, 0.4], ["noisy_25", 0.5]])
    torch.manual_seed(cfg.seed)
    untrained = TCDModel(ModelConfig.from_dict(cfg.model))
    before = validation_loss(untrained, Schedule(DiffusionConfig()), cfg, Windows(seqs["val"], 14, cfg.val_stride), "cpu")
    res = train(cfg, tmp_path / "full", sequences=seqs, log=lambda *a: None)
    assert res["best_val"] < 0.6 * before, (before, res["best_val"])
    part = tmp_path / "part"
    train(cfg, part, sequences=seqs, max_minutes=0.0, log=lambda *a: None)   # stops after one batch
    train(cfg, part, sequences=seqs, resume=True, log=lambda *a: None)
    a = torch.load(tmp_path / "full" / "last.pt", weights_only=False)["model"]
    b = torch.load(part / "last.pt", weights_only=False)["model"]
    for k in a:
        assert torch.equal(a[k], b[k]), k


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
    assert full["ema_n"] == resumed["ema_n"] == 12
    key = "diffmodel.residual_layers.0.mid_projection.weight"
    assert not torch.allclose(full["ema"][key], full["model"][key])        # an average, not the last weights
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
    assert any("torch.compile failed (RuntimeError: no compiler here); training eagerly" in l for l in lines), lines


@pytest.mark.slow
def test_gpu_session_sizes_the_schedule_trains_and_exports(tmp_path):
    """training.gpu_session end to end on the CPU at the tiny size: the probe times the configured step, the
    epochs are chosen to fit the budget and written to RUN/config.json, the run trains and the best (EMA)
    weights are exported."""
    from dataclasses import asdict
    from training import gpu_session
    from training.export import load_model_file
    cache = tmp_path / "h36m_model_cache_test.npz"
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    np.savez(cache, **{f"{split}/{i:02d}": s.astype(np.float16) for split, ss in seqs.items() for i, s in enumerate(ss)})
    cfg_path = tmp_path / "cfg.json"
    cfg_path.write_text(json.dumps(asdict(tiny_cfg(batches="device", ema_decay=0.9, steps_per_epoch=5, warmup_steps=3))))
    run, export = tmp_path / "run", tmp_path / "export"
    rc = gpu_session.main(["--config", str(cfg_path), "--run", str(run), "--data", str(cache), "--budget-minutes", "0.05",
                           "--minutes", "1", "--probe-steps", "2", "--device", "cpu", "--export", str(export),
                           "--copy-to", str(tmp_path / "copy")])
    assert rc == 0
    chosen = json.loads((run / "config.json").read_text())
    assert chosen["epochs"] >= 1 and chosen["val_every"] <= chosen["epochs"]
    log = (run / "log.txt").read_text()
    assert "probe:" in log and "steps/s" in log
    model, _, meta = load_model_file(export / "short.safetensors")
    # best.pt is the epoch with the lowest validation loss: any of the run's epochs, not necessarily the last
    assert meta["training"]["weights"] == "ema" and 1 <= meta["training"]["epoch"] <= chosen["epochs"]
    assert (tmp_path / "copy" / "best.pt").is_file()
    assert "optimizer" not in torch.load(run / "best.pt", weights_only=False)      # weights only: small enough to hand back


def test_gpu_session_fits_training_into_the_call():
    """--call-minutes: training gets what set-up, probe, the training's own compiling and the reserve leave;
    a one-call schedule is sized to that, a schedule spread over calls keeps its budget; no time left is an
    error before anything trains."""
    import argparse
    import time
    from training import gpu_session
    now = time.time()
    ns = lambda **kw: argparse.Namespace(**{"call_minutes": 5.0, "minutes": 8.0, "budget_minutes": 8.0, **kw})  # noqa: E731
    minutes, budget = gpu_session.fit_call(ns(), now, 1.0, lambda *a: None)
    assert minutes == pytest.approx(5.0 - 1.0 - gpu_session.RESERVE_MINUTES, abs=0.01) and budget == minutes
    assert gpu_session.fit_call(ns(budget_minutes=20.0), now, 1.0, lambda *a: None)[1] == 20.0
    assert gpu_session.fit_call(ns(minutes=1.0, budget_minutes=1.0), now, 1.0, lambda *a: None) == (1.0, 1.0)
    assert gpu_session.fit_call(ns(call_minutes=None), now, 1.0, lambda *a: None) == (8.0, 8.0)
    with pytest.raises(SystemExit, match="no time left"):
        gpu_session.fit_call(ns(call_minutes=2.0), now, 1.0, lambda *a: None)


def test_ema_probes_are_validated_beside_and_change_nothing(tmp_path):
    """ema_probe_decays: each probe's and the raw weights' validation loss beside the exported EMA's, at
    every validation; the run itself (losses, exported weights) is the same as without probes; probes
    resume with the run."""
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    base = dict(epochs=2, steps_per_epoch=4, ema_decay=0.9)
    plain = train(tiny_cfg(**base), tmp_path / "plain", sequences=seqs, log=lambda *a: None)
    lines = []
    probed = train(tiny_cfg(**base, ema_probe_decays=[0.5, 0.99]), tmp_path / "probed", sequences=seqs, log=lines.append)
    assert [h["val_loss"] for h in probed["history"]] == [h["val_loss"] for h in plain["history"]]
    assert [h["train_loss"] for h in probed["history"]] == [h["train_loss"] for h in plain["history"]]
    first, last = probed["history"]                # probes at the schedule's end only (each costs a validation)
    assert "val_loss_probes" not in first and set(last["val_loss_probes"]) == {"ema_0.5", "ema_0.99", "raw"}
    assert all(np.isfinite(v) for v in last["val_loss_probes"].values())
    assert len(set(last["val_loss_probes"].values()) | {last["val_loss"]}) == 4       # four different weights
    assert any(line.startswith("  probes: ema_0.5") for line in lines)
    ck = torch.load(tmp_path / "probed" / "last.pt", weights_only=False)
    assert [p["decay"] for p in ck["ema_probes"]] == [0.5, 0.99] and ck["ema_probes"][0]["n"] == 8
    assert "ema_probes" not in torch.load(tmp_path / "probed" / "best.pt", weights_only=False)
    # stopped after its first batch and resumed: the probes end where the uninterrupted run's do
    cfg = tiny_cfg(**base, ema_probe_decays=[0.5, 0.99])
    train(cfg, tmp_path / "resumed", sequences=seqs, max_minutes=0, log=lambda *a: None)
    resumed = train(cfg, tmp_path / "resumed", sequences=seqs, resume=True, log=lambda *a: None)
    assert resumed["history"][-1]["val_loss_probes"] == probed["history"][-1]["val_loss_probes"]
    # ... from the probes' saved state: shifted weights in last.pt show in the resumed probe alone
    train(cfg, tmp_path / "shifted", sequences=seqs, max_minutes=0, log=lambda *a: None)
    ck = torch.load(tmp_path / "shifted" / "last.pt", weights_only=False)
    ck["ema_probes"][1]["weights"] = {k: v + 0.05 for k, v in ck["ema_probes"][1]["weights"].items()}
    torch.save(ck, tmp_path / "shifted" / "last.pt")
    shifted = train(cfg, tmp_path / "shifted", sequences=seqs, resume=True, log=lambda *a: None)["history"][-1]
    assert shifted["val_loss_probes"]["ema_0.5"] == probed["history"][-1]["val_loss_probes"]["ema_0.5"]
    assert shifted["val_loss_probes"]["ema_0.99"] != probed["history"][-1]["val_loss_probes"]["ema_0.99"]
    with pytest.raises(ValueError, match="ema_probe_decays"):
        tiny_cfg(ema_probe_decays=[1.0])


def test_gpu_session_plans_the_whole_schedule_into_the_minutes():
    """plan_schedule: 20 epochs of as many steps as the probed rate allows once the schedule's validations
    (timed) are paid for, so the decays fall at 75 % and 90 % of the steps and the schedule ends within the
    minutes; the config's own epoch size plays no part (it used to round a few minutes down to whole epochs
    of 500 steps: 1,440 steps' time gave 2 epochs, 1,000 steps, both decays after the first)."""
    from training import gpu_session
    from training.train import learning_rate, validations_per_schedule
    cfg = tiny_cfg(epochs=50, steps_per_epoch=500, val_every=5, ema_decay=0.999, ema_probe_decays=[0.99, 0.9997],
                   milestones=[0.75, 0.9], warmup_steps=0)
    plan = gpu_session.plan_schedule(cfg, steps_per_s=4.0, minutes=6.0, validation_s=10.0)
    steps = plan.epochs * plan.steps_per_epoch
    assert (plan.epochs, plan.val_every) == (20, 5)
    assert validations_per_schedule(plan) == 4 + 3              # 4 of the EMA, then 2 probes and the raw weights
    spent = steps / 4.0 + validations_per_schedule(plan) * 10.0
    assert 0.9 * 360 < spent <= 360                              # the minutes are used, and not overrun
    rates = [learning_rate(plan, i, plan.steps_per_epoch) for i in range(steps)]
    drops = [i for i in range(1, steps) if rates[i] < rates[i - 1]]
    assert drops == [15 * plan.steps_per_epoch, 18 * plan.steps_per_epoch]
    assert [round(d / steps, 2) for d in drops] == [0.75, 0.9]
    # very few steps: epochs of one step, still at least one step
    few = gpu_session.plan_schedule(cfg, steps_per_s=0.05, minutes=2.0, validation_s=1.0)
    assert few.steps_per_epoch == 1 and 1 <= few.epochs < 20 and few.val_every <= few.epochs
    assert gpu_session.plan_schedule(cfg, steps_per_s=1.0, minutes=0.01, validation_s=60.0).epochs == 1


def test_choose_average_keeps_the_lowest_validated_weights(tmp_path):
    """choose_average: at the validation with probes, a probe (or the raw weights) whose validation loss is
    below the exported average's is what best.pt keeps and what is exported, under its name; off (the
    default), best.pt keeps the average whatever the probes say."""
    from training.export import checkpoint_weights, export_checkpoint, load_model_file
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    # an average far too slow for 8 steps: it stays near the initial weights, which the others beat
    base = dict(epochs=2, steps_per_epoch=4, ema_decay=0.99, ema_probe_decays=[0.5])
    chose = train(tiny_cfg(**base, choose_average=True), tmp_path / "chose", sequences=seqs, log=lambda *a: None)
    last = chose["history"][-1]
    name = min(last["val_loss_probes"], key=last["val_loss_probes"].get)
    assert last["val_loss_probes"][name] < last["val_loss"] and last["chosen"] == name
    ck = torch.load(tmp_path / "chose" / "best.pt", weights_only=False)
    assert ck["chosen"]["name"] == name and ck["best_val"] == last["val_loss_probes"][name] == chose["best_val"]
    model, _, meta = load_model_file(export_checkpoint(tmp_path / "chose" / "best.pt", tmp_path / "export"))
    assert meta["training"]["weights"] == name
    assert all(torch.equal(model.state_dict()[k], v) for k, v in checkpoint_weights(ck).items())
    assert not all(torch.equal(ck["ema"][k], v) for k, v in ck["chosen"]["weights"].items())
    # the same run without the option: the same losses, and best.pt holds the average
    kept = train(tiny_cfg(**base), tmp_path / "kept", sequences=seqs, log=lambda *a: None)
    assert kept["history"][-1]["val_loss_probes"] == last["val_loss_probes"] and "chosen" not in kept["history"][-1]
    assert "chosen" not in torch.load(tmp_path / "kept" / "best.pt", weights_only=False)


def test_training_stops_at_the_deadline(tmp_path):
    """train(deadline=): a wall-clock stop (a GPU call's), counted whatever set-up and compiling took: a
    deadline already past stops after the first batch, validated and resumable, like max_minutes=0;
    gpu_session's deadline leaves RESERVE_MINUTES of the call."""
    import argparse
    import time
    from training import gpu_session
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    cfg = tiny_cfg(epochs=2, steps_per_epoch=4)
    res = train(cfg, tmp_path / "r", sequences=seqs, deadline=time.time() - 1, log=lambda *a: None)
    assert (res["epoch"], res["batch"]) == (0, 1) and res["history"][-1]["stopped"] == "max-minutes"
    assert train(cfg, tmp_path / "r", sequences=seqs, resume=True, log=lambda *a: None)["epoch"] == 2
    t = time.time()
    assert gpu_session.deadline(argparse.Namespace(call_minutes=9.5), t) == t + 60 * (9.5 - gpu_session.RESERVE_MINUTES)
    assert gpu_session.deadline(argparse.Namespace(call_minutes=None), t) is None
