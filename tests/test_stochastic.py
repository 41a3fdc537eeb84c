"""Tests of the DLow / GSPS stochastic metrics (training/stochastic.py) on hand-made arrays."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from training.stochastic import (
    ade,
    apd,
    apd_top50,
    evaluate_stochastic,
    fde,
    mmade,
    mmfde,
    pairwise_distances,
)


def _samples_from_flat(vectors, t_pred=2, d=3) -> np.ndarray:
    """Samples whose flattened (t_pred * d) vectors are given (padded with zeros)."""
    out = np.zeros((len(vectors), t_pred * d))
    for i, v in enumerate(vectors):
        out[i, : len(v)] = v
    return out.reshape(len(vectors), t_pred, d)


def test_apd_three_samples_3_4_5():
    # flattened samples 0, 3 e_0, 4 e_5: pairwise distances 3, 4, 5 -> mean 4
    pred = _samples_from_flat([[0.0], [3.0], [0, 0, 0, 0, 0, 4.0]])
    np.testing.assert_allclose(sorted(pairwise_distances(pred)), [3.0, 4.0, 5.0])
    assert apd(pred) == pytest.approx(4.0)


def test_apd_two_samples_and_single_sample():
    pred = np.zeros((2, 5, 4))
    pred[1] = 0.5  # 20 coordinates differing by 0.5 -> distance 0.5 * sqrt(20)
    assert apd(pred) == pytest.approx(0.5 * math.sqrt(20))
    assert apd(pred[:1]) == 0.0
    assert apd_top50(pred[:1]) == 0.0
    assert apd(np.repeat(pred[:1], 4, axis=0)) == 0.0


def test_apd_is_over_whole_flattened_sequence_not_per_frame():
    pred = np.zeros((2, 2, 1))
    pred[1] = [[3.0], [4.0]]  # per-frame distances 3 and 4; flattened distance 5
    assert apd(pred) == pytest.approx(5.0)


def test_apd_top50_nonstandard():
    pred = _samples_from_flat([[0.0], [3.0], [0, 0, 0, 0, 0, 4.0]])
    assert apd_top50(pred) == pytest.approx(4.0)  # fewer than 50 pairs: all of them
    rng = np.random.default_rng(0)
    pred = rng.normal(size=(20, 3, 2))  # 190 pairs
    brute = sorted((np.linalg.norm(a - b) for a, b in itertools.combinations(pred.reshape(20, -1), 2)), reverse=True)
    assert apd_top50(pred) == pytest.approx(np.mean(brute[:50]))
    assert apd(pred) == pytest.approx(np.mean(brute))
    assert apd_top50(pred) > apd(pred)


def test_ade_fde_min_taken_separately():
    gt = np.zeros((2, 2))
    pred = np.array(
        [
            [[3.0, 4.0], [0.0, 0.0]],  # per-frame errors 5, 0 -> mean 2.5, last 0
            [[1.0, 0.0], [0.0, 2.0]],  # per-frame errors 1, 2 -> mean 1.5, last 2
        ]
    )
    assert ade(pred, gt) == pytest.approx(1.5)
    assert fde(pred, gt) == pytest.approx(0.0)
    assert ade(pred[:1], gt) == pytest.approx(2.5)
    assert fde(pred[1:], gt) == pytest.approx(2.0)


def test_ade_uses_norm_of_flattened_pose_not_per_joint_mean():
    gt = np.ones((1, 6))
    pred = gt[None].copy()
    pred[0, 0, 0] += 3.0  # joint 0 off by 3
    pred[0, 0, 4] += 4.0  # joint 1 off by 4: per-joint mean 3.5, flattened norm 5
    assert ade(pred, gt) == pytest.approx(5.0)
    assert fde(pred, gt) == pytest.approx(5.0)


def test_mmade_mmfde_average_over_futures():
    pred = np.array(
        [
            [[0.0], [0.0]],
            [[2.0], [2.0]],
        ]
    )  # (S=2, t_pred=2, D=1)
    gt_multi = np.array(
        [
            [[0.0], [1.0]],  # s0: errors 0,1 -> ade .5 fde 1; s1: 2,1 -> ade 1.5 fde 1 => ade .5, fde 1
            [[2.0], [3.0]],  # s0: 2,3 -> 2.5, 3; s1: 0,1 -> .5, 1                     => ade .5, fde 1
            [[1.0], [1.0]],  # s0: 1,1 -> 1, 1;   s1: 1,1 -> 1, 1                       => ade 1, fde 1
        ]
    )
    assert mmade(pred, gt_multi) == pytest.approx((0.5 + 0.5 + 1.0) / 3)
    assert mmfde(pred, gt_multi) == pytest.approx(1.0)
    assert mmade(pred, gt_multi[:1]) == pytest.approx(ade(pred, gt_multi[0]))


def test_evaluate_stochastic_averages_windows():
    w1 = np.zeros((2, 2, 1)), np.zeros((2, 1))
    pred2 = np.array([[[0.0], [0.0]], [[0.0], [4.0]]])
    gt2 = np.array([[1.0], [1.0]])
    gt_multi2 = np.stack([gt2, np.array([[0.0], [4.0]])])
    res = evaluate_stochastic([w1[0], pred2], [w1[1], gt2], [w1[1][None], gt_multi2])
    assert set(res) == {"APD", "ADE", "FDE", "MMADE", "MMFDE"}
    # window 1: everything 0. window 2: APD 4; ADE min(1, (1+3)/2)=1; FDE min(1, 3)=1;
    # MMADE mean(1, 0)=0.5; MMFDE mean(1, 0)=0.5
    assert res["APD"] == pytest.approx(2.0)
    assert res["ADE"] == pytest.approx(0.5)
    assert res["FDE"] == pytest.approx(0.5)
    assert res["MMADE"] == pytest.approx(0.25)
    assert res["MMFDE"] == pytest.approx(0.25)
    res2 = evaluate_stochastic([pred2], [gt2], [gt_multi2], include_apd_top50=True)
    assert res2["APD_top50_nonstandard"] == pytest.approx(4.0)


def test_shape_errors():
    with pytest.raises(ValueError):
        ade(np.zeros((2, 3, 4)), np.zeros((3, 5)))
    with pytest.raises(ValueError):
        apd(np.zeros((3, 4)))
    with pytest.raises(ValueError):
        mmade(np.zeros((2, 3, 4)), np.zeros((0, 3, 4)))
    with pytest.raises(ValueError):
        evaluate_stochastic([np.zeros((2, 3, 4))], [], [])


def test_perfect_sample_gives_zero_error_with_multimodal_gt():
    from training.data.humaneva import multimodal_gt

    rng = np.random.default_rng(1)
    windows = rng.normal(scale=0.05, size=(6, 75, 14, 3))
    mm = multimodal_gt(windows, 15, threshold=0.5)
    gts = [w[15:].reshape(60, 42) for w in windows]
    preds = [np.stack([g, g + 1.0]) for g in gts]
    res = evaluate_stochastic(preds, gts, mm)
    assert res["ADE"] == pytest.approx(0.0) and res["FDE"] == pytest.approx(0.0)
    assert res["APD"] == pytest.approx(math.sqrt(60 * 42))
    # each window's own future is among its multimodal futures (distance 0), the others are not: MMADE is
    # the mean, over windows and their futures g, of the best sample's mean per-frame distance to g
    assert all(any(np.array_equal(g, gt) for g in m) for m, gt in zip(mm, gts))
    mmade = np.mean(
        [np.mean([min(np.linalg.norm(p - g, axis=1).mean() for p in pred) for g in m]) for pred, m in zip(preds, mm)]
    )
    assert res["MMADE"] == pytest.approx(mmade)


def test_oracle_best_picks_each_windows_sample_by_its_mean_error():
    """training.metrics.oracle_best (the Human3.6M oracle best of n): per window, all frames of the one sample whose
    mean error over the frames is lowest, even where another sample is lower at some frame."""
    from training.metrics import oracle_best

    errs = np.array(
        [
            [[1.0, 9.0], [5.0, 5.0]],  # sample 0: window 0 mean 5, window 1 mean 5
            [[4.0, 4.0], [2.0, 7.0]],
        ]
    )  # sample 1: window 0 mean 4, window 1 mean 4.5
    np.testing.assert_array_equal(oracle_best(errs), [[4.0, 4.0], [2.0, 7.0]])
    errs[1, 1] = [6.0, 6.0]  # now sample 0 is window 1's best
    np.testing.assert_array_equal(oracle_best(errs), [[4.0, 4.0], [5.0, 5.0]])
