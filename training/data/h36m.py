"""Human3.6M exp-map data (Setting-B, spec section 3.1 and 10.2).

Source: either the packed ``h36m_expmap_50fps.npz`` (keys ``S5/walking_1``, (T, 99) float32 at 50 Hz)
or the standard tree ``[dataset/]S{s}/{action}_{n}.txt`` (99 comma-separated columns per row).
Pipeline: every 2nd frame (50 Hz -> 25 fps) -> root position and root rotation zeroed -> forward
kinematics on the 32-joint skeleton (mm) -> the 22 model joints in metres, (T, 22, 3).
"""

from __future__ import annotations

import hashlib
import json
import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from tcd.layouts import NAMES32  # the 32-joint skeleton's names: the package's, one list

from .kinematics import SKELETON_PATH, fk_expmap

REPO_ROOT = Path(__file__).resolve().parents[2]
DEFAULT_DATA_ROOT = Path(os.environ.get("TCD_DATA_DIR", REPO_ROOT.parent / "shared" / "data"))
DEFAULT_H36M_DIR = DEFAULT_DATA_ROOT / "h36m"

ACTIONS = (
    "walking",
    "eating",
    "smoking",
    "discussion",
    "directions",
    "greeting",
    "phoning",
    "posing",
    "purchases",
    "sitting",
    "sittingdown",
    "takingphoto",
    "waiting",
    "walkingdog",
    "walkingtogether",
)
SPLITS = {"train": (1, 6, 7, 8, 9), "val": (11,), "test": (5,)}
FPS = 25
SOURCE_FPS = 50
TEST_SEED = 1234567890


@lru_cache(maxsize=1)
def skeleton() -> dict:
    """The 32-joint skeleton (parents, offsets in mm, the 22-joint subset, duplicated joints)."""
    with open(SKELETON_PATH) as f:
        sk = json.load(f)
    sk["offsets_mm"] = np.asarray(sk["offsets_mm"], dtype=np.float64)
    sk["joints_copied_at_evaluation"] = {int(k): int(v) for k, v in sk["joints_copied_at_evaluation"].items()}
    return sk


def joints_used() -> list[int]:
    return list(skeleton()["joints_used_22"])


def joint_names_22() -> list[str]:
    return [NAMES32[j] for j in joints_used()]


class H36MSource:
    """Raw 50 Hz exp-map sequences, from the packed npz or the txt tree."""

    def __init__(self, data_dir: str | os.PathLike = DEFAULT_H36M_DIR):
        self.dir = Path(data_dir)
        npz = self.dir / "h36m_expmap_50fps.npz" if self.dir.is_dir() else self.dir
        if npz.is_file() and npz.suffix == ".npz":
            self._npz = np.load(npz)
            self.keys = set(self._npz.files)
            self.origin = str(npz)
        else:
            root = self.dir / "dataset" if (self.dir / "dataset").is_dir() else self.dir
            files = sorted(root.glob("S*/*_*.txt"))
            if not files:
                raise FileNotFoundError(
                    f"no Human3.6M exp-map data in {self.dir}: expected h36m_expmap_50fps.npz or S*/<action>_<n>.txt"
                )
            self._npz = None
            self._files = {f"{f.parent.name}/{f.stem}": f for f in files}
            self.keys = set(self._files)
            self.origin = str(root)

    def has(self, subject: int, action: str, subact: int) -> bool:
        return f"S{subject}/{action}_{subact}" in self.keys

    def raw(self, subject: int, action: str, subact: int) -> np.ndarray:
        key = f"S{subject}/{action}_{subact}"
        if key not in self.keys:
            raise KeyError(f"{key} is not in {self.origin}")
        if self._npz is not None:
            return np.asarray(self._npz[key], dtype=np.float64)
        return np.loadtxt(self._files[key], delimiter=",", dtype=np.float64)

    def fingerprint(self) -> str:
        return hashlib.sha1(("|".join(sorted(self.keys)) + self.origin).encode()).hexdigest()[:12]


def expmap_to_xyz32(seq: np.ndarray, sample_rate: int = 2) -> np.ndarray:
    """(T, 99) exp-map at 50 Hz -> (T', 32, 3) joint positions in mm at 50/sample_rate fps, root removed."""
    seq = np.asarray(seq, dtype=np.float64)[::sample_rate].copy()
    if seq.ndim != 2 or seq.shape[1] != 99:
        raise ValueError(f"expected exp-map rows of 99 values, got shape {seq.shape}")
    seq[:, 0:6] = 0.0  # global translation and rotation removed
    sk = skeleton()
    return fk_expmap(seq[:, 3:].reshape(-1, 32, 3), sk["parents"], sk["offsets_mm"])


def xyz32_to_model(xyz32_mm: np.ndarray) -> np.ndarray:
    """(..., 32, 3) mm -> (..., 22, 3) metres in the model's joint order."""
    return (xyz32_mm[..., joints_used(), :] / 1000.0).astype(np.float32)


def model_to_xyz32(pred_m: np.ndarray, gt32_mm: np.ndarray) -> np.ndarray:
    """Paste 22 predicted joints (metres) into the ground-truth 32-joint skeleton (mm) and copy the
    duplicated joints, the HRI/TCD evaluation convention. Shapes (..., 22, 3) and (..., 32, 3)."""
    out = np.array(gt32_mm, dtype=np.float64, copy=True)
    out[..., joints_used(), :] = np.asarray(pred_m, dtype=np.float64) * 1000.0
    for dst, src in skeleton()["joints_copied_at_evaluation"].items():
        out[..., dst, :] = out[..., src, :]
    return out


def find_indices_256(
    n1: int, n2: int, seq_len: int, input_n: int = 50, draws: int = 128, seed: int = TEST_SEED
) -> tuple[np.ndarray, np.ndarray]:
    """The HRI/SRNN test-window draw: one RandomState(seed) per action, draws alternating between the two
    sub-actions, idx ~ randint(16, n - 150); window = frames idx + 50 - input_n ... + seq_len.
    Returns start frames for sub-action 1 and 2 (``draws`` each)."""
    rng = np.random.RandomState(seed)
    s1, s2 = [], []
    for _ in range(draws):
        i1 = rng.randint(16, n1 - 150)
        i2 = rng.randint(16, n2 - 150)
        s1.append(i1 + 50 - input_n)
        s2.append(i2 + 50 - input_n)
    return np.asarray(s1), np.asarray(s2)


class H36M:
    """Processed Human3.6M with a disk cache of the 25 fps 32-joint positions (mm, float32)."""

    def __init__(self, data_dir: str | os.PathLike = DEFAULT_H36M_DIR, cache_dir: str | os.PathLike | None = None):
        self.source = H36MSource(data_dir)
        cache_dir = Path(cache_dir or os.environ.get("TCD_CACHE_DIR", Path.home() / ".cache" / "tcd"))
        self.cache_path = cache_dir / f"h36m_xyz32_{self.source.fingerprint()}.npz"
        self._xyz: dict[str, np.ndarray] | None = None

    def _load_all(self) -> dict[str, np.ndarray]:
        if self._xyz is None:
            if self.cache_path.is_file():
                with np.load(self.cache_path) as z:
                    self._xyz = {k: z[k] for k in z.files}
            else:
                self._xyz = {}
                for key in sorted(self.source.keys):
                    subj, rest = key.split("/")
                    action, sub = rest.rsplit("_", 1)
                    expmap = self.source.raw(int(subj[1:]), action, int(sub))
                    self._xyz[key] = expmap_to_xyz32(expmap).astype(np.float32)
                try:
                    self.cache_path.parent.mkdir(parents=True, exist_ok=True)
                    tmp = self.cache_path.with_suffix(".tmp.npz")
                    np.savez(tmp, **self._xyz)
                    os.replace(tmp, self.cache_path)
                except OSError:
                    pass  # a read-only home only costs recomputation
        return self._xyz

    def xyz32(self, subject: int, action: str, subact: int) -> np.ndarray:
        """(T, 32, 3) mm at 25 fps."""
        return self._load_all()[f"S{subject}/{action}_{subact}"]

    def sequences(self, split: str, actions=ACTIONS) -> list[tuple[str, np.ndarray]]:
        """[(key, (T, 22, 3) metres)] for a split's subjects."""
        out = []
        for subj in SPLITS[split]:
            for action in actions:
                for sub in (1, 2):
                    if self.source.has(subj, action, sub):
                        out.append((f"S{subj}/{action}_{sub}", xyz32_to_model(self.xyz32(subj, action, sub))))
        return out

    def test_actions(self, subject: int = 5) -> list[str]:
        """Actions with at least one sub-action for the subject (13 of 15 for our S5 copy)."""
        return [a for a in ACTIONS if self.source.has(subject, a, 1) or self.source.has(subject, a, 2)]

    def test_windows(
        self,
        action: str,
        seq_len: int = 75,
        input_n: int = 50,
        per_action: int = 256,
        subject: int = 5,
        seed: int = TEST_SEED,
    ) -> np.ndarray:
        """The 256-per-action protocol (section 10.2): (W, seq_len, 32, 3) mm. Where only one sub-action exists,
        both draw streams index it. ``per_action`` < 256 keeps the first windows of the interleaved order
        (1, 2, 1, 2, ...), so smaller evaluations are prefixes of the full one."""
        subs = [s for s in (1, 2) if self.source.has(subject, action, s)]
        if not subs:
            raise KeyError(f"S{subject}/{action} has no data in {self.source.origin}")
        seq1 = self.xyz32(subject, action, subs[0])
        seq2 = self.xyz32(subject, action, subs[-1])
        st1, st2 = find_indices_256(len(seq1), len(seq2), seq_len, input_n, seed=seed)
        wins = []
        for a, b in zip(st1, st2):
            wins.append(seq1[a : a + seq_len])
            wins.append(seq2[b : b + seq_len])
        return np.stack(wins[:per_action]).astype(np.float64)


def random_windows(seqs: list, n: int, length: int, rng: np.random.Generator) -> np.ndarray:
    """(n, length, ...) float32: ``n`` windows of ``seqs``, each a sequence, then a start, drawn uniformly from
    ``rng`` (the repair benchmark's draw, ``benches/repair_quality.py``, and the in-betweener's training windows)."""
    out = []
    for _ in range(n):
        x = seqs[int(rng.integers(len(seqs)))]
        s = int(rng.integers(0, len(x) - length + 1))
        out.append(x[s : s + length])
    return np.stack(out).astype(np.float32)


def train_windows_index(seqs: list[np.ndarray], seq_len: int, stride: int = 1) -> np.ndarray:
    """(N, 2) array of (sequence index, start frame) for all windows of seq_len frames with the given stride."""
    idx = [(i, s) for i, seq in enumerate(seqs) for s in range(0, len(seq) - seq_len + 1, stride)]
    return np.asarray(idx, dtype=np.int64).reshape(-1, 2)
