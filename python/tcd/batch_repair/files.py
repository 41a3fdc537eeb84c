"""Writing outputs atomically (a temporary file in the destination directory, renamed into place) and
planning which input goes to which output."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

# ---------------------------------------------------------------------------------------------- writing
def _write_atomic(dst: Path, mode: str, write: Any) -> None:
    """Calls ``write(fh)`` on a temporary file in ``dst``'s directory, then ``os.replace``s it onto ``dst``:
    ``dst`` is either the complete new file or untouched; the temporary file never outlives a failure."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{dst.name}.", suffix=".tmp", dir=dst.parent)
    try:
        with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"})) as fh:
            write(fh)
        os.replace(tmp, dst)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def write_npz_atomic(dst: Path, overwrite: bool, **arrays: np.ndarray) -> None:
    """Writes ``dst`` atomically (see :func:`_write_atomic`), synced to disk. Raises ``FileExistsError`` when
    ``dst`` exists and not ``overwrite``."""
    if not overwrite and dst.exists():
        raise FileExistsError(f"{dst} exists")

    def write(fh: Any) -> None:
        np.savez(fh, **arrays)
        fh.flush()
        os.fsync(fh.fileno())

    _write_atomic(dst, "wb", write)
    for stale in dst.parent.glob(f".{glob_escape(dst.name)}.*.tmp"):  # left by a killed earlier run
        try:
            stale.unlink()
        except OSError:
            pass


def glob_escape(name: str) -> str:
    return "".join(f"[{c}]" if c in "*?[]" else c for c in name)


def write_text_atomic(dst: Path, text: str) -> None:
    _write_atomic(dst, "w", lambda fh: fh.write(text))
