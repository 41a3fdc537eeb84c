"""What ``benches/report.py``'s generators read and how they write numbers: the results files and the bundled
model directories (:class:`Sources`, JSON only), and one format for each kind of number."""

from __future__ import annotations

import glob
import hashlib
import json
import struct
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benches" / "results"
DEFAULT_FILES = ("README.md", "MODEL_CARD.md", "docs/**/*.md")
H36M_DIR = "python/tcd/weights"
HUMANEVA_DIR = "python/tcd/weights_humaneva"
SETTING_A_DIR = "python/tcd/weights_h36m_stochastic"
#: the bundled model directories, in the order the generated tables list them
BUNDLED_DIRS = (H36M_DIR, HUMANEVA_DIR, SETTING_A_DIR)
HORIZONS = ("80", "160", "320", "400", "560", "720", "880", "1000")
NONE = "—"


class ReportError(ValueError):
    """A block the report cannot write: an unknown generator, a missing or stale results file, a broken block."""


# ------------------------------------------------------------------------------------------ sources


class Sources:
    """Where the generators read: the results folder and the repository (for the bundled model directories)."""

    def __init__(self, results: Path = RESULTS, root: Path = ROOT):
        self.results, self.root = Path(results), Path(root)
        self.read: list[str] = []  # the files read, in order (for --list)

    def json(self, name: str) -> dict:
        """A results file, ``name`` relative to the results folder."""
        path = self.results / name
        self.read.append(str(path))
        if not path.is_file():
            raise ReportError(f"missing results file {path}")
        try:
            return json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise ReportError(f"results file {path} is not JSON: {e}") from None

    def glob(self, pattern: str) -> list[tuple[str, dict]]:
        """Every results file matching ``pattern`` (relative to the results folder), sorted; none is no error."""
        self.read.append(str(self.results / pattern))
        paths = sorted(glob.glob(str(self.results / pattern)))
        return [(Path(p).stem, json.loads(Path(p).read_text())) for p in paths]

    def repo_json(self, name: str) -> dict:
        path = self.root / name
        self.read.append(str(path))
        if not path.is_file():
            raise ReportError(f"missing file {path}")
        return json.loads(path.read_text())

    def model_sha256(self, model_dir: str) -> str:
        """A model directory's checksum as ``tcd.TCD.sha256`` has it: the sha256 of its SHA256SUMS."""
        path = self.root / model_dir / "SHA256SUMS"
        self.read.append(str(path))
        if not path.is_file():
            raise ReportError(f"missing file {path}")
        return hashlib.sha256(path.read_bytes()).hexdigest()

    def safetensors(self, path: str) -> tuple[dict, dict]:
        """A weight file's tensors ({name: {"shape": ...}}) and its ``tcd_config`` metadata, from its header."""
        p = self.root / path
        self.read.append(str(p))
        if not p.is_file():
            raise ReportError(f"missing weight file {p}")
        with open(p, "rb") as f:
            (n,) = struct.unpack("<Q", f.read(8))
            header = json.loads(f.read(n))
        meta = header.pop("__metadata__", {})
        return header, json.loads(meta.get("tcd_config", "{}"))

    def bundled(self, name: str, sha: str | None, model_dir: str) -> None:
        """Refuse a results file measured on other weights than the bundled ones of ``model_dir``."""
        want = self.model_sha256(model_dir)
        if sha != want:
            raise ReportError(
                f"results file {self.results / name} was measured on the model {sha}, not the bundled "
                f"{model_dir} ({want}): run its benchmark again"
            )


def paper_table(src: Sources, name: str) -> dict:
    """A ``python -m benches.paper`` results file, refused where its models have changed since it was made."""
    d = src.json(name)
    for model_dir, sha in d.get("models", {}).items():
        if src.model_sha256(model_dir) != sha:
            raise ReportError(
                f"results file {src.results / name} scored {model_dir} at {sha}, which has changed "
                f"since: {d.get('command', 'python -m benches.paper')} again"
            )
    return d


def rows_by_key(d: dict, which: str = "our_rows") -> dict:
    return {r["key"]: r for r in d[which]}


# ------------------------------------------------------------------------------------------ formats


def mm(x) -> str:
    return NONE if x is None else f"{x:.1f}"


def metres(x) -> str:
    return NONE if x is None else f"{x:.3f}"


def ratio(x) -> str:
    return NONE if x is None else f"{x:.2f}"


def count(n) -> str:
    return NONE if n is None else f"{int(round(n)):,}"


def ms(seconds) -> str:
    return NONE if seconds is None else f"{1000 * seconds:.1f} ms"


def secs(seconds) -> str:
    return NONE if seconds is None else (f"{seconds:.1f} s" if seconds >= 10 else f"{seconds:.2f} s")


def hours(h) -> str:
    return NONE if h is None else f"{h:.2f}"


def table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def divide(a, b):
    return None if a is None or not b else a / b
