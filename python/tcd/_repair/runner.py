"""The engine loop: the windows of several files batched into one engine call, each file's outcome,
and :func:`repair_file` for one file."""

from __future__ import annotations

import json
import math
import os
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, Iterable, Iterator, List, Optional, Sequence, Tuple

import numpy as np

from ..engine import repair_raw
from ..exceptions import InvalidInputError
from .._files import write_npz_atomic
from .._sampler import SamplerOptions
from .._wild_calls import Capture
from .inputs import load_input, peek_frames
from .options import (
    DEFAULT_FILES_PER_BATCH,
    DEFAULT_LOOKAHEAD,
    DEFAULT_OVERLAP,
    DEFAULT_SEED,
    INPUT_SUFFIXES,
    BadFile,
    PathLike,
    RepairOptions,
    _denoiser,
    provenance,
)
from .windows import FileJob


# ---------------------------------------------------------------------------------------------- the engine loop
@dataclass
class Task:
    """One input of a run: ``src`` -> ``dst`` (``name`` is how reports call it)."""

    src: Path
    dst: Path
    name: str = ""


@dataclass
class Outcome:
    task: Task
    status: str  # "repaired", "skipped" or "failed"
    reason: Optional[str] = None
    frames: int = 0
    missing: int = 0  # missing (frame, joint, axis) entries repaired
    windows: int = 0
    seconds: float = 0.0
    worker: Optional[str] = None  # host:pid of the Ray worker that repaired it (tcd repair --ray)

    def as_dict(self) -> Dict[str, Any]:
        d = {
            "input": str(self.task.src),
            "output": str(self.task.dst),
            "status": self.status,
            "frames": self.frames,
            "missing_values": self.missing,
            "windows": self.windows,
            "seconds": round(self.seconds, 4),
        }
        if self.reason is not None:
            d["reason"] = self.reason
        if self.worker is not None:
            d["worker"] = self.worker
        return d


def run_tasks(
    model: Any,
    tasks: Iterable[Task],
    opts: RepairOptions,
    *,
    overwrite: bool = False,
    files_per_batch: int = DEFAULT_FILES_PER_BATCH,
    on_frames: Optional[Callable[[int], None]] = None,
    on_outcome: Optional[Callable[[Outcome], None]] = None,
) -> List[Outcome]:
    """Repairs every task, at most ``files_per_batch`` files in memory, their windows batched per engine
    call. Bad inputs and failed writes become ``failed`` outcomes; the run goes on. Returns the outcomes
    in task order."""
    den = _denoiser(model)
    fills = model._repair_fills(den)  # repair_raw's fill (and its forecaster) for the repair model
    w = model.obs_len
    joint_index = (model.data or {}).get("joint_index_32")
    outcomes: Dict[int, Outcome] = {}
    order: List[int] = []

    def done(i: int, o: Outcome) -> None:
        outcomes[i] = o
        if on_outcome is not None:
            on_outcome(o)

    def frames_cb(n: int) -> None:
        if on_frames is not None and n > 0:
            on_frames(n)

    @dataclass
    class Active:
        i: int
        task: Task
        job: FileJob
        t0: float
        reported: int = 0

        def progress(self) -> None:  # source frames done, proportional to model frames done
            j = self.job
            now = j.loaded.frames if j.finished else int(j.loaded.frames * min(j.done, j.model_frames) / j.model_frames)
            frames_cb(now - self.reported)
            self.reported = now

    settings = resume_settings(provenance(model, opts, None))
    it: Iterator[Tuple[int, Task]] = iter(enumerate(tasks))
    active: List[Active] = []

    def refill() -> None:
        while len(active) < files_per_batch:
            nxt = next(it, None)
            if nxt is None:
                return
            i, task = nxt
            order.append(i)
            t0 = time.perf_counter()
            if task.dst.exists() and not overwrite:
                n = peek_frames(task.src)
                mismatch = finished_output_mismatch(task.dst, {**settings, "input": task.name or task.src.name})
                if mismatch is None:
                    done(i, Outcome(task, "skipped", "already repaired with these settings", frames=n))
                else:
                    done(
                        i,
                        Outcome(
                            task,
                            "failed",
                            f"the output exists but {mismatch}; pass --overwrite to replace it",
                            frames=n,
                        ),
                    )
                frames_cb(n)
                continue
            try:
                loaded = load_input(
                    task.src, model.num_joints, opts.units, opts.fps, model.fps, joint_index, opts.layout, opts.up
                )
            except BadFile as e:
                done(i, Outcome(task, "failed", str(e), seconds=time.perf_counter() - t0))
                frames_cb(peek_frames(task.src))
                continue
            active.append(Active(i, task, FileJob(loaded, w, opts.overlap, model.fps, opts.units, opts.lookahead), t0))

    refill()
    while active:
        obs, msk = [], []
        for a in active:
            o, m = a.job.next_window()
            obs.append(o)
            msk.append(m)
        # Window k of a file draws the engine's stream k, whichever files share the batch.
        out = repair_raw(
            den,
            np.stack(obs),
            np.stack(msk),
            num_samples=opts.num_samples,
            seed=opts.seed,
            sequences=[a.job.k for a in active],
            threads=opts.threads,
            sampler=opts.sampling,
            **fills,
        )
        still: List[Active] = []
        for a, mean in zip(active, out["mean"]):
            a.job.accept(mean)
            if not a.job.finished:
                a.progress()
                still.append(a)
                continue
            ld = a.job.loaded
            try:
                poses = a.job.result()
                prov = provenance(model, opts, None if not math.isfinite(ld.fps) else ld.fps)
                prov["input"] = a.task.name or a.task.src.name
                write_npz_atomic(
                    a.task.dst,
                    overwrite,
                    poses=poses,
                    mask=ld.mask_out,
                    provenance=np.array(json.dumps(prov, sort_keys=True)),
                )
                done(
                    a.i,
                    Outcome(
                        a.task,
                        "repaired",
                        frames=ld.frames,
                        missing=int((~ld.full_mask).sum()),
                        windows=a.job.windows,
                        seconds=time.perf_counter() - a.t0,
                    ),
                )
            except FileExistsError:
                done(a.i, Outcome(a.task, "skipped", "the output appeared during the run", frames=ld.frames))
            except OSError as e:
                done(a.i, Outcome(a.task, "failed", f"cannot write the output: {e}", frames=ld.frames))
            a.progress()
        active = still
        refill()
    return [outcomes[i] for i in sorted(order)]


# ---------------------------------------------------------------------------------------------- public API
def repair_file(
    src: PathLike,
    dst: PathLike,
    model: Any = None,
    *,
    num_samples: Optional[int] = None,
    seed: Optional[int] = DEFAULT_SEED,
    units: str = "m",
    capture: Optional[Capture] = None,
    overlap: int = DEFAULT_OVERLAP,
    lookahead: int = DEFAULT_LOOKAHEAD,
    threads: Optional[int] = None,
    overwrite: bool = False,
    sampler: Optional[SamplerOptions] = None,
) -> Dict[str, Any]:
    """Repairs the pose sequence in ``src`` (an ``.npz`` with ``poses`` (T, J, 3), NaN = missing, and an
    optional ``mask``; or a Human3.6M exp-map ``.txt``) of any length T, and writes ``dst`` (an ``.npz``
    with ``poses``, ``mask`` and ``provenance``) atomically. See :mod:`tcd._repair` for the windowing,
    the frame-rate conversion and the output format; ``tcd repair`` runs the same code on many files.

    Args:
        model: a :class:`tcd.TCD`, a model directory, or ``None`` for the bundled model.
        capture: how the poses were captured, a :class:`tcd.Capture` (``None``: in the model's layout and
            coordinates, at the file's own rate (50 for exp-map ``.txt``, a ``.bvh``'s) or else the model's): another
            joint layout, in world or camera coordinates with ``up`` the vertical axis (``"x"``, ``"y"`` or ``"z"``,
            optionally signed), is converted to the model's convention and back (:mod:`tcd.wild`); its ``fps``, the
            input's frame rate, overrides the file's; rates other than the model's are resampled to it and back.
        overlap: frames shared by consecutive windows (the conditioning on already repaired frames).
        lookahead: trailing frames of each window (but the last) left to the next window, which generates
            them again seeing the frames after them.
        num_samples: samples averaged per window; ``None`` (default) the model's :attr:`tcd.TCD.repair_samples`
            (0, the repair fill alone, for the bundled model).
        seed: the noise seed (default 0): the same seed gives the same output.
        units: ``"m"``, ``"cm"`` or ``"mm"``, the units of the poses (and of the output).
        sampler: a :class:`tcd.SamplerOptions`; ``None`` the model's ``sampling["repair"]``.
        Others: as :meth:`tcd.TCD.repair`.

    Returns a summary dict (``status``, ``frames``, ``missing_values``, ``windows``, ...). Raises
    :class:`tcd.exceptions.InvalidInputError` (``argument="src"``) when ``src`` cannot be repaired,
    ``FileExistsError`` when ``dst`` exists and not ``overwrite``, ``ValueError`` when ``dst`` is ``src``.
    """
    from .._model import TCD, load

    m = model if isinstance(model, TCD) else load(model)
    opts = RepairOptions.make(
        m,
        sampler=sampler,
        num_samples=num_samples,
        seed=seed,
        units=units,
        capture=capture,
        overlap=overlap,
        lookahead=lookahead,
        threads=threads,
    )
    s, d = Path(src), Path(dst)
    if same_path(s, d):
        raise InvalidInputError(f"The output {d} is the input {s}: an input is never overwritten in place.", "dst")
    if d.exists() and not overwrite:
        raise FileExistsError(f"The output file {d} exists; pass overwrite=True to replace it.")
    (o,) = run_tasks(m, [Task(s, d, s.name)], opts, overwrite=overwrite, files_per_batch=1)
    if o.status == "failed":
        raise InvalidInputError(f"{s}: {o.reason}", "src")
    if o.status == "skipped":
        raise FileExistsError(f"The output file {d} exists; pass overwrite=True to replace it.")
    return o.as_dict()


# What an existing output must have been made with to count as finished: everything in its provenance but
# the frame rate (the input's own), the model's path (the same weights may move) and the package version.
_NOT_SETTINGS = ("fps", "model_path", "tcd_version")


def resume_settings(prov: Dict[str, Any]) -> Dict[str, Any]:
    return {k: v for k, v in prov.items() if k not in _NOT_SETTINGS}


def finished_output_mismatch(dst: Path, settings: Dict[str, Any]) -> Optional[str]:
    """None when ``dst`` is a readable tcd repair output made with ``settings``; else what is wrong with it.
    Reads only the provenance (np.load is lazy), not the poses: a resume over many outputs stays cheap."""
    try:
        with np.load(dst, allow_pickle=False) as z:
            if not {"poses", "mask", "provenance"} <= set(z.files):
                return "is not a tcd repair output (it lacks poses, mask or provenance)"
            recorded = json.loads(str(z["provenance"]))
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, AttributeError, TypeError):
        return "is not a readable tcd repair output"
    if not isinstance(recorded, dict):  # provenance that is JSON but not a record
        return "is not a readable tcd repair output"
    differ = sorted(k for k in settings if recorded.get(k) != settings[k])
    if differ:
        shown = ", ".join(f"{k} {recorded.get(k)!r} (this run: {settings[k]!r})" for k in differ)
        return f"was made with other settings: {shown}"
    return None


def same_path(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.normcase(os.path.abspath(a)) == os.path.normcase(os.path.abspath(b)) or a.resolve() == b.resolve()


# ---------------------------------------------------------------------------------------------- planning (CLI)
def collect_tasks(inputs: Sequence[PathLike], outdir: PathLike) -> Tuple[List[Task], List[Outcome]]:
    """Expands files and directories (recursively: ``*.npz``, ``*.txt`` and ``*.bvh``) into tasks writing
    ``outdir/<relative path>.npz``. Files under ``outdir`` are never inputs. Returns (tasks, failures):
    a second input mapping to an already used output path is a failure. Raises ``FileNotFoundError``
    for a missing input and ``ValueError`` when an output path is an input path."""
    out = Path(outdir)
    out_res = out.resolve()
    tasks: List[Task] = []
    failures: List[Outcome] = []
    seen: Dict[str, Task] = {}
    sources: List[Path] = []

    def add(src: Path, rel: Path) -> None:
        dst = out / rel.with_suffix(".npz")
        key = os.path.normcase(str(dst.resolve()))
        task = Task(src, dst, str(rel))
        if key in seen:
            failures.append(Outcome(task, "failed", f"its output {dst} is also the output of {seen[key].src}"))
            return
        seen[key] = task
        tasks.append(task)

    for raw in inputs:
        p = Path(raw)
        if not p.exists():
            raise FileNotFoundError(f"The input {p} does not exist.")
        if p.is_dir():
            found = []
            skip_out = out_res != p.resolve()  # OUTDIR == the input directory: refused below instead
            for f in p.rglob("*"):
                if f.suffix.lower() not in INPUT_SUFFIXES or not f.is_file() or f.name.startswith("."):
                    continue
                fr = f.resolve()
                if skip_out and out_res in fr.parents:
                    continue  # our own outputs (OUTDIR inside an input directory)
                found.append(f)
            for f in sorted(found, key=lambda x: x.relative_to(p).as_posix()):
                sources.append(f)
                add(f, f.relative_to(p))
        else:
            sources.append(p)
            add(p, Path(p.name))
    src_keys = {os.path.normcase(str(s.resolve())) for s in sources}
    for t in tasks:
        if os.path.normcase(str(t.dst.resolve())) in src_keys:
            raise ValueError(f"The output {t.dst} would overwrite the input {t.src}: choose another output directory.")
    return tasks, failures
