"""The `tcd` command line: info, a forecast round trip, refusal to overwrite, exit code 2 on bad input."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

import tcd
from fixtures_util import poses
from tcd._cli import main
from tcd import SamplerOptions

FAST = ["--samples", "2", "--steps", "2", "--sampler", "ddim"]


@pytest.fixture()
def npz(tmp_path):
    path = tmp_path / "in.npz"
    np.savez(path, poses=poses(np.random.default_rng(0)))
    return path


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_info(tiny_model_dir, capsys):
    code, out, err = run(["info", "--model", tiny_model_dir], capsys)
    assert code == 0, err
    assert "observed frames (obs_len): 50" in out and "forecast frames (horizon): 25" in out
    assert "joints: 22" in out and "short: window 50 + 5 frames" in out and "repair: none" in out
    code, out, _ = run(["info", "--model", tiny_model_dir, "--json"], capsys)
    assert code == 0
    import json

    info = json.loads(out)
    assert info["horizon"] == 25 and info["config"]["long"]["window"]["seq_len"] == 75
    assert info["forecast_mode"] == {"mode": "cascade"}
    assert "forecast_tempo" not in info and "generator_share" not in info
    code, out, _ = run(["info", "--model", tiny_model_dir], capsys)
    assert code == 0 and "default forecast mode: the cascade\n" in out and "generator: none" in out


@pytest.mark.parametrize(
    "sampling,mode,text",
    [
        ({"forecast_tempo": [0.7, 1.4]}, {"mode": "tempo", "lo": 0.7, "hi": 1.4}, "the cascade at tempi 0.7 to 1.4"),
        ({"forecast_generator_share": 0}, {"mode": "cascade"}, "the cascade"),
    ],
)
def test_info_shows_the_default_forecast_mode(tiny_model_dir, tmp_path, capsys, sampling, mode, text):
    """``tcd info`` prints the directory's default mode (sampling.json), ``--json`` as ``forecast_mode``."""
    import json

    d = shutil.copytree(tiny_model_dir, tmp_path / "m")
    (d / "sampling.json").write_text(json.dumps(sampling))
    code, out, err = run(["info", "--model", d, "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["forecast_mode"] == mode
    code, out, err = run(["info", "--model", d], capsys)
    assert code == 0, err
    assert f"default forecast mode: {text}\n" in out


def test_info_humaneva_bundled_model_mixes_in_its_generator(capsys):
    import json

    if not (tcd.humaneva_model_dir() / "short.safetensors").is_file():
        pytest.skip("no bundled HumanEva-I model in this build")
    code, out, err = run(["info", "--model", "humaneva", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["forecast_mode"] == {"mode": "mixture", "share": 0.5}
    code, out, err = run(["info", "--model", "humaneva"], capsys)
    assert code == 0, err
    assert "default forecast mode: the cascade with a share of 0.5 of the samples from the generator" in out
    assert "generator: MLP" in out


def test_info_without_bundled_model(capsys, tmp_path, monkeypatch):
    import tcd._directory

    monkeypatch.setattr(tcd._directory, "bundled_model_dir", lambda name: tmp_path)  # an installation without weights
    code, out, err = run(["info"], capsys)
    assert code == 2 and out == ""
    assert "'h36m' is not bundled" in err


def test_info_bundled_model(capsys):
    import tcd

    if not (tcd.default_model_dir() / "short.safetensors").is_file():
        pytest.skip("no bundled model in this build")
    code, out, err = run(["info"], capsys)
    assert code == 0, err
    assert "layers 3" in out and "channels 32" in out
    assert f"kernels: {tcd.engine.supported_kernels()[-1]}" in out


def test_forecast_round_trip(tiny_model_dir, npz, tmp_path, capsys):
    out_path = tmp_path / "out.npz"
    code, out, err = run(["forecast", npz, "-o", out_path, "--model", tiny_model_dir, "--seed", "11", *FAST], capsys)
    assert code == 0, err
    assert "wrote" in out
    with np.load(out_path) as f:
        got = {k: f[k] for k in f.files}
    assert set(got) == {"mean", "samples", "repaired", "seed", "times"}
    np.testing.assert_allclose(got["times"], np.arange(1, 26) / 25.0)
    assert got["mean"].shape == (25, 22, 3) and got["samples"].shape == (2, 25, 22, 3)
    assert got["repaired"].shape == (50, 22, 3) and int(got["seed"]) == 11
    poses_in = np.load(npz)["poses"]
    want = tcd.load(tiny_model_dir).forecast(
        poses_in, seed=11, num_samples=2, sampler=SamplerOptions(num_inference_steps=2, sampler="ddim")
    )
    assert np.array_equal(got["samples"], want.samples) and np.array_equal(got["repaired"], want.repaired)
    seen = ~np.isnan(poses_in)
    assert np.array_equal(got["repaired"][seen], poses_in[seen])


def test_forecast_any_length(tiny_model_dir, npz, tmp_path, capsys):
    """The API's length rule: 40 frames are padded with missing frames, as TCD.forecast does."""
    short = np.load(npz)["poses"][10:]
    out_path = tmp_path / "out.npz"
    code, _, err = run(
        [
            "forecast",
            save(tmp_path / "short.npz", poses=short),
            "-o",
            out_path,
            "--model",
            tiny_model_dir,
            "--seed",
            "3",
            *FAST,
        ],
        capsys,
    )
    assert code == 0, err
    want = tcd.load(tiny_model_dir).forecast(
        short, seed=3, num_samples=2, sampler=SamplerOptions(num_inference_steps=2, sampler="ddim")
    )
    with np.load(out_path) as f:
        assert f["repaired"].shape == (40, 22, 3) and np.array_equal(f["samples"], want.samples)


def test_forecast_dpmpp2m(tiny_model_dir, npz, tmp_path, capsys):
    out_path = tmp_path / "out_dpm.npz"
    args = ["--samples", "2", "--steps", "3", "--sampler", "dpmpp2m", "--seed", "5"]
    code, _, err = run(["forecast", npz, "-o", out_path, "--model", tiny_model_dir, *args], capsys)
    assert code == 0, err
    want = tcd.load(tiny_model_dir).forecast(
        np.load(npz)["poses"], seed=5, num_samples=2, sampler=SamplerOptions(num_inference_steps=3, sampler="dpmpp2m")
    )
    with np.load(out_path) as f:
        assert np.array_equal(f["samples"], want.samples)


def test_forecast_noise_coupling(tiny_model_dir, npz, tmp_path, capsys):
    """--noise-coupling sets the API's noise_coupling: centred samples are the API's, and not the independent ones."""
    out_path = tmp_path / "out_centred.npz"
    args = ["--samples", "3", "--steps", "1", "--sampler", "ddim", "--seed", "5", "--noise-coupling", "centered"]
    code, _, err = run(["forecast", npz, "-o", out_path, "--model", tiny_model_dir, *args], capsys)
    assert code == 0, err
    model, poses = tcd.load(tiny_model_dir), np.load(npz)["poses"]
    kw = dict(seed=5, num_samples=3)
    ddim1 = dict(num_inference_steps=1, sampler="ddim")
    want = model.forecast(poses, sampler=SamplerOptions(**ddim1, noise_coupling="centered"), **kw)
    with np.load(out_path) as f:
        assert np.array_equal(f["samples"], want.samples)
        assert not np.array_equal(
            f["samples"],
            model.forecast(poses, sampler=SamplerOptions(**ddim1, noise_coupling="independent"), **kw).samples,
        )


def test_forecast_batched_with_mask_and_random_seed(tiny_model_dir, tmp_path, capsys):
    x = poses(np.random.default_rng(1), batch=2, missing=0.0) * np.float32(1000)  # millimetres
    mask = np.ones((2, 50, 22), np.float32)
    mask[:, 10:20] = 0
    inp = tmp_path / "in.npz"
    np.savez(inp, poses=x, mask=mask)
    out_path = tmp_path / "out.npz"
    code, _, err = run(["forecast", inp, "-o", out_path, "--model", tiny_model_dir, "--units", "mm", *FAST], capsys)
    assert code == 0, err
    with np.load(out_path) as f:
        assert f["mean"].shape == (2, 25, 22, 3) and f["samples"].shape == (2, 2, 25, 22, 3)
        seed = int(f["seed"])
        repaired = f["repaired"]
    assert np.array_equal(repaired[:, :10], x[:, :10]) and not np.array_equal(repaired[:, 10:20], x[:, 10:20])
    want = tcd.load(tiny_model_dir).forecast(
        x, mask, seed=seed, num_samples=2, sampler=SamplerOptions(num_inference_steps=2, sampler="ddim"), units="mm"
    )
    assert np.array_equal(repaired, want.repaired)


def test_refuses_to_overwrite(tiny_model_dir, npz, tmp_path, capsys):
    out_path = tmp_path / "out.npz"
    out_path.write_bytes(b"precious")
    code, _, err = run(["forecast", npz, "-o", out_path, "--model", tiny_model_dir, *FAST], capsys)
    assert code == 2 and "exists" in err and "--overwrite" in err
    assert out_path.read_bytes() == b"precious"


def test_failure_while_writing_leaves_no_output(tiny_model_dir, npz, tmp_path, capsys, monkeypatch):
    """OUT is written atomically: a failure half-way (np.savez raising after some bytes) leaves no file
    under OUT, or with --overwrite the old OUT as it was, and no temporary file."""

    def savez(fh, **arrays):
        fh.write(b"partial bytes")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", savez)
    out_path = tmp_path / "out.npz"
    code, _, err = run(["forecast", npz, "-o", out_path, "--model", tiny_model_dir, *FAST], capsys)
    assert code == 1 and "disk full" in err
    assert not out_path.exists()
    out_path.write_bytes(b"precious")
    code, _, err = run(["forecast", npz, "-o", out_path, "--model", tiny_model_dir, "--overwrite", *FAST], capsys)
    assert code == 1 and "disk full" in err
    assert out_path.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.npz", "out.npz"]


def test_output_appearing_during_the_run_is_kept(tiny_model_dir, npz, tmp_path, capsys, monkeypatch):
    """Without --overwrite an OUT that appears after the start (another process) is never replaced."""
    out_path = tmp_path / "out.npz"
    real_savez = np.savez

    def savez(fh, **arrays):
        out_path.write_bytes(b"someone else's")
        real_savez(fh, **arrays)

    monkeypatch.setattr(np, "savez", savez)
    code, _, err = run(["forecast", npz, "-o", out_path, "--model", tiny_model_dir, *FAST], capsys)
    assert code == 2 and "exists" in err and "--overwrite" in err
    assert out_path.read_bytes() == b"someone else's"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.npz", "out.npz"]
    code, _, err = run(["forecast", npz, "-o", out_path, "--model", tiny_model_dir, "--overwrite", *FAST], capsys)
    assert code == 0, err
    with np.load(out_path) as f:
        assert f["mean"].shape == (25, 22, 3)


def save(path, **arrays):
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize(
    "case",
    [
        "empty_window",
        "wrong_joints",
        "no_poses",
        "missing_input",
        "not_npz",
        "bad_mask",
        "all_missing",
        "bad_samples",
        "bad_steps",
        "bad_eta",
        "missing_model",
        "negative_seed",
    ],
)
def test_bad_input_exit_code_2(tiny_model_dir, npz, tmp_path, capsys, case):
    good = np.load(npz)["poses"]
    inp, extra, model = npz, [], tiny_model_dir
    if case == "empty_window":  # any length is forecast from its last obs_len frames: here all missing
        inp = save(tmp_path / "x.npz", poses=np.concatenate([good, np.full_like(good, np.nan)]))
    elif case == "wrong_joints":
        inp = save(tmp_path / "x.npz", poses=good[:, :17])
    elif case == "no_poses":
        inp = save(tmp_path / "x.npz", data=good)
    elif case == "missing_input":
        inp = tmp_path / "nope.npz"
    elif case == "not_npz":
        inp = tmp_path / "x.npz"
        inp.write_text("hello")
    elif case == "bad_mask":
        inp = save(tmp_path / "x.npz", poses=np.nan_to_num(good), mask=np.full((50, 22), 0.5))
    elif case == "all_missing":
        inp = save(tmp_path / "x.npz", poses=np.full_like(good, np.nan))
    elif case == "bad_samples":
        extra = ["--samples", "0"]
    elif case == "bad_steps":
        extra = ["--steps", "51"]
    elif case == "bad_eta":
        extra = ["--eta", "2"]
    elif case == "missing_model":
        model = tmp_path / "no_model"
    elif case == "negative_seed":
        extra = ["--seed", "-5"]
    out_path = tmp_path / "out.npz"
    code, out, err = run(["forecast", inp, "-o", out_path, "--model", model, *FAST, *extra], capsys)
    assert code == 2, (out, err)
    assert err.startswith("tcd forecast: error: ") and len(err.strip()) > len("tcd forecast: error: ") + 10
    assert "Traceback" not in err
    assert not out_path.exists()


@pytest.mark.parametrize(
    "command, flag, value",
    [
        ("forecast", "--sampler", "euler"),
        ("forecast", "--units", "inch"),
        ("forecast", "--spacing", "middle"),
        ("forecast", "--noise-coupling", "antithetic"),
        ("demo", "--sampler", "euler"),
    ],
)
def test_bad_choice_is_a_usage_error(tiny_model_dir, npz, tmp_path, capsys, command, flag, value):
    """An enumerated flag's choices are argparse's: a bad one exits with 2, naming the flag and the value."""
    out_path = tmp_path / "out.npz"
    argv = [command, *([npz] if command == "forecast" else []), "-o", out_path, "--model", tiny_model_dir, flag, value]
    with pytest.raises(SystemExit) as ei:
        run(argv, capsys)
    assert ei.value.code == 2
    err = capsys.readouterr().err
    assert f"tcd {command}: error: " in err and flag in err and value in err
    assert "Traceback" not in err
    assert not out_path.exists()


def test_usage_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as ei:
        main(["forecast"])  # no input, no -o
    assert ei.value.code == 2
    with pytest.raises(SystemExit) as ei:
        main(["frobnicate"])
    assert ei.value.code == 2
    capsys.readouterr()


def test_console_script_and_module(tiny_model_dir, tmp_path):
    """The installed `tcd` script (and `python -m tcd`) run in a fresh process."""
    env = {**os.environ, "PYTHONPATH": ""}
    script = shutil.which("tcd")
    cmd = [script] if script else [sys.executable, "-m", "tcd"]
    r = subprocess.run(
        [*cmd, "info", "--model", str(tiny_model_dir)],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert "forecast frames (horizon): 25" in r.stdout
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "tcd",
            "forecast",
            str(tmp_path / "nope.npz"),
            "-o",
            str(tmp_path / "o.npz"),
            "--model",
            str(tiny_model_dir),
        ],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )
    assert r.returncode == 2 and "does not exist" in r.stderr
