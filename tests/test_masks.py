"""Tests of training/masks.py: imperfect-observation masks (TCD reference, section 4)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import H36M_DIR, needs_data
from training.masks import (
    JOINTS32_H36M_22,
    PATTERNS,
    coord_mask,
    corrupt,
    make_mask,
)

OBS, SEQ, J = 50, 75, 22
N_DRAWS = 2000

# Model-joint columns of the 22-joint layout, worked out by hand from joints_used_22.
LEG_ARM_COLS = [0, 1, 12, 13, 14]  # 32-joints 2, 3, 17, 18, 19 (1 is not in the layout)
RIGHT_LEG_COLS = [0, 1]  # 32-joints 2, 3
LEGS_COLS = [0, 1, 4, 5]  # 32-joints 2, 3, 7, 8 (1 and 6 are not in the layout)

SKELETON = H36M_DIR / "skeleton32.json"


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def draws(pattern: str, n: int = N_DRAWS, seed: int = 0, **kw) -> np.ndarray:
    g = rng(seed)
    return np.stack([make_mask(pattern, OBS, SEQ, g, **kw) for _ in range(n)])


def others(cols):
    return [j for j in range(J) if j not in cols]


# ----------------------------------------------------------------------------------------------
# the joint layout


@needs_data("h36m/skeleton32.json")
def test_default_layout_matches_skeleton_file():
    assert list(JOINTS32_H36M_22) == json.loads(SKELETON.read_text())["joints_used_22"]


# ----------------------------------------------------------------------------------------------
# shapes, future rows, none


@pytest.mark.parametrize("pattern", PATTERNS)
def test_shape_dtype_binary_and_future_zero(pattern):
    for seed in range(20):
        m = make_mask(pattern, OBS, SEQ, rng(seed))
        assert m.shape == (SEQ, J)
        assert m.dtype == np.float32
        assert set(np.unique(m)) <= {0.0, 1.0}
        assert not m[OBS:].any()


@pytest.mark.parametrize("pattern", PATTERNS)
def test_custom_layout_width_and_obs_equals_seq(pattern):
    layout = (0, 1, 2, 3, 6, 7, 8, 17)
    m = make_mask(pattern, 30, 30, rng(1), joints32=layout)
    assert m.shape == (30, len(layout)) and m.dtype == np.float32


def test_none_all_observed_visible():
    m = make_mask("none", OBS, SEQ, rng())
    assert (m[:OBS] == 1).all() and (m[OBS:] == 0).all()


def test_unmapped_joints_have_no_effect():
    # A layout holding only joints that no pattern touches: nothing is ever hidden by the
    # joint-specific patterns.
    layout = (12, 13, 14, 15)
    for pattern in ("random_leg_arm", "structured_leg", "noisy_50"):
        g = rng(3)
        for _ in range(50):
            assert (make_mask(pattern, OBS, SEQ, g, joints32=layout)[:OBS] == 1).all()
    # The hips (32-joints 1 and 6) are masked when the layout holds them.
    g = rng(4)
    m = np.stack([make_mask("noisy_50", OBS, SEQ, g, joints32=(1, 6)) for _ in range(400)])
    assert 0.4 < 1 - m[:, :OBS].mean() < 0.6  # each leg joint hidden with probability 3/6


# ----------------------------------------------------------------------------------------------
# statistics of each pattern


def test_random_leg_arm_exact_counts_and_uniform_frames():
    m = draws("random_leg_arm")
    obs = m[:, :OBS]
    hidden = obs == 0
    # Nothing outside the 5 mapped leg/arm joints is ever hidden.
    assert not hidden[:, :, others(LEG_ARM_COLS)].any()
    # The 5 joints are hidden together, in exactly floor(0.4 * 50) = 20 frames.
    leg_arm = hidden[:, :, LEG_ARM_COLS]
    assert (leg_arm.all(axis=2) == leg_arm.any(axis=2)).all()
    assert (leg_arm.all(axis=2).sum(axis=1) == 20).all()
    # Each frame is chosen with probability 0.4 (binomial sd ~0.011 over 2000 draws).
    per_frame = leg_arm.all(axis=2).mean(axis=0)
    assert np.abs(per_frame - 0.4).max() < 0.06


def test_random_leg_arm_rate_argument():
    m = draws("random_leg_arm", n=50, rate=0.3)
    assert ((m[:, :OBS, 0] == 0).sum(axis=1) == 15).all()


def _blocks(hidden_rows: np.ndarray):
    """Start and length of every run of True in a 1-D boolean array."""
    d = np.diff(np.concatenate([[0], hidden_rows.astype(int), [0]]))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return starts, ends - starts


def test_consecutive_frames_one_block_of_ten_all_joints():
    m = draws("consecutive_frames")
    obs = m[:, :OBS]
    starts = []
    for w in obs:
        rows_hidden = (w == 0).all(axis=1)
        # Frames are hidden whole or not at all.
        assert ((w == 0).any(axis=1) == rows_hidden).all()
        s, lengths = _blocks(rows_hidden)
        assert len(s) == 1 and lengths[0] == 10  # round(0.2 * 50): the paper's 20 %, not 5 frames
        starts.append(s[0])
    starts = np.array(starts)
    # Start uniform over the 41 valid positions 0..40.
    assert starts.min() == 0 and starts.max() == 40
    counts = np.bincount(starts, minlength=41)
    assert counts.min() > 20  # expected ~48.8 each


def test_consecutive_frames_length_follows_rate():
    for rate, length in ((0.1, 5), (0.5, 25), (1.0, 50), (0.0, 0)):
        m = make_mask("consecutive_frames", OBS, SEQ, rng(5), rate=rate)
        assert (m[:OBS] == 0).all(axis=1).sum() == length


def test_structured_leg_block_on_right_leg():
    m = draws("structured_leg", n=1000)
    obs = m[:, :OBS]
    hidden = obs == 0
    assert not hidden[:, :, others(RIGHT_LEG_COLS)].any()
    assert (hidden[:, :, 0] == hidden[:, :, 1]).all()
    starts = []
    for w in hidden[:, :, 0]:
        s, lengths = _blocks(w)
        assert len(s) == 1 and lengths[0] == 10
        starts.append(s[0])
    assert min(starts) == 0 and max(starts) == 40
    # Length follows the rate.
    m = make_mask("structured_leg", OBS, SEQ, rng(), rate=0.4)
    assert (m[:OBS, 0] == 0).sum() == 20


def test_random_frames_counts():
    m = draws("random_frames", n=500)
    obs = m[:, :OBS]
    rows_hidden = (obs == 0).all(axis=2)
    assert ((obs == 0).any(axis=2) == rows_hidden).all()
    assert (rows_hidden.sum(axis=1) == 10).all()  # floor(0.2 * 50)
    # Not a contiguous block in general.
    n_blocks = [len(_blocks(r)[0]) for r in rows_hidden]
    assert np.mean(n_blocks) > 3


def test_random_joints_rate():
    m = draws("random_joints")
    assert abs(1 - m[:, :OBS].mean() - 0.2) < 0.01
    m = draws("random_joints", rate=0.35, seed=1)
    assert abs(1 - m[:, :OBS].mean() - 0.35) < 0.01
    # Independent across joints: every joint has the rate.
    per_joint = 1 - m[:, :OBS].mean(axis=(0, 1))
    assert np.abs(per_joint - 0.35).max() < 0.03


def test_random_joints_tuple_rate_drawn_per_window():
    m = draws("random_joints", rate=(0.1, 0.4))
    per_window = 1 - m[:, :OBS].mean(axis=(1, 2))
    assert abs(per_window.mean() - 0.25) < 0.01
    # The rate varies from window to window, over the whole range (a fixed rate 0.25 would give a
    # per-window sd of ~0.018; U(0.1, 0.4) gives ~0.087).
    assert per_window.std() > 0.06
    assert per_window.min() < 0.13 and per_window.max() > 0.37
    # A degenerate range is the fixed rate.
    m = draws("random_joints", rate=(0.3, 0.3))
    assert abs(1 - m[:, :OBS].mean() - 0.3) < 0.01


def test_random_pattern_rate_is_uniform_per_window():
    m = draws("random")
    per_window = 1 - m[:, :OBS].mean(axis=(1, 2))
    assert abs(per_window.mean() - 0.5) < 0.03
    assert abs(per_window.std() - np.sqrt(1 / 12)) < 0.03
    assert per_window.min() < 0.05 and per_window.max() > 0.95


@pytest.mark.parametrize("pattern", ["noisy_25", "noisy_50"])
def test_noisy_mask_three_leg_joints_per_frame(pattern):
    m = draws(pattern)
    hidden = m[:, :OBS] == 0
    assert not hidden[:, :, others(LEGS_COLS)].any()
    per_frame = hidden[:, :, LEGS_COLS].sum(axis=2)
    # 3 of the 6 leg joints drawn; 4 of them are mapped: hypergeometric, mean 2, support 1..3.
    assert abs(per_frame.mean() - 2.0) < 0.02
    assert per_frame.min() >= 1 and per_frame.max() <= 3
    # Hypergeometric(N=6, K=4, n=3): P(1) = 0.2, P(2) = 0.6, P(3) = 0.2.
    freq = np.bincount(per_frame.ravel(), minlength=4)[1:] / per_frame.size
    np.testing.assert_allclose(freq, [0.2, 0.6, 0.2], atol=0.01)
    # Each mapped leg joint hidden with probability 1/2.
    assert np.abs(hidden[:, :, LEGS_COLS].mean(axis=(0, 1)) - 0.5).max() < 0.01


@pytest.mark.parametrize("pattern, sigma", [("noisy_25", 0.025), ("noisy_50", 0.05)])
def test_noisy_corrupt_noise_std(pattern, sigma):
    g = rng(7)
    clean = rng(8).normal(size=(SEQ, J, 3))
    residuals = []
    for _ in range(300):
        observed, mask = corrupt(clean, pattern, OBS, g)
        vis = mask.astype(bool)
        residuals.append((observed - clean)[vis])
        assert (observed[~vis] == 0).all()
    r = np.concatenate(residuals)
    assert abs(r.mean()) < 0.02 * sigma
    assert abs(r.std() / sigma - 1) < 0.03


def test_noise_units_per_mm():
    clean = np.zeros((SEQ, J, 3))
    observed, mask = corrupt(clean, "noisy_50", OBS, rng(9), units_per_mm=1.0)  # window in mm
    assert abs(observed[mask.astype(bool)].std() / 50.0 - 1) < 0.1


@pytest.mark.parametrize("pattern", [p for p in PATTERNS if not p.startswith("noisy")])
def test_corrupt_without_noise_keeps_visible_values(pattern):
    clean = rng(10).normal(size=(SEQ, J, 3)).astype(np.float32)
    observed, mask = corrupt(clean, pattern, OBS, rng(11))
    vis = mask.astype(bool)
    assert observed.dtype == np.float32
    np.testing.assert_array_equal(observed[vis], clean[vis])
    assert (observed[~vis] == 0).all()
    np.testing.assert_array_equal(mask, make_mask(pattern, OBS, SEQ, rng(11)))


# ----------------------------------------------------------------------------------------------
# corrupt: no mutation, zeros


@pytest.mark.parametrize("pattern", PATTERNS)
def test_corrupt_does_not_mutate_and_zeros_masked(pattern):
    clean = rng(12).normal(size=(SEQ, J, 3)) + 5.0  # no exact zeros in the input
    before = clean.copy()
    observed, mask = corrupt(clean, pattern, OBS, rng(13))
    np.testing.assert_array_equal(clean, before)
    assert observed is not clean and not np.shares_memory(observed, clean)
    assert observed.shape == clean.shape and observed.dtype == clean.dtype
    assert mask.shape == (SEQ, J) and mask.dtype == np.float32
    assert (observed[mask == 0] == 0).all()
    assert (observed[mask == 1] != 0).all()
    assert (observed[OBS:] == 0).all()


def test_corrupt_hidden_nan_becomes_zero():
    clean = np.full((SEQ, J, 3), np.nan)
    observed, mask = corrupt(clean, "none", OBS, rng())
    assert (observed[OBS:] == 0).all()


# ----------------------------------------------------------------------------------------------
# determinism


@pytest.mark.parametrize("pattern", [p for p in PATTERNS if p != "none"])
def test_same_seed_same_mask_different_seeds_differ(pattern):
    a = make_mask(pattern, OBS, SEQ, rng(42))
    b = make_mask(pattern, OBS, SEQ, rng(42))
    np.testing.assert_array_equal(a, b)
    others_ = [make_mask(pattern, OBS, SEQ, rng(s)) for s in range(43, 53)]
    assert any(not np.array_equal(a, o) for o in others_)
    # Consecutive draws from one generator differ too.
    g = rng(42)
    assert not np.array_equal(make_mask(pattern, OBS, SEQ, g), make_mask(pattern, OBS, SEQ, g))


@pytest.mark.parametrize("pattern", ["noisy_50", "random_joints"])
def test_corrupt_deterministic(pattern):
    clean = rng(14).normal(size=(SEQ, J, 3))
    o1, m1 = corrupt(clean, pattern, OBS, rng(1))
    o2, m2 = corrupt(clean, pattern, OBS, rng(1))
    np.testing.assert_array_equal(o1, o2)
    np.testing.assert_array_equal(m1, m2)
    o3, _ = corrupt(clean, pattern, OBS, rng(2))
    assert not np.array_equal(o1, o3)


def test_tuple_rate_deterministic():
    a = make_mask("random_joints", OBS, SEQ, rng(5), rate=(0.1, 0.4))
    b = make_mask("random_joints", OBS, SEQ, rng(5), rate=(0.1, 0.4))
    np.testing.assert_array_equal(a, b)


# ----------------------------------------------------------------------------------------------
# coord_mask


def test_coord_mask_repeats_each_joint_three_times():
    jm = np.array([[1, 0, 1], [0, 1, 0]], dtype=np.float32)
    cm = coord_mask(jm)
    np.testing.assert_array_equal(cm, [[1, 1, 1, 0, 0, 0, 1, 1, 1], [0, 0, 0, 1, 1, 1, 0, 0, 0]])
    assert cm.dtype == np.float32
    m = make_mask("random_joints", OBS, SEQ, rng())
    cm = coord_mask(m)
    assert cm.shape == (SEQ, J * 3)
    # Matches the (J, 3) -> J*3 flattening of positions.
    np.testing.assert_array_equal(cm, np.broadcast_to(m[:, :, None], (SEQ, J, 3)).reshape(SEQ, -1))
    batch = np.stack([m, m])
    assert coord_mask(batch).shape == (2, SEQ, J * 3)


# ----------------------------------------------------------------------------------------------
# errors


def _raises(arg: str):
    return pytest.raises(ValueError, match=arg)


def test_unknown_pattern_lists_valid_ones():
    with pytest.raises(ValueError, match="pattern") as info:
        make_mask("occlusion", OBS, SEQ, rng())
    for p in PATTERNS:
        assert p in str(info.value)
    with _raises("pattern"):
        corrupt(np.zeros((SEQ, J, 3)), "random_right_leg", OBS, rng())


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), "0.2", (0.1,), (0.5, 0.2), (0.1, 1.2), (-1, 0.3)])
def test_bad_rate(bad):
    with _raises("rate"):
        make_mask("random_joints", OBS, SEQ, rng(), rate=bad)


def test_rate_rules_per_pattern():
    with _raises("rate"):
        make_mask("random_frames", OBS, SEQ, rng(), rate=(0.1, 0.2))  # tuples only for random_joints
    with _raises("rate"):
        make_mask("consecutive_frames", OBS, SEQ, rng(), rate=2.0)
    for p in ("none", "noisy_25", "noisy_50", "random"):
        with _raises("rate"):
            make_mask(p, OBS, SEQ, rng(), rate=0.2)
    with _raises("rate"):
        corrupt(np.zeros((SEQ, J, 3)), "random_leg_arm", OBS, rng(), rate=-0.5)
    # Boundary rates are valid.
    assert (make_mask("random_frames", OBS, SEQ, rng(), rate=1.0)[:OBS] == 0).all()
    assert (make_mask("random_joints", OBS, SEQ, rng(), rate=0.0)[:OBS] == 1).all()


def test_bad_lengths():
    with _raises("obs_len"):
        make_mask("none", 80, SEQ, rng())
    with _raises("obs_len"):
        make_mask("none", -1, SEQ, rng())
    with _raises("obs_len"):
        make_mask("none", 2.5, SEQ, rng())
    with _raises("seq_len"):
        make_mask("none", 0, 0, rng())
    with _raises("obs_len"):
        corrupt(np.zeros((SEQ, J, 3)), "none", SEQ + 1, rng())


@pytest.mark.parametrize("shape", [(SEQ, J), (SEQ, J + 1, 3), (SEQ, J, 2), (1, SEQ, J, 3), (0, J, 3)])
def test_bad_window_shape(shape):
    with _raises("window"):
        corrupt(np.zeros(shape), "random_joints", min(OBS, max(shape[0], 1)), rng())


def test_window_shape_must_match_joints32():
    with _raises("window"):
        corrupt(np.zeros((SEQ, J, 3)), "none", OBS, rng(), joints32=(2, 3, 4))
    observed, mask = corrupt(np.ones((SEQ, 3, 3)), "none", OBS, rng(), joints32=(2, 3, 4))
    assert observed.shape == (SEQ, 3, 3) and mask.shape == (SEQ, 3)


@pytest.mark.parametrize("bad", [(), (2, 32), (-1, 2), [[2, 3]], (2.0, 3.0)])
def test_bad_joints32(bad):
    with _raises("joints32"):
        make_mask("none", OBS, SEQ, rng(), joints32=bad)


@pytest.mark.parametrize("bad", [0.0, -1e-3, float("inf"), float("nan")])
def test_bad_units_per_mm(bad):
    with _raises("units_per_mm"):
        corrupt(np.zeros((SEQ, J, 3)), "noisy_25", OBS, rng(), units_per_mm=bad)


def test_rng_must_be_generator():
    with pytest.raises(TypeError, match="rng"):
        make_mask("random", OBS, SEQ, 0)
