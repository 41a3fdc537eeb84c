"""Every file the package writes goes through here: it is written under a temporary name in the
destination directory and renamed into place, so an output either is complete or does not exist."""
from __future__ import annotations

import errno
import os
import secrets
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any, Callable, Iterator

import numpy as np


def _exists(dst: Path) -> FileExistsError:
    return FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(dst))  # as open(dst, "x") raises


def _remove(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def _new_temp(dst: Path, suffix: str) -> Path:
    """A new empty file beside ``dst``, made as ``open(path, "x")`` makes one (mode 0o666 less the umask:
    the output gets the permissions a plainly written file would)."""
    while True:
        tmp = dst.with_name(f".{dst.name}.{secrets.token_hex(4)}.tmp{suffix}")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            continue


def _move_into_place(tmp: Path, dst: Path, overwrite: bool) -> None:
    if overwrite:
        os.replace(tmp, dst)
        return
    # Without overwrite, a hard link is the rename that fails when dst appeared since the check.
    try:
        os.link(tmp, dst)
    except FileExistsError:
        raise _exists(dst) from None
    except OSError:  # a file system without hard links: check, then rename
        if dst.exists():
            raise _exists(dst) from None
        os.replace(tmp, dst)
        return
    _remove(tmp)


@contextmanager
def staged(dst: Path, overwrite: bool = True, *, suffix: str = "") -> Iterator[Path]:
    """The path of a new empty temporary file in ``dst``'s directory (created if needed) to write; when the
    block ends without an exception it becomes ``dst``, else it is removed and ``dst`` is untouched. Raises
    ``FileExistsError`` when ``dst`` exists (or appears meanwhile) and not ``overwrite``. The temporary
    name is ``.<dst name>.<random>.tmp<suffix>``."""
    if not overwrite and dst.exists():
        raise _exists(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = _new_temp(dst, suffix)
    try:
        yield tmp
        _move_into_place(tmp, dst, overwrite)
    except BaseException:
        _remove(tmp)
        raise


def write_atomic(dst: Path, write: Callable[[IO[Any]], Any], overwrite: bool = True, *, binary: bool = True) -> None:
    """Calls ``write(fh)`` on the open temporary file of :func:`staged` (UTF-8 text unless ``binary``)."""
    with staged(dst, overwrite) as tmp:
        with open(tmp, "wb") if binary else open(tmp, "w", encoding="utf-8") as fh:
            write(fh)


def write_npz_atomic(dst: Path, overwrite: bool, **arrays: np.ndarray) -> None:
    """Writes ``arrays`` to ``dst`` (``np.savez``) atomically, synced to disk."""
    def write(fh: IO[bytes]) -> None:
        np.savez(fh, **arrays)
        fh.flush()
        os.fsync(fh.fileno())

    write_atomic(dst, write, overwrite)
    for stale in dst.parent.glob(f".{glob_escape(dst.name)}.*.tmp"):  # left by a killed earlier run
        _remove(stale)


def write_text_atomic(dst: Path, text: str, overwrite: bool = True) -> None:
    write_atomic(dst, lambda fh: fh.write(text), overwrite, binary=False)


def write_named_atomic(dst: Path, write: Callable[[Path], Any], overwrite: bool = True) -> None:
    """Calls ``write(path)`` for a writer that takes a file name. The temporary name ends in ``dst``'s
    suffix, as such writers may choose the format by it (Pillow does)."""
    with staged(dst, overwrite, suffix=dst.suffix) as tmp:
        write(tmp)


def glob_escape(name: str) -> str:
    return "".join(f"[{c}]" if c in "*?[]" else c for c in name)
