"""`tcd demo`, the bundled demo clip, and the bundled model's checksum checks."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import tcd
import tcd._directory
from tcd import _demo as demo
from tcd._cli import main
from tcd.exceptions import WeightsError

FAST = ["--samples", "2", "--steps", "2", "--sampler", "ddim", "--quiet"]


def test_demo_clip_is_a_plausible_22_joint_walk():
    clip = demo.load_clip()
    p = clip["poses"]
    assert p.dtype == np.float32 and p.ndim == 3 and p.shape[1:] == (22, 3)
    assert p.shape[0] >= 75 and clip["fps"] == 25.0
    assert np.isfinite(p).all()
    assert "mocap.cs.cmu.edu" in clip["source"]["dataset"]
    names = clip["joint_names"]
    i = {n: k for k, n in enumerate(names)}
    # Human3.6M bone lengths are kept exactly (knee -> ankle 454.2 mm, elbow -> wrist 251.7 mm)
    shin = np.linalg.norm(p[:, i["right_knee"]] - p[:, i["right_ankle"]], axis=-1)
    forearm = np.linalg.norm(p[:, i["left_elbow"]] - p[:, i["left_wrist"]], axis=-1)
    np.testing.assert_allclose(shin, 0.4542, atol=2e-4)
    np.testing.assert_allclose(forearm, 0.2517, atol=2e-4)
    # upright, root-relative: head above the root, feet below; moving (walking), not frozen
    assert (p[:, i["head"], 1] > 0.4).all() and (p[:, i["left_ankle"], 1] < -0.6).all()
    assert np.abs(np.diff(p, axis=0)).max() > 0.01


def test_occlusion_mask_hides_the_documented_limbs():
    names = demo.load_clip()["joint_names"]
    m = demo.occlusion_mask(50, names, seed=0)
    i = {n: k for k, n in enumerate(names)}
    assert m.shape == (50, 22)
    assert (m[10:30, i["right_knee"]] == 0).all() and (m[25:45, i["left_wrist"]] == 0).all()
    assert 0.1 < 1 - m.mean() < 0.35
    np.testing.assert_array_equal(m, demo.occlusion_mask(50, names, seed=0))


def test_demo_cli_runs_and_writes_results(tiny_model_dir, tmp_path, capsys):
    out = tmp_path / "demo.npz"
    assert main(["demo", "--model", str(tiny_model_dir), "-o", str(out), *FAST]) == 0
    text = capsys.readouterr().out
    assert "forecast error, mm" in text and "zero-velocity" in text and "repair of the occluded" in text
    with np.load(out, allow_pickle=False) as f:
        assert f["forecast_mean"].shape == (25, 22, 3)
        assert f["forecast_samples"].shape == (2, 25, 22, 3)
        obs, rep, mask = f["observed"], f["repaired"], f["occlusion_mask"]
        summary = json.loads(str(f["summary"]))
    np.testing.assert_array_equal(rep[mask > 0], obs[mask > 0])  # observed entries bit-identical
    assert np.isfinite(rep).all()
    assert set(summary["forecast_mm"]) == {"80", "160", "320", "400", "560", "720", "880", "1000"}
    assert summary["model_sha256"] == tcd.load(tiny_model_dir).sha256
    assert summary["settings"]["mode"] == {"mode": "cascade"} and summary["settings"]["generator_samples"] == 0
    assert "tempo" not in summary["settings"]
    # deterministic for a fixed seed
    out2 = tmp_path / "demo2.npz"
    assert main(["demo", "--model", str(tiny_model_dir), "-o", str(out2), *FAST]) == 0
    with np.load(out2) as f2, np.load(out) as f1:
        np.testing.assert_array_equal(f1["forecast_mean"], f2["forecast_mean"])


def test_demo_refuses_to_overwrite(tiny_model_dir, tmp_path, capsys):
    out = tmp_path / "demo.npz"
    out.write_bytes(b"keep me")
    assert main(["demo", "--model", str(tiny_model_dir), "-o", str(out), *FAST]) == 2
    assert "exists" in capsys.readouterr().err
    assert out.read_bytes() == b"keep me"


def test_demo_runs_again_over_its_own_output_only(tiny_model_dir, tmp_path, capsys):
    out = tmp_path / "demo.npz"
    argv = ["demo", "--model", str(tiny_model_dir), "-o", str(out), "--quiet", *FAST]
    assert main(argv) == 0
    first = out.read_bytes()
    text = capsys.readouterr().out
    assert main(argv + ["--seed", "1"]) == 0  # its own output: replaced without --overwrite
    assert out.read_bytes() != first
    # the closing sentences: what the table shows, and how good this model is (from its own size)
    cfg = tcd.load(tiny_model_dir).short.config["model"]
    assert "The table is the forecast error in mm" in text
    assert f"This is a reduced model ({cfg['num_layers']} layers x {cfg['channels']} channels" in text
    assert "beats Zero-Velocity at" in text
    # a GIF is the demo's only when the demo's .npz records its SHA-256
    gif = tmp_path / "anim.gif"
    gif.write_bytes(b"GIF89a someone else's animation")
    assert not demo.is_own_output(gif, out)
    assert demo.is_own_output(out, out) and not demo.is_own_output(out, tmp_path / "missing.npz")


def test_demo_bad_steps_names_the_option(tiny_model_dir, tmp_path, capsys):
    assert main(["demo", "--model", str(tiny_model_dir), "-o", str(tmp_path / "d.npz"), "--steps", "0", "--quiet"]) == 2
    assert "--steps" in capsys.readouterr().err


# ----------------------------------------------------------------------------- checksums


def test_checksums_verified_when_present(tiny_model_dir, tmp_path):
    d = Path(shutil.copytree(tiny_model_dir, tmp_path / "m"))
    tcd._directory.write_checksums(d)
    m = tcd.load(d)
    assert len(m.sha256) == 64 and set(m.file_sha256) == {"short.safetensors", "long.safetensors"}
    raw = bytearray((d / "long.safetensors").read_bytes())
    raw[-1] ^= 0x01  # one flipped bit in a weight
    (d / "long.safetensors").write_bytes(bytes(raw))
    with pytest.raises(WeightsError, match="SHA-256"):
        tcd.load(d)


def test_bundled_model_requires_checksums(tiny_model_dir, tmp_path, monkeypatch):
    d = Path(shutil.copytree(tiny_model_dir, tmp_path / "bundled"))
    monkeypatch.setattr(tcd._directory, "bundled_model_dir", lambda name: d)
    with pytest.raises(WeightsError, match="SHA256SUMS"):
        tcd.load()
    tcd._directory.write_checksums(d)
    assert tcd.load().sha256 == tcd.load(d).sha256


def test_bundled_model_loads_and_matches_its_checksums():
    d = tcd.default_model_dir()
    if not (d / "short.safetensors").is_file():
        pytest.skip("no bundled model in this build")
    m = tcd.load()
    sums = {n: h for h, n in (line.split() for line in (d / "SHA256SUMS").read_text().splitlines() if line.strip())}
    assert m.file_sha256 == {n: sums[n] for n in m.file_sha256}
    assert m.num_joints == 22 and m.obs_len == 50 and m.horizon == 25


def test_summary_columns_stay_apart_for_any_error(tiny_model_dir):
    """An untrained model's errors reach metres (six digits in mm): the table widens instead of running
    numbers together."""
    model = tcd.load(tiny_model_dir)
    res = demo.run(
        model, samples=1, quiet=True, sampling=dict.fromkeys(model.sampling, tcd.SamplerOptions(num_inference_steps=2))
    )
    res["forecast_mm"] = {m: 123456.7 for m in res["forecast_mm"]}  # as the full-size random model gives
    rows = [
        line
        for line in demo.summary(res, model).splitlines()
        if line.startswith(("  tcd, ", "  zero-velocity", "  horizon"))
    ]
    assert len(rows) == 4
    for line in rows:
        assert len(line[30:].split()) == len(res["forecast_mm"]), line
    assert "123456.7" in rows[1]


def test_verdict_names_each_stage_size_where_they_differ():
    """The demo's closing sentence reads the size from the model's own metadata: one size where the stages agree,
    each stage's where they differ (the bundled long-term model is larger than the short-term one), "full-size"
    only where every stage is the paper's size."""
    from types import SimpleNamespace

    def stage(size):
        return SimpleNamespace(config={"model": {"num_layers": size[0], "channels": size[1]}})

    def model(short, long, generator=None, mode=None):
        mode = tcd.Cascade() if mode is None else mode
        return SimpleNamespace(short=stage(short), long=stage(long), generator=generator, forecast_mode=mode)

    res = {"forecast_mm": {80: 10.0, 1000: 150.0}, "zero_velocity_mm": {80: 20.0, 1000: 140.0}}
    same = demo.verdict(res, model((3, 32), (3, 32)))
    assert "a reduced model (3 layers x 32 channels; the paper's is 12 x 64)" in same
    assert "beats Zero-Velocity at 1 of 2 horizons" in same
    mixed = demo.verdict(res, model((3, 32), (4, 64)))
    assert "short-term 3 layers x 32 channels, long-term 4 layers x 64 channels" in mixed and "reduced" in mixed
    assert "a full-size model (12 layers x 64 channels" in demo.verdict(res, model((12, 64), (12, 64)))
    assert "reduced" in demo.verdict(res, model((12, 64), (4, 64)))
    mlp = SimpleNamespace(layers=3, hidden=768)  # a directory with a generator names it, and its share
    assert "and an MLP generator of 3 x 768 drawing 0.5 of the samples" in demo.verdict(
        res, model((3, 32), (3, 32), mlp, tcd.Mixture(0.5))
    )
    assert "MLP" not in demo.verdict(res, model((3, 32), (3, 32), mlp, tcd.Cascade()))
    assert "MLP" not in demo.verdict(res, model((3, 32), (3, 32), mlp, tcd.Mixture(0.0)))  # a share of 0: none drawn
    assert "MLP" not in demo.verdict(res, model((3, 32), (3, 32), mlp, tcd.Tempo(0.8, 1.25)))
