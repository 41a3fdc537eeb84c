"""The command line's bad inputs, table-driven (issue 19, item 4): every case is an exit code and a fragment
of the one-line message, never a traceback, and nothing is written. (The API's bad inputs are in
test_errors.py.)"""

from __future__ import annotations

import os

import numpy as np
import pytest

from fixtures_util import poses
from tcd._cli import main


def run_cli(argv) -> int:
    """main()'s exit code, also for argparse's usage errors (which exit through SystemExit)."""
    try:
        return main(argv)
    except SystemExit as e:
        return e.code


def npz(path, **arrays):
    np.savez(path, **arrays)
    return path


def make_input(kind: str, d):
    """An input of the given kind under d; returns its path."""
    good = poses(np.random.default_rng(0))
    p = d / "in.npz"
    if kind == "good":
        return npz(p, poses=good)
    if kind == "npy_named_npz":
        with open(p, "wb") as f:
            np.save(f, good)
        return p
    if kind == "text":
        p.write_text("frame,x,y,z\n0,1,2,3\n")
        return p
    if kind == "binary":
        p.write_bytes(bytes(range(256)) * 4)
        return p
    if kind == "empty":
        p.write_bytes(b"")
        return p
    if kind == "pickled":
        return npz(p, poses=np.array([good, "x"], dtype=object))
    if kind == "no_poses":
        return npz(p, pose=good)
    if kind == "amass":  # SMPL-H parameters, as AMASS distributes them
        return npz(p, poses=np.zeros((50, 156)), trans=np.zeros((50, 3)), mocap_framerate=np.array(120.0))
    if kind == "directory":
        (d / "dir.npz").mkdir()
        return d / "dir.npz"
    if kind == "missing":
        return d / "nothing.npz"
    if kind == "millimetres":
        return npz(p, poses=good * 1000)
    if kind == "booleans":
        return npz(p, poses=np.nan_to_num(good) > 0)
    raise ValueError(kind)


FAST = ["--samples", "1", "--steps", "1", "--sampler", "ddim"]

# (input kind, extra arguments, exit code, fragment of the message)
FORECAST_CASES = [
    ("npy_named_npz", [], 2, "it is a single .npy array, not an .npz archive"),
    ("text", [], 2, "it is a text file, not an .npz archive"),
    ("binary", [], 2, "it is a binary file, not an .npz archive"),
    ("empty", [], 2, "it is empty"),
    ("pickled", [], 2, "object (pickled) arrays, which are never loaded"),
    ("no_poses", [], 2, "it is an .npz archive without a `poses` array (it holds: pose)"),
    ("amass", [], 2, "it is an AMASS file: its `poses` are SMPL-H joint rotations"),
    ("directory", [], 2, "it is a directory, not an .npz file"),
    ("missing", [], 2, "does not exist"),
    ("millimetres", [], 2, "pass units='mm'. (`units` is --units.)"),
    ("good", ["--units", "mm"], 2, "pass units='m'. (`units` is --units.)"),
    ("booleans", [], 2, "dtype bool"),
    ("good", ["--samples", "0"], 2, "(`num_samples` is --samples.)"),
    ("good", ["--seed", "-1"], 2, "(`seed` is --seed.)"),
    ("good", ["--threads", "0"], 2, "(`threads` is --threads.)"),
    ("good", ["--steps", "0"], 2, "--steps"),
    ("good", ["--sampler", "euler"], 2, "invalid choice: 'euler'"),
    ("good", ["--units", "inch"], 2, "invalid choice: 'inch'"),
    ("good", ["--model", "/nonexistent/model"], 2, "does not exist"),
]


@pytest.mark.parametrize(
    "kind,extra,code,fragment",
    FORECAST_CASES,
    ids=[f"{k}{'-' + '-'.join(e) if e else ''}" for k, e, _, _ in FORECAST_CASES],
)
def test_forecast_bad_input(tiny_model_dir, tmp_path, capsys, kind, extra, code, fragment):
    src = make_input(kind, tmp_path)
    out = tmp_path / "out.npz"
    model = [] if "--model" in extra else ["--model", str(tiny_model_dir)]
    got = run_cli(["forecast", str(src), "-o", str(out), *model, *FAST, *extra])
    err = capsys.readouterr().err
    assert got == code, err
    assert fragment in err, err
    assert "Traceback" not in err and not out.exists()


def test_forecast_never_overwrites_its_input(tiny_model_dir, tmp_path, capsys):
    src = make_input("good", tmp_path)
    before = src.read_bytes()
    assert run_cli(["forecast", str(src), "-o", str(src), "--overwrite", "--model", str(tiny_model_dir), *FAST]) == 2
    assert "is the input file" in capsys.readouterr().err
    assert src.read_bytes() == before


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root reads files whatever their mode")
def test_forecast_unreadable_file(tiny_model_dir, tmp_path, capsys):
    src = make_input("good", tmp_path)
    src.chmod(0)
    assert run_cli(["forecast", str(src), "-o", str(tmp_path / "o.npz"), "--model", str(tiny_model_dir), *FAST]) == 2
    assert "permission denied" in capsys.readouterr().err


# tcd repair: bad options are exit 2 before any file is read; a bad file is reported (exit 1), the others repaired
REPAIR_OPTION_CASES = [
    (["--samples", "1000000"], "(`num_samples` is --samples.)"),
    (["--samples", "0"], "(`num_samples` is --samples.)"),
    (["--seed", "-1"], "(`seed` is --seed.)"),
    (["--jobs", "0"], "--jobs"),
    (["--fps", "0"], "--fps"),
]


@pytest.mark.parametrize("extra,fragment", REPAIR_OPTION_CASES, ids=[" ".join(e) for e, _ in REPAIR_OPTION_CASES])
def test_repair_bad_options(tiny_model_dir, tmp_path, capsys, extra, fragment):
    (tmp_path / "in").mkdir()
    make_input("good", tmp_path / "in")
    code = run_cli(
        [
            "repair",
            str(tmp_path / "in"),
            "-o",
            str(tmp_path / "out"),
            "--model",
            str(tiny_model_dir),
            "--quiet",
            "--steps",
            "1",
            "--sampler",
            "ddim",
            *extra,
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and fragment in err and "Traceback" not in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "kind,fragment",
    [
        ("npy_named_npz", "a single .npy array"),
        ("amass", "an AMASS file"),
        ("text", "a text file"),
        ("pickled", "object (pickled) arrays"),
        ("millimetres", "pass units='mm'"),
    ],
)
def test_repair_reports_a_bad_file_and_repairs_the_others(tiny_model_dir, tmp_path, capsys, kind, fragment):
    (tmp_path / "in" / "bad").mkdir(parents=True)
    make_input(kind, tmp_path / "in" / "bad")
    np.savez(tmp_path / "in" / "good.npz", poses=poses(np.random.default_rng(1), frames=60))
    code = run_cli(
        [
            "repair",
            str(tmp_path / "in"),
            "-o",
            str(tmp_path / "out"),
            "--model",
            str(tiny_model_dir),
            "--quiet",
            "--steps",
            "1",
            "--sampler",
            "ddim",
            "--samples",
            "1",
        ]
    )
    err = capsys.readouterr().err
    assert code == 1 and fragment in err and "Traceback" not in err, err
    assert (tmp_path / "out" / "good.npz").is_file() and not (tmp_path / "out" / "bad").exists()
