"""`.ci/run` fails when a test fails (CI lands nothing then): run with stand-ins for python3 and cargo that
fail where told, and a stand-in wheel check that leaves a mark."""
import os
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def fake(path: Path, body: str) -> None:
    path.write_text("#!/usr/bin/env bash\n" + body + "\n")
    path.chmod(path.stat().st_mode | stat.S_IEXEC)


@pytest.mark.parametrize("failing,should_pass", [(None, True), ("pytest", False), ("pip", False), ("cargo", False)])
def test_ci_run_fails_when_a_step_fails(tmp_path, failing, should_pass):
    repo, bin_dir = tmp_path / "repo", tmp_path / "bin"
    (repo / ".ci").mkdir(parents=True)
    bin_dir.mkdir()
    shutil.copy(ROOT / ".ci" / "run", repo / ".ci" / "run")
    fake(repo / ".ci" / "wheel_check.sh", f"touch {tmp_path / 'wheel_check_ran'}")
    fake(bin_dir / "python3", f'[ "$2" = "{failing}" ] && exit 1; exit 0')     # python3 -m pip|pytest ...
    fake(bin_dir / "cargo", f'[ "{failing}" = cargo ] && exit 1; exit 0')
    env = dict(os.environ, PATH=f"{bin_dir}:{os.environ['PATH']}")
    r = subprocess.run(["bash", str(repo / ".ci" / "run")], env=env, capture_output=True, text=True)
    assert (r.returncode == 0) == should_pass, (failing, r.returncode, r.stderr)
    assert (tmp_path / "wheel_check_ran").exists() == should_pass
