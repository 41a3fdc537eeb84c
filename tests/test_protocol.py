"""training.protocol: the whole evaluation in one resumable process, on the CPU with a tiny model and a few
windows."""

import json

import numpy as np
import pytest

from conftest import H36M_DIR, import_torch, needs_h36m

torch = import_torch("the evaluation protocol (training/protocol.py)")

import tcd  # noqa: E402
from fixtures_util import make_model_dir  # noqa: E402
from training import evaluate as E  # noqa: E402
from training import protocol  # noqa: E402
from training.data.h36m import H36M  # noqa: E402
from training.export import load_model_dir  # noqa: E402

FEW = ["--windows-per-action", "1", "--samples", "2", "--steps", "2", "--quiet", "--threads", "1"]


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    """Tiny short, long and repair models (the repair model conditions on the spline fill)."""
    return make_model_dir(tmp_path_factory.mktemp("protocol_model"), "tiny", seed=3, repair={"cond_fill": "spline"})


def run(model_dir, out, *extra):
    return protocol.main(["--model", str(model_dir), "--out", str(out), "--data", str(H36M_DIR), *FEW, *extra])


def units(out):
    return sorted(str(p.relative_to(out)) for p in out.glob("*_*/*.json"))


@needs_h36m
def test_every_unit_written_resumed_and_summarized(model_dir, tmp_path, capsys):
    out = tmp_path / "res"
    assert run(model_dir, out, "--patterns", "none,random_leg_arm") == 0
    actions = H36M(H36M_DIR).test_actions()
    assert units(out) == sorted(
        f"{part}/{a}.json"
        for part in ("forecast_none", "forecast_random_leg_arm", "repair_random_leg_arm")
        for a in actions
    )
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary["forecast"]) == ["none", "random_leg_arm"] and list(summary["repair"]) == ["random_leg_arm"]
    assert summary["incomplete"] == [] and summary["actions"] == len(actions) == 13
    f = summary["forecast"]["none"]
    assert f["actions"] == 13 and f["windows_per_action"] == 1 and f["samples"] == 2 and f["steps"] == 2
    assert f["mean_of_n_ratio"] == pytest.approx(f["mean_of_n_mm"] / f["zero_velocity_mm"])
    unit = json.loads((out / "forecast_none" / f"{actions[0]}.json").read_text())
    assert unit["protocol"]["actions"] == [actions[0]]
    assert unit["settings"]["weights_sha256"].keys() == {"short", "long", "repair"}
    assert "| none |" in capsys.readouterr().out

    # a second call keeps every unit and computes nothing
    stamps = {u: (out / u).stat().st_mtime_ns for u in units(out)}
    assert run(model_dir, out, "--patterns", "none,random_leg_arm") == 0
    assert stamps == {u: (out / u).stat().st_mtime_ns for u in units(out)}
    assert "13 of 13 actions done before" in capsys.readouterr().err
    # units made with other settings are never mixed in
    with pytest.raises(SystemExit, match="other settings"):
        run(model_dir, out, "--patterns", "none", "--seed", "1")


@needs_h36m
def test_units_pool_to_the_whole_protocol_run(model_dir, tmp_path):
    """Action by action (what a resumed evaluation does) gives the numbers of training.evaluate's one run
    over every action: same seeds per action, the same mean over actions."""
    out = tmp_path / "res"
    run(model_dir, out, "--patterns", "random_leg_arm", "--forward", "reference", "--batch-size", "16")
    whole = E.main(
        [
            "--model",
            str(model_dir),
            "--data",
            str(H36M_DIR),
            "--mask",
            "random_leg_arm",
            "--windows-per-action",
            "1",
            "--samples",
            "2",
            "--steps",
            "2",
            "--quiet",
            "--threads",
            "1",
            "--json",
            str(tmp_path / "whole.json"),
        ]
    )
    assert whole == 0
    ref = json.loads((tmp_path / "whole.json").read_text())
    got = json.loads((out / "summary.json").read_text())["forecast"]["random_leg_arm"]
    for block in ("best_of_n", "mean_of_n", "zero_velocity"):
        for h, v in ref[block]["average"].items():
            assert got[f"{block}_all_horizons"][h] == pytest.approx(v, rel=1e-9)
    assert got["cascade_repair_ade_mm"] == pytest.approx(ref["repair"]["ade_mm"], rel=1e-9)


@needs_h36m
def test_budget_stops_before_a_unit_and_says_what_is_left(model_dir, tmp_path, capsys):
    out = tmp_path / "res"
    assert run(model_dir, out, "--patterns", "none", "--max-minutes", "0") == 0
    assert units(out) == []
    captured = capsys.readouterr()
    assert "run again to continue" in captured.err
    assert "not done yet: forecast_none (0 of 13 actions)" in captured.out


@needs_h36m
def test_channels_last_forward_gives_the_reference_numbers(model_dir, tmp_path):
    """The fast forward the protocol runs by default against the reference forward: same errors."""
    a, b = tmp_path / "fast", tmp_path / "ref"
    run(model_dir, a, "--patterns", "random_leg_arm")
    run(model_dir, b, "--patterns", "random_leg_arm", "--forward", "reference")
    x, y = (json.loads((d / "summary.json").read_text()) for d in (a, b))
    fx, fy = x["forecast"]["random_leg_arm"], y["forecast"]["random_leg_arm"]
    for block in ("best_of_n_all_horizons", "mean_of_n_all_horizons", "zero_velocity_all_horizons"):
        for h in fx[block]:
            assert fx[block][h] == pytest.approx(fy[block][h], rel=1e-5)
    for k in ("tcd", "linear", "spline"):
        assert x["repair"]["random_leg_arm"][k] == pytest.approx(y["repair"]["random_leg_arm"][k], rel=1e-5)
    assert protocol.compare(a, b)["better"] == {"forecast": None, "repair": None}  # equal within the margin


@needs_h36m
def test_repair_baselines_are_the_engine_interpolations(model_dir, tmp_path):
    """The linear and spline ADEs of a repair part, recomputed here with the engine's fills
    (``tcd.interpolate``) on the same corrupted windows."""
    out = tmp_path / "res"
    run(model_dir, out, "--patterns", "structured_leg")
    got = json.loads((out / "summary.json").read_text())["repair"]["structured_leg"]
    data = H36M(H36M_DIR)
    for method in ("linear", "spline"):
        total, count = 0.0, 0
        for ai, action in enumerate(data.test_actions()):
            _, clean, obs, jmask = E.protocol_windows(data, action, ai, 1, "structured_leg", 0)
            filled = tcd.interpolate(np.where(jmask[..., None] > 0.5, obs, np.nan), method=method)
            hidden = jmask < 0.5
            total += float(np.linalg.norm(filled - clean, axis=-1)[hidden].sum())
            count += int(hidden.sum())
        assert count == got["hidden_entries"] > 0
        assert got[method] == pytest.approx(1000.0 * total / count, rel=1e-4)


def test_compare_is_a_paired_test_over_actions(tmp_path):
    """Scores: the mean over patterns of mean-of-n / Zero-Velocity at 1 s, and of repair / spline, on the
    patterns both sets evaluated on every action; one set is better only by more than the margin and more
    than two standard errors of the per-action differences."""
    actions = [f"action{i:02d}" for i in range(13)]

    def results(d, ratios, repair, forecast_actions=13):
        for i, act in enumerate(actions):
            if i < forecast_actions:
                (d / "forecast_none").mkdir(parents=True, exist_ok=True)
                (d / "forecast_none" / f"{act}.json").write_text(
                    json.dumps(
                        {
                            "protocol": {"windows_per_action": 64, "actions": [act]},
                            "sampling": {"samples": 5, "steps": 50},
                            "zero_velocity": {"per_action": {act: {"1000": 100.0}}},
                            "best_of_n": {"per_action": {act: {"1000": 70.0}}},
                            "mean_of_n": {"per_action": {act: {"1000": 100.0 * ratios[i]}}},
                        }
                    )
                )
            (d / "repair_noisy_25").mkdir(parents=True, exist_ok=True)
            (d / "repair_noisy_25" / f"{act}.json").write_text(
                json.dumps(
                    {
                        "pattern": "noisy_25",
                        "action": act,
                        "hidden_entries": 10,
                        "sum_mm": {"tcd": 20.0 * repair[i], "linear": 40.0, "spline": 20.0},
                    }
                )
            )
        (d / "summary.json").write_text(json.dumps(protocol.summarize(d, actions)))
        return d

    rng = np.random.default_rng(0)
    noisy = lambda level, spread: level + spread * rng.standard_normal(13)  # noqa: E731
    a = results(tmp_path / "a", noisy(0.80, 0.02), np.full(13, 0.5))
    b = results(tmp_path / "b", noisy(0.805, 0.02), np.full(13, 1.5))
    cmp = protocol.compare(a, b)
    assert cmp["a"]["repair"] == pytest.approx(0.5) and cmp["b"]["repair"] == pytest.approx(1.5)
    assert cmp["paired"]["forecast"]["pairs"] == 13 and cmp["paired"]["repair"]["standard_error"] == 0.0
    assert cmp["better"] == {"forecast": None, "repair": str(a)}
    assert protocol.compare(a, b, margin=0.0)["better"]["forecast"] is None  # within sampling noise
    # the same 1 % lead on every action is no noise; still within a 5 % margin
    c = results(tmp_path / "c", np.full(13, 0.80), np.full(13, 1.0))
    d = results(tmp_path / "d", np.full(13, 0.808), np.full(13, 1.0))
    assert protocol.compare(c, d, margin=0.001)["better"] == {"forecast": str(c), "repair": None}
    assert protocol.compare(c, d, margin=0.05)["better"]["forecast"] is None
    # a pattern one set has not finished is left out of both
    e = results(tmp_path / "e", np.full(13, 0.5), np.full(13, 1.0), forecast_actions=7)
    assert (
        protocol.compare(c, e)["a"]["forecast_patterns"] == [] and protocol.compare(c, e)["better"]["forecast"] is None
    )


def test_bf16_autocast_forward_stays_close_and_float32():
    models = load_model_dir(tcd.default_model_dir())
    model, _, _ = models["long"]
    fast = protocol.fast_models(
        {"long": models["long"]}, forward="channels_last", precision="bf16", compile_=False, device="cpu"
    )["long"][0]
    g = torch.Generator().manual_seed(0)
    noisy, observed = torch.randn(2, 66, 75, generator=g), 0.3 * torch.randn(2, 66, 75, generator=g)
    mask = (torch.rand(2, 66, 75, generator=g) < 0.5).float()
    with torch.no_grad():
        want, got = model(noisy, observed, mask, 20), fast(noisy, observed, mask, 20)
    assert got.dtype == torch.float32
    rel = float((got - want).norm() / want.norm())
    assert 0 < rel < 3e-2  # bf16 operands: ~1e-2, never the fp32 result itself
