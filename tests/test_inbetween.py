"""The repair fill's in-betweener (``training.inbetween``): its inputs, its fit, and its place in the repair fill's
file (``training.export.set_inbetween``). Parity with the engine: tests/test_parity.py."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

pytest.importorskip("torch")

import tcd  # noqa: E402
from training import inbetween as ib  # noqa: E402
from training.data.h36m import DEFAULT_H36M_DIR  # noqa: E402


def test_inputs_are_the_segment_the_fractions_and_their_products():
    """One coordinate's row: the fill over [s - C, s + n + C) minus frame s - 1 (indices clamped), the fractions
    of the context inside the window, and the segment times each; ``correct`` adds W x to the gap's frames only."""
    t, c, n = 12, 2, 3
    fill = np.arange(t, dtype=np.float64)[None, :, None] ** 2  # (1, T, 1)
    for s, before, after in ((4, 1.0, 1.0), (1, 0.5, 1.0), (9, 1.0, 0.0)):
        x = ib.per_coordinate(ib.segment_features(fill, np.array([s]), n, c), n, c)
        assert x.shape == (1, ib.kernel_width(n, c))
        frames = np.clip(np.arange(s - c, s + n + c), 0, t - 1)
        seg = frames**2 - max(s - 1, 0) ** 2
        np.testing.assert_array_equal(x[0], np.concatenate([seg, [before, after], seg * before, seg * after]))
        w = np.random.default_rng(s).standard_normal((n, ib.kernel_width(n, c)))
        out = ib.correct(fill, [(0, s, s + n)], {n: w}, c)
        np.testing.assert_allclose(out[0, s : s + n, 0], fill[0, s : s + n, 0] + w @ x[0])
        assert np.array_equal(
            np.delete(out[0, :, 0], np.arange(s, s + n)), np.delete(fill[0, :, 0], np.arange(s, s + n))
        )
    # a gap without a kernel for its length keeps the fill
    assert np.array_equal(ib.correct(fill, [(0, 4, 8)], {3: w}, c), fill)


def test_set_inbetween_round_trip(tmp_path):
    """The kernels go into a copy of the bundled directory's repair fill in place of its own (config keys and
    tensors, the fill's own weights as they were; the engine loads it), wrong shapes are refused, and ``None``
    takes them out."""
    from safetensors.numpy import load_file

    from training.export import set_inbetween
    from training.prior_net import load_prior_file

    src = tcd.default_model_dir()
    if not (src / "repair_fill.safetensors").is_file():
        pytest.skip("no bundled repair fill in this build")
    d = tmp_path / "m"
    shutil.copytree(src, d)
    (d / "SHA256SUMS").unlink(missing_ok=True)
    before = {
        k: v for k, v in load_file(str(d / "repair_fill.safetensors")).items() if not k.startswith("inbetween_")
    }  # the fill's own weights (the bundled has kernels)
    rng = np.random.default_rng(0)
    # Fortran-ordered, as a solve's transpose is: written contiguous all the same
    kernels = {n: np.asfortranarray(rng.standard_normal((n, ib.kernel_width(n, 3))), np.float32) for n in (1, 2, 3)}
    ib.save_kernels(tmp_path / "k.npz", kernels, 3, {"test": True})
    (d / "repair_fill.safetensors").chmod(0o644)
    set_inbetween(d, tmp_path / "k.npz")
    assert (d / "repair_fill.safetensors").stat().st_mode & 0o777 == 0o644  # the file keeps its mode
    after = load_file(str(d / "repair_fill.safetensors"))
    assert set(after) == set(before) | {"inbetween_1", "inbetween_2", "inbetween_3"}
    assert all(np.array_equal(after[k], before[k]) for k in before)
    assert np.array_equal(after["inbetween_2"], kernels[2])
    twin = load_prior_file(d / "repair_fill.safetensors")[0]
    assert (twin.cfg.inbetween_context, twin.cfg.inbetween_max_gap) == (3, 3)
    assert tcd.engine.Prior.load(d / "repair_fill.safetensors").num_features == 66
    bad = dict(kernels)
    bad[2] = bad[2][:, :-1]
    ib.save_kernels(tmp_path / "bad.npz", bad, 3, {})
    with pytest.raises(ValueError, match="inbetween_2 has shape"):
        set_inbetween(d, tmp_path / "bad.npz")
    set_inbetween(d, None)
    again = load_file(str(d / "repair_fill.safetensors"))
    assert set(again) == set(before) and all(np.array_equal(again[k], before[k]) for k in before)
    assert load_prior_file(d / "repair_fill.safetensors")[0].cfg.inbetween_max_gap == 0


@pytest.mark.skipif(not (DEFAULT_H36M_DIR / "h36m_expmap_50fps.npz").is_file(), reason="needs the Human3.6M data")
def test_fit_gives_a_kernel_per_gap_length_that_an_overwhelming_penalty_zeroes():
    """``fit`` on a few training windows: one kernel per gap length of its width; with an overwhelming ridge
    penalty every kernel is ~0 (the fill as it was), with a slight one it is not."""
    m = tcd.load()
    if m.repair_fill is None:
        pytest.skip("no bundled repair fill in this build")
    k = ib.fit(m, max_gap=2, windows=8, lam=1e-3, log=lambda _: None)
    assert sorted(k) == [1, 2] and k[2].shape == (2, ib.kernel_width(2, ib.CONTEXT)) and np.abs(k[2]).max() > 1e-3
    k = ib.fit(m, max_gap=2, windows=8, lam=1e12, log=lambda _: None)
    assert max(np.abs(w).max() for w in k.values()) < 1e-6


def test_joint_runs_are_a_coordinates_hidden_runs_outside_the_whole_frame_gaps():
    """``joint_runs``: per window and coordinate, each run of hidden frames; not one that touches a whole-frame gap,
    nor a coordinate hidden over the whole window; ``correct_runs`` changes those runs' entries only."""
    mask = np.ones((2, 10, 3), np.float32)
    mask[0, 2:4, 0] = 0  # a run of 2 in coordinate 0
    mask[0, 6, 1] = 0  # a run of 1 in coordinate 1
    mask[0, 5:8, :] = 0  # a whole-frame gap 5-7: coordinate 1's run 5-7 lies in it
    mask[1, :, 2] = 0  # coordinate 2 of window 1 hidden throughout
    mask[1, 9, 0] = 0  # a run at the window's end
    gaps = [(0, 5, 8)]
    assert sorted(ib.joint_runs(mask, gaps)) == [(0, 0, 2, 4), (1, 0, 9, 10)]
    fill = np.random.default_rng(1).standard_normal((2, 10, 3))
    w = {1: np.ones((1, ib.kernel_width(1, 2))), 2: np.ones((2, ib.kernel_width(2, 2)))}
    out = ib.correct_runs(fill, ib.joint_runs(mask, gaps), w, 2)
    changed = out != fill
    assert changed[0, 2:4, 0].all() and changed[1, 9, 0] and changed.sum() == 3
