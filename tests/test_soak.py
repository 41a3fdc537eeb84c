"""Soak and concurrency (issue 19, item 6): hundreds of calls in one process do not grow its memory, and four
threads sharing one loaded model get exactly the results of serial calls."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from fixtures_util import poses
from tcd import SamplerOptions

FAST = dict(sampler=SamplerOptions(sampler="ddim", num_inference_steps=2), num_samples=2)


def rss_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads the resident set from /proc")
def test_hundreds_of_calls_do_not_grow_memory(tiny_model):
    rng = np.random.default_rng(0)
    inputs = [poses(rng, batch=b) for b in (1, 3, 2)]

    def round_of_calls(i):
        x = inputs[i % 3]
        tiny_model.forecast(x, seed=i, threads=1 + i % 2, **FAST)
        tiny_model.repair(x, seed=i, threads=1 + i % 2, **FAST)

    for i in range(40):  # warm-up: allocator pools, thread pools of both sizes, caches
        round_of_calls(i)
    before = rss_mib()
    for i in range(150):  # 300 calls
        round_of_calls(i)
    grown = rss_mib() - before
    # a leak of even one output array per call (2 x 25 x 66 x 4 bytes and up) would add several MiB
    assert grown < 8.0, f"resident memory grew by {grown:.1f} MiB over 300 calls"


def test_four_threads_on_one_model_match_serial_calls(tiny_model):
    rng = np.random.default_rng(1)
    jobs = [(poses(rng, batch=b), seed) for b, seed in ((1, 10), (3, 11), (2, 12), (4, 13))]
    serial = [tiny_model.forecast(x, seed=s, threads=1, **FAST).samples for x, s in jobs]
    got = [None] * 4
    errors = []

    def work(i):
        try:
            x, s = jobs[i]
            for _ in range(5):  # repeated, so the threads really overlap
                got[i] = tiny_model.forecast(x, seed=s, threads=1, **FAST).samples
        except BaseException as e:  # surfaced below: an exception in a thread would otherwise be lost
            errors.append(e)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for i in range(4):
        np.testing.assert_array_equal(got[i], serial[i])
