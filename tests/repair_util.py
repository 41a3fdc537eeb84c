"""Helpers of the dataset-repair tests (test_repair.py, test_repair_inputs.py): fast sampler settings, gappy
random poses, running `tcd repair` in-process and comparing output trees."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fixtures_util import poses
from tcd._cli import main
from tcd import SamplerOptions

FAST = ["--steps", "2", "--sampler", "ddim", "--samples", "2"]
FAST_KW = dict(sampler=SamplerOptions(num_inference_steps=2, sampler="ddim"), num_samples=2)
W = 50


def gappy(rng, frames, missing=0.2, block=None):
    """Random poses (metres) with random missing joints and optionally a block of missing frames."""
    x = poses(rng, frames=frames, missing=missing)
    if block is not None:
        x[block[0] : block[1]] = np.nan
    return x


def run(argv, capsys):
    code = main(["repair", *[str(a) for a in argv]])
    out = capsys.readouterr()
    return code, out.out, out.err


def load_npz(path):
    with np.load(path, allow_pickle=False) as f:
        return {k: f[k] for k in f.files}


def tree(d: Path):
    """{relative path: arrays} of every file under d (asserting nothing but finished .npz files)."""
    out = {}
    for f in sorted(d.rglob("*")):
        if f.is_file():
            assert f.suffix == ".npz" and not f.name.startswith("."), f"stray file {f}"
            out[f.relative_to(d).as_posix()] = load_npz(f)
    return out


def same_tree(a, b):
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].keys() == b[k].keys()
        for name in a[k]:
            assert np.array_equal(a[k][name], b[k][name]), (k, name)
