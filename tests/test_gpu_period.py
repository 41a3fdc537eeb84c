"""training/gpu_period.sh, each mode as a GPU period calls it, dry-run on the CPU at the tiny size: a wrong
path or a shell mistake found here costs no GPU minute. (The eval mode's dry run is in test_protocol.py.)"""
import json
import subprocess
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pytest

from conftest import H36M_DIR, gpu_machine_env, needs_h36m
from test_train import synthetic_motion, tiny_cfg
from training.export import load_model_file

ROOT = Path(__file__).resolve().parents[1]


def period(mode_args, tmp_path, **env):
    out = tmp_path / "out"
    e = gpu_machine_env(tmp_path, OUT=str(out), GPU_RUNS=str(tmp_path / "runs"))
    e.update(env)
    r = subprocess.run(["bash", "training/gpu_period.sh", *mode_args], cwd=ROOT, env=e, capture_output=True, text=True)
    return r, out


@pytest.fixture
def carry(tmp_path):
    """A carry folder with a (synthetic) training cache, as training.gpu_carry lays it out."""
    d = tmp_path / "carry"
    d.mkdir()
    seqs = {"train": synthetic_motion(4, seed=0), "val": synthetic_motion(2, seed=1)}
    np.savez(d / "h36m_model_cache.npz",
             **{f"{split}/{i:02d}": s.astype(np.float16) for split, ss in seqs.items() for i, s in enumerate(ss)})
    return d


@pytest.mark.slow
def test_role_call_trains_and_exports_within_the_call(carry, tmp_path):
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps(asdict(tiny_cfg(role="long", batches="device", ema_decay=0.9, steps_per_epoch=5)),
                              indent=1))
    r, out = period(["long", "0.05"], tmp_path, GPU_CARRY=str(carry), GPU_CONFIG=str(cfg), CALL_MINUTES="3")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    _, _, meta = load_model_file(out / "export" / "long.safetensors")
    assert meta["training"]["weights"] == "ema"
    log = (out / "long.log").read_text()
    assert (out / "long" / "best.pt").is_file() and "probe:" in log and "warm start" not in log
    # the next period: the weights carried in init/ start the run (a fresh run folder, as on a new machine)
    (carry / "init").mkdir()
    (out / "export" / "long.safetensors").rename(carry / "init" / "long.safetensors")
    r, out = period(["long", "0.05"], tmp_path, GPU_CARRY=str(carry), GPU_CONFIG=str(cfg), CALL_MINUTES="3",
                    GPU_RUNS=str(tmp_path / "runs2"))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert f"warm start from exported weights {carry / 'init' / 'long.safetensors'}" in (out / "long.log").read_text()


def test_call_minutes_too_short_fails_before_training(carry, tmp_path):
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps(asdict(tiny_cfg(role="short", batches="device"))))
    r, out = period(["short", "1"], tmp_path, GPU_CARRY=str(carry), GPU_CONFIG=str(cfg), CALL_MINUTES="1")
    assert r.returncode != 0 and "no time left to train" in r.stdout + r.stderr
    assert not (out / "export").exists()


def test_bench_call_writes_the_throughput_json(tmp_path):
    r, out = period(["bench", "1"], tmp_path, BENCH_ARGS="--preset tiny --batch 4 --steps 1 --reps 1 --warmup 1 "
                                                        "--roles repair --impls channels_last --modes eager")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    res = json.loads((out / "train_throughput.json").read_text())
    assert [(x["role"], x["impl"], x["mode"]) for x in res["results"] if "windows_per_s" in x] == [
        ("repair", "channels_last", "eager")]


def test_unknown_mode_prints_the_usage(tmp_path):
    r, _ = period(["train"], tmp_path)
    assert r.returncode == 2 and "usage: bash training/gpu_period.sh" in r.stderr and "eval MINUTES" in r.stderr


@needs_h36m
def test_gpu_carry_prepares_the_folder(tmp_path, capsys):
    """training.gpu_carry: the training cache and the S5 subset, full-size weights only as warm starts, the
    candidate and the returned protocol units, and the folder's size against the carry limit."""
    from training import gpu_carry
    from training.data.h36m import H36MSource
    from training.export import random_init_dir
    weights = random_init_dir(tmp_path / "weights", "full", seed=2)
    random_init_dir(tmp_path / "small", "tiny", seed=2, repair={}).joinpath("repair.safetensors").rename(
        weights / "repair.safetensors")                                   # a role that is not full size
    returned = tmp_path / "returned" / "protocol" / "candidate" / "forecast_none"
    returned.mkdir(parents=True)
    (returned / "walking.json").write_text("{}")
    out = tmp_path / "carry"
    assert gpu_carry.main(["--data", str(H36M_DIR), "--out", str(out), "--weights", str(weights),
                           "--candidate", str(weights), "--protocol", str(tmp_path / "returned" / "protocol")]) == 0
    src = H36MSource(out / "h36m")
    assert src.keys and all(k.startswith("S5/") for k in src.keys)
    assert sorted(p.name for p in (out / "init").iterdir()) == ["long.safetensors", "short.safetensors"]
    assert sorted(p.name for p in (out / "candidate").iterdir()) == ["long.safetensors", "repair.safetensors",
                                                                     "short.safetensors"]
    assert (out / "protocol" / "candidate" / "forecast_none" / "walking.json").is_file()
    printed = capsys.readouterr().out
    assert "repair: no full-size weights" in printed and "MiB of the 64 MiB" in printed
    assert gpu_carry.folder_bytes(out) < gpu_carry.CARRY_LIMIT


def test_compare_configs_differ_in_the_batch_recipe_only():
    """`gpu_period.sh compare`: batch 256 (scaled rate, warm-up) against the paper's batch 32 on the same number
    of windows per epoch; everything else (model, data, masks, validation, seed) the same."""
    from training.train import TrainConfig
    a, b = (json.loads((ROOT / f"training/configs/gpu12_long_cmp_{n}.json").read_text()) for n in ("b256", "b32"))
    recipe = {"comment", "batch_size", "lr", "warmup_steps", "steps_per_epoch"}
    assert {k for k in a.keys() | b.keys() if a.get(k) != b.get(k)} == recipe
    assert a["batch_size"] * a["steps_per_epoch"] == b["batch_size"] * b["steps_per_epoch"]
    assert (a["batch_size"], b["batch_size"], b["lr"], b["warmup_steps"]) == (256, 32, 1e-3, 0)
    for name in ("b256", "b32"):
        TrainConfig.load(ROOT / f"training/configs/gpu12_long_cmp_{name}.json")


def test_compare_call_shares_the_call_between_its_runs(carry, tmp_path):
    """`gpu_period.sh compare` runs each config in turn, each stopped by its share of the call's minutes as
    well as by MINUTES of training: with a call too short for the first run's share (CALL_MINUTES 1.4: 42 s,
    less 45 s for its last validation), the first run stops after one batch, validated; the second still runs."""
    cfgs = []
    for name in ("cmp_a", "cmp_b"):
        cfgs.append(tmp_path / f"{name}.json")
        cfgs[-1].write_text(json.dumps(asdict(tiny_cfg(role="long", batches="device", epochs=2, steps_per_epoch=3))))
    r, out = period(["compare", "5"], tmp_path, GPU_CARRY=str(carry), CALL_MINUTES="1.4",
                    GPU_CMP_CONFIGS=" ".join(map(str, cfgs)))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    first, second = (out / "cmp_a.log").read_text(), (out / "cmp_b.log").read_text()
    assert "stopped after" in first and "at epoch 0 batch 1" in first
    assert "val loss" in second
