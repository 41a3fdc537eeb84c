"""tcd._files, the atomic writes of every output: complete or absent, never replacing a file without
overwrite, no temporary file left behind."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from tcd import _files as files


def names(d):
    return sorted(p.name for p in d.iterdir())


def test_npz_and_text_written_with_the_umask_permissions(tmp_path):
    files.write_npz_atomic(tmp_path / "a.npz", False, x=np.arange(3))
    files.write_text_atomic(tmp_path / "r.json", "{}\n")
    with np.load(tmp_path / "a.npz") as f:
        assert f["x"].tolist() == [0, 1, 2]
    assert (tmp_path / "r.json").read_text() == "{}\n"
    umask = os.umask(0)
    os.umask(umask)
    for name in ("a.npz", "r.json"):  # as open(path, "w") would make them, not mkstemp's 0o600
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o666 & ~umask
    assert names(tmp_path) == ["a.npz", "r.json"]


@pytest.mark.parametrize("links", [True, False])
def test_existing_file_kept_without_overwrite(tmp_path, monkeypatch, links):
    if not links:  # a file system without hard links: the check-then-rename fallback

        def no_link(src, dst):
            raise PermissionError("no hard links here")

        monkeypatch.setattr(os, "link", no_link)
    dst = tmp_path / "out.txt"
    files.write_text_atomic(dst, "first", overwrite=False)
    with pytest.raises(FileExistsError) as ei:
        files.write_text_atomic(dst, "second", overwrite=False)
    assert ei.value.filename == str(dst)
    with pytest.raises(FileExistsError):  # appearing while being written
        files.write_atomic(
            dst.with_name("late.txt"), lambda fh: dst.with_name("late.txt").write_text("other"), overwrite=False
        )
    assert (tmp_path / "late.txt").read_text() == "other"
    files.write_text_atomic(dst, "third", overwrite=True)
    assert dst.read_text() == "third"
    assert names(tmp_path) == ["late.txt", "out.txt"]


def test_named_writer_sees_the_suffix_and_failures_leave_nothing(tmp_path):
    seen = []

    def write(path):
        seen.append(path)
        path.write_bytes(b"GIF89a")

    files.write_named_atomic(tmp_path / "demo.gif", write)
    assert seen[0].suffix == ".gif" and seen[0].parent == tmp_path and seen[0].name.startswith(".demo.gif.")
    assert (tmp_path / "demo.gif").read_bytes() == b"GIF89a"

    def fail(path):
        path.write_bytes(b"half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        files.write_named_atomic(tmp_path / "demo.gif", fail)
    assert (tmp_path / "demo.gif").read_bytes() == b"GIF89a"
    assert names(tmp_path) == ["demo.gif"]
