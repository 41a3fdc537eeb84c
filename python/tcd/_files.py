"""Every file the package writes goes through here: it is written under a temporary name in the
destination directory and renamed into place, so an output either is complete or does not exist. And the
one reader of the user's .npz inputs (:func:`read_npz`), which says what a file is when it is not one."""

from __future__ import annotations

import errno
import os
import secrets
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any, Callable, Dict, Iterator

import numpy as np


class UnreadableFile(ValueError):
    """An input that is not a readable .npz archive; the message says what it is instead."""


def read_npz(path: Path) -> Dict[str, np.ndarray]:
    """Every array of the .npz archive ``path`` (never unpickling). Raises FileNotFoundError when nothing
    is there, and :class:`UnreadableFile` naming what the file is otherwise: a directory, a file without
    read permission, an empty file, a single .npy array, a text file, another binary, a damaged archive."""
    path = Path(path)
    if path.is_dir():
        raise UnreadableFile("a directory, not an .npz file")
    try:
        with open(path, "rb") as fh:
            head = fh.read(512)
    except FileNotFoundError:
        raise
    except PermissionError:
        raise UnreadableFile("not readable: permission denied") from None
    except OSError as e:
        raise UnreadableFile(f"not readable: {e.strerror or e}") from None
    if not head:
        raise UnreadableFile("empty")
    if head.startswith(b"\x93NUMPY"):
        raise UnreadableFile("a single .npy array, not an .npz archive with `poses` (save with numpy.savez)")
    if not head.startswith(b"PK"):
        try:
            head.decode("utf-8")
            what = "a text file"
        except UnicodeDecodeError:
            what = "a binary file"
        raise UnreadableFile(f"{what}, not an .npz archive (no zip signature)")
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except ValueError as e:
        if "pickle" in str(e):
            raise UnreadableFile("an .npz archive holding object (pickled) arrays, which are never loaded") from None
        raise UnreadableFile(f"not a valid .npz archive ({e})") from None
    except (OSError, zipfile.BadZipFile, EOFError, KeyError) as e:
        raise UnreadableFile(f"not a valid .npz archive ({type(e).__name__}: {e})") from None


def read_pose_npz(path: Path) -> Dict[str, np.ndarray]:
    """:func:`read_npz` of an input of poses: it must hold ``poses`` as joint positions. An AMASS file (SMPL-H
    parameters under the same name) or an archive without ``poses`` is an :class:`UnreadableFile` saying so."""
    data = read_npz(path)
    if "poses" not in data:
        held = ", ".join(sorted(data)) or "nothing"
        raise UnreadableFile(f"an .npz archive without a `poses` array (it holds: {held})")
    if data["poses"].ndim == 2 and {"trans", "mocap_framerate"} <= set(data):
        raise UnreadableFile(
            "an AMASS file: its `poses` are SMPL-H joint rotations (axis-angle), not joint positions; compute the "
            "joints with the SMPL-H body model (the smplx package) and pass them as `poses` (T, 24, 3) with "
            "layout smpl24"
        )
    return data


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
