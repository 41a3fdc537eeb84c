"""training.compare: the paired test that gates bundled weights."""

import json

import pytest

from training.compare import compare, main


def result(errors, seed=0, windows=256):
    per_action = {f"a{i}": {"1000": e, "80": e / 10} for i, e in enumerate(errors)}
    return {
        "protocol": {"subject": "S5", "windows_per_action": windows, "data": "x"},
        "seeds": {"sampling": seed},
        "per_action": per_action,
        "mean_of_n": {"per_action": per_action},
    }


def test_a_consistent_drop_beyond_the_margin_is_better_and_noise_is_not():
    old = [100.0, 110.0, 120.0, 130.0, 90.0]
    assert compare(result([e - 3 for e in old]), result(old))["verdict"] == "new is better"
    assert compare(result(old), result([e - 3 for e in old]))["verdict"] == "bundled is better"
    mixed = [e + d for e, d in zip(old, (-6, 5, -6, 5, -1))]  # 0.6 mm lower on average, noisy
    assert compare(result(mixed), result(old))["verdict"] == "within noise"
    small = [e - 0.5 for e in old]  # consistent but below the 1 % margin
    assert compare(result(small), result(old))["verdict"] == "within noise"
    assert compare(result(small), result(old), margin=0.001)["verdict"] == "new is better"


def test_results_of_different_protocols_are_refused(tmp_path):
    with pytest.raises(ValueError, match="same protocol"):
        compare(result([1.0, 2.0], windows=64), result([1.0, 2.0]))
    with pytest.raises(ValueError, match="same seeds"):
        compare(result([1.0, 2.0], seed=1), result([1.0, 2.0]))
    with pytest.raises(ValueError, match="best_of_n"):
        compare(result([1.0, 2.0]), result([1.0, 2.0]), key="best_of_n")


def test_exit_status_gates(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(result([90.0, 95.0, 99.0])))
    b.write_text(json.dumps(result([100.0, 104.0, 110.0])))
    assert main([str(a), str(b)]) == 0
    assert main([str(b), str(a)]) == 1


def humaneva_result(ade, seed=0):
    scores = {"ADE": float(sum(ade) / len(ade)), "per_window": {k: list(ade) for k in ("ADE", "FDE", "MMADE", "MMFDE")}}
    return {"protocol": {"dataset": "humaneva-i", "windows": len(ade)}, "seeds": {"sampling": seed}, "model": scores}


def test_humaneva_results_are_paired_over_windows():
    rng = __import__("numpy").random.default_rng(0)
    old = list(0.3 + 0.1 * rng.random(40))
    res = compare(humaneva_result([e - 0.01 for e in old]), humaneva_result(old))
    assert res["verdict"] == "new is better" and res["windows"] == 40 and res["key"] == "average"
    assert (
        compare(humaneva_result(old), humaneva_result([e - 0.01 for e in old]), key="FDE")["verdict"]
        == "bundled is better"
    )
    noisy = [e + d for e, d in zip(old, rng.normal(0, 0.05, 40))]
    assert compare(humaneva_result(noisy), humaneva_result(old))["verdict"] == "within noise"
    with pytest.raises(ValueError, match="one of"):
        compare(humaneva_result(old), humaneva_result(old), key="best_of_n")
    without = humaneva_result(old)
    del without["model"]["per_window"]
    with pytest.raises(ValueError, match="per-window"):
        compare(without, humaneva_result(old))


def test_bundled_key_pairs_a_tcd_run_with_a_prior_run():
    """--bundled-key: a TCD run's mean_of_n against a prior run's average (a prior run has no mean_of_n)."""
    tcd_run = result([100.0, 110.0, 120.0])
    tcd_run["mean_of_n"] = {"per_action": {f"a{i}": {"1000": e} for i, e in enumerate([95.0, 104.0, 116.0])}}
    prior_run = result([100.0, 110.0, 120.0])
    del prior_run["mean_of_n"]
    with pytest.raises(ValueError, match="mean_of_n"):
        compare(tcd_run, prior_run, key="mean_of_n")
    r = compare(tcd_run, prior_run, key="mean_of_n", old_key="average")
    assert r["verdict"] == "new is better" and r["bundled_key"] == "average" and r["mean_difference"] == -5.0
    assert compare(tcd_run, prior_run)["verdict"] == "within noise"  # average against average: equal


def repair_result(tcd_mm, spline_mm, seed=0):
    """A benches/repair_quality.py --json result: two patterns, per-window ADE of the model and the spline."""
    patterns = [["random_leg_arm", 0.4], ["random_joints", [0.1, 0.4]]]
    row = {
        "tcd": {"ade_mm": 0.0, "per_window_mm": list(tcd_mm)},
        "spline": {"ade_mm": 0.0, "per_window_mm": list(spline_mm)},
    }
    return {
        "protocol": {"task": "repair", "windows": len(tcd_mm), "patterns": patterns},
        "seeds": {"windows_masks_sampling": seed},
        "results": [row, {**row, "tcd": {"per_window_mm": [9.0] * len(tcd_mm)}}],
    }


def test_repair_results_are_paired_over_windows_per_pattern_and_method():
    rng = __import__("numpy").random.default_rng(1)
    spline = list(4.0 + rng.random(30))
    better = [e - 0.3 for e in spline]
    new, old = repair_result(better, spline), repair_result(spline, spline)
    r = compare(new, old, key="random_leg_arm")
    assert r["verdict"] == "new is better" and r["windows"] == 30 and abs(r["mean_difference"] + 0.3) < 1e-9
    assert compare(new, old, key="random_joints")["verdict"] == "within noise"  # 9.0 on both sides
    # one file, the model against the spline it is conditioned on
    assert compare(new, new, key="random_leg_arm", old_key="random_leg_arm:spline")["verdict"] == "new is better"
    assert compare(new, new, key="random_joints", old_key="random_joints:spline")["verdict"] == "bundled is better"
    with pytest.raises(ValueError, match="PATTERN one of"):
        compare(new, old)  # the default key names no pattern
    with pytest.raises(ValueError, match="method 'savgol'"):
        compare(new, old, key="random_leg_arm:savgol")
    with pytest.raises(ValueError, match="same seeds"):
        compare(new, repair_result(spline, spline, seed=1), key="random_leg_arm")
    unpaired = {k: v for k, v in old.items() if k != "protocol"}  # a repair result from before the records
    with pytest.raises(ValueError, match="BUNDLED has no 'protocol'"):
        compare(new, unpaired, key="random_leg_arm")
