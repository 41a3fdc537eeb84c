"""`.ci/run` fails when a test fails (CI lands nothing then), the run without torch (tests/without_torch.py)
included: run with stand-ins for python3 and cargo that fail where told, and a stand-in wheel check that leaves
a mark."""

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def fake(path: Path, body: str) -> None:
    path.write_text("#!/usr/bin/env bash\n" + body + "\n")
    path.chmod(path.stat().st_mode | stat.S_IEXEC)


@pytest.mark.parametrize(
    "failing,should_pass",
    [(None, True), ("pytest", False), ("pip", False), ("cargo", False), ("tests/without_torch.py", False)],
)
def test_ci_run_fails_when_a_step_fails(tmp_path, failing, should_pass):
    repo, bin_dir = tmp_path / "repo", tmp_path / "bin"
    (repo / ".ci").mkdir(parents=True)
    bin_dir.mkdir()
    shutil.copy(ROOT / ".ci" / "run", repo / ".ci" / "run")
    fake(repo / ".ci" / "wheel_check.sh", f"touch {tmp_path / 'wheel_check_ran'}")
    # python3 -m pip|pytest ... ($2), python3 tests/without_torch.py ... ($1)
    fake(bin_dir / "python3", f'[ "$2" = "{failing}" ] || [ "$1" = "{failing}" ] && exit 1; exit 0')
    fake(bin_dir / "cargo", f'[ "{failing}" = cargo ] && exit 1; exit 0')
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}")
    r = subprocess.run(["bash", str(repo / ".ci" / "run")], env=env, capture_output=True, text=True)
    assert (r.returncode == 0) == should_pass, (failing, r.returncode, r.stderr)
    assert (tmp_path / "wheel_check_ran").exists() == should_pass


def test_without_torch_hides_torch_and_fails_when_a_test_fails(tmp_path):
    """tests/without_torch.py: ``import torch`` (and its submodules) raises ModuleNotFoundError, as where torch is
    not installed, so ``importorskip`` skips; a failing test fails the run."""
    (tmp_path / "test_probe.py").write_text(
        "import pytest\n\n\n"
        "def test_torch_is_hidden():\n"
        "    for name in ('torch', 'torch.nn'):\n"
        "        with pytest.raises(ModuleNotFoundError, match='without_torch'):\n"
        "            __import__(name)\n"
        "    pytest.importorskip('torch')\n\n\n"
        "def test_fails():\n"
        "    assert False\n"
    )
    r = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "without_torch.py"), "-q", "-p", "no:cacheprovider", "test_probe.py"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 1 and "1 failed, 1 skipped" in r.stdout, (r.returncode, r.stdout, r.stderr)
