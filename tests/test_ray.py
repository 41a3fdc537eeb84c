"""`tcd repair --ray` (issue 18): the same bytes as a local run, a worker killed in the middle of a file, resume,
and the bad inputs, on a local Ray cluster."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

ray = pytest.importorskip("ray")

from repair_util import FAST, gappy, run, same_tree, tree  # noqa: E402
from tcd._repair import distributed  # noqa: E402

pytestmark = pytest.mark.slow
RAY_INIT = dict(num_cpus=2, include_dashboard=False, logging_level="ERROR", log_to_driver=False)


@pytest.fixture(autouse=True)
def no_session_left():
    yield
    ray.shutdown()


def dataset(d, n=5):
    d.mkdir(parents=True)
    rng = np.random.default_rng(11)
    for i in range(n):
        np.savez(d / f"take{i}.npz", poses=gappy(rng, 40 + 37 * i, block=(10, 18)))
    return d


def test_ray_run_writes_the_local_bytes_and_resumes(tiny_model_dir, tmp_path, capsys):
    src = dataset(tmp_path / "in")
    common = ["-o", None, "--model", str(tiny_model_dir), "--quiet", *FAST]
    local = [str(src), *common]
    local[2] = str(tmp_path / "local")
    code, _, err = run(local, capsys)
    assert code == 0, err
    on_ray = [str(src), *common, "--ray", "--report", str(tmp_path / "report.json")]
    on_ray[2] = str(tmp_path / "ray")
    code, text, err = run(on_ray, capsys)
    assert code == 0, err
    same_tree(tree(tmp_path / "local"), tree(tmp_path / "ray"))  # byte-identical arrays and provenance
    report = json.loads((tmp_path / "report.json").read_text())
    assert all(f["status"] == "repaired" and ":" in f["worker"] for f in report["files"])
    code, text, err = run(on_ray, capsys)  # re-run: everything is finished
    report = json.loads((tmp_path / "report.json").read_text())
    assert code == 0 and [f["status"] for f in report["files"]] == ["skipped"] * 5, err


def test_a_worker_killed_in_the_middle_of_a_file(tiny_model_dir, tmp_path, capsys):
    src = dataset(tmp_path / "in")
    code, _, err = run(
        [str(src), "-o", str(tmp_path / "local"), "--model", str(tiny_model_dir), "--quiet", *FAST], capsys
    )
    assert code == 0, err
    marker = tmp_path / "killed"
    ray.init(runtime_env={"env_vars": {distributed.KILL_ONCE_ENV: str(marker)}}, **RAY_INIT)
    code, text, err = run(
        [str(src), "-o", str(tmp_path / "ray"), "--model", str(tiny_model_dir), "--ray", *FAST], capsys
    )
    assert marker.exists(), "no worker was killed"
    assert code == 0, err
    # the retry finished the run: the same bytes, and nothing partial or temporary left behind (tree checks)
    same_tree(tree(tmp_path / "local"), tree(tmp_path / "ray"))


def test_bad_ray_arguments(tiny_model_dir, tmp_path, capsys, monkeypatch):
    src = dataset(tmp_path / "in", n=1)
    argv = [str(src), "-o", str(tmp_path / "out"), "--model", str(tiny_model_dir), *FAST]
    code, _, err = run(argv + ["--ray", "127.0.0.1:1"], capsys)  # nothing listens there
    assert code == 2 and "the Ray cluster at 127.0.0.1:1 cannot be reached" in err, err
    monkeypatch.setitem(sys.modules, "ray", None)  # Ray not installed
    code, _, err = run(argv + ["--ray"], capsys)
    assert code == 2 and 'pip install "tcd-forecast[ray]"' in err, err
    assert not any((tmp_path / "out").glob("*.npz"))
