"""HumanEva-I on the training side (issue 31): the training windows, the prior on HumanEva's 14 joints,
training configs and a few training steps, and the stochastic evaluation through the engine on the committed
tiny random model directory (tests/fixtures/tiny_humaneva_model). Needs torch (the training code); the package
side is tests/test_humaneva.py.

Tests on the real data skip cleanly where ``../shared/data/humaneva`` (``$TCD_DATA_DIR``) is absent; the rest
use small synthetic data made here."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import FIXTURES, ROOT, import_torch

torch = import_torch("HumanEva-I training and evaluation (training/)")

import tcd  # noqa: E402
from test_humaneva import HUMANEVA_FILE, needs_humaneva, walking, write_synthetic_file  # noqa: E402
from training import evaluate, evaluate_stochastic  # noqa: E402
from training.batches import Windows  # noqa: E402
from training.data.humaneva import (  # noqa: E402
    HUMANEVA_MODEL_JOINT_NAMES,
    humaneva_test_windows,
    load_humaneva,
    training_sequences,
)
from training.export import HUMANEVA_WINDOWS, export_checkpoint, export_prior  # noqa: E402
from training.prior_net import load_prior_file  # noqa: E402
from training.fileformat import read_config  # noqa: E402
from training.prior import load as load_prior_checkpoint, training_frames  # noqa: E402
from training.prior_net import PriorConfig, PriorNet  # noqa: E402
from training.prior import train as train_prior  # noqa: E402
from training.train import train  # noqa: E402
from training.train_config import TrainConfig  # noqa: E402

CONFIGS = ROOT / "training" / "configs"
PRIOR_MODEL = {"cond_fill": "prior", "target": "prior_residual", "target_scale": 10.0}
TINY = {"num_joints": 14, "channels": 16, "num_layers": 1, "num_heads": 2, "ffn_dim": 16, "dropout": 0.0}

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # a busy 2-core machine: PyTorch's threads only thrash


@pytest.fixture(scope="module")
def synthetic_file(tmp_path_factory) -> Path:
    return write_synthetic_file(tmp_path_factory.mktemp("humaneva"))


@pytest.fixture(scope="module")
def humaneva_model_dir() -> Path:
    """The committed tiny HumanEva-I model around a random prior (read only here)."""
    return FIXTURES / "tiny_humaneva_model"


# ------------------------------------------------------------------------------------------ the data


@needs_humaneva
def test_real_training_windows_and_split():
    seqs = training_sequences(HUMANEVA_FILE)
    assert all(k.startswith("Train/") for k in seqs) and len(seqs) == 33
    assert "Train/S3/Walking 1 chunk0" not in seqs and "Train/S3/Walking 1 chunk2" not in seqs
    assert sum(len(v) for v in seqs.values()) == 4251
    # the cascade's windows, stride 1 inside a chunk: the long model's 75 frames, the short model's 16
    assert len(Windows(list(seqs.values()), 75, 1)) == 2612
    assert len(Windows(list(seqs.values()), 16, 1)) == 3797
    test = humaneva_test_windows(load_humaneva(HUMANEVA_FILE, "Validate"))
    assert test.shape == (188, 75, 14, 3)
    # no test window appears in the training data
    train_starts = {np.round(v[i], 5).tobytes() for v in seqs.values() for i in range(len(v))}
    assert not any(np.round(w[0], 5).tobytes() in train_starts for w in test)


# ------------------------------------------------------------------------------------------ the prior


def test_prior_config_and_network_on_humaneva():
    cfg = PriorConfig.load(CONFIGS / "humaneva_prior.json")
    assert (cfg.dataset, cfg.num_joints, cfg.obs_len) == ("humaneva", 14, 15) and cfg.chunk <= cfg.obs_len
    assert cfg.subjects == (1, 2, 3)
    net = PriorNet(cfg)
    assert net.fc_in.in_features == 42
    x = torch.randn(2, 15, 42)
    assert net(x).shape == (2, cfg.chunk, 42)
    assert net.rollout(x, 60).shape == (2, 60, 42)
    with pytest.raises(ValueError, match="chunk"):
        PriorConfig(dataset="humaneva", obs_len=15, chunk=60, subjects=(1, 2, 3))
    with pytest.raises(ValueError, match="subjects"):
        PriorConfig(dataset="humaneva", obs_len=15)  # Human3.6M's subjects by default
    with pytest.raises(ValueError, match="dataset"):
        PriorConfig(dataset="amass")
    # a checkpoint's config written before `dataset` existed is a Human3.6M one, and compares equal to it
    old = PriorConfig().to_dict()
    del old["dataset"]
    assert PriorConfig.from_dict(old) == PriorConfig()


def test_prior_trains_exports_and_runs_in_the_engine(tmp_path):
    cfg = PriorConfig(
        dataset="humaneva", obs_len=15, chunk=10, blocks=2, batch_size=16, iterations=3, subjects=(1, 2, 3)
    )
    seqs = [walking(90, s)[:, 1:] - walking(90, s)[:, :1] for s in range(3)]
    frames = training_frames(cfg, seqs=[q.astype(np.float32) for q in seqs])
    assert frames[0].shape == (270, 42) and len(frames[1]) == 3 * (90 - 25 + 1)
    res = train_prior(cfg, tmp_path / "run", frames=frames, log=lambda *a: None)
    assert res["done"]
    net = load_prior_checkpoint(tmp_path / "run" / "last.pt")
    assert net.fc_in.in_features == 42
    path = export_prior(tmp_path / "run" / "last.pt", tmp_path / "model")
    meta = read_config(path)
    assert meta["model"]["num_joints"] == 14 and meta["model"]["obs_len"] == 15
    assert meta["data"]["dataset"] == "humaneva" and meta["data"]["joint_names"] == list(HUMANEVA_MODEL_JOINT_NAMES)
    assert meta["data"]["fps"] == 60.0
    with torch.no_grad():
        for p in net.parameters():  # make every weight count before comparing with the engine
            p.add_(0.01 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel())))
    from training.prior_net import save_prior

    save_prior(path, net)
    obs = np.stack(seqs)[:, :15].astype(np.float32).reshape(3, 15, 42)
    engine = tcd.engine.Prior.load(path).predict(obs, 60)
    with torch.no_grad():
        ref = load_prior_file(path)[0].rollout(torch.from_numpy(obs), 60).numpy()
    assert engine.shape == (3, 60, 42)
    np.testing.assert_allclose(engine, ref, rtol=1e-4, atol=1e-5)


@needs_humaneva
def test_prior_training_frames_on_the_real_data():
    cfg = PriorConfig.load(CONFIGS / "humaneva_prior.json")
    frames, starts = training_frames(cfg)
    assert frames.shape == (4251, 42)
    assert len(starts) == 3454  # windows of 15 + 15 frames inside a chunk


# ------------------------------------------------------------------------------------------ training


def test_humaneva_train_configs_chain_into_the_cascade():
    short = TrainConfig.load(CONFIGS / "humaneva_short.json")
    long = TrainConfig.load(CONFIGS / "humaneva_long.json")
    for cfg in (short, long):
        assert cfg.dataset == "humaneva" and cfg.model["num_joints"] == 14
        assert cfg.model["cond_fill"] == "prior" and cfg.diffusion["prediction_type"] == "sample"
        assert (cfg.model["num_layers"], cfg.model["channels"], cfg.model["num_heads"]) == (3, 32, 4)
    assert short.obs_len == 15 and long.obs_len == short.obs_len + short.pred_len  # the engine's cascade
    assert long.obs_len + long.pred_len == 75 and long.role == "long" and short.role == "short"
    assert (short.obs_len, short.pred_len) == HUMANEVA_WINDOWS["short"]
    assert (long.obs_len, long.pred_len) == HUMANEVA_WINDOWS["long"]
    with pytest.raises(ValueError, match="dataset"):
        TrainConfig(dataset="amass")


@pytest.mark.slow
def test_a_few_training_steps_on_humaneva_shaped_windows(tmp_path):
    from training.prior_net import random_prior, build_prior_config
    from training.fileformat import save_model_file, data_meta

    prior = random_prior(blocks=2, seed=0, obs_len=15, joints=14)
    prior_path = tmp_path / "prior.safetensors"
    save_model_file(prior_path, prior, build_prior_config(prior, data_meta("humaneva")))
    seqs = {"train": [walking(90, s)[:, 1:] for s in range(3)], "val": [walking(80, 9)[:, 1:]]}
    cfg = TrainConfig(
        role="long",
        dataset="humaneva",
        obs_len=16,
        pred_len=59,
        model={**TINY, **PRIOR_MODEL},
        diffusion={"prediction_type": "sample"},
        prior=str(prior_path),
        batch_size=4,
        epochs=1,
        steps_per_epoch=2,
        val_every=1,
        val_timesteps=2,
        val_max_windows=4,
        train_stride=5,
        val_stride=5,
    )
    res = train(cfg, tmp_path / "run", sequences=seqs, log=lambda *a: None)
    assert np.isfinite(res["best_val"])
    ck = torch.load(tmp_path / "run" / "last.pt", weights_only=False)
    assert ck["data"]["dataset"] == "humaneva" and ck["window"] == {"obs_len": 16, "pred_len": 59, "seq_len": 75}
    out = export_checkpoint(tmp_path / "run" / "best.pt", tmp_path / "model")
    meta = read_config(out)
    assert meta["data"]["joint_names"] == list(HUMANEVA_MODEL_JOINT_NAMES) and meta["model"]["num_joints"] == 14
    # a model of the wrong joint count is refused before any step
    with pytest.raises(ValueError, match="joints"):
        train(
            TrainConfig(**{**cfg.__dict__, "model": {**cfg.model, "num_joints": 22}}),
            tmp_path / "bad",
            sequences=seqs,
            log=lambda *a: None,
        )


def test_action_balance_trains_from_the_data_files_actions(synthetic_file, tmp_path):
    """action_balance reads the actions from the HumanEva-I file (training_actions); given sequences carry none."""
    cfg = TrainConfig(
        role="long",
        dataset="humaneva",
        obs_len=16,
        pred_len=59,
        model=TINY,
        batch_size=4,
        epochs=1,
        steps_per_epoch=2,
        val_every=1,
        val_timesteps=2,
        val_max_windows=4,
        train_stride=5,
        val_stride=5,
        action_balance=1.0,
    )
    res = train(cfg, tmp_path / "run", data=str(synthetic_file), log=lambda *a: None)
    assert np.isfinite(res["best_val"])
    seqs = {"train": [walking(90, s)[:, 1:] for s in range(3)], "val": [walking(80, 9)[:, 1:]]}
    with pytest.raises(ValueError, match="action_balance"):
        train(cfg, tmp_path / "given", sequences=seqs, log=lambda *a: None)


# ------------------------------------------------------------------------------------------ evaluation


def test_evaluate_humaneva_through_the_engine(humaneva_model_dir, synthetic_file, tmp_path):
    out = tmp_path / "he.json"
    assert (
        evaluate.main(
            [
                "--protocol",
                "humaneva",
                "--model",
                str(humaneva_model_dir),
                "--engine",
                "tcd",
                "--samples",
                "4",
                "--steps",
                "2",
                "--sampler",
                "ddim",
                "--data",
                str(synthetic_file),
                "--json",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    r = json.loads(out.read_text())
    n = len(humaneva_test_windows(load_humaneva(synthetic_file, "Validate")))
    assert r["protocol"]["windows"] == r["protocol"]["windows_in_protocol"] == n > 0
    for block in ("model", "prior", "zero_velocity", "neighbours"):
        metrics = {"APD", "ADE", "FDE", "MMADE", "MMFDE", "mean_ADE", "mean_FDE"}  # mean_*: the samples' mean's
        assert set(r[block]) == metrics | {"per_window"}  # each window's values: training.compare pairs them
        assert all(np.isfinite(r[block][k]) and r[block][k] >= 0 for k in metrics)
        assert set(r[block]["per_window"]) == metrics
        for k in metrics:
            assert len(r[block]["per_window"][k]) == n
            assert r[block]["per_window"][k] and np.isclose(np.mean(r[block]["per_window"][k]), r[block][k])
    assert r["model"]["APD"] > 0 and r["prior"]["APD"] == r["zero_velocity"]["APD"] == 0.0
    for block in ("prior", "zero_velocity"):  # one forecast: its mean is itself
        assert np.isclose(r[block]["mean_ADE"], r[block]["ADE"]) and np.isclose(r[block]["mean_FDE"], r[block]["FDE"])
    assert r["stochastic"] == r["model"] and r["sampling"]["samples"] == 4
    assert r["published"]["TCD"] == {"ADE": 0.199, "FDE": 0.215} and r["published"]["HumanMAC"]["ADE"] == 0.209
    # each action's windows (the synthetic file: Walking 130 frames -> 4 windows, Box 105 -> 2, Jog 80 -> 1)
    assert {a: d["windows"] for a, d in r["per_action"].items()} == {"Box": 2, "Jog": 1, "Walking": 4}
    walking = r["model"]["per_window"]["FDE"][:4]  # the file's order: the Walking take first
    assert np.isclose(r["per_action"]["Walking"]["FDE"], np.mean(walking))
    assert np.isclose(sum(d["ADE"] * d["windows"] for d in r["per_action"].values()) / n, r["model"]["ADE"])
    # the prior alone (a directory with nothing else in it) and the default sample count
    only_prior = tmp_path / "prior_only"
    only_prior.mkdir()
    (only_prior / "prior.safetensors").write_bytes((humaneva_model_dir / "prior.safetensors").read_bytes())
    assert (
        evaluate.main(
            [
                "--protocol",
                "humaneva",
                "--prior",
                str(only_prior),
                "--data",
                str(synthetic_file),
                "--json",
                str(out),
                "--quiet",
                "--max-windows",
                "2",
            ]
        )
        == 0
    )
    r2 = json.loads(out.read_text())
    assert r2["protocol"]["windows"] == 2 and r2["method"].startswith("prior")
    assert {a: d["windows"] for a, d in r2["per_action"].items()} == {"Walking": 1, "Jog": 1}


def test_the_nearest_training_futures_baseline(synthetic_file, tmp_path):
    """--baseline neighbours: the futures of the training windows that arrive nearest, joined to the observation.
    An observation that is a training window's own past finds that window first, and its own future unchanged."""
    train = [q for q in training_sequences(synthetic_file).values()]
    windows = np.stack([train[0][5:80], train[2][3:78]]).astype(np.float64)  # (2, 75, 14, 3)
    f = evaluate_stochastic.NeighbourForecaster(evaluate_stochastic.HUMANEVA, 3, synthetic_file)(windows[:, :15])
    assert f.shape == (3, 2, 60, 14, 3)
    np.testing.assert_allclose(f[0], windows[:, 15:], atol=1e-6)
    assert not np.allclose(f[1], windows[:, 15:])  # the next nearest: another
    # every sample starts from the observation: the join's offset is the largest at the first future frame
    step = np.linalg.norm(f[:, :, 0] - windows[None, :, 14], axis=-1).max()
    assert step < 0.2
    out = tmp_path / "nb.json"
    assert (
        evaluate.main(
            [
                "--protocol",
                "humaneva",
                "--baseline",
                "neighbours",
                "--samples",
                "3",
                "--data",
                str(synthetic_file),
                "--json",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
    r = json.loads(out.read_text())
    assert r["method"] == "nearest training futures" and r["stochastic"] == r["neighbours"]
    assert r["neighbours"]["APD"] > 0
    with pytest.raises(SystemExit, match="find itself"):
        evaluate.main(
            [
                "--protocol",
                "humaneva",
                "--baseline",
                "neighbours",
                "--split",
                "Train",
                "--samples",
                "3",
                "--data",
                str(synthetic_file),
                "--quiet",
            ]
        )
    with pytest.raises(SystemExit, match="--samples must be in 1..108"):  # more than there are: an error
        evaluate_stochastic.NeighbourForecaster(evaluate_stochastic.HUMANEVA, 109, synthetic_file)
    with pytest.raises(SystemExit):
        evaluate.main(["--baseline", "neighbours"])  # Human3.6M: not a baseline there


# ------------------------------------------------------------- Human3.6M in a HumanEva-I model's training


def test_h36m_share_is_a_humaneva_option_and_the_weights_say_they_learnt_from_human36m():
    from training.prior_net import prior_data_meta
    from training.fileformat import data_meta

    for make in (
        lambda **kw: PriorConfig(obs_len=15, chunk=15, subjects=(1, 2, 3), **kw),
        lambda **kw: TrainConfig(role="long", obs_len=16, pred_len=59, **kw),
    ):
        make(dataset="humaneva", h36m_share=0.5)
        for bad in (
            {"dataset": "h36m", "h36m_share": 0.5},
            {"dataset": "humaneva", "h36m_share": 1.0},
            {"dataset": "humaneva", "h36m_share": -0.1},
        ):
            with pytest.raises(ValueError, match="h36m_share"):
                make(**bad)
    plain, mixed = data_meta("humaneva"), data_meta("humaneva", h36m_share=0.5)
    assert "Human3.6M" not in plain["training_data"] + plain["licence"]
    assert "Human3.6M S1,S6,S7,S8,S9,S11" in mixed["training_data"] and "0.5 of the windows" in mixed["training_data"]
    assert "Human3.6M" in mixed["licence"]
    prior = prior_data_meta(PriorConfig(obs_len=15, chunk=15, subjects=(1, 2, 3), dataset="humaneva", h36m_share=0.5))
    assert prior["training_data"] == mixed["training_data"] and prior["licence"] == mixed["licence"]


@needs_humaneva
def test_a_prior_starts_from_an_exported_prior_file(tmp_path):
    cfg = PriorConfig(
        obs_len=15, chunk=15, blocks=2, subjects=(1, 2, 3), dataset="humaneva", iterations=1, batch_size=4, seed=3
    )
    first = tmp_path / "first"
    train_prior(cfg, first, data=str(HUMANEVA_FILE), log=lambda *_: None)
    export_prior(first / "last.pt", tmp_path / "exported")
    # a step at learning rate 0 leaves the weights as they were loaded
    cfg2 = PriorConfig(
        **{
            **cfg.to_dict(),
            "subjects": (1, 2, 3),
            "lr": 0.0,
            "lr_final": 0.0,
            "init_from": str(tmp_path / "exported" / "prior.safetensors"),
        }
    )
    train_prior(cfg2, tmp_path / "second", data=str(HUMANEVA_FILE), log=lambda *_: None)
    a = load_prior_checkpoint(first / "last.pt").state_dict()
    b = load_prior_checkpoint(tmp_path / "second" / "last.pt").state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@needs_humaneva
def test_a_stopped_generator_run_resumes_to_the_weights_of_one_that_never_stopped(tmp_path):
    """training.generator_imle --checkpoint: a run stopped after step 3 of 6 and resumed reaches, bit for bit, the
    weights and scores of the same 6 steps in one go (one thread); a checkpoint of another schedule is refused."""
    from training import generator_imle

    base = ["--steps", "6", "--cands", "4", "--targets", "2", "--rotate", "--mirror", "--threads", "1"]
    base += ["--hidden", "32", "--layers", "2", "--data", str(HUMANEVA_FILE)]
    assert generator_imle.main(base + ["--json", str(tmp_path / "a.json"), "--save", str(tmp_path / "a.pt")]) == 0
    ck = ["--checkpoint", str(tmp_path / "last.pt")]
    b = base + ck + ["--json", str(tmp_path / "b.json"), "--save", str(tmp_path / "b.pt")]
    assert generator_imle.main(b + ["--stop-after-steps", "3"]) == 0
    assert not (tmp_path / "b.json").exists() and torch.load(tmp_path / "last.pt")["step"] == 3
    assert generator_imle.main(b) == 0
    a, r = torch.load(tmp_path / "a.pt"), torch.load(tmp_path / "b.pt")
    assert all(torch.equal(a[k], r[k]) for k in a)
    score = lambda p: json.loads(p.read_text())["stochastic"]  # noqa: E731
    assert score(tmp_path / "a.json") == score(tmp_path / "b.json")
    with pytest.raises(SystemExit, match="6-step run, not 8"):
        generator_imle.main([*base[:1], "8", *base[2:], *ck, "--json", str(tmp_path / "c.json")])
