"""`tcd repair`'s inputs: units, frame rates (resampled to the model's and back), Human3.6M exp-map text
files and the forward kinematics that turn them into joint positions. Structure, not accuracy, as in
test_repair.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

import tcd
from conftest import H36M_DIR, needs_h36m
from repair_util import FAST, FAST_KW, gappy, load_npz, run
from tcd import _fk as fk
from tcd._repair import windows
from tcd._resample import resample_backward, resample_forward


# ---------------------------------------------------------------------------------------------- units and rates
def test_units_mm(tiny_model, tmp_path):
    rng = np.random.default_rng(9)
    x = gappy(rng, 120)
    np.savez(tmp_path / "m.npz", poses=x)
    np.savez(tmp_path / "mm.npz", poses=x * np.float32(1000))
    tcd.repair_file(tmp_path / "m.npz", tmp_path / "out_m.npz", tiny_model, **FAST_KW)
    tcd.repair_file(tmp_path / "mm.npz", tmp_path / "out_mm.npz", tiny_model, units="mm", **FAST_KW)
    a = load_npz(tmp_path / "out_m.npz")["poses"]
    b = load_npz(tmp_path / "out_mm.npz")["poses"]
    seen = ~np.isnan(x)
    assert np.array_equal(b[seen], (x * np.float32(1000))[seen])
    assert np.allclose(b, a * 1000, atol=0.05)  # the same repair, in mm (up to float32 rounding)
    assert json.loads(str(load_npz(tmp_path / "out_mm.npz")["provenance"]))["units"] == "mm"
    # read as metres, the mm values are no person's size: refused, naming the unit that fits, nothing written
    with pytest.raises(tcd.InvalidInputError, match="look like millimetres: pass units='mm'"):
        tcd.repair_file(tmp_path / "mm.npz", tmp_path / "out_wrong.npz", tiny_model, **FAST_KW)
    assert not (tmp_path / "out_wrong.npz").exists()


def test_resampling_mask_is_conservative():
    x = np.arange(5, dtype=np.float64)[:, None] * np.ones((1, 2))
    m = np.ones((5, 2), bool)
    m[2, 0] = False
    # 12.5 fps -> 25 fps: model frames at source positions 0, 0.5, 1, ..., 4
    y, ym = resample_forward(x, m, 12.5, 25.0)
    assert y.shape == (9, 2)
    assert np.allclose(y[ym[:, 1], 1], np.arange(9)[ym[:, 1]] / 2)
    assert ym[:, 1].all()
    assert list(np.flatnonzero(~ym[:, 0])) == [3, 4, 5]  # every model frame touching source frame 2
    # 50 fps -> 25: every other frame, exactly; back again: interpolation
    x = np.random.default_rng(0).normal(size=(9, 3))
    y, ym = resample_forward(x, np.ones_like(x, bool), 50.0, 25.0)
    assert np.array_equal(y, x[::2]) and ym.all()
    back = resample_backward(y, 9, 50.0, 25.0)
    assert np.array_equal(back[::2], x[::2]) and np.allclose(back[1::2], (x[0:-1:2] + x[2::2]) / 2)
    # 30 fps, 10 frames: 0.3 s -> 25 fps frames at 0, 0.04, ..., 0.32 (the last past the end: missing)
    y, ym = resample_forward(np.zeros((10, 1)), np.ones((10, 1), bool), 30.0, 25.0)
    assert len(y) == 9 and ym[:8].all() and not ym[8].any()


def test_fps_resampled_and_back(tiny_model, tmp_path, monkeypatch):
    seen_frames = []
    real = windows.FileJob.__init__

    def init(self, *a, **kw):
        real(self, *a, **kw)
        seen_frames.append(self.model_frames)

    monkeypatch.setattr(windows.FileJob, "__init__", init)
    rng = np.random.default_rng(10)
    t = np.arange(201)[:, None, None] / 50.0
    x = (np.sin(2 * np.pi * t + rng.normal(size=(1, 22, 3))) * 0.3).astype(np.float32)
    x[rng.random((201, 22)) < 0.2] = np.nan
    x[100:111] = np.nan
    np.savez(tmp_path / "in.npz", poses=x)
    tcd.repair_file(
        tmp_path / "in.npz", tmp_path / "out50.npz", tiny_model, capture=tcd.Capture("h36m22", fps=50), **FAST_KW
    )
    assert seen_frames == [101]  # 4 s at 25 fps
    got = load_npz(tmp_path / "out50.npz")
    seen = ~np.isnan(x)
    assert got["poses"].shape == x.shape and not np.isnan(got["poses"]).any()
    assert np.array_equal(got["poses"][seen], x[seen])
    assert json.loads(str(got["provenance"]))["fps"] == 50.0
    # at the model's rate (explicitly or by default) nothing is resampled
    tcd.repair_file(
        tmp_path / "in.npz", tmp_path / "out25.npz", tiny_model, capture=tcd.Capture("h36m22", fps=25), **FAST_KW
    )
    tcd.repair_file(tmp_path / "in.npz", tmp_path / "outd.npz", tiny_model, **FAST_KW)
    assert seen_frames[1:] == [201, 201]
    assert np.array_equal(load_npz(tmp_path / "out25.npz")["poses"], load_npz(tmp_path / "outd.npz")["poses"])
    assert not np.array_equal(load_npz(tmp_path / "out25.npz")["poses"], got["poses"])


def test_cli_fps_and_units(tiny_model_dir, tmp_path, capsys):
    rng = np.random.default_rng(11)
    x = gappy(rng, 75) * np.float32(1000)
    np.savez(tmp_path / "in.npz", poses=x)
    code, _, err = run(
        [
            tmp_path / "in.npz",
            "-o",
            tmp_path / "out",
            "--model",
            tiny_model_dir,
            "--fps",
            "30",
            "--units",
            "mm",
            "--quiet",
            *FAST,
        ],
        capsys,
    )
    assert code == 0, err
    tcd.repair_file(
        tmp_path / "in.npz",
        tmp_path / "api.npz",
        tiny_model_dir,
        capture=tcd.Capture("h36m22", fps=30),
        units="mm",
        **FAST_KW,
    )
    a, b = load_npz(tmp_path / "out" / "in.npz"), load_npz(tmp_path / "api.npz")
    assert np.array_equal(a["poses"], b["poses"])
    prov = json.loads(str(a["provenance"]))
    assert prov["fps"] == 30.0 and prov["units"] == "mm"


# ---------------------------------------------------------------------------------------------- exp-map txt
def _expmap_rows(rng, frames):
    rows = rng.normal(scale=0.2, size=(frames, 99))
    rows[:, :3] = rng.normal(scale=500, size=(frames, 3))  # root position: ignored
    return rows


def test_expmap_txt_input(tiny_model_dir, tmp_path, capsys):
    rng = np.random.default_rng(12)
    rows = _expmap_rows(rng, 64)
    rows[10:14] = np.nan  # missing frames
    rows[20:30, 3 + 3 * 17 : 3 + 3 * 18] = np.nan  # left shoulder rotation unknown: the arm below it missing
    d = tmp_path / "h36m" / "S5"
    d.mkdir(parents=True)
    np.savetxt(d / "walking_1.txt", rows, delimiter=",")
    code, _, err = run([tmp_path / "h36m", "-o", tmp_path / "out", "--model", tiny_model_dir, "--quiet", *FAST], capsys)
    assert code == 0, err
    got = load_npz(tmp_path / "out" / "S5" / "walking_1.npz")
    xyz = fk.expmap_to_model(np.loadtxt(d / "walking_1.txt", delimiter=","))
    seen = ~np.isnan(xyz)
    assert got["poses"].shape == (64, 22, 3) and not np.isnan(got["poses"]).any()
    assert np.array_equal(got["mask"], seen)
    assert not seen[10:14].any() and seen[:10].all()
    names = tcd.load(tiny_model_dir).joint_names
    arm = [names.index(n) for n in ("left_elbow", "left_wrist", "left_thumb", "left_hand")]
    assert not seen[20:30, arm].any() and seen[20:30, names.index("left_shoulder")].all()
    assert np.array_equal(got["poses"][seen], xyz[seen])
    assert json.loads(str(got["provenance"]))["fps"] == fk.H36M_TXT_FPS
    # a txt file that is not an exp-map table fails with its reason
    (d / "bad.txt").write_text("1,2,3\n4,5,6\n")
    code, _, err = run([tmp_path / "h36m", "-o", tmp_path / "out", "--model", tiny_model_dir, "--quiet", *FAST], capsys)
    assert code == 1 and "bad.txt" in err and "99 values per row" in err


# ---------------------------------------------------------------------------------------------- forward kinematics
def test_fk_matches_training_kinematics():
    from training.data import h36m

    rows = _expmap_rows(np.random.default_rng(13), 30)
    want = h36m.xyz32_to_model(h36m.expmap_to_xyz32(rows, sample_rate=1))
    got = fk.expmap_to_model(rows)
    assert np.allclose(got, want, atol=1e-6)
    assert np.array_equal(got.astype(np.float32), want)


@needs_h36m
def test_fk_matches_training_on_real_expmap_file(tmp_path):
    from training.data import h36m

    with np.load(H36M_DIR / "h36m_expmap_50fps.npz") as z:
        rows = np.asarray(z["S5/walking_1"][:300], dtype=np.float64)
    path = tmp_path / "walking_1.txt"
    np.savetxt(path, rows, delimiter=",", fmt="%.9g")
    from_txt = fk.read_expmap_txt(path)
    want = h36m.xyz32_to_model(h36m.expmap_to_xyz32(from_txt, sample_rate=1))
    assert np.array_equal(fk.expmap_to_model(from_txt).astype(np.float32), want)
    # the training pipeline's 25 fps frames are every other row
    assert np.allclose(fk.expmap_to_model(from_txt)[::2], h36m.xyz32_to_model(h36m.expmap_to_xyz32(rows)), atol=1e-6)
