"""Offline repair of pose sequences of any length, file by file: ``tcd repair`` and :func:`repair_file`.

Inputs
    * ``.npz`` with ``poses`` ``(T, J, 3)`` (NaN = missing; J = the model's joints, in its order,
      root-relative) and optionally ``mask`` ``(T, J, 3)`` or ``(T, J)`` (1 = observed; entries with
      mask 0 are repaired whatever their value);
    * Human3.6M exp-map ``.txt`` files (99 comma-separated values per row, 50 Hz), converted through
      forward kinematics (:mod:`tcd.fk`) to the 22 model joints; NaN in a joint's exp-map marks the
      joint's descendants missing.

Windows
    The repair model sees W = ``TCD.obs_len`` (50) frames at a time. A sequence of T > W frames is cut
    into overlapping windows starting at 0, S, 2 S, ... and a last one ending at T, with the stride
    S = W - C - L (C = ``overlap``, 5 by default; L = ``lookahead``, 10 by default). They are repaired in
    order. A window commits its frames except its L trailing ones (the last window commits all): those
    were generated without seeing what follows them (a gap running past the window's end is extrapolated),
    so the next window generates them again. In each window after the first, the committed frames (at
    least C) count as observed in the in-painting mask, so the new frames are generated conditioned on them
    and there are no seams. A sequence of T < W frames is padded to W with masked frames (discarded
    afterwards). ``benches/repair_dataset.py`` measured the lookahead: on 8 occluded S5 recordings at
    25 fps (DDPM-10 x 5), ADE 12.6 mm with C = 10, L = 0 against 8.0 mm with C = 5, L = 10.

Frame rates
    Inputs at another rate F than the model's (``TCD.fps``, 25) are resampled to it and back. Forward:
    model frame j (time j / 25) takes the linear interpolation of the two source frames around it; an
    entry counts as observed only when both of them are observed (conservative: a gap never shrinks),
    and model frames past the last source frame are missing. Backward: every source frame takes the
    linear interpolation of the two repaired model frames around it. Either way, the observed entries
    of the output are the input's, bit for bit; only missing entries come from the model.

Noise and determinism
    Window k of a file uses the engine's seeded noise stream ``first_sequence = k`` of ``seed`` (0 by
    default), so a file's result depends only on the file, the model and the settings: not on the
    other files, the batching, the thread count, nor on whether an earlier run was interrupted. Windows
    of several files are batched into one engine call (``files_per_batch`` files in lock step).

Outputs
    ``poses`` (repaired, the input's units and dtype), ``mask`` (the input's ``mask`` as given, else
    the observation mask ``~isnan(poses)`` as bool ``(T, J, 3)``) and ``provenance`` (a JSON string:
    package version, model SHA-256, sampler, steps, samples, seed, ...). Files are written to a
    temporary file in the destination directory and renamed into place, so an output either is
    complete or does not exist.
"""
from __future__ import annotations

import json
import math
import os
import sys
import tempfile
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, Iterable, Iterator, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _checks, fk
from ._native import __version__
from .denoiser import STAGE_SHORT, Denoiser, repair_raw, seeded_noise
from .exceptions import InvalidInputError
from .options import SamplerOptions

__all__ = ["repair_file", "RepairOptions", "DEFAULT_OVERLAP", "DEFAULT_SEED", "INPUT_SUFFIXES"]

PathLike = Union[str, "os.PathLike[str]"]

DEFAULT_OVERLAP = 5
DEFAULT_LOOKAHEAD = 10
DEFAULT_SEED = 0
DEFAULT_FILES_PER_BATCH = 4
INPUT_SUFFIXES = (".npz", ".txt")
_UNIT_SCALE = {"m": 1.0, "mm": 1000.0}
_EPS = 1e-9


class BadFile(Exception):
    """An input that cannot be repaired; ``str(e)`` is the reason."""


# ---------------------------------------------------------------------------------------------- options
@dataclass(frozen=True)
class RepairOptions:
    """Validated settings of a repair run (see :func:`repair_file`)."""

    num_samples: int = 5
    sampling: SamplerOptions = SamplerOptions()
    seed: int = DEFAULT_SEED
    units: str = "m"
    fps: Optional[float] = None
    overlap: int = DEFAULT_OVERLAP
    lookahead: int = DEFAULT_LOOKAHEAD
    threads: Optional[int] = None

    @staticmethod
    def make(model: Any, *, options: Optional[SamplerOptions] = None, sampler: Optional[Dict[str, Any]] = None,
             **kw: Any) -> "RepairOptions":
        """Checked settings: ``options`` / ``sampler`` (its fields) as :meth:`SamplerOptions.build`, the rest
        as the keywords of :func:`repair_file`."""
        sampling = SamplerOptions.build(options, **(sampler or {})).for_model(_denoiser(model).num_train_timesteps)
        seed = kw.get("seed", DEFAULT_SEED)
        fps = kw.get("fps")
        if fps is not None:
            if isinstance(fps, bool) or not isinstance(fps, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(float(fps)) or float(fps) <= 0:
                raise _checks.fail("fps", "a positive frame rate (frames per second)", repr(fps))
            fps = float(fps)
            if model.fps is None:
                raise _checks.fail("fps", "None: the model does not record its frame rate, so inputs cannot be "
                                   "resampled", repr(fps))
        overlap = _checks.integer("overlap", kw.get("overlap", DEFAULT_OVERLAP), 1, model.obs_len - 1)
        lookahead = _checks.integer("lookahead", kw.get("lookahead", DEFAULT_LOOKAHEAD), 0, model.obs_len - 1 - overlap)
        return RepairOptions(
            num_samples=_checks.integer("num_samples", kw.get("num_samples", 5), 1),
            sampling=sampling,
            seed=_checks.integer("seed", DEFAULT_SEED if seed is None else seed, 0, _checks.MAX_SEED),
            units=_checks.choice("units", kw.get("units", "m"), tuple(_UNIT_SCALE)),
            fps=fps,
            overlap=overlap, lookahead=lookahead,
            threads=_checks.threads(kw.get("threads")),
        )


def _denoiser(model: Any) -> Denoiser:
    """The denoiser :meth:`TCD.repair` uses: the repair model, else the short-term model."""
    return model.repair_model if model.repair_model is not None else model.short


def provenance(model: Any, opts: RepairOptions, fps: float) -> Dict[str, Any]:
    den = _denoiser(model)
    steps = len(den.timesteps(options=opts.sampling))
    return {
        "tool": "tcd repair",
        "tcd_version": __version__,
        "model_sha256": model.sha256,
        "model_path": None if model.path is None else str(model.path),
        "repair_model": "repair" if model.repair_model is not None else "short",
        "sampler": opts.sampling.sampler,
        "steps": steps,
        "num_samples": opts.num_samples,
        "eta": opts.sampling.eta,
        "timestep_spacing": opts.sampling.timestep_spacing,
        "seed": opts.seed,
        "units": opts.units,
        "fps": fps,
        "model_fps": model.fps,
        "window": model.obs_len,
        "overlap": opts.overlap,
        "lookahead": opts.lookahead,
    }


# ---------------------------------------------------------------------------------------------- inputs
@dataclass
class Loaded:
    poses: np.ndarray      # (T, J, 3) the caller's values in the output dtype (NaN / anything where missing)
    full_mask: np.ndarray  # (T, J, 3) bool, True = observed
    mask_out: np.ndarray   # what goes to the output's `mask`
    fps: float             # the input's frame rate

    @property
    def frames(self) -> int:
        return int(self.poses.shape[0])


def is_expmap_txt(path: Path) -> bool:
    return path.suffix.lower() == ".txt"


def _read_npz(path: Path) -> Dict[str, np.ndarray]:
    try:
        with open(path, "rb") as fh:
            magic = fh.read(6)
    except OSError as e:
        raise BadFile(f"unreadable: {e}") from None
    if magic == b"\x93NUMPY":
        raise BadFile("unreadable: a single .npy array, not an .npz archive with `poses`")
    if not magic.startswith(b"PK"):
        raise BadFile("unreadable: not an .npz archive (no zip signature)" if magic else "unreadable: the file is empty")
    try:
        with np.load(path, allow_pickle=False) as f:
            if not isinstance(f, np.lib.npyio.NpzFile):
                raise BadFile("unreadable: a single .npy array, not an .npz archive with `poses`")
            return {k: f[k] for k in f.files}
    except BadFile:
        raise
    except AttributeError:  # np.load returned an ndarray (no context manager)
        raise BadFile("unreadable: a single .npy array, not an .npz archive with `poses`") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, KeyError) as e:
        raise BadFile(f"unreadable: not a valid .npz archive ({type(e).__name__}: {e})") from None


def _check_pose_array(a: Any, num_joints: int) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype.kind not in "biuf":
        raise BadFile(f"`poses` has dtype {a.dtype}; a float array (T, {num_joints}, 3) is required")
    if a.ndim != 3 or a.shape[1] != num_joints or a.shape[2] != 3 or a.shape[0] < 1:
        raise BadFile(f"wrong shape: `poses` has shape {_checks.shape_str(a.shape)}; expected (T, {num_joints}, 3) "
                      f"with T >= 1 frames and the model's {num_joints} joints")
    dtype = np.result_type(a.dtype, np.float32) if a.dtype.kind == "f" else np.dtype(np.float64)
    a = a.astype(dtype, copy=False)
    inf = np.isinf(a)
    if inf.any():
        t, j, c = (int(i) for i in np.argwhere(inf)[0])
        raise BadFile(f"`poses` holds an infinite value ({a[t, j, c]}) at frame {t}, joint {j}; "
                      "only finite values and NaN (missing) are allowed")
    return a


def _check_mask(m: Any, a: np.ndarray) -> np.ndarray:
    m = np.asarray(m)
    if m.dtype.kind not in "biuf":
        raise BadFile(f"`mask` has dtype {m.dtype}; 0 (missing) / 1 (observed) values are required")
    if m.shape not in (a.shape, a.shape[:-1]):
        raise BadFile(f"wrong shape: `mask` has shape {_checks.shape_str(m.shape)}; expected "
                      f"{_checks.shape_str(a.shape)} or {_checks.shape_str(a.shape[:-1])}")
    bad = ~((m == 0) | (m == 1))
    if bad.any():
        raise BadFile(f"`mask` holds {m[bad][0]!r} at index {tuple(int(i) for i in np.argwhere(bad)[0])}; "
                      "only 0 (missing) and 1 (observed) are allowed")
    full = m.astype(bool)
    if full.shape != a.shape:
        full = np.repeat(full[..., None], 3, axis=-1)
    clash = full & np.isnan(a)
    if clash.any():
        t, j, _ = (int(i) for i in np.argwhere(clash)[0])
        raise BadFile(f"`poses` is NaN at frame {t}, joint {j}, where `mask` is 1 (observed)")
    return full


def load_input(path: PathLike, num_joints: int, units: str = "m", fps: Optional[float] = None,
               model_fps: Optional[float] = None, joint_index_32: Optional[Sequence[int]] = None) -> Loaded:
    """Reads and checks one input file; raises :class:`BadFile` with the reason when it cannot be repaired."""
    path = Path(path)
    if not path.is_file():
        raise BadFile("unreadable: not a file" if path.exists() else "unreadable: the file does not exist")
    if is_expmap_txt(path):
        if num_joints != 22 or (joint_index_32 is not None and list(joint_index_32) != fk.joints_used()):
            raise BadFile("a Human3.6M exp-map .txt file, but the model does not use the Human3.6M 22-joint layout")
        try:
            rows = fk.read_expmap_txt(path)
        except (OSError, UnicodeDecodeError) as e:
            raise BadFile(f"unreadable: {e}") from None
        except ValueError as e:
            raise BadFile(f"unreadable as a Human3.6M exp-map file: {e}") from None
        if np.isinf(rows).any():
            t, c = (int(i) for i in np.argwhere(np.isinf(rows))[0])
            raise BadFile(f"the exp-map file holds an infinite value at row {t}, column {c}")
        poses = fk.expmap_to_model(rows) * _UNIT_SCALE[units]
        full = ~np.isnan(poses)
        src_fps = fk.H36M_TXT_FPS if fps is None else fps
        mask_out = full
    else:
        data = _read_npz(path)
        if "poses" not in data:
            raise BadFile(f"no `poses` array (the archive holds: {', '.join(sorted(data)) or 'nothing'})")
        poses = _check_pose_array(data["poses"], num_joints)
        if "mask" in data:
            full = _check_mask(data["mask"], poses)
            mask_out = data["mask"]
        else:
            full = ~np.isnan(poses)
            mask_out = full
        src_fps = fps if fps is not None else (model_fps if model_fps is not None else float("nan"))
    if not full.any():
        raise BadFile("every value is missing: nothing to condition the repair on")
    return Loaded(poses=poses, full_mask=full, mask_out=mask_out, fps=src_fps)


def peek_frames(path: Path) -> int:
    """T of an input without loading it (0 when that fails): the npz header or the txt line count."""
    try:
        if is_expmap_txt(path):
            with open(path, "rb") as f:
                return sum(1 for line in f if line.strip())
        with zipfile.ZipFile(path) as z:
            with z.open("poses.npy") as f:
                version = np.lib.format.read_magic(f)
                shape = (np.lib.format.read_array_header_1_0(f) if version == (1, 0)
                         else np.lib.format.read_array_header_2_0(f))[0]
                return int(shape[0]) if len(shape) == 3 else 0
    except Exception:  # noqa: BLE001 - a progress estimate only; the real read reports the problem
        return 0


# ---------------------------------------------------------------------------------------------- resampling
def _resample_forward(x: np.ndarray, m: np.ndarray, src_fps: float, dst_fps: float) -> Tuple[np.ndarray, np.ndarray]:
    """(T, K) values and bool mask at ``src_fps`` -> (T', K) at ``dst_fps`` (see the module doc)."""
    t = x.shape[0]
    n = int(math.ceil((t - 1) * dst_fps / src_fps - _EPS)) + 1
    pos = np.arange(n) * (src_fps / dst_fps)  # fractional source index of each model frame
    i0 = np.floor(pos + _EPS).astype(np.int64)
    frac = pos - i0
    exact = frac < _EPS
    frac = np.where(exact, 0.0, frac)
    inside = i0 < t
    i0c = np.minimum(i0, t - 1)
    i1 = np.where(exact, i0c, np.minimum(i0c + 1, t - 1))
    ok = inside & (exact | (i0 + 1 < t))
    xv = np.where(m, x, 0.0)
    out = (1.0 - frac)[:, None] * xv[i0c] + frac[:, None] * xv[i1]
    out_mask = m[i0c] & m[i1] & ok[:, None]
    return np.where(out_mask, out, 0.0), out_mask


def _resample_backward(y: np.ndarray, frames: int, src_fps: float, dst_fps: float) -> np.ndarray:
    """(T', K) values at ``dst_fps`` -> (frames, K) at ``src_fps`` by linear interpolation."""
    n = y.shape[0]
    pos = np.arange(frames) * (dst_fps / src_fps)
    j0 = np.minimum(np.floor(pos + _EPS).astype(np.int64), n - 1)
    frac = np.clip(pos - j0, 0.0, 1.0)
    frac = np.where(frac < _EPS, 0.0, frac)
    j1 = np.minimum(j0 + 1, n - 1)
    return (1.0 - frac)[:, None] * y[j0] + frac[:, None] * y[j1]


def window_starts(frames: int, window: int, overlap: int, lookahead: int = 0) -> List[int]:
    """Start frames of the windows covering ``frames`` (>= ``window``) frames; consecutive windows share
    at least ``overlap + lookahead`` frames and the last one ends at ``frames``."""
    if not 1 <= overlap + lookahead < window or overlap < 1 or lookahead < 0:
        raise ValueError(f"need overlap >= 1, lookahead >= 0 and overlap + lookahead < window ({window}), "
                         f"got overlap {overlap}, lookahead {lookahead}")
    starts = [0]
    while starts[-1] + window < frames:
        starts.append(min(starts[-1] + window - overlap - lookahead, frames - window))
    return starts


# ---------------------------------------------------------------------------------------------- one file
class FileJob:
    """One input's repair, window by window, in the model's units, layout (frames, K) and frame rate."""

    def __init__(self, loaded: Loaded, window: int, overlap: int, model_fps: Optional[float], units: str,
                 lookahead: int = 0) -> None:
        self.loaded = loaded
        self.scale = _UNIT_SCALE[units]
        p = loaded.poses
        t, j, _ = p.shape
        k = j * 3
        x = np.where(loaded.full_mask, p, 0.0).reshape(t, k).astype(np.float64) / self.scale
        m = loaded.full_mask.reshape(t, k)
        self.resample = (model_fps is not None and math.isfinite(loaded.fps)
                         and abs(loaded.fps - model_fps) > 1e-9 * model_fps)
        if self.resample:
            x, m = _resample_forward(x, m, loaded.fps, float(model_fps))
        self.model_frames = x.shape[0]
        padded = max(self.model_frames, window)
        self.values = np.zeros((padded, k), np.float32)
        self.values[: self.model_frames] = np.where(m, x, 0.0)
        self.mask = np.zeros((padded, k), bool)
        self.mask[: self.model_frames] = m
        self.window = window
        self.starts = window_starts(padded, window, overlap, lookahead)
        self.lookahead = lookahead
        self.k = 0              # next window
        self.done = 0           # frames [0, done) repaired
        self.model_fps = model_fps

    @property
    def finished(self) -> bool:
        return self.k >= len(self.starts)

    @property
    def windows(self) -> int:
        return len(self.starts)

    def next_window(self) -> Tuple[np.ndarray, np.ndarray]:
        """(observed, mask) of the next window, each (K, W) float32: frames already repaired count as observed."""
        s = self.starts[self.k]
        w = self.window
        mask = self.mask[s:s + w].copy()
        if self.done > s:
            mask[: self.done - s] = True
        obs = np.where(mask, self.values[s:s + w], 0.0)
        return np.ascontiguousarray(obs.T, dtype=np.float32), np.ascontiguousarray(mask.T, dtype=np.float32)

    def accept(self, mean: np.ndarray) -> int:
        """Stores the repaired window (K, W); returns the model frames newly repaired (committed). Except in
        the last window, the trailing ``lookahead`` frames are not committed: the next window, which sees
        the frames after them, generates them again."""
        s = self.starts[self.k]
        w = self.window
        first = max(self.done - s, 0)
        self.values[s + first:s + w] = mean.T[first:]
        end = s + w if self.k == len(self.starts) - 1 else s + w - self.lookahead
        new = min(end, self.model_frames) - min(max(self.done, s), self.model_frames)
        self.done = max(self.done, end)
        self.k += 1
        return max(new, 0)

    def result(self) -> np.ndarray:
        """The repaired poses (T, J, 3) in the caller's units and dtype; observed entries bit-identical."""
        ld = self.loaded
        t, j, _ = ld.poses.shape
        y = self.values[: self.model_frames].astype(np.float64)
        if self.resample:
            y = _resample_backward(y, t, ld.fps, float(self.model_fps))
        dtype = ld.poses.dtype
        rep = (y.reshape(t, j, 3) * self.scale).astype(dtype) if self.scale != 1.0 else y.reshape(t, j, 3).astype(dtype)
        return np.where(ld.full_mask, ld.poses, rep)


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
    status: str                     # "repaired", "skipped" or "failed"
    reason: Optional[str] = None
    frames: int = 0
    missing: int = 0                # missing (frame, joint, axis) entries repaired
    windows: int = 0
    seconds: float = 0.0

    def as_dict(self) -> Dict[str, Any]:
        d = {"input": str(self.task.src), "output": str(self.task.dst), "status": self.status,
             "frames": self.frames, "missing_values": self.missing, "windows": self.windows,
             "seconds": round(self.seconds, 4)}
        if self.reason is not None:
            d["reason"] = self.reason
        return d


def run_tasks(model: Any, tasks: Iterable[Task], opts: RepairOptions, *, overwrite: bool = False,
              files_per_batch: int = DEFAULT_FILES_PER_BATCH, on_frames: Optional[Callable[[int], None]] = None,
              on_outcome: Optional[Callable[[Outcome], None]] = None) -> List[Outcome]:
    """Repairs every task, at most ``files_per_batch`` files in memory, their windows batched per engine
    call. Bad inputs and failed writes become ``failed`` outcomes; the run goes on. Returns the outcomes
    in task order."""
    den = _denoiser(model)
    w, k, length = model.obs_len, den.num_features, den.seq_len
    blocks = den.num_noise_blocks(options=opts.sampling)
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
                done(i, Outcome(task, "skipped", "the output exists (pass --overwrite to replace it)", frames=n))
                frames_cb(n)
                continue
            try:
                loaded = load_input(task.src, model.num_joints, opts.units, opts.fps, model.fps, joint_index)
            except BadFile as e:
                done(i, Outcome(task, "failed", str(e), seconds=time.perf_counter() - t0))
                frames_cb(peek_frames(task.src))
                continue
            active.append(Active(i, task, FileJob(loaded, w, opts.overlap, model.fps, opts.units, opts.lookahead), t0))

    refill()
    while active:
        obs, msk, noise = [], [], []
        for a in active:
            o, m = a.job.next_window()
            obs.append(o)
            msk.append(m)
            noise.append(seeded_noise(opts.seed, STAGE_SHORT, opts.num_samples, blocks, 1, k, length,
                                      first_sequence=a.job.k))
        out = repair_raw(den, np.stack(obs), np.stack(msk), num_samples=opts.num_samples,
                         noise=np.concatenate(noise, axis=2), options=opts.sampling, threads=opts.threads)
        del noise
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
                write_npz_atomic(a.task.dst, overwrite, poses=poses, mask=ld.mask_out,
                                 provenance=np.array(json.dumps(prov, sort_keys=True)))
                done(a.i, Outcome(a.task, "repaired", frames=ld.frames, missing=int((~ld.full_mask).sum()),
                                  windows=a.job.windows, seconds=time.perf_counter() - a.t0))
            except FileExistsError:
                done(a.i, Outcome(a.task, "skipped", "the output appeared during the run", frames=ld.frames))
            except OSError as e:
                done(a.i, Outcome(a.task, "failed", f"cannot write the output: {e}", frames=ld.frames))
            a.progress()
        active = still
        refill()
    return [outcomes[i] for i in sorted(order)]


# ---------------------------------------------------------------------------------------------- public API
def repair_file(src: PathLike, dst: PathLike, model: Any = None, *, num_samples: int = 5,
                options: Optional[SamplerOptions] = None, seed: Optional[int] = DEFAULT_SEED, units: str = "m",
                fps: Optional[float] = None, overlap: int = DEFAULT_OVERLAP, lookahead: int = DEFAULT_LOOKAHEAD,
                threads: Optional[int] = None, overwrite: bool = False, **sampler: Any) -> Dict[str, Any]:
    """Repairs the pose sequence in ``src`` (an ``.npz`` with ``poses`` (T, J, 3), NaN = missing, and an
    optional ``mask``; or a Human3.6M exp-map ``.txt``) of any length T, and writes ``dst`` (an ``.npz``
    with ``poses``, ``mask`` and ``provenance``) atomically. See :mod:`tcd.batch_repair` for the windowing,
    the frame-rate conversion and the output format; ``tcd repair`` runs the same code on many files.

    Args:
        model: a :class:`tcd.TCD`, a model directory, or ``None`` for the bundled model.
        fps: the input's frame rate (default: the model's, 50 for exp-map ``.txt``); other rates than
            the model's are resampled to it and back.
        overlap: frames shared by consecutive windows (the conditioning on already repaired frames).
        lookahead: trailing frames of each window (but the last) left to the next window, which generates
            them again seeing the frames after them.
        seed: the noise seed (default 0): the same seed gives the same output.
        units: ``"m"`` or ``"mm"``, the units of the poses (and of the output).
        options, ``**sampler``: the sampler (:class:`tcd.SamplerOptions`, or its fields as keywords).
        Others: as :meth:`tcd.TCD.repair`.

    Returns a summary dict (``status``, ``frames``, ``missing_values``, ``windows``, ...). Raises
    :class:`tcd.exceptions.InvalidInputError` (``argument="src"``) when ``src`` cannot be repaired,
    ``FileExistsError`` when ``dst`` exists and not ``overwrite``, ``ValueError`` when ``dst`` is ``src``.
    """
    from .model import TCD, load

    m = model if isinstance(model, TCD) else load(model)
    opts = RepairOptions.make(m, options=options, sampler=sampler, num_samples=num_samples, seed=seed,
                              units=units, fps=fps, overlap=overlap, lookahead=lookahead, threads=threads)
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


def same_path(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.normcase(os.path.abspath(a)) == os.path.normcase(os.path.abspath(b)) or \
        a.resolve() == b.resolve()


# ---------------------------------------------------------------------------------------------- planning (CLI)
def collect_tasks(inputs: Sequence[PathLike], outdir: PathLike) -> Tuple[List[Task], List[Outcome]]:
    """Expands files and directories (recursively: ``*.npz`` and ``*.txt``) into tasks writing
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


# ---------------------------------------------------------------------------------------------- `tcd repair`
CLI_USAGE = ("tcd repair INPUT... -o OUTDIR [--model DIR] [--units m|mm] [--fps F] [--steps N] [--sampler ddpm|ddim|dpmpp2m] "
             "[--samples N] [--seed S] [--overlap C] [--lookahead L] [--jobs N] [--overwrite] [--report report.json] [--quiet]")


def add_subparser(sub: Any) -> Any:
    """Adds the ``repair`` subcommand to the ``tcd`` argument parser."""
    rp = sub.add_parser(
        "repair", help="repair (fill the missing values of) pose files of any length",
        description="Repair the missing values (NaN or mask 0) of pose sequences of any length: .npz files with "
        "`poses` (T, J, 3) and optional `mask`, Human3.6M exp-map .txt files, or directories of them (recursive). "
        "Writes OUTDIR/<relative path>.npz with `poses`, `mask` and `provenance`; observed values are kept bit for "
        "bit. Finished outputs are skipped on a re-run (resume) unless --overwrite.",
        epilog="Exit codes: 0 every file repaired (or skipped), 1 some file failed (listed on stderr and in the "
        "report), 2 bad arguments, 130 interrupted (re-run the command to resume).")
    rp.add_argument("inputs", nargs="+", metavar="INPUT", help=".npz / .txt files or directories")
    rp.add_argument("-o", "--output", metavar="OUTDIR", required=True, help="output directory (created if needed)")
    rp.add_argument("--model", metavar="DIR", help="model directory (default: the bundled model)")
    rp.add_argument("--units", default="m", help="units of the poses: m (default) or mm (outputs in the same units)")
    rp.add_argument("--fps", type=float, default=None, metavar="F",
                    help="frame rate of the inputs (default: the model's; 50 for exp-map .txt); other rates are "
                    "resampled to the model's and back")
    from .cli import add_sampler_flags
    add_sampler_flags(rp, tuning=False)
    rp.add_argument("--samples", type=int, default=5, metavar="N", help="samples averaged per window (default 5)")
    rp.add_argument("--seed", type=int, default=DEFAULT_SEED, metavar="S",
                    help=f"noise seed (default {DEFAULT_SEED}): the same seed gives the same outputs")
    rp.add_argument("--overlap", type=int, default=DEFAULT_OVERLAP, metavar="C",
                    help=f"frames shared by consecutive windows (default {DEFAULT_OVERLAP})")
    rp.add_argument("--lookahead", type=int, default=DEFAULT_LOOKAHEAD, metavar="L",
                    help="trailing frames of each window regenerated by the next one, which sees what follows "
                    f"them (default {DEFAULT_LOOKAHEAD})")
    rp.add_argument("--jobs", type=int, default=None, metavar="N", help="worker threads (default: all cores)")
    rp.add_argument("--overwrite", action="store_true", help="replace existing outputs (default: skip them)")
    rp.add_argument("--report", metavar="FILE", help="write a JSON report of every input (status, reason, frames)")
    rp.add_argument("--quiet", action="store_true", help="no progress bar and no summary")
    return rp


def _progress_bar(total: int, quiet: bool) -> Any:
    if quiet or not sys.stderr.isatty():
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a dependency
        return None
    return tqdm(total=total, unit="frame", unit_scale=True, desc="tcd repair", file=sys.stderr, dynamic_ncols=True)


def cli(args: Any) -> int:
    """Runs ``tcd repair``; returns the exit code (0 ok, 1 some file failed, 2 bad arguments, 130 interrupted)."""
    from .exceptions import WeightsError
    from .model import load

    def bad(msg: str) -> int:
        print(f"tcd repair: error: {msg}", file=sys.stderr)
        return 2

    out = Path(args.output)
    if out.exists() and not out.is_dir():
        return bad(f"the output {out} exists and is not a directory.")
    try:
        tasks, collisions = collect_tasks(args.inputs, out)
    except (FileNotFoundError, ValueError) as e:
        return bad(str(e))
    if not tasks and not collisions:
        return bad("no input files (.npz, .txt) found in " + ", ".join(str(p) for p in args.inputs) + ".")
    if args.report and any(same_path(Path(args.report), t.src) for t in tasks):
        return bad(f"the report {args.report} would overwrite an input.")
    try:
        model = load(args.model)
    except (FileNotFoundError, NotADirectoryError, WeightsError, InvalidInputError) as e:
        return bad(str(e))
    from .cli import SAMPLER_FLAGS, _BadInput, sampler_options
    try:
        opts = RepairOptions.make(model, options=sampler_options(args), num_samples=args.samples, seed=args.seed,
                                  units=args.units, fps=args.fps, overlap=args.overlap, lookahead=args.lookahead,
                                  threads=args.jobs)
    except _BadInput as e:
        return bad(str(e))
    except InvalidInputError as e:
        flag = {"num_samples": "--samples", "seed": "--seed", "units": "--units", "fps": "--fps",
                "overlap": "--overlap", "lookahead": "--lookahead", "threads": "--jobs",
                **SAMPLER_FLAGS}.get(e.argument or "")
        return bad(f"{e} (`{e.argument}` is {flag}.)" if flag else str(e))
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        return bad(f"cannot create the output directory {out}: {e}")

    for c in collisions:
        print(f"tcd repair: {c.task.src}: failed: {c.reason}", file=sys.stderr)
    bar = _progress_bar(sum(peek_frames(t.src) for t in tasks), args.quiet)

    def on_frames(n: int) -> None:
        if bar is not None:
            bar.update(n)

    def on_outcome(o: Outcome) -> None:
        if o.status == "failed":
            msg = f"tcd repair: {o.task.src}: failed: {o.reason}"
            if bar is not None:
                bar.write(msg, file=sys.stderr)
            else:
                print(msg, file=sys.stderr)

    t0 = time.perf_counter()
    try:
        outcomes = run_tasks(model, tasks, opts, overwrite=args.overwrite,
                             files_per_batch=DEFAULT_FILES_PER_BATCH, on_frames=on_frames, on_outcome=on_outcome)
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        print("tcd repair: interrupted; finished outputs are complete, re-run the command to resume.",
              file=sys.stderr)
        return 130
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - t0
    outcomes = outcomes + collisions
    count = {s: sum(o.status == s for o in outcomes) for s in ("repaired", "skipped", "failed")}
    frames = sum(o.frames for o in outcomes if o.status == "repaired")
    summary = {"files": len(outcomes), **count, "frames_repaired": frames, "seconds": round(seconds, 3),
               "frames_per_second": round(frames / seconds, 2) if seconds > 0 and frames else None}
    if args.report:
        report = {"tool": "tcd repair", "tcd_version": __version__, "model": str(model.path),
                  "model_sha256": model.sha256, "output": str(out),
                  "settings": {"sampler": opts.sampling.sampler, "steps": opts.sampling.num_inference_steps, "samples": opts.num_samples,
                               "seed": opts.seed, "units": opts.units, "fps": opts.fps, "overlap": opts.overlap,
                               "lookahead": opts.lookahead, "jobs": opts.threads, "overwrite": bool(args.overwrite)},
                  "summary": summary, "files": [o.as_dict() for o in outcomes]}
        try:
            write_text_atomic(Path(args.report), json.dumps(report, indent=2) + "\n")
        except OSError as e:
            print(f"tcd repair: error: cannot write the report {args.report}: {e}", file=sys.stderr)
            return 1
    if not args.quiet:
        fps_txt = f", {summary['frames_per_second']} frames/s" if summary["frames_per_second"] else ""
        print(f"tcd repair: {count['repaired']} repaired, {count['skipped']} skipped, {count['failed']} failed "
              f"({frames} frames in {seconds:.1f} s{fps_txt}) -> {out}")
    return 1 if count["failed"] else 0
