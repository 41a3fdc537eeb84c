"""Long calls are visible and can be stopped (issue 19, item 2): ``progress=`` reports the engine's count of
denoiser forwards; Ctrl-C (SIGINT) or an exception raised in the progress callback stops the call early with
that exception, and the command line exits with 130 and one line, writing nothing.

No timing thresholds: a stop is proven by the forwards done being fewer than the call's total."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import tcd
from fixtures_util import poses

FAST = dict(sampler="ddim", num_inference_steps=3)


def test_progress_counts_every_forward(tiny_model):
    obs = poses(np.random.default_rng(0), batch=2)
    seen = []
    tiny_model.forecast(obs, num_samples=3, seed=0, progress=lambda done, total: seen.append((done, total)), **FAST)
    total = 3 * 2 * 3 * 2                               # samples x sequences x steps x (short, long)
    assert seen[-1] == (total, total)
    assert all(t == total for _, t in seen) and [d for d, _ in seen] == sorted(d for d, _ in seen)
    seen.clear()
    tiny_model.repair(obs, num_samples=2, seed=0, progress=lambda d, t: seen.append((d, t)), **FAST)
    assert seen[-1] == (2 * 2 * 3, 2 * 2 * 3)
    a = tiny_model.forecast(obs, num_samples=2, seed=1, progress=True, **FAST)       # a tqdm bar on stderr
    b = tiny_model.forecast(obs, num_samples=2, seed=1, **FAST)
    np.testing.assert_array_equal(a.samples, b.samples)


def test_bad_progress_argument(tiny_model):
    from fixtures_util import bad
    bad("progress", tiny_model.forecast, poses(np.random.default_rng(0)), progress="yes", **FAST)


class Stop(Exception):
    pass


def long_call_and_stop(model, trigger):
    """Runs a forecast of 16,000 forwards; ``trigger()`` fires at the first progress report with forwards
    done. Returns (the exception the call ended with, the last (done, total) reported)."""
    obs = poses(np.random.default_rng(1), batch=16, missing=0.0)
    seen = []

    def progress(done, total):
        seen.append((done, total))
        if done > 0 and not any(d > 0 for d, _ in seen[:-1]):
            trigger()

    with pytest.raises(BaseException) as ei:
        model.forecast(obs, num_samples=5, seed=0, threads=1, progress=progress)   # DDPM-50, both stages
    return ei.value, seen[-1]


def test_exception_in_the_progress_callback_stops_the_call():
    def stop():
        raise Stop()

    err, (done, total) = long_call_and_stop(tcd.load(), stop)
    assert isinstance(err, Stop)
    assert 0 < done < total


def test_ctrl_c_stops_the_call_with_keyboard_interrupt():
    model = tcd.load()
    err, (done, total) = long_call_and_stop(model, lambda: os.kill(os.getpid(), signal.SIGINT))
    assert isinstance(err, KeyboardInterrupt)
    assert done < total
    # the model is still usable, and the stopped call left nothing running that changes later results
    obs = poses(np.random.default_rng(2))
    a = model.forecast(obs, num_samples=1, seed=3, **FAST)
    np.testing.assert_array_equal(a.samples, model.forecast(obs, num_samples=1, seed=3, **FAST).samples)


def test_cli_ctrl_c_exits_130_with_one_line_and_no_output(tmp_path):
    obs = poses(np.random.default_rng(3), batch=64, missing=0.0)
    np.savez(tmp_path / "in.npz", poses=obs)
    out = tmp_path / "out.npz"
    # the same main() as the console script, started once imports are done (SIGINT during `import` is Python's)
    code = ("import sys; from tcd.cli import main; print('ready', flush=True); "
            f"sys.exit(main(['forecast', {str(tmp_path / 'in.npz')!r}, '-o', {str(out)!r}, '--threads', '1']))")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "ready"
    time.sleep(0.5)          # into the forecast (about 32,000 forwards), past argument parsing
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert err.strip().splitlines() == ["tcd forecast: interrupted"], err
    assert not out.exists() and list(tmp_path.iterdir()) == [tmp_path / "in.npz"]


def test_cli_closed_pipe_ends_quietly():
    """`tcd info | head`: the reader is gone before anything is written; no "Broken pipe", exit 0."""
    p = subprocess.Popen([sys.executable, "-m", "tcd", "info"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    p.stdout.close()
    _, err = p.communicate(timeout=60)
    assert p.returncode == 0 and err == "", err
