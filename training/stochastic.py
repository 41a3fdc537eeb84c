"""Stochastic-prediction metrics of the DLow / GSPS protocol (spec section 6), numpy.

Shapes: ``pred`` (S, t_pred, D) samples, ``gt`` (t_pred, D) and ``gt_multi`` (M, t_pred, D), with D the
flattened pose (e.g. 48 for Human3.6M Setting-A, 42 for HumanEva-I), in metres. The error of one
sample at one frame is the **L2 norm of the whole D-dim pose difference** (not a per-joint mean).

* APD: mean L2 distance over all unordered pairs of flattened (t_pred * D) samples; 0 when S = 1.
* ADE: min over samples of the mean over frames of the per-frame error.
* FDE: min over samples of the last frame's error.
* MMADE / MMFDE: ADE / FDE against each multimodal future, averaged over those futures.

``apd_top50`` is MotionDiff's **non-standard** diversity (mean of the 50 largest pairwise
distances); report it only when comparing with MotionDiff's numbers, and say so.
Papers print these numbers x1000 (e.g. DLow's ADE 0.425 appears as 425).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

METRIC_KEYS = ("APD", "ADE", "FDE", "MMADE", "MMFDE")


def _as_samples(pred) -> np.ndarray:
    pred = np.asarray(pred, dtype=np.float64)
    if pred.ndim != 3:
        raise ValueError(f"pred must be (S, t_pred, D), got {pred.shape}")
    return pred


def pairwise_distances(pred) -> np.ndarray:
    """The S (S - 1) / 2 distances between flattened samples, in ``scipy.spatial.distance.pdist`` order."""
    pred = _as_samples(pred)
    flat = pred.reshape(pred.shape[0], -1)
    s = flat.shape[0]
    # Row-wise differences (exact; avoids the cancellation of the Gram-matrix formula).
    out = np.empty(s * (s - 1) // 2)
    pos = 0
    for a in range(s - 1):
        d = np.linalg.norm(flat[a + 1 :] - flat[a], axis=1)
        out[pos : pos + d.size] = d
        pos += d.size
    return out


def apd(pred) -> float:
    """Average pairwise distance (DLow ``compute_diversity``); 0.0 for a single sample."""
    d = pairwise_distances(pred)
    return float(d.mean()) if d.size else 0.0


def apd_top50(pred, k: int = 50) -> float:
    """NON-STANDARD: MotionDiff's diversity, the mean of the ``k`` (50) largest pairwise distances.

    With 50 samples there are 1225 pairs, so this is much larger than the standard ``apd``.
    0.0 for a single sample; all pairs when there are fewer than ``k``.
    """
    d = pairwise_distances(pred)
    if d.size == 0:
        return 0.0
    return float(np.sort(d)[::-1][:k].mean())


def _frame_errors(pred, gt) -> np.ndarray:
    """(S, t_pred) per-frame L2 norms of the flattened pose difference."""
    pred = _as_samples(pred)
    gt = np.asarray(gt, dtype=np.float64)
    if gt.shape != pred.shape[1:]:
        raise ValueError(f"gt {gt.shape} does not match samples {pred.shape[1:]}")
    return np.linalg.norm(pred - gt[None], axis=2)


def ade(pred, gt) -> float:
    """Best-of-S average displacement error: min_s mean_t ||pred[s, t] - gt[t]||."""
    return float(_frame_errors(pred, gt).mean(axis=1).min())


def fde(pred, gt) -> float:
    """Best-of-S final displacement error: min_s ||pred[s, -1] - gt[-1]||."""
    return float(_frame_errors(pred, gt)[:, -1].min())


def _check_multi(gt_multi) -> np.ndarray:
    gt_multi = np.asarray(gt_multi, dtype=np.float64)
    if gt_multi.ndim != 3 or gt_multi.shape[0] == 0:
        raise ValueError(f"gt_multi must be a non-empty (M, t_pred, D) array, got {gt_multi.shape}")
    return gt_multi


def mmade(pred, gt_multi) -> float:
    """Multimodal ADE: ``ade(pred, g)`` averaged over the M futures g of ``gt_multi`` (M, t_pred, D)."""
    return _multimodal(pred, gt_multi)[0]


def mmfde(pred, gt_multi) -> float:
    """Multimodal FDE: ``fde(pred, g)`` averaged over the M futures g of ``gt_multi``."""
    return _multimodal(pred, gt_multi)[1]


def _multimodal(pred, gt_multi, chunk: int = 16) -> tuple[float, float]:
    """``(mmade(pred, gt_multi), mmfde(pred, gt_multi))``: each future's ``ade`` / ``fde``, ``chunk`` futures at a
    time in one pass over the errors (Setting-A's sets hold 59 futures on average)."""
    pred, gt_multi = _as_samples(pred), _check_multi(gt_multi)
    if gt_multi.shape[1:] != pred.shape[1:]:
        raise ValueError(f"gt_multi {gt_multi.shape} does not match samples {pred.shape[1:]}")
    ades, fdes = [], []
    for a in range(0, len(gt_multi), chunk):
        e = np.linalg.norm(pred[None] - gt_multi[a : a + chunk, None], axis=3)  # (m, S, t_pred)
        ades.append(e.mean(axis=2).min(axis=1))
        fdes.append(e[:, :, -1].min(axis=1))
    return float(np.mean(np.concatenate(ades))), float(np.mean(np.concatenate(fdes)))


def evaluate_stochastic(
    preds: Sequence[np.ndarray],
    gts: Sequence[np.ndarray],
    gt_multis: Sequence[np.ndarray],
    include_apd_top50: bool = False,
    per_window: bool = False,
) -> dict:
    """Average each metric over the test windows (each window weighs 1, as DLow's ``AverageMeter``).

    ``preds[i]`` (S, t_pred, D), ``gts[i]`` (t_pred, D), ``gt_multis[i]`` (M_i, t_pred, D).
    Returns ``{"APD", "ADE", "FDE", "MMADE", "MMFDE"}`` (plus ``"APD_top50_nonstandard"`` if asked), in
    the data's units (metres); with ``per_window`` also ``"per_window"``: each metric's value on every window,
    in order (what ``training.compare`` pairs two models on).
    """
    if not (len(preds) == len(gts) == len(gt_multis)):
        raise ValueError(f"got {len(preds)} predictions, {len(gts)} ground truths, {len(gt_multis)} multimodal sets")
    if len(preds) == 0:
        raise ValueError("no windows to evaluate")
    values: dict[str, list[float]] = {k: [] for k in METRIC_KEYS}
    top50 = 0.0
    for pred, gt, gt_multi in zip(preds, gts, gt_multis):
        values["APD"].append(apd(pred))
        values["ADE"].append(ade(pred, gt))
        values["FDE"].append(fde(pred, gt))
        mm_ade, mm_fde = _multimodal(pred, gt_multi)
        values["MMADE"].append(mm_ade)
        values["MMFDE"].append(mm_fde)
        if include_apd_top50:
            top50 += apd_top50(pred)
    n = len(preds)
    out: dict = {k: sum(v) / n for k, v in values.items()}
    if include_apd_top50:
        out["APD_top50_nonstandard"] = top50 / n
    if per_window:
        out["per_window"] = values
    return out
