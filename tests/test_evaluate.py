import json

import numpy as np
import pytest

from conftest import DATA, H36M_DIR, import_torch, needs_data, needs_h36m

torch = import_torch("the evaluation (training/evaluate.py)")

from training import evaluate  # noqa: E402
from training.data.h36m import find_indices_256  # noqa: E402
from training.export import random_init_dir  # noqa: E402


def test_find_indices_256_draws_alternate_from_one_rng():
    s1, s2 = find_indices_256(1000, 3000, 75, 50)
    assert len(s1) == len(s2) == 128
    rng = np.random.RandomState(1234567890)
    draws = [rng.randint(16, hi) for _ in range(128) for hi in (1000 - 150, 3000 - 150)]
    assert list(s1) == draws[0::2] and list(s2) == draws[1::2]
    # input_n shifts the window start so that the prediction always begins at idx + 50
    t1, _ = find_indices_256(1000, 3000, 35, 10)
    assert np.array_equal(t1, s1 + 40)


def test_zero_velocity_carries_the_last_visible_value():
    obs = np.arange(2 * 3 * 1 * 3, dtype=float).reshape(2, 3, 1, 3)
    jm = np.ones((2, 3, 1))
    jm[0, 2, 0] = 0  # last frame hidden in window 0
    out = evaluate.zero_velocity(obs, jm, horizon=4)
    assert out.shape == (2, 4, 1, 3)
    assert np.array_equal(out[0, 0, 0], obs[0, 1, 0]) and np.array_equal(out[1, 3, 0], obs[1, 2, 0])


@needs_h36m
def test_zero_velocity_reproduces_the_protocol_numbers(tmp_path):
    out = tmp_path / "zv.json"
    assert evaluate.main(["--baseline", "zero-velocity", "--data", str(H36M_DIR), "--json", str(out), "--quiet"]) == 0
    res = json.loads(out.read_text())
    expected = {"80": 24.3, "320": 77.4, "560": 108.8, "720": 123.2, "880": 133.7, "1000": 139.1}
    for ms, mm in expected.items():
        assert res["average"][ms] == pytest.approx(mm, abs=0.3), ms
    assert len(res["per_frame"]) == 25 and len(res["per_action"]) == 13
    assert res["protocol"]["windows_per_action"] == 256 and res["seeds"]["windows"] == 1234567890


@needs_h36m
@pytest.mark.parametrize("engine", ["torch", "tcd"])
def test_model_evaluation_runs_end_to_end(tmp_path, engine):
    d = random_init_dir(tmp_path / "m", preset="tiny")
    out = tmp_path / "m.json"
    assert (
        evaluate.main(
            [
                "--model",
                str(d),
                "--data",
                str(H36M_DIR),
                "--json",
                str(out),
                "--windows-per-action",
                "1",
                "--samples",
                "2",
                "--steps",
                "2",
                "--sampler",
                "ddim",
                "--mask",
                "random_leg_arm",
                "--engine",
                engine,
                "--quiet",
            ]
        )
        == 0
    )
    res = json.loads(out.read_text())
    assert set(res["average"]) == {"80", "160", "320", "400", "560", "720", "880", "1000"}
    assert res["best_of_n"]["label"].startswith("oracle") and res["mean_of_n"]["label"].startswith("mean")
    assert res["repair"]["occluded_entries"] > 0 and np.isfinite(res["repair"]["ade_mm"])
    assert "zero_velocity_on_repaired" in res and res["select"] == "best"
    assert res["sampling"]["engine"] == engine
    assert res["sampling"]["tempo"] is None  # the tiny model's directory sets none


@needs_h36m
def test_tempo_runs_through_the_engine_and_is_recorded(tmp_path):
    d = random_init_dir(tmp_path / "m", preset="tiny")
    args = [
        "--model",
        str(d),
        "--data",
        str(H36M_DIR),
        "--windows-per-action",
        "1",
        "--samples",
        "3",
        "--steps",
        "1",
        "--sampler",
        "ddim",
        "--quiet",
    ]
    out = tmp_path / "t.json"
    assert evaluate.main(args + ["--engine", "tcd", "--tempo", "0.8", "1.25", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["sampling"]["tempo"] == [0.8, 1.25]
    with pytest.raises(SystemExit) as e:  # the PyTorch reference has no tempo sampling
        evaluate.main(args + ["--engine", "torch", "--tempo", "0.8", "1.25"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:  # two forecast modes (tcd.Tempo, tcd.Mixture): refused
        evaluate.main(args + ["--engine", "tcd", "--tempo", "0.8", "1.25", "--generator-share", "0"])
    assert e.value.code == 2


@needs_h36m
def test_txt_tree_source_equals_the_npz(tmp_path):
    from training.data.h36m import H36MSource

    npz = H36MSource(H36M_DIR)
    raw = npz.raw(5, "walking", 1)[:40]
    (tmp_path / "dataset" / "S5").mkdir(parents=True)
    np.savetxt(tmp_path / "dataset" / "S5" / "walking_1.txt", raw, delimiter=",", fmt="%.9g")
    txt = H36MSource(tmp_path)
    assert txt.keys == {"S5/walking_1"} and txt.has(5, "walking", 1) and not txt.has(5, "walking", 2)
    assert np.allclose(txt.raw(5, "walking", 1), raw, rtol=1e-6)
    with pytest.raises(FileNotFoundError, match="no Human3.6M"):
        H36MSource(tmp_path / "dataset" / "S5" / "nothing")


@needs_data("humaneva/humaneva_i_15j_60hz.npz")
def test_humaneva_zero_velocity_protocol(tmp_path):
    out = tmp_path / "he.json"
    assert (
        evaluate.main(
            [
                "--protocol",
                "humaneva",
                "--baseline",
                "zero-velocity",
                "--json",
                str(out),
                "--data",
                str(DATA / "humaneva"),
                "--quiet",
            ]
        )
        == 0
    )
    res = json.loads(out.read_text())
    assert res["protocol"]["windows"] == 188
    s = res["stochastic"]
    assert s["APD"] == 0.0  # one deterministic sample has no diversity
    assert 0 < s["ADE"] < s["FDE"] and 0 < s["MMADE"] < s["MMFDE"]
    # the same windows' rule on the training split: another set, named in the protocol block
    out = tmp_path / "he_train.json"
    assert (
        evaluate.main(
            [
                "--protocol",
                "humaneva",
                "--baseline",
                "zero-velocity",
                "--json",
                str(out),
                "--split",
                "Train",
                "--data",
                str(DATA / "humaneva"),
                "--quiet",
            ]
        )
        == 0
    )
    train = json.loads(out.read_text())
    assert train["protocol"]["split"] == "Train" and res["protocol"]["split"] == "Validate"
    assert train["protocol"]["windows"] != 188 and train["stochastic"]["ADE"] != s["ADE"]


@needs_h36m
def test_prior_checkpoint_evaluation(tmp_path):
    """--prior with a training checkpoint: an untrained prior is Zero-Velocity (its output layer starts at
    ~0), so on clean windows its errors are Zero-Velocity's; under an occlusion the missing entries are
    filled first (spline) and every horizon has a finite error."""
    import torch
    from training.prior_net import PriorConfig, PriorNet

    cfg = PriorConfig(blocks=2)
    torch.manual_seed(0)
    torch.save({"config": cfg.to_dict(), "model": PriorNet(cfg).state_dict()}, tmp_path / "last.pt")
    out = tmp_path / "clean.json"
    evaluate.main(
        [
            "--prior",
            str(tmp_path / "last.pt"),
            "--windows-per-action",
            "2",
            "--quiet",
            "--data",
            str(H36M_DIR),
            "--json",
            str(out),
        ]
    )
    r = json.loads(out.read_text())
    assert r["method"].startswith("prior") and r["fill"] == "auto"
    for ms, zv in r["zero_velocity"]["average"].items():
        assert r["average"][ms] == pytest.approx(zv, abs=1e-3)
    out = tmp_path / "occluded.json"
    evaluate.main(
        [
            "--prior",
            str(tmp_path / "last.pt"),
            "--windows-per-action",
            "2",
            "--quiet",
            "--fill",
            "spline",
            "--mask",
            "consecutive_frames",
            "--data",
            str(H36M_DIR),
            "--json",
            str(out),
        ]
    )
    r = json.loads(out.read_text())
    assert r["protocol"]["mask"] == "consecutive_frames" and r["fill"] == "spline"
    assert all(np.isfinite(v) for v in r["average"].values()) and len(r["average"]) == 8
