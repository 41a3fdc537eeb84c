"""training.augment: heading, mirror, playback-speed and swapped-future augmentation of training windows."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import import_torch

import_torch("training.augment is imported through the training package")
from training.augment import (  # noqa: E402
    arrival_keys,
    check_axis,
    future_neighbours,
    mirror,
    mirror_permutation,
    resample,
    rotate_about,
    sequence_ends,
    swap_futures,
)


def test_rotation_about_the_vertical_keeps_heights_and_shapes():
    rng = np.random.default_rng(0)
    wins = rng.normal(size=(6, 5, 4, 3)).astype(np.float32)
    out = rotate_about(wins, "z", np.random.default_rng(1))
    np.testing.assert_array_equal(out[..., 2], wins[..., 2])  # heights untouched
    d = lambda x: np.linalg.norm(x[:, :, :, None] - x[:, :, None], axis=-1)  # noqa: E731
    np.testing.assert_allclose(d(out), d(wins), atol=1e-5)  # a rigid motion
    assert not np.allclose(out, wins)
    # one angle per window, the same for all its frames and joints
    theta = np.random.default_rng(1).uniform(0, 2 * np.pi, 6)
    c, s = np.cos(theta[1]), np.sin(theta[1])
    np.testing.assert_allclose(
        out[1, 3, 2, :2],
        [c * wins[1, 3, 2, 0] - s * wins[1, 3, 2, 1], s * wins[1, 3, 2, 0] + c * wins[1, 3, 2, 1]],
        atol=1e-5,
    )


def test_mirror_swaps_left_and_right_through_a_vertical_plane():
    names = ("thorax", "left_hand", "right_hand", "head")
    perm = mirror_permutation(names)
    np.testing.assert_array_equal(perm, [0, 2, 1, 3])
    rng = np.random.default_rng(0)
    wins = rng.normal(size=(4, 5, 4, 3)).astype(np.float32)
    which = np.array([True, False, True, False])
    out = mirror(wins, "z", perm, which)
    np.testing.assert_array_equal(out[~which], wins[~which])  # the others untouched
    # z (vertical) and x kept, y negated; the left hand is where the right one was, reflected
    np.testing.assert_array_equal(out[0, :, 1], wins[0, :, 2] * np.array([1, -1, 1], np.float32))
    np.testing.assert_array_equal(out[0, :, 0], wins[0, :, 0] * np.array([1, -1, 1], np.float32))
    np.testing.assert_array_equal(mirror(out, "z", perm, which), wins)  # its own inverse
    d = lambda x: np.linalg.norm(x[:, :, :, None] - x[:, :, None], axis=-1)  # noqa: E731
    np.testing.assert_allclose(d(out[which])[:, :, perm][:, :, :, perm], d(wins[which]), atol=1e-6)  # relabelled
    with pytest.raises(ValueError, match="left_foot"):
        mirror_permutation(("left_foot", "right_hand", "left_hand"))


def test_prior_batches_mirror_and_need_the_vertical():
    from training.prior import batch
    from training.prior_net import PriorConfig

    with pytest.raises(ValueError, match="mirror_prob"):
        PriorConfig(dataset="humaneva", subjects=(1, 2, 3), mirror_prob=0.5)
    rng = np.random.default_rng(0)
    frames = rng.normal(size=(200, 42)).astype(np.float32)
    base = dict(dataset="humaneva", subjects=(1, 2, 3), obs_len=15, chunk=15, batch_size=64, rotate_axis="z")
    plain = batch(PriorConfig(**base), frames, np.arange(170), 5).numpy().reshape(64, 30, 14, 3)
    mir = batch(PriorConfig(**base, mirror_prob=0.5), frames, np.arange(170), 5).numpy().reshape(64, 30, 14, 3)
    same = np.all(mir == plain, axis=(1, 2, 3))
    assert 16 < int((~same).sum()) < 48  # about half of 64 mirrored
    # the same windows, the same headings: the mirrored ones are the plain ones mirrored
    from training.data.humaneva import HUMANEVA_MODEL_JOINT_NAMES

    perm = mirror_permutation(HUMANEVA_MODEL_JOINT_NAMES)
    np.testing.assert_array_equal(mirror(plain, "z", perm, ~same), mir)


def test_resample_reads_each_window_at_its_speed_inside_its_sequence():
    # frame r of the data is the number r: a window's values are the rows it read
    frames = np.repeat(np.arange(30, dtype=np.float32)[:, None], 6, axis=1)
    starts = np.r_[np.arange(0, 11), np.arange(20, 26)]  # sequences [0, 15) and [20, 30), windows of 5
    ends = sequence_ends(starts, 5)
    np.testing.assert_array_equal(ends, [15] * 11 + [30] * 6)
    w = resample(frames, np.array([0, 2, 21, 20, 25]), ends[[0, 2, 12, 11, 16]], 5, np.array([1.0, 2.0, 0.5, 3.0, 1.2]))
    np.testing.assert_allclose(
        w[..., 0],
        [
            [0, 1, 2, 3, 4],  # speed 1: the plain window
            [2, 4, 6, 8, 10],  # twice as fast
            [21, 21.5, 22, 22.5, 23],  # half as fast: interpolated
            [20, 22.25, 24.5, 26.75, 29],  # 3 would leave the sequence: 2.25
            [25, 26, 27, 28, 29],
        ],
    )  # the last start: speed 1 at most
    assert w.dtype == np.float32


def test_prior_batches_play_windows_at_a_speed_in_range():
    from training.prior import batch
    from training.prior_net import PriorConfig

    for bad in ([1.2], [1.2, 0.8], [0.0, 1.0], [0.8, float("inf")]):
        with pytest.raises(ValueError, match="speed_range"):
            PriorConfig(speed_range=tuple(bad))
    frames = np.repeat(np.arange(400, dtype=np.float32)[:, None], 42, axis=1)  # frame r holds r
    starts = np.r_[np.arange(0, 171), np.arange(200, 371)]  # two sequences of 200
    base = dict(dataset="humaneva", subjects=(1, 2, 3), obs_len=15, chunk=15, batch_size=256, flip_prob=0.0)
    plain = batch(PriorConfig(**base), frames, starts, 3).numpy()[..., 0]
    fast = batch(PriorConfig(**base, speed_range=(0.8, 1.25)), frames, starts, 3).numpy()[..., 0]
    np.testing.assert_array_equal(fast[:, 0], plain[:, 0])  # the same starts
    steps = np.abs(np.diff(fast, axis=1)).mean(axis=1)  # each window's speed
    assert steps.min() >= 0.8 - 1e-5 and steps.max() <= 1.25 + 1e-5 and steps.std() > 0.1
    assert np.all(np.abs(np.diff(plain, axis=1)) == 1)
    assert PriorConfig.from_dict(PriorConfig(**base, speed_range=(0.8, 1.25)).to_dict()).speed_range == (0.8, 1.25)


def test_rotation_axis_is_checked():
    check_axis("", "cfg")
    check_axis("y", "cfg")
    with pytest.raises(ValueError, match="rotate_axis"):
        check_axis("up", "cfg")


def test_training_batches_turn_the_windows_and_keep_every_other_draw():
    """A diffusion run with rotate_axis draws the same windows, masks, steps and noise as without it; only the
    poses are turned (about z: heights equal, horizontal distances to the root kept)."""
    import torch
    from training.batches import BatchSource, Windows
    from training.train_config import TrainConfig

    rng = np.random.default_rng(0)
    seqs = [rng.normal(size=(40, 22, 3)).astype(np.float32) for _ in range(3)]
    wins = Windows(seqs, 12, 1)
    plain = TrainConfig(
        role="long", obs_len=8, pred_len=4, batch_size=5, mask_mix=[["none", 1.0], ["random_joints", 1.0]]
    )
    turned = TrainConfig(**{**plain.__dict__, "rotate_axis": "z"})
    a = BatchSource(plain, wins, 50, 10).batch(2, 3)
    b = BatchSource(turned, wins, 50, 10).batch(2, 3)
    for i in (2, 3, 4):  # mask, t, eps
        assert torch.equal(a[i], b[i])
    xa, xb = (x.reshape(5, 22, 3, 12) for x in (a[0], b[0]))  # (B, J, 3, L)
    assert torch.equal(xa[:, :, 2], xb[:, :, 2]) and not torch.allclose(xa, xb)
    torch.testing.assert_close(xa[:, :, :2].norm(dim=2), xb[:, :, :2].norm(dim=2))
    with pytest.raises(ValueError, match="rotate_axis"):
        TrainConfig(rotate_axis="vertical")


def test_arrival_keys_are_the_last_observed_pose_and_its_velocity():
    wins = np.arange(2 * 6 * 2 * 3, dtype=np.float64).reshape(2, 6, 2, 3)
    keys = arrival_keys(wins, 4, velocity_weight=5.0)
    np.testing.assert_array_equal(keys[:, :6], wins[:, 3].reshape(2, 6))
    np.testing.assert_array_equal(keys[:, 6:], 5.0 * (wins[:, 3] - wins[:, 1]).reshape(2, 6))


def test_future_neighbours_are_the_nearest_outside_the_windows_own_stretch():
    # one key coordinate: window i's key is keys[i]; windows 0-3 of sequence 0 (starts 0-3), 4-6 of sequence 1
    keys = np.array([[0.0], [0.1], [0.2], [5.0], [0.05], [3.0], [0.3]])
    seq = np.array([0, 0, 0, 0, 1, 1, 1])
    start = np.array([0, 1, 2, 40, 0, 1, 2])
    nn = future_neighbours(keys, seq, start, k=2, exclude_frames=30)
    # window 0: its own sequence's windows 1 and 2 start within 30 frames: out; the nearest others are 4 (0.05) and 6
    np.testing.assert_array_equal(nn[0], [4, 6])
    np.testing.assert_array_equal(nn[3], [5, 6])  # window 3 starts 40 frames on: sequence 0's others are in
    np.testing.assert_array_equal(future_neighbours(keys, seq, start, k=2, exclude_frames=1)[0], [4, 1])
    for i, row in enumerate(nn):  # never itself, never its own stretch
        assert i not in row and not any(seq[j] == seq[i] and abs(start[j] - start[i]) < 30 for j in row)
    with pytest.raises(ValueError, match="fewer than 5"):  # window 0 has 4 windows outside its stretch
        future_neighbours(keys, seq, start, k=5, exclude_frames=30)
    with pytest.raises(ValueError, match="k must be"):
        future_neighbours(keys, seq, start, k=0, exclude_frames=30)


def test_swapped_futures_join_the_window_and_take_the_donors_motion():
    rng = np.random.default_rng(0)
    wins, donors = rng.normal(size=(2, 3, 10, 4, 3)).astype(np.float32)
    out = swap_futures(wins, donors, obs_len=4)
    np.testing.assert_array_equal(out[:, :4], wins[:, :4])  # the past is the window's own
    np.testing.assert_array_equal(out[:, -1], donors[:, -1])  # the offset is gone at the end
    # the first future frame: the donor's, moved by 5/6 of the offset between the two last observed poses
    np.testing.assert_allclose(out[:, 4], donors[:, 4] + 5 / 6 * (wins[:, 3] - donors[:, 3]), atol=1e-6)
    # the donor's frame-to-frame motion, less a constant share of the offset per frame
    step = (wins[:, 3] - donors[:, 3]) / 6
    np.testing.assert_allclose(np.diff(out[:, 4:], axis=1), np.diff(donors[:, 4:], axis=1) - step[:, None], atol=1e-5)
    assert out.dtype == np.float32


def test_training_batches_swap_a_share_of_the_futures_and_keep_every_other_draw():
    """future_swap replaces the future of about that share of the windows by a near window's, joined to its past;
    the rest of the batch (masks, steps, noise) and the pasts are those of the run without it, and the batch is a
    pure function of (seed, epoch, batch index)."""
    import torch
    from training.batches import BatchSource, Windows
    from training.train_config import TrainConfig

    rng = np.random.default_rng(0)
    seqs = [np.cumsum(rng.normal(scale=0.01, size=(120, 22, 3)), axis=0).astype(np.float32) for _ in range(3)]
    wins = Windows(seqs, 12, 1)
    plain = TrainConfig(
        role="long", obs_len=8, pred_len=4, batch_size=64, mask_mix=[["none", 1.0], ["random_joints", 1.0]]
    )
    swapped = TrainConfig(**{**plain.__dict__, "future_swap": 0.5, "future_swap_k": 3})
    a = BatchSource(plain, wins, 50, 10).batch(2, 3)
    source = BatchSource(swapped, wins, 50, 10)
    b = source.batch(2, 3)
    for i in (1, 2, 3, 4):  # observation, mask, t, eps
        assert torch.equal(a[i], b[i])
    assert torch.equal(a[0][..., :8], b[0][..., :8])
    changed = (a[0][..., 8:] != b[0][..., 8:]).flatten(1).any(1)
    assert 16 < int(changed.sum()) < 48  # about half of 64
    assert all(torch.equal(x, y) for x, y in zip(b, BatchSource(swapped, wins, 50, 10).batch(2, 3)))
    # each swapped future is one of the window's neighbours' futures, joined (swap_futures)
    k = int(np.flatnonzero(changed.numpy())[0])
    window = a[0][k].T.reshape(12, 22, 3).numpy()
    candidates = [
        swap_futures(window[None], wins.gather(np.array([j])), 8)[0] for j in source.neighbours[_row_of(wins, window)]
    ]
    assert any(np.allclose(c, b[0][k].T.reshape(12, 22, 3).numpy(), atol=1e-6) for c in candidates)
    with pytest.raises(ValueError, match="future_swap"):
        TrainConfig(future_swap=1.5)
    with pytest.raises(ValueError, match="future_swap_k"):
        TrainConfig(future_swap=0.5, future_swap_k=0)


def test_training_batches_add_further_imle_targets_and_keep_every_other_draw():
    """imle_targets M: the batch of the run without them (the same windows, swaps, turns, masks, steps, noise and
    candidates) followed by M - 1 further futures per window: its own past, turned with it, joined to the future
    of one of its neighbours."""
    import torch
    from training.batches import BatchSource, Windows
    from training.train_config import TrainConfig

    rng = np.random.default_rng(1)
    seqs = [np.cumsum(rng.normal(scale=0.01, size=(120, 22, 3)), axis=0).astype(np.float32) for _ in range(3)]
    wins = Windows(seqs, 12, 1)
    plain = TrainConfig(
        role="long",
        obs_len=8,
        pred_len=4,
        batch_size=16,
        rotate_axis="z",
        future_swap=0.5,
        future_swap_k=3,
        imle_samples=2,
        diffusion={"prediction_type": "sample"},
    )
    more = TrainConfig(**{**plain.__dict__, "imle_targets": 3})
    a = BatchSource(plain, wins, 50, 10).batch(1, 2)
    source = BatchSource(more, wins, 50, 10)
    b = source.batch(1, 2)
    assert len(a) == 6 and len(b) == 7
    assert all(torch.equal(x, y) for x, y in zip(a, b))
    others = b[6]
    assert others.shape == (2, *b[0].shape)
    assert torch.equal(others[..., :8], b[0][..., :8].expand(2, -1, -1, -1))  # the window's own (turned) past
    assert (others[..., 8:] != b[0][..., 8:]).flatten(2).any(2).float().mean() > 0.5
    assert all(torch.equal(x, y) for x, y in zip(b, BatchSource(more, wins, 50, 10).batch(1, 2)))
    # unturned, each further future is one of the window's neighbours' futures, joined (swap_futures)
    flat = TrainConfig(**{**more.__dict__, "rotate_axis": "", "future_swap": 0.0})
    c = BatchSource(flat, wins, 50, 10).batch(1, 2)
    window = c[0][0].T.reshape(12, 22, 3).numpy()
    joined = [
        swap_futures(window[None], wins.gather(np.array([j])), 8)[0] for j in source.neighbours[_row_of(wins, window)]
    ]
    for m in range(2):
        got = c[6][m, 0].T.reshape(12, 22, 3).numpy()
        assert any(np.allclose(j, got, atol=1e-6) for j in joined)


def _row_of(wins, window: np.ndarray) -> int:
    """The index of the window (L, J, 3) among ``wins``' windows."""
    all_w = wins.gather(np.arange(len(wins)))
    return int(np.flatnonzero(np.all(all_w == window, axis=(1, 2, 3)))[0])


def test_action_balance_draws_each_action_by_its_weight_and_stays_seeded():
    """action_weights: n ** -balance per window, n its action's windows; BatchSource with weights draws an epoch's
    rows with replacement by them (every action alike at 1), from the (seed, epoch) stream as the permutation did."""
    from training.batches import BatchSource, Windows, action_weights
    from training.train_config import TrainConfig

    rng = np.random.default_rng(0)
    seqs = [rng.normal(size=(200, 2, 3)).astype(np.float32), rng.normal(size=(30, 2, 3)).astype(np.float32)]
    wins = Windows(seqs, 12, 1)  # 189 windows of "Walk", 19 of "Box"
    actions = np.asarray(["Walk", "Box"])[wins.index[:, 0]]
    np.testing.assert_allclose(action_weights(actions, 0.0), 1 / len(wins))
    w = action_weights(actions, 1.0)
    assert w[actions == "Box"].sum() == pytest.approx(0.5) and w.sum() == pytest.approx(1.0)
    half = action_weights(actions, 0.5)
    assert half[actions == "Box"].sum() == pytest.approx(19**0.5 / (19**0.5 + 189**0.5))
    cfg = TrainConfig(role="long", obs_len=8, pred_len=4, batch_size=len(wins))
    plain, balanced = BatchSource(cfg, wins, 50, 1), BatchSource(cfg, wins, 50, 1, w)
    plain.batch(0, 0)
    assert sorted(plain._perm) == list(range(len(wins)))  # uniform: each window once per epoch
    balanced.batch(0, 0)
    drawn = balanced._perm
    assert 0.35 < np.mean(actions[drawn] == "Box") < 0.65  # about half, against 19 of 208 uniform
    again = BatchSource(cfg, wins, 50, 1, w)
    again.batch(0, 0)
    np.testing.assert_array_equal(again._perm, drawn)
    with pytest.raises(ValueError, match="one per window"):
        BatchSource(cfg, wins, 50, 1, w[:-1])
    for bad in (
        {"action_balance": 1.5, "dataset": "humaneva"},
        {"action_balance": 1.0},  # Human3.6M
        {"action_balance": 1.0, "dataset": "humaneva", "h36m_share": 0.5},
    ):
        with pytest.raises(ValueError, match="action_balance"):
            TrainConfig(role="long", obs_len=16, pred_len=59, **bad)
