"""Progress of a long engine call, for ``progress=`` in the API and the command line's bars.

The engine counts per-sequence denoiser forwards; the binding calls back ``(done, total)`` about ten times
a second from the calling thread, and once at the end (see ``crates/tcd-py/src/run.rs``). ``progress``:
``None`` / ``False`` shows nothing, ``True`` a tqdm bar on stderr, and a callable ``f(done, total)`` gets
the counts (raising in it stops the call with that exception, as Ctrl-C does with KeyboardInterrupt).

Ctrl-C is seen by a call made from the main thread (the only one where Python runs signal handlers; from
another thread, raise in the callback) in a process where SIGINT raises KeyboardInterrupt, Python's default:
a process started with SIGINT ignored (a script's ``python app.py &``) keeps it ignored, and tcd does not
change it. A Ctrl-C that arrived just before the call stops it before its first forward."""

from __future__ import annotations

import sys
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Optional, Union

from . import _checks

__all__ = ["Progress", "reporter"]

Callback = Callable[[int, int], Any]

#: What ``progress=`` takes: None / False (nothing), True (a tqdm bar on stderr) or a callable ``f(done, total)``.
Progress = Union[None, bool, Callback]


@contextmanager
def reporter(progress: Progress, desc: str) -> Iterator[Optional[Callback]]:
    """The callback to hand to the binding for ``progress`` (None for none); a bar is closed on exit."""
    if progress is None or progress is False:
        yield None
        return
    if progress is not True:
        if not callable(progress):
            raise _checks.fail("progress", "True, False, None or a callable f(done, total)", repr(progress))
        yield progress
        return
    from tqdm import tqdm

    bar = tqdm(total=0, unit="forward", desc=desc, file=sys.stderr, dynamic_ncols=True, leave=False)

    def update(done: int, total: int) -> None:
        if total != bar.total:
            bar.total = total
        bar.update(done - bar.n)

    try:
        yield update
    finally:
        bar.close()
