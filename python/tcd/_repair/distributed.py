"""``tcd repair --ray``: the same per-file repair (:func:`run_tasks`) spread over a Ray cluster.

Files are cut into chunks of ``files_per_task`` and each chunk is one Ray task. A worker process loads the
model once (a per-process cache) and repairs its chunk exactly as a local run does: the same windows, the
same per-file noise streams (window k of a file draws stream k whatever else is batched with it), the same
atomic writes into the output directory. Every worker must see that directory and the model directory at
the same paths (a shared filesystem; object stores are not supported). So a Ray run writes the same bytes
as a local run.

Faults: when a worker dies in the middle of a chunk, Ray runs the task again, at most ``max_retries`` times.
Outputs the dead attempt had finished are then found finished (the resume check: the same settings) and
skipped; nothing partial is ever at an output path, and the dead attempt's temporary files are removed at the
end. A chunk that fails every attempt is reported file by file as failed (exit code 1), and the rest of the
run completes.

Needs Ray on the driver and on every node: ``pip install "tcd-forecast[ray]"``.
"""

from __future__ import annotations

import dataclasses
import os
import socket
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence

from .options import RepairOptions
from .runner import Outcome, Task, run_tasks

__all__ = ["RAY_EXTRA", "connect", "run_tasks_ray", "check_writable"]

RAY_EXTRA = 'pip install "tcd-forecast[ray]"'
#: Seconds to wait for a Ray cluster's address to answer before giving up.
CONNECT_TIMEOUT_S = 5.0
#: Test-only fault injection: a path; the first worker to repair frames creates it and dies.
KILL_ONCE_ENV = "TCD_TEST_KILL_WORKER_ONCE"

_MODELS: Dict[str, Any] = {}  # per worker process: model directory -> loaded model


def _ray():
    try:
        import ray
    except ImportError:
        raise ImportError(f"--ray needs Ray, which is not installed: {RAY_EXTRA}") from None
    return ray


def connect(address: Optional[str] = None) -> str:
    """Joins the Ray cluster at ``address`` (or ``$RAY_ADDRESS``), or starts one on this machine when there
    is neither; returns what was joined. An address that does not answer within CONNECT_TIMEOUT_S is a
    ConnectionError (Ray itself would keep trying)."""
    ray = _ray()
    if ray.is_initialized():
        return "the running Ray session"
    addr = os.environ.get("RAY_ADDRESS") if address is None else (None if address == "local" else address)
    if addr and addr != "auto":
        host, _, port = addr.split("://")[-1].rpartition(":")
        try:
            socket.create_connection((host or "127.0.0.1", int(port)), timeout=CONNECT_TIMEOUT_S).close()
        except (OSError, ValueError) as e:
            raise ConnectionError(f"the Ray cluster at {addr} cannot be reached ({e})") from None
    ray.init(
        address=addr or None,
        include_dashboard=False,
        logging_level="ERROR",
        log_to_driver=False,
        ignore_reinit_error=True,
    )
    return addr or "a local Ray cluster on this machine"


def _repair_chunk(model_dir: str, tasks: Sequence[Task], opts: RepairOptions, overwrite: bool):
    """On a worker: the chunk's outcomes, with this worker's name."""
    from .._model import load

    model = _MODELS.get(model_dir)
    if model is None:
        model = _MODELS[model_dir] = load(model_dir)
    marker = os.environ.get(KILL_ONCE_ENV)

    def on_frames(_: int) -> None:
        if marker and not os.path.exists(marker):
            Path(marker).touch()
            os._exit(1)  # dies in the middle of a file, once

    outcomes = run_tasks(
        model, list(tasks), opts, overwrite=overwrite, files_per_batch=max(len(tasks), 1), on_frames=on_frames
    )
    worker = f"{socket.gethostname()}:{os.getpid()}"
    for o in outcomes:
        o.worker = worker
    return outcomes


def check_writable(out: Path) -> Optional[str]:
    """None when a Ray worker can create files in ``out``; else why not (checked before any work)."""
    ray = _ray()

    def probe(path: str) -> Optional[str]:
        try:
            p = Path(path)
            p.mkdir(parents=True, exist_ok=True)
            test = p / f".tcd-write-test-{os.getpid()}"
            test.write_bytes(b"")
            test.unlink()
            return None
        except OSError as e:
            return f"{socket.gethostname()} cannot write into {path}: {e}"

    return ray.get(ray.remote(probe).remote(str(out)))


def run_tasks_ray(
    model: Any,
    tasks: Sequence[Task],
    opts: RepairOptions,
    *,
    overwrite: bool = False,
    files_per_task: int = 4,
    max_retries: int = 3,
    on_frames: Optional[Callable[[int], None]] = None,
    on_outcome: Optional[Callable[[Outcome], None]] = None,
) -> List[Outcome]:
    """:func:`run_tasks` on the connected Ray cluster (:func:`connect` first); outcomes in task order."""
    ray = _ray()
    if model.path is None:
        raise ValueError("a Ray run needs a model loaded from a directory (workers load it by path)")
    # one engine thread per task unless --jobs says otherwise: Ray runs one task per CPU
    opts_remote = opts if opts.threads is not None else dataclasses.replace(opts, threads=1)
    remote = ray.remote(num_cpus=opts_remote.threads, max_retries=max_retries)(_repair_chunk)
    tasks = list(tasks)
    outcomes: List[Optional[Outcome]] = [None] * len(tasks)
    starts = {
        remote.remote(str(model.path), tasks[i : i + files_per_task], opts_remote, overwrite): i
        for i in range(0, len(tasks), files_per_task)
    }
    waiting = list(starts)
    while waiting:
        ready, waiting = ray.wait(waiting, num_returns=1)
        start = starts[ready[0]]
        chunk = tasks[start : start + files_per_task]
        try:
            results = ray.get(ready[0])
        except ray.exceptions.RayError as e:
            reason = f"failed on every attempt on the cluster ({type(e).__name__})"
            results = [Outcome(t, "failed", reason) for t in chunk]
        for k, o in enumerate(results):
            outcomes[start + k] = o
            if on_outcome is not None:
                on_outcome(o)
            if on_frames is not None and o.frames:
                on_frames(o.frames)
    for t in tasks:  # what killed attempts left behind
        for stale in t.dst.parent.glob(f".{t.dst.name}.*.tmp*"):
            try:
                stale.unlink()
            except OSError:
                pass
    return [o for o in outcomes if o is not None]
