import numpy as np
import pytest

from conftest import import_torch

torch = import_torch("the training code's noise schedule (training/diffusion.py)")

from training.diffusion import DiffusionConfig, Schedule, make_betas, step_pairs, timesteps  # noqa: E402


def test_cosine_betas_match_spec_section_1_6():
    s = Schedule(DiffusionConfig())
    assert s.betas.dtype == np.float64 and s.betas.shape == (50,)
    assert s.betas[0] == pytest.approx(1.75e-3, abs=5e-6)
    assert s.betas[1] == pytest.approx(3.69e-3, abs=5e-6)
    assert np.all(s.betas[-3:] == 0.5) and s.betas[-4] < 0.5
    assert s.alphas_cumprod[0] == pytest.approx(0.99825, abs=5e-6)
    assert s.alphas_cumprod[-1] == pytest.approx(1.09e-3, rel=5e-3)
    assert np.all(np.diff(s.betas) >= 0)


def test_linear_and_quad_schedules():
    lin = make_betas(DiffusionConfig(num_train_timesteps=100, beta_schedule="linear", beta_start=1e-4, beta_end=0.05))
    assert lin[0] == 1e-4 and lin[-1] == pytest.approx(0.05) and len(lin) == 100
    quad = make_betas(DiffusionConfig(beta_schedule="quad", beta_start=1e-4, beta_end=0.5))
    assert quad[0] == pytest.approx(1e-4) and quad[-1] == pytest.approx(0.5)
    assert np.allclose(np.sqrt(quad), np.linspace(0.01, np.sqrt(0.5), 50))


def test_bad_schedule_and_stored_betas_rejected():
    with pytest.raises(ValueError, match="beta_schedule"):
        make_betas(DiffusionConfig(beta_schedule="sigmoid"))
    d = DiffusionConfig().to_dict()
    d["betas"][3] += 1e-6
    with pytest.raises(ValueError, match="betas"):
        DiffusionConfig.from_dict(d)
    assert DiffusionConfig.from_dict(DiffusionConfig().to_dict()) == DiffusionConfig()


@pytest.mark.parametrize(
    "spacing,n,expected",
    [
        ("trailing", 5, [49, 39, 29, 19, 9]),
        ("leading", 5, [40, 30, 20, 10, 0]),
        ("linspace", 5, [49, 37, 24, 12, 0]),
        ("trailing", 50, list(range(49, -1, -1))),
        ("leading", 50, list(range(49, -1, -1))),
    ],
)
def test_timestep_spacing(spacing, n, expected):
    assert timesteps(50, n, spacing) == expected


def test_step_pairs_end_at_minus_one_and_reject_bad_counts():
    assert step_pairs(50, "ddim", 5, "trailing")[-1] == (9, -1)
    assert len(step_pairs(50, "ddpm", None, "trailing")) == 50
    for bad in (0, -1, 51):
        with pytest.raises(ValueError, match="num_inference_steps"):
            timesteps(50, bad)
    with pytest.raises(ValueError, match="timestep_spacing"):
        timesteps(50, 5, "uniform")
