"""training.gpu_burst's arithmetic: the step rate read off a training log, and the schedule sized to a budget."""
import pytest

pytest.importorskip("torch")
from training.gpu_burst import sized, step_rate  # noqa: E402

# lines as training.train prints them (the periodic ones, then a stop by the time budget)
LOG = """long: 126,753 parameters, 2,612 training windows, 112 validation windows, 100 steps/epoch x 1000 epochs
epoch 0 batch 100/100 loss 0.0469 lr 3.3e-04 10s
epoch 1 batch 100/100 loss 0.0461 lr 6.7e-04 18s
epoch 2 batch 100/100 loss 0.0455 lr 1.0e-03 26s
stopped after 0.50 min of training at epoch 3 batch 40: val loss 0.0535
"""


def test_step_rate_leaves_out_the_warm_up():
    # between the 2nd and the last periodic line: 100 steps in 8 s (the first 10 s held the warm-up)
    assert step_rate(LOG, 100) == pytest.approx(100 / 8)


def test_step_rate_falls_back_on_the_stop_line_and_says_none_without_one():
    short = LOG.splitlines()[0] + "\n" + LOG.splitlines()[-1]
    assert step_rate(short, 100) == pytest.approx(340 / 30)
    assert step_rate("Traceback (most recent call last):\n", 100) is None


def test_sized_fits_the_epochs_into_the_seconds():
    cfg = {"epochs": 20, "steps_per_epoch": 100, "batch_size": 256}
    d = sized(cfg, rate=10.0, seconds=400, safety=0.95)
    assert d["steps_per_epoch"] == 190 and d["epochs"] == 20 and cfg["steps_per_epoch"] == 100
    assert sized(cfg, rate=0.1, seconds=10, safety=1.0)["steps_per_epoch"] == 20   # never below 20
