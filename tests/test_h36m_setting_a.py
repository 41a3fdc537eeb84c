"""Human3.6M Setting-A's data (training.data.h36m_setting_a): the world rotation integrated from the root's
increments, 16 root-relative joints in metres, DLow's test windows, and Zero-Velocity on them."""

import numpy as np
import pytest
from conftest import H36M_DIR, import_torch, needs_h36m

from training.data import h36m_setting_a as A
from training.data.kinematics import expmap_to_rotmat


def test_world_rotation_integrates_the_root_increments():
    step = np.array([0.0, 0.1, 0.0])  # the same turn about the vertical every frame
    rows = np.zeros((4, 99))
    rows[:, 3:6] = step
    r = A.world_rotations(rows[:, 3:6])
    one = expmap_to_rotmat(step[None])[0]
    assert np.allclose(r[0], one) and np.allclose(r[3], np.linalg.matrix_power(one, 4))


def test_positions_are_16_root_relative_joints_in_the_world_rotation():
    rows = np.zeros((3, 99))
    rows[:, 0:3] = [100.0, 200.0, 300.0]  # the translation is removed
    still = A.setting_a_positions(rows)
    assert still.shape == (3, 16, 3) and np.allclose(still[0], still[2])
    rows[1:, 3:6] = [0.0, np.pi / 2, 0.0]  # a quarter turn at frame 1, another at frame 2
    turned = A.setting_a_positions(rows)
    # the body keeps its shape (its distances to the pelvis) and turns with the root
    assert np.allclose(np.linalg.norm(turned, axis=2), np.linalg.norm(still, axis=2))
    assert not np.allclose(turned[1], still[1]) and np.allclose(
        turned[2] @ expmap_to_rotmat(rows[2:3, 3:6])[0].T, turned[1]
    )
    with pytest.raises(ValueError, match="99 values"):
        A.setting_a_positions(np.zeros((3, 98)))


@needs_h36m
def test_the_test_windows_and_zero_velocity_on_them():
    """S9 and S11 give 4,313 windows of 125 frames; Zero-Velocity on them scores ADE 0.563 / FDE 0.834 (the L2 norm
    of the flattened 48-dim pose), our protocol's reference numbers."""
    windows, actions = A.setting_a_test_windows(A.setting_a_sequences(data_dir=H36M_DIR))
    assert windows.shape == (4313, 125, 16, 3) and len(actions) == 4313 and "walking" in actions
    flat = windows.reshape(len(windows), 125, 48)
    zv = np.repeat(flat[:, A.SETTING_A_T_HIS - 1 : A.SETTING_A_T_HIS], A.SETTING_A_T_PRED, axis=1)
    err = np.linalg.norm(zv - flat[:, A.SETTING_A_T_HIS :], axis=2)
    assert err.mean() == pytest.approx(0.563, abs=5e-4) and err[:, -1].mean() == pytest.approx(0.834, abs=5e-4)
    with pytest.raises(FileNotFoundError, match="subjects"):
        A.setting_a_sequences(subjects=(99,), data_dir=H36M_DIR)


def test_multimodal_sets_are_dlow_s_without_copies():
    """MultimodalSets holds indices; each set equals training.data.humaneva.multimodal_gt's copy."""
    from training.data.humaneva import multimodal_gt
    from training.evaluate_stochastic import MultimodalSets

    rng = np.random.default_rng(0)
    wins = rng.normal(scale=0.2, size=(40, 9, 2, 3))
    sets, want = MultimodalSets(wins, 4), multimodal_gt(wins, 4)
    assert len(sets) == 40 and list(sets.sizes()) == [len(w) for w in want] and sets.sizes().max() > 1
    for i in range(40):
        np.testing.assert_array_equal(sets[i], want[i])


def test_the_multimodal_metrics_in_one_pass_equal_the_definitions():
    """MMADE / MMFDE: each future's ADE / FDE, averaged over the futures (37: more than one chunk of 16)."""
    from training.stochastic import ade, fde, mmade, mmfde

    rng = np.random.default_rng(1)
    pred, multi = rng.normal(size=(7, 5, 6)), rng.normal(size=(37, 5, 6))
    assert mmade(pred, multi) == pytest.approx(np.mean([ade(pred, g) for g in multi]), rel=1e-12)
    assert mmfde(pred, multi) == pytest.approx(np.mean([fde(pred, g) for g in multi]), rel=1e-12)
    with pytest.raises(ValueError, match="does not match"):
        mmade(pred, multi[:, :4])


@needs_h36m
def test_the_setting_a_protocol_scores_zero_velocity(tmp_path):
    """python -m training.evaluate --protocol h36m-a: Setting-A's block, its published rows, Zero-Velocity on a few
    windows (their multimodal sets from all 4,313), and a model of another protocol refused by name."""
    import json

    import_torch("training.evaluate")
    from training import evaluate

    out = tmp_path / "a.json"
    argv = ["--protocol", "h36m-a", "--data", str(H36M_DIR), "--max-windows", "12", "--quiet"]
    assert evaluate.main(argv + ["--baseline", "zero-velocity", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    p = r["protocol"]
    assert (p["dataset"], p["split"], p["t_his"], p["t_pred"], p["fps"]) == ("h36m-setting-a", "S9+S11", 25, 100, 50)
    assert p["windows"] == 12 and p["windows_in_protocol"] == 4313 and "48-dim" in p["units"]
    assert r["method"] == "zero-velocity" and r["stochastic"]["APD"] == 0.0
    assert (
        0.1 < r["stochastic"]["ADE"] < r["stochastic"]["FDE"] < 2.0 and len(r["stochastic"]["per_window"]["ADE"]) == 12
    )
    assert r["multimodal_sets"]["mean"] >= 1 and r["published"]["TCD"]["FDE"] == 0.396
    with pytest.raises(SystemExit, match="the Human3.6M Setting-A protocol (needs|gives) 25"):
        evaluate.main(argv + ["--model", "python/tcd/weights_humaneva", "--engine", "tcd"])
    with pytest.raises(SystemExit):
        evaluate.main(argv + ["--baseline", "zero-velocity", "--split", "Validate"])  # HumanEva-I's split


def test_a_setting_a_prior_config_names_its_subjects_and_data():
    """``"dataset": "h36m-a"``: 16 joints, the Setting-A training subjects only (S9 and S11 are the test), and the
    file's data block says 50 Hz, the h36m17 layout without its pelvis."""
    import_torch("the prior trainer")
    from training.prior import PriorConfig, dataset_joint_names
    from training.prior_net import prior_data_meta

    cfg = PriorConfig(dataset="h36m-a", obs_len=25, chunk=25, blocks=2, subjects=(1, 5, 6, 7, 8))
    assert cfg.num_joints == 16 and len(dataset_joint_names("h36m-a")) == 16
    meta = prior_data_meta(cfg)
    assert (meta["dataset"], meta["fps"], meta["layout"], meta["joint_names"][0]) == (
        "h36m-setting-a",
        50.0,
        "h36m17",
        dataset_joint_names("h36m-a")[0],
    )
    assert "S1,S5,S6,S7,S8" in meta["training_data"]
    for subjects in ((1, 9), ()):
        with pytest.raises(ValueError, match="Setting-A prior trains on subjects among"):
            PriorConfig(dataset="h36m-a", obs_len=25, chunk=25, subjects=subjects)


@needs_h36m
def test_a_setting_a_prior_trains_exports_and_scores_on_the_protocol(tmp_path):
    """A few iterations on S1's Setting-A sequences, exported: the engine's prior forecasts Setting-A's 100 frames
    from 25, as ``training.evaluate --protocol h36m-a --prior`` reads it."""
    import_torch("the prior trainer")
    from training import prior as P
    from training.evaluate_stochastic import SETTING_A, prior_forecast
    from training.export import export_prior

    cfg = P.PriorConfig(
        dataset="h36m-a", obs_len=25, chunk=25, blocks=2, batch_size=8, iterations=3, subjects=(1,), rotate_axis="y"
    )
    frames, starts = P.training_frames(cfg, str(H36M_DIR))
    assert frames.shape[1] == 48 and len(starts) > 1000
    P.train(cfg, tmp_path / "run", frames=(frames, starts), log=lambda m: None)
    path = export_prior(tmp_path / "run" / "last.pt", tmp_path / "model")
    obs = np.zeros((2, 25, 16, 3)) + np.linspace(0, 1, 48).reshape(16, 3)
    out = prior_forecast(SETTING_A, tmp_path / "model", obs)
    assert path.name == "prior.safetensors" and out.shape == (2, 100, 16, 3) and np.isfinite(out).all()


def test_the_bundled_setting_a_model_loads_and_runs_the_demo():
    """``tcd.load("h36m-stochastic")``: the Setting-A generator directory, 25 -> 100 frames at 50 Hz on 16 joints,
    the protocol's call ``forecast(obs, num_samples=50)``; ``tcd demo`` runs it on its own clip (no repair: the
    directory has no repair model)."""
    import tcd
    from tcd import _demo as demo

    if (
        "h36m-stochastic" not in tcd.BUNDLED_MODELS
        or not (tcd.default_model_dir().with_name("weights_h36m_stochastic") / "generator.safetensors").is_file()
    ):
        pytest.skip("no bundled Setting-A model in this build")
    m = tcd.load("h36m-stochastic")
    assert (m.obs_len, m.horizon, m.num_joints, m.fps) == (25, 100, 16, 50.0)
    assert m.forecast_mode == tcd.Mixture(1.0) and m.data["dataset"] == "h36m-setting-a"
    clip = demo.load_clip(demo.SETTING_A_CLIP_PATH)
    f = m.forecast(clip["poses"][:25], num_samples=50, seed=0)
    assert f.samples.shape == (50, 100, 16, 3) and np.allclose(f.times[[0, -1]], [0.02, 2.0])
    res = demo.run(m, quiet=True)
    assert "repair_skipped" in res and res["forecast_mm"][1000] > 0
    assert "Setting-A layout" in demo.summary(res, m)
