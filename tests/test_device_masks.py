"""training/device_masks.py (batched masks drawn on the device) against training/masks.py (the per-window
numpy reference): the same distributions, compared on statistics with Monte-Carlo tolerances."""
import numpy as np
import pytest
import torch

from training import masks as M
from training.device_masks import MaskMix, corrupt_batch

OBS, SEQ, J, N = 50, 55, 22, 3000


def device_draws(pattern, rate=None, n=N, seed=0):
    entry = [pattern, 1.0] + ([] if rate is None else [list(rate) if isinstance(rate, tuple) else rate])
    mask, _ = MaskMix([entry], OBS, SEQ).draw(n, torch.Generator().manual_seed(seed))
    return mask.numpy()


def reference_draws(pattern, rate=None, n=N, seed=1):
    g = np.random.default_rng(seed)
    return np.stack([M.make_mask(pattern, OBS, SEQ, g, rate=rate) for _ in range(n)])


def close(a, b, what, k=5.0):
    """Means of per-window statistics a, b (n,) or (n, d) agree within k standard errors of their difference
    (plus a floor for statistics that are constant in both)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    se = np.sqrt(a.var(0) / len(a) + b.var(0) / len(b))
    diff = np.abs(a.mean(0) - b.mean(0))
    assert np.all(diff <= k * se + 1e-9), f"{what}: max diff {diff.max():.4g} vs {k} se {np.max(k * se):.4g}"


CASES = [(p, None) for p in M.PATTERNS] + [("random_leg_arm", 0.2), ("consecutive_frames", 0.3),
                                           ("random_joints", 0.6), ("random_joints", (0.05, 0.5))]


@pytest.mark.parametrize("pattern,rate", CASES, ids=[f"{p}-{r}" for p, r in CASES])
def test_same_distribution_as_the_reference(pattern, rate):
    dev, ref = device_draws(pattern, rate), reference_draws(pattern, rate)
    assert dev.shape == ref.shape == (N, SEQ, J) and dev.dtype == np.float32
    assert np.all(dev[:, OBS:] == 0) and set(np.unique(dev)) <= {0.0, 1.0}
    hd, hr = 1 - dev[:, :OBS], 1 - ref[:, :OBS]
    close(hd.reshape(N, -1).sum(1), hr.reshape(N, -1).sum(1), "hidden entries per window")
    close(hd.reshape(N, -1).sum(1) ** 2, hr.reshape(N, -1).sum(1) ** 2, "its second moment (the spread)")
    close(hd.mean(2), hr.mean(2), "per-frame profile")
    close(hd.mean(1), hr.mean(1), "per-joint profile")
    # the support: which joints a pattern may hide, and how many frames it touches per window
    assert set(np.flatnonzero(hd.any((0, 1)))) == set(np.flatnonzero(hr.any((0, 1))))
    frames_d, frames_r = hd.any(2).sum(1), hr.any(2).sum(1)
    if pattern in ("random_leg_arm", "random_frames", "structured_leg", "consecutive_frames"):
        assert set(frames_d) == set(frames_r) and len(set(frames_d)) == 1      # exactly n frames, every window
    if pattern in ("structured_leg", "consecutive_frames"):
        rows = hd.any(2)
        first, last = rows.argmax(1), OBS - 1 - rows[:, ::-1].argmax(1)
        assert np.all(last - first + 1 == frames_d)                            # one contiguous block
        assert first.min() == 0 and last.max() == OBS - 1                      # starts over the whole range


def test_mixture_proportions_follow_the_weights():
    mix = MaskMix([["none", 3.0], ["consecutive_frames", 1.0]], OBS, SEQ)
    mask, sigma = mix.draw(8000, torch.Generator().manual_seed(0))
    frac_occluded = float((mask[:, :OBS] == 0).any(2).any(1).float().mean())
    assert abs(frac_occluded - 0.25) < 5 * np.sqrt(0.25 * 0.75 / 8000)
    assert torch.all(sigma == 0)


def test_corrupt_batch_noise_and_zeros():
    """Hidden entries and the future are exactly 0; the noisy windows (about half here) carry N(0, 50 mm)
    noise in metres on their visible entries, the other windows their clean values bit for bit."""
    wins = torch.randn(2000, SEQ, J, 3, generator=torch.Generator().manual_seed(3))
    mix = MaskMix([["noisy_50", 1.0], ["random_leg_arm", 1.0]], OBS, SEQ)
    observed, mask = corrupt_batch(wins, mix, torch.Generator().manual_seed(4))
    vis = mask[..., None].expand_as(wins) > 0
    assert torch.all(observed[~vis] == 0)
    diff = observed - wins
    moved = (diff.abs() * vis).flatten(1).amax(1) > 0
    assert 0.45 < float(moved.float().mean()) < 0.55
    std = float(diff[moved][vis[moved]].std())
    assert abs(std - 0.05) < 0.001, std
    assert torch.equal(observed[~moved][vis[~moved]], wins[~moved][vis[~moved]])


def test_deterministic_per_seed():
    mix = MaskMix([["random", 1.0], ["random_leg_arm", 1.0], ["noisy_25", 1.0]], OBS, SEQ)
    a = mix.draw(64, torch.Generator().manual_seed(7))
    b = mix.draw(64, torch.Generator().manual_seed(7))
    c = mix.draw(64, torch.Generator().manual_seed(8))
    assert all(torch.equal(x, y) for x, y in zip(a, b))
    assert not torch.equal(a[0], c[0])


@pytest.mark.parametrize("mix,word", [([["random_joints"]], "mask_mix entry"), ([["nope", 1.0]], "pattern must be one of"),
                                      ([["none", 1.0, 0.3]], "rate is not used"), ([["random_leg_arm", -1.0]], "weight"),
                                      ([["random_leg_arm", 1.0, 1.5]], "rate must be in"), ([], "empty"),
                                      ([["none", 0.0]], "sum to 0")])
def test_bad_mix_entries_are_refused(mix, word):
    with pytest.raises(ValueError, match=word):
        MaskMix(mix, OBS, SEQ)
