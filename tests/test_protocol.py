"""training.protocol: the whole evaluation in one resumable process (what a GPU period runs), on the CPU
with a tiny model and a few windows."""
import json

import numpy as np
import pytest
import torch

import tcd
from conftest import H36M_DIR, needs_h36m
from fixtures_util import make_model_dir
from training import evaluate as E
from training import protocol
from training.data.h36m import H36M
from training.export import load_model_dir

FEW = ["--windows-per-action", "1", "--samples", "2", "--steps", "2", "--quiet", "--threads", "1"]


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    """Tiny short, long and repair models (the repair model conditions on the spline fill)."""
    return make_model_dir(tmp_path_factory.mktemp("protocol_model"), "tiny", seed=3,
                          repair={"cond_fill": "spline"})


def run(model_dir, out, *extra):
    return protocol.main(["--model", str(model_dir), "--out", str(out), "--data", str(H36M_DIR), *FEW, *extra])


@needs_h36m
def test_every_part_written_resumed_and_summarized(model_dir, tmp_path, capsys):
    out = tmp_path / "res"
    assert run(model_dir, out, "--patterns", "none,random_leg_arm") == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["forecast_none.json", "forecast_random_leg_arm.json", "repair_random_leg_arm.json",
                     "summary.json"]
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary["forecast"]) == ["none", "random_leg_arm"] and list(summary["repair"]) == ["random_leg_arm"]
    f = summary["forecast"]["none"]
    assert f["mean_of_n_ratio"] == pytest.approx(f["mean_of_n_mm"] / f["zero_velocity_mm"])
    assert f["windows_per_action"] == 1 and f["samples"] == 2 and f["steps"] == 2
    part = json.loads((out / "forecast_none.json").read_text())
    assert part["settings"]["weights_sha256"].keys() == {"short", "long", "repair"}
    assert "| none |" in capsys.readouterr().out

    # a second call keeps every part and computes nothing
    stamps = {p.name: p.stat().st_mtime_ns for p in out.glob("forecast_*.json")}
    assert run(model_dir, out, "--patterns", "none,random_leg_arm") == 0
    assert stamps == {p.name: p.stat().st_mtime_ns for p in out.glob("forecast_*.json")}
    assert "done before" in capsys.readouterr().err
    # parts made with other settings are never mixed in
    with pytest.raises(SystemExit, match="other settings"):
        run(model_dir, out, "--patterns", "none", "--seed", "1")


@needs_h36m
def test_budget_stops_before_a_part_and_says_what_is_left(model_dir, tmp_path, capsys):
    out = tmp_path / "res"
    assert run(model_dir, out, "--patterns", "none", "--max-minutes", "0") == 0
    assert not (out / "forecast_none.json").exists()
    captured = capsys.readouterr()
    assert "run again to continue" in captured.err and "not done yet: forecast_none" in captured.out


@needs_h36m
def test_channels_last_forward_gives_the_reference_numbers(model_dir, tmp_path):
    """The fast forward the protocol runs by default against the reference forward: same errors."""
    a, b = tmp_path / "fast", tmp_path / "ref"
    run(model_dir, a, "--patterns", "random_leg_arm")
    run(model_dir, b, "--patterns", "random_leg_arm", "--forward", "reference")
    for name in ("forecast_random_leg_arm.json", "repair_random_leg_arm.json"):
        x, y = (json.loads((d / name).read_text()) for d in (a, b))
        if "per_frame" in x:
            np.testing.assert_allclose(x["per_frame"], y["per_frame"], rtol=1e-5)
            np.testing.assert_allclose(x["mean_of_n"]["per_frame"], y["mean_of_n"]["per_frame"], rtol=1e-5)
        else:
            for k in ("tcd", "linear", "spline"):
                assert x["ade_mm"][k] == pytest.approx(y["ade_mm"][k], rel=1e-5)
    cmp = protocol.compare(a, b)
    assert cmp["better"] == {"forecast": None, "repair": None}       # equal within the margin


@needs_h36m
def test_repair_baselines_are_the_engine_interpolations(model_dir, tmp_path):
    """The linear and spline ADEs of a repair part, recomputed here with the engine's fills
    (``tcd.interpolate``) on the same corrupted windows."""
    out = tmp_path / "res"
    run(model_dir, out, "--patterns", "structured_leg")
    part = json.loads((out / "repair_structured_leg.json").read_text())
    data = H36M(H36M_DIR)
    for method in ("linear", "spline"):
        total, count = 0.0, 0
        for ai, action in enumerate(data.test_actions()):
            _, clean, obs, jmask = E.protocol_windows(data, action, ai, 1, "structured_leg", 0)
            filled = tcd.interpolate(np.where(jmask[..., None] > 0.5, obs, np.nan), method=method)
            hidden = jmask < 0.5
            total += float(np.linalg.norm(filled - clean, axis=-1)[hidden].sum())
            count += int(hidden.sum())
        assert count == part["hidden_entries"] > 0
        assert part["ade_mm"][method] == pytest.approx(1000.0 * total / count, rel=1e-4)


def test_compare_needs_a_margin_to_call_one_better(tmp_path):
    """Scores: the mean over patterns of mean-of-n / Zero-Velocity at 1 s, and of repair / spline."""
    def results(d, ratio, rep):
        d.mkdir()
        (d / "forecast_none.json").write_text(json.dumps({
            "protocol": {"mask": "none", "windows_per_action": 256}, "sampling": {"samples": 5, "steps": 50},
            "zero_velocity": {"average": {"1000": 100.0}}, "best_of_n": {"average": {"1000": 70.0}},
            "mean_of_n": {"average": {"1000": 100.0 * ratio}}}))
        (d / "repair_noisy_25.json").write_text(json.dumps({
            "pattern": "noisy_25", "ade_mm": {"tcd": rep, "linear": 4.0, "spline": 2.0}}))
        return d
    a = results(tmp_path / "a", 0.80, 1.0)
    b = results(tmp_path / "b", 0.805, 3.0)
    cmp = protocol.compare(a, b)
    assert cmp["a"]["forecast"] == pytest.approx(0.80) and cmp["b"]["repair"] == pytest.approx(1.5)
    assert cmp["better"] == {"forecast": None, "repair": str(a)}        # 0.6 % apart is within the 1 % margin
    assert protocol.compare(a, b, margin=0.001)["better"]["forecast"] == str(a)


def test_bf16_autocast_forward_stays_close_and_float32():
    models = load_model_dir(tcd.default_model_dir())
    model, _, _ = models["long"]
    fast = protocol.fast_models({"long": models["long"]}, forward="channels_last", precision="bf16",
                                compile_=False, device="cpu")["long"][0]
    g = torch.Generator().manual_seed(0)
    noisy, observed = torch.randn(2, 66, 75, generator=g), 0.3 * torch.randn(2, 66, 75, generator=g)
    mask = (torch.rand(2, 66, 75, generator=g) < 0.5).float()
    with torch.no_grad():
        want, got = model(noisy, observed, mask, 20), fast(noisy, observed, mask, 20)
    assert got.dtype == torch.float32
    rel = float((got - want).norm() / want.norm())
    assert 0 < rel < 3e-2      # bf16 operands: ~1e-2, never the fp32 result itself


@needs_h36m
def test_gpu_period_eval_call_dry_run_on_the_cpu(model_dir, tmp_path):
    """`gpu_period.sh eval` as a GPU period runs it (its CPU dry run): the carried S5 subset, results under
    $OUT/protocol/NAME, and the next call resumes from the parts carried back in gpu_carry/protocol/."""
    import os
    import shutil
    import subprocess
    from pathlib import Path
    from training import gpu_carry
    root = Path(__file__).resolve().parents[1]
    carry = tmp_path / "carry"
    assert gpu_carry.write_eval_subset(H36M_DIR, carry / "h36m" / "h36m_expmap_50fps.npz") > 0
    shutil.copytree(model_dir, carry / "candidate")
    env = dict(os.environ, GPU_DEVICE="cpu", GPU_CARRY=str(carry), OUT=str(tmp_path / "out1"),
               PROTOCOL_ARGS="--windows-per-action 1 --samples 2 --steps 2 --patterns none,noisy_25 --quiet")

    def call(out):
        env["OUT"] = str(out)
        r = subprocess.run(["bash", "training/gpu_period.sh", "eval", "5"], cwd=root, env=env,
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr + r.stdout
        return r.stdout

    first = call(tmp_path / "out1")
    got = tmp_path / "out1" / "protocol" / "candidate"
    assert {p.name for p in got.glob("*_*.json")} == {"forecast_none.json", "forecast_noisy_25.json",
                                                     "repair_noisy_25.json"}
    assert "| noisy_25 |" in first
    # what came back is carried into the next call, which computes nothing again
    shutil.copytree(tmp_path / "out1" / "protocol", carry / "protocol")
    second = call(tmp_path / "out2")
    assert "done before" in second and json.loads((tmp_path / "out2" / "protocol" / "candidate" / "summary.json")
                                               .read_text()) == json.loads((got / "summary.json").read_text())
