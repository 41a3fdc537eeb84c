"""Offline repair of files of any length (`tcd repair`, `tcd.repair_file`, issue 6).

A random-init tiny model's values are meaningless: these tests check the structure (shapes, masks,
bit-identical observed values, windows and their conditioning), determinism, resumability and the error
handling, not accuracy (benches/repair_quality.py measures that)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import tcd
from conftest import ROOT
from repair_util import FAST, FAST_KW, W, gappy, load_npz, run, same_tree, tree
from tcd._files import write_npz_atomic
from tcd._repair import options as repair_options
from tcd._repair import runner as repair_runner
from tcd._repair.windows import window_starts
from tcd._cli import repair as repair_command


# ---------------------------------------------------------------------------------------------- windows
@pytest.mark.parametrize("frames", [50, 51, 89, 90, 91, 313, 1000])
@pytest.mark.parametrize("overlap,lookahead", [(1, 0), (10, 0), (25, 0), (49, 0), (5, 10), (1, 48), (20, 20)])
def test_window_starts_cover_with_overlap(frames, overlap, lookahead):
    starts = window_starts(frames, W, overlap, lookahead)
    assert starts[0] == 0 and starts[-1] + W == frames
    for a, b in zip(starts, starts[1:]):
        assert a < b and a + W - b >= overlap + lookahead  # consecutive windows share >= overlap + lookahead frames
    assert len(starts) == max(1, -(-(frames - W) // (W - overlap - lookahead)) + 1)


@pytest.mark.parametrize("overlap,lookahead", [(0, 0), (5, 45), (10, -1)])
def test_window_starts_refuse_no_progress(overlap, lookahead):
    with pytest.raises(ValueError, match="overlap"):
        window_starts(200, W, overlap, lookahead)


# ---------------------------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("frames", [7, 50, 313])
def test_round_trip_lengths(tiny_model, tmp_path, frames):
    rng = np.random.default_rng(frames)
    x = gappy(rng, frames, block=(frames // 3, frames // 3 + 12))
    src, dst = tmp_path / "in.npz", tmp_path / "out.npz"
    np.savez(src, poses=x)
    info = tcd.repair_file(src, dst, tiny_model, seed=5, **FAST_KW)
    got = load_npz(dst)
    assert set(got) == {"poses", "mask", "provenance"}
    assert got["poses"].shape == x.shape and got["poses"].dtype == x.dtype
    assert not np.isnan(got["poses"]).any()
    seen = ~np.isnan(x)
    assert np.array_equal(got["poses"][seen], x[seen])  # observed values bit for bit
    assert got["mask"].dtype == bool and np.array_equal(got["mask"], seen)
    prov = json.loads(str(got["provenance"]))
    assert prov["model_sha256"] == tiny_model.sha256 and len(prov["model_sha256"]) == 64
    assert prov["sampler"] == "ddim" and prov["steps"] == 2 and prov["seed"] == 5 and prov["num_samples"] == 2
    assert prov["tcd_version"] == tcd.__version__
    assert info["status"] == "repaired" and info["frames"] == frames
    assert info["windows"] == len(
        window_starts(max(frames, W), W, repair_options.DEFAULT_OVERLAP, repair_options.DEFAULT_LOOKAHEAD)
    )
    assert info["missing_values"] == int((~seen).sum())


def test_one_window_equals_tcd_repair(tiny_model, tmp_path):
    """A file of exactly one window is TCD.repair of that window with the same seed (noise stream 0)."""
    x = gappy(np.random.default_rng(14), W)
    np.savez(tmp_path / "in.npz", poses=x)
    tcd.repair_file(tmp_path / "in.npz", tmp_path / "out.npz", tiny_model, seed=21, **FAST_KW)
    want = tiny_model.repair(x, seed=21, **FAST_KW).poses
    assert np.array_equal(load_npz(tmp_path / "out.npz")["poses"], want)


def test_fill_alone_file_equals_tcd_repair(tmp_path, capsys):
    """``num_samples=0`` through the file repair: a one-window file of the bundled model is TCD.repair's fill
    alone, whatever the seed, with 0 samples in its provenance; the CLI's ``--samples 0`` writes the same."""
    m = tcd.load()
    if m.repair_fill is None:
        pytest.skip("no bundled repair fill in this build")
    x = gappy(np.random.default_rng(15), W, block=(20, 30))
    np.savez(tmp_path / "in.npz", poses=x)
    info = tcd.repair_file(tmp_path / "in.npz", tmp_path / "out.npz", m, num_samples=0, seed=3)
    got = load_npz(tmp_path / "out.npz")
    assert info["status"] == "repaired" and json.loads(str(got["provenance"]))["num_samples"] == 0
    assert np.array_equal(got["poses"], m.repair(x, num_samples=0, seed=9).poses)
    code, _, err = run(
        [tmp_path / "in.npz", "-o", tmp_path / "cli", "--samples", "0", "--seed", "4", "--quiet"], capsys
    )
    assert code == 0, err
    assert np.array_equal(load_npz(tmp_path / "cli" / "in.npz")["poses"], got["poses"])


def test_explicit_mask_and_float64(tiny_model, tmp_path):
    rng = np.random.default_rng(1)
    x = rng.normal(scale=0.3, size=(80, 22, 3))  # float64, no NaN: the mask says what is missing
    mask = (rng.random((80, 22)) > 0.3).astype(np.uint8)
    np.savez(tmp_path / "in.npz", poses=x, mask=mask)
    tcd.repair_file(tmp_path / "in.npz", tmp_path / "out.npz", tiny_model, **FAST_KW)
    got = load_npz(tmp_path / "out.npz")
    assert got["poses"].dtype == np.float64
    assert np.array_equal(got["mask"], mask) and got["mask"].dtype == mask.dtype  # the mask as given
    m3 = np.repeat(mask.astype(bool)[..., None], 3, -1)
    assert np.array_equal(got["poses"][m3], x[m3])
    assert not np.array_equal(got["poses"][~m3], x[~m3])  # masked values were replaced


def spy_windows(monkeypatch):
    """Records (observed, mask, mean) of every engine call tcd.repair_file makes (one per window here)."""
    calls = []
    real = repair_runner.repair_raw

    def spy(den, observed, mask, **kw):
        out = real(den, observed, mask, **kw)
        calls.append((observed.copy(), mask.copy(), out["mean"].copy()))
        return out

    monkeypatch.setattr(repair_runner, "repair_raw", spy)
    return calls


def test_later_windows_condition_on_repaired_frames(tiny_model, tmp_path, monkeypatch):
    """Window k > 0 sees the frames already repaired as observed (mask 1, repaired values): no seams
    (lookahead 0: every frame of a window is committed)."""
    calls = spy_windows(monkeypatch)
    rng = np.random.default_rng(2)
    x = gappy(rng, 130, missing=0.3, block=(35, 48))  # the overlap of windows 0 and 1 (frames 40..49) has gaps
    np.savez(tmp_path / "in.npz", poses=x)
    tcd.repair_file(tmp_path / "in.npz", tmp_path / "out.npz", tiny_model, overlap=10, lookahead=0, **FAST_KW)
    starts = window_starts(130, W, 10)
    assert starts == [0, 40, 80] and len(calls) == 3
    out = load_npz(tmp_path / "out.npz")["poses"]
    for k in (1, 2):
        prev_obs, prev_mask, prev_mean = calls[k - 1]
        obs, mask, _ = calls[k]
        shared = starts[k - 1] + W - starts[k]
        assert mask[0, :, :shared].all()  # every entry of the shared frames counts as observed
        # ... with the values the previous window produced (repaired where they were missing)
        assert np.array_equal(obs[0, :, :shared], prev_mean[0, :, W - shared :])
        assert (prev_mask[0, :, W - shared :] == 0).any()
        # the new frames keep the original mask
        orig = (~np.isnan(x[starts[k] + shared : starts[k] + W])).reshape(W - shared, -1).T
        assert np.array_equal(mask[0, :, shared:].astype(bool), orig)
    # and the output's missing entries are the windows' values for their new frames
    for k, (lo, hi) in enumerate(((0, 50), (50, 90), (90, 130))):
        win = calls[k][2][0].T.reshape(W, 22, 3)[lo - starts[k] : hi - starts[k]]
        miss = np.isnan(x[lo:hi])
        assert np.array_equal(out[lo:hi][miss], win[miss])


def test_lookahead_frames_are_generated_again_by_the_next_window(tiny_model, tmp_path, monkeypatch):
    """With lookahead L, a window (but the last) commits all but its L trailing frames; the next window sees
    only the committed frames as observed (its first `overlap` frames, with the committing window's values)
    and generates the L frames again, seeing what follows them; the output takes each frame from the window
    that committed it."""
    calls = spy_windows(monkeypatch)
    rng = np.random.default_rng(4)
    x = gappy(rng, 130, missing=0.3, block=(36, 47))  # a gap across window 0's uncommitted tail (40..49)
    np.savez(tmp_path / "in.npz", poses=x)
    info = tcd.repair_file(tmp_path / "in.npz", tmp_path / "out.npz", tiny_model, overlap=5, lookahead=10, **FAST_KW)
    starts = window_starts(130, W, 5, 10)
    assert starts == [0, 35, 70, 80] and len(calls) == 4 and info["windows"] == 4
    done = [40, 75, 110, 130]  # committed up to (exclusive) after each window
    prov = json.loads(str(load_npz(tmp_path / "out.npz")["provenance"]))
    assert prov["overlap"] == 5 and prov["lookahead"] == 10
    out = load_npz(tmp_path / "out.npz")["poses"]
    for k in (1, 2, 3):
        obs, mask, _ = calls[k]
        ctx = done[k - 1] - starts[k]
        assert ctx == (5 if k < 3 else 30)
        assert mask[0, :, :ctx].all()
        prev_mean = calls[k - 1][2][0]
        assert np.array_equal(obs[0, :, :ctx], prev_mean[:, starts[k] - starts[k - 1] : done[k - 1] - starts[k - 1]])
        orig = (~np.isnan(x[done[k - 1] : starts[k] + W])).reshape(starts[k] + W - done[k - 1], -1).T
        assert np.array_equal(mask[0, :, ctx:].astype(bool), orig)  # the lookahead frames keep their gaps
    lo = 0
    for k in range(4):
        win = calls[k][2][0].T.reshape(W, 22, 3)[lo - starts[k] : done[k] - starts[k]]
        miss = np.isnan(x[lo : done[k]])
        assert np.array_equal(out[lo : done[k]][miss], win[miss])
        lo = done[k]
    # window 0's own values for its uncommitted tail were replaced by window 1's
    tail = np.isnan(x[40:50])
    assert not np.array_equal(out[40:50][tail], calls[0][2][0].T.reshape(W, 22, 3)[40:50][tail])


# ---------------------------------------------------------------------------------------------- determinism
def test_same_seed_same_output_regardless_of_jobs_and_batching(tiny_model_dir, tmp_path, capsys):
    rng = np.random.default_rng(3)
    d = tmp_path / "data"
    d.mkdir()
    for i, t in enumerate((60, 210, 33)):
        np.savez(d / f"s{i}.npz", poses=gappy(rng, t))
    outs = {}
    for jobs in ("1", "2"):
        code, _, err = run(
            [
                d,
                "-o",
                tmp_path / f"out{jobs}",
                "--model",
                tiny_model_dir,
                "--jobs",
                jobs,
                "--seed",
                "9",
                "--quiet",
                *FAST,
            ],
            capsys,
        )
        assert code == 0, err
        outs[jobs] = tree(tmp_path / f"out{jobs}")
    same_tree(outs["1"], outs["2"])
    # one file alone through the API: the same as within the batch of three
    tcd.repair_file(d / "s1.npz", tmp_path / "alone.npz", tcd.load(tiny_model_dir), seed=9, threads=1, **FAST_KW)
    assert np.array_equal(load_npz(tmp_path / "alone.npz")["poses"], outs["1"]["s1.npz"]["poses"])
    # another seed changes the repaired values
    tcd.repair_file(d / "s1.npz", tmp_path / "other.npz", tiny_model_dir, seed=10, **FAST_KW)
    assert not np.array_equal(load_npz(tmp_path / "other.npz")["poses"], outs["1"]["s1.npz"]["poses"])


# ---------------------------------------------------------------------------------------------- the command
def test_directory_with_bad_files(tiny_model_dir, tmp_path, capsys):
    rng = np.random.default_rng(4)
    d = tmp_path / "data"
    (d / "a" / "b").mkdir(parents=True)
    np.savez(d / "good1.npz", poses=gappy(rng, 70))
    np.savez(d / "a" / "b" / "good2.npz", poses=gappy(rng, 20))
    (d / "a" / "corrupt.npz").write_bytes(b"PK\x03\x04 truncated")
    (d / "a" / "garbage.npz").write_bytes(b"not an archive at all")
    np.savez(d / "wrong_shape.npz", poses=np.zeros((10, 17, 3), np.float32))
    allnan = np.full((30, 22, 3), np.nan, np.float32)
    np.savez(d / "all_missing.npz", poses=allnan)
    inf = gappy(rng, 30)
    inf[3, 4, 1] = np.inf
    np.savez(d / "inf.npz", poses=inf)
    np.savez(d / "no_poses.npz", joints=np.zeros(3))
    (d / "notes.md").write_text("ignored: not an input suffix")
    report = tmp_path / "report.json"
    code, out, err = run([d, "-o", tmp_path / "out", "--model", tiny_model_dir, "--report", report, *FAST], capsys)
    assert code == 1
    assert "2 repaired, 0 skipped, 6 failed" in out
    got = tree(tmp_path / "out")
    assert set(got) == {"good1.npz", "a/b/good2.npz"}
    rep = json.loads(report.read_text())
    by = {Path(f["input"]).name: f for f in rep["files"]}
    assert rep["summary"]["failed"] == 6 and rep["summary"]["repaired"] == 2
    assert rep["model_sha256"] == tcd.load(tiny_model_dir).sha256
    reasons = {
        "corrupt.npz": "unreadable",
        "garbage.npz": "unreadable",
        "wrong_shape.npz": "17 joints",
        "all_missing.npz": "every value is missing",
        "inf.npz": "finite, with NaN marking missing",
        "no_poses.npz": "without a `poses` array",
    }
    for name, why in reasons.items():
        assert by[name]["status"] == "failed" and why in by[name]["reason"], by[name]
        assert name in err and why in err
    assert by["good1.npz"]["status"] == "repaired" and by["good1.npz"]["frames"] == 70
    assert "notes.md" not in by


def test_rerun_skips_and_overwrite(tiny_model_dir, tmp_path, capsys):
    rng = np.random.default_rng(5)
    src = tmp_path / "in.npz"
    np.savez(src, poses=gappy(rng, 60))
    out = tmp_path / "out"
    code, _, err = run([src, "-o", out, "--model", tiny_model_dir, "--seed", "1", "--quiet", *FAST], capsys)
    assert code == 0, err
    first = load_npz(out / "in.npz")
    stamp = (out / "in.npz").stat().st_mtime_ns
    time.sleep(0.01)
    code, text, _ = run([src, "-o", out, "--model", tiny_model_dir, "--seed", "1", *FAST], capsys)
    assert code == 0 and "0 repaired, 1 skipped" in text  # finished with these settings: resumed past it
    # an output made with other settings is not "finished": it is reported, and left as it is
    code, text, err = run([src, "-o", out, "--model", tiny_model_dir, "--seed", "2", *FAST], capsys)
    assert code == 1 and "0 repaired, 0 skipped, 1 failed" in text
    assert "was made with other settings: seed 1 (this run: 2)" in err
    assert (out / "in.npz").stat().st_mtime_ns == stamp  # untouched
    code, text, _ = run([src, "-o", out, "--model", tiny_model_dir, "--seed", "2", "--overwrite", *FAST], capsys)
    assert code == 0 and "1 repaired, 0 skipped" in text
    second = load_npz(out / "in.npz")
    assert not np.array_equal(first["poses"], second["poses"])
    assert json.loads(str(second["provenance"]))["seed"] == 2
    with pytest.raises(FileExistsError):
        tcd.repair_file(src, out / "in.npz", tiny_model_dir, **FAST_KW)
    # any other file at the output path is reported, never taken for a finished output
    (out / "in.npz").write_text("not an output")
    code, _, err = run([src, "-o", out, "--model", tiny_model_dir, "--seed", "2", *FAST], capsys)
    assert code == 1 and "is not a readable tcd repair output" in err
    assert (out / "in.npz").read_text() == "not an output"
    # an archive whose provenance is JSON but not a record is reported too (it used to crash the run)
    np.savez(out / "in.npz", poses=np.zeros(1), mask=np.zeros(1), provenance=np.array("[1, 2]"))
    code, _, err = run([src, "-o", out, "--model", tiny_model_dir, "--seed", "2", *FAST], capsys)
    assert code == 1 and "is not a readable tcd repair output" in err


def test_never_overwrites_an_input(tiny_model_dir, tmp_path, capsys):
    rng = np.random.default_rng(6)
    d = tmp_path / "data"
    d.mkdir()
    x = gappy(rng, 40)
    np.savez(d / "x.npz", poses=x)
    before = (d / "x.npz").read_bytes()
    code, _, err = run([d, "-o", d, "--model", tiny_model_dir, "--overwrite", *FAST], capsys)
    assert code == 2 and "would overwrite the input" in err
    assert (d / "x.npz").read_bytes() == before
    with pytest.raises(ValueError):
        tcd.repair_file(d / "x.npz", d / "x.npz", tiny_model_dir, overwrite=True, **FAST_KW)
    assert (d / "x.npz").read_bytes() == before
    # an output directory inside the input directory: its files are never taken as inputs
    code, _, err = run([d, "-o", d / "repaired", "--model", tiny_model_dir, "--quiet", *FAST], capsys)
    assert code == 0, err
    code, text, _ = run([d, "-o", d / "repaired", "--model", tiny_model_dir, *FAST], capsys)
    assert code == 0 and "0 repaired, 1 skipped, 0 failed" in text


def test_bad_arguments_exit_2(tiny_model_dir, tmp_path, capsys):
    src = tmp_path / "in.npz"
    np.savez(src, poses=gappy(np.random.default_rng(7), 20))
    for extra, why in (
        (["--steps", "0"], "--steps"),
        (["--fps", "-5"], "--fps"),
        (["--overlap", "50"], "--overlap"),
        (["--lookahead", "45"], "--lookahead"),
        (["--samples", "0"], "num_samples"),
    ):  # the fill alone: the tiny model has no repair fill
        code, _, err = run([src, "-o", tmp_path / "o", "--model", tiny_model_dir, *extra], capsys)
        assert code == 2 and why in err, (extra, err)
    for flag, value in (("--units", "inch"), ("--sampler", "euler")):  # choices: argparse's usage error
        with pytest.raises(SystemExit) as ei:
            run([src, "-o", tmp_path / "o", "--model", tiny_model_dir, flag, value], capsys)
        err = capsys.readouterr().err
        assert ei.value.code == 2 and "tcd repair: error: " in err and flag in err and value in err, err
    code, _, err = run([tmp_path / "missing.npz", "-o", tmp_path / "o", "--model", tiny_model_dir], capsys)
    assert code == 2 and "does not exist" in err
    code, _, err = run([src, "-o", tmp_path / "o", "--model", tmp_path / "nomodel"], capsys)
    assert code == 2
    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = run([empty, "-o", tmp_path / "o", "--model", tiny_model_dir], capsys)
    assert code == 2 and "no input files" in err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


# ---------------------------------------------------------------------------------------------- interruptions
def _dataset(d: Path, n: int = 4, frames: int = 90):
    rng = np.random.default_rng(8)
    d.mkdir()
    for i in range(n):
        np.savez(d / f"seq{i}.npz", poses=gappy(rng, frames + 17 * i))


def test_interrupted_run_then_rerun_matches(tiny_model_dir, tmp_path, capsys, monkeypatch):
    data = tmp_path / "data"
    _dataset(data)
    code, _, err = run([data, "-o", tmp_path / "ref", "--model", tiny_model_dir, "--quiet", *FAST], capsys)
    assert code == 0, err
    ref = tree(tmp_path / "ref")

    # interrupt while writing the second output: after np.savez has written part of the temporary file
    real_savez = np.savez
    written = []

    def savez(fh, **arrays):
        if len(written) == 1:
            fh.write(b"partial bytes")
            raise KeyboardInterrupt
        written.append(fh)
        real_savez(fh, **arrays)

    monkeypatch.setattr(np, "savez", savez)
    out = tmp_path / "out"
    code, _, err = run([data, "-o", out, "--model", tiny_model_dir, "--quiet", *FAST], capsys)
    assert code == 130 and "interrupted" in err
    partial = tree(out)  # asserts: no temporary or partial files left behind
    assert len(partial) == 1
    monkeypatch.setattr(np, "savez", real_savez)
    code, text, err = run([data, "-o", out, "--model", tiny_model_dir, *FAST], capsys)
    assert code == 0, err
    assert "3 repaired, 1 skipped" in text
    same_tree(tree(out), ref)


def test_killed_subprocess_then_rerun_matches(tiny_model_dir, tmp_path, capsys):
    data = tmp_path / "data"
    _dataset(data, n=6, frames=150)
    settings = ["--steps", "2", "--sampler", "ddim", "--samples", "1", "--jobs", "1"]
    cmd = [sys.executable, "-m", "tcd", "repair", str(data), "--model", str(tiny_model_dir), "--quiet", *settings]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    code, _, err = run([data, "-o", tmp_path / "ref", "--model", tiny_model_dir, "--quiet", *settings], capsys)
    assert code == 0, err
    ref = tree(tmp_path / "ref")
    out = tmp_path / "out"
    proc = subprocess.Popen(cmd + ["-o", str(out)], env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 60
    while time.time() < deadline and proc.poll() is None and not list(out.glob("*.npz")):
        time.sleep(0.01)
    if proc.poll() is None:
        os.kill(proc.pid, signal.SIGKILL)
    proc.communicate()
    # whatever was written is complete (a killed run may leave a hidden temporary file, never a partial
    # output; the re-run removes it when it writes that output)
    for f in out.glob("*.npz"):
        load_npz(f)
    done_before = len(list(out.glob("*.npz")))
    assert proc.returncode in (0, -signal.SIGKILL)  # killed mid-way (or, on a fast machine, finished)
    code, text, err = run([data, "-o", out, "--model", tiny_model_dir, *settings], capsys)
    assert code == 0, err
    assert f"{done_before} skipped" in text
    same_tree(tree(out), ref)


def test_atomic_write_leaves_nothing_on_failure(tmp_path, monkeypatch):
    dst = tmp_path / "x.npz"

    def boom(fh, **arrays):
        fh.write(b"half")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", boom)
    with pytest.raises(OSError):
        write_npz_atomic(dst, False, poses=np.zeros(3))
    assert list(tmp_path.iterdir()) == []


def test_progress_bar_only_on_a_terminal(monkeypatch):
    assert repair_command._progress_bar(10, quiet=False) is None  # pytest captures stderr: not a terminal
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    assert repair_command._progress_bar(10, quiet=True) is None
    bar = repair_command._progress_bar(10, quiet=False)
    assert bar is not None and bar.total == 10
    bar.close()
