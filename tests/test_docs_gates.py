"""The user-facing documents describe the package, not how it was made: README.md and MODEL_CARD.md stay short, and
neither they nor docs/**/*.md keep a development diary (no "installment", "session", "lent" or "lease" as words, no
"until / since / before <a date>"). The version CITATION.cff and CHANGELOG.md name is the Cargo workspace's.

The words are matched whole, case-insensitively, so "release", "silent", "talent" or "leaseholder" never count; an
API name that merely contains one (ONNX Runtime's ``InferenceSession``, ``SessionOptions``) has no word boundary
around it and is not matched either. No other exemption: a document that needs one of the words in a product sense
should say it another way. No data needed."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = {"README.md": 150, "MODEL_CARD.md": 250}

#: diary words, whole words (plurals and "leased" included)
DIARY_WORDS = re.compile(r"\b(?:installments?|sessions?|lent|leases?|leased)\b", re.IGNORECASE)
_MONTH = (
    r"(?:jan(?:uary)?|feb(?:ruary)?|mar(?:ch)?|apr(?:il)?|may|june?|july?|aug(?:ust)?|sep(?:t(?:ember)?)?"
    r"|oct(?:ober)?|nov(?:ember)?|dec(?:ember)?)"
)
_DATE = (
    r"(?:(?:19|20)\d{2}-(?:0?[1-9]|1[0-2])(?:-\d{1,2})?\b"  # 2026-11-28, 2026-11
    r"|\d{1,2}/\d{1,2}/\d{2,4}\b"  # 28/11/2026
    rf"|{_MONTH}\.?\s+\d{{1,4}}\b"  # Nov 28, November 2026, Nov. 28
    rf"|\d{{1,2}}(?:st|nd|rd|th)?\s+(?:of\s+)?{_MONTH}\b)"
)  # 28 November, 28th of Nov
#: "until / since / before" (or "till") and a date, across a line break too
DIARY_DATES = re.compile(rf"\b(?:until|till|since|before)\s+(?:the\s+)?{_DATE}", re.IGNORECASE)


def diary_hits(text: str) -> list[tuple[int, str]]:
    """(line number, the text matched) of every diary word and every "until / since / before <date>" in
    ``text``, in order; a phrase broken over lines is reported at the line it starts on."""
    hits = [(m.start(), m.group(0)) for pattern in (DIARY_WORDS, DIARY_DATES) for m in pattern.finditer(text)]
    return [(text.count("\n", 0, start) + 1, " ".join(found.split())) for start, found in sorted(hits)]


def documents() -> list[Path]:
    return [ROOT / "README.md", ROOT / "MODEL_CARD.md", *sorted((ROOT / "docs").rglob("*.md"))]


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


@pytest.mark.parametrize("name", sorted(MAX_LINES))
def test_front_documents_stay_short(name):
    lines = (ROOT / name).read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_LINES[name], f"{name}: {len(lines)} lines, at most {MAX_LINES[name]}"


@pytest.mark.parametrize("path", documents(), ids=_rel)
def test_no_development_diary(path):
    text = path.read_text(encoding="utf-8")
    lines = text.splitlines()
    hits = [f"{_rel(path)}:{n}: {found!r} in: {lines[n - 1].strip()[:100]}" for n, found in diary_hits(text)]
    assert not hits, (
        f"{len(hits)} development-diary phrase(s); say what the code does, not when or in which "
        "sitting it was done:\n" + "\n".join(hits)
    )


def test_diary_hits_finds_the_diary_and_nothing_else():
    diary = (
        "The short model's installment 1, trained on lent GPUs\n"
        "(bundled in the twentieth Session; the fourth lease's weights) and two sessions earlier,\n"
        "valid until 2026-11-28, used since Nov 28, refused before\n"
        "28 November and since the 3rd of December; since November 2026 it leased a GPU.\n"
    )
    assert diary_hits(diary) == [
        (1, "installment"),
        (1, "lent"),
        (2, "Session"),
        (2, "lease"),
        (2, "sessions"),
        (3, "until 2026-11-28"),
        (3, "since Nov 28"),
        (3, "before 28 November"),
        (4, "since the 3rd of December"),
        (4, "since November 2026"),
        (4, "leased"),
    ]
    clean = (
        "A release is silent about talent; ort.InferenceSession(path, ort.SessionOptions()) runs the peer.\n"
        "Since the prior forecasts, the samples spread; until convergence, before 50 steps, since 2 cores\n"
        "are few. Training lasts 12 h; a leaseholder is no diary, nor is a session_id or a sessionless call.\n"
        "From 2026-11-28 is not one of the three words; the 25 fps clip is from May, before the data.\n"
    )
    assert diary_hits(clean) == []


def _workspace_version() -> str:
    cargo = (ROOT / "Cargo.toml").read_text(encoding="utf-8")
    package = cargo.split("[workspace.package]", 1)[1].split("\n[", 1)[0]
    match = re.search(r'^version\s*=\s*"([^"]+)"', package, re.MULTILINE)
    assert match, "Cargo.toml: no version under [workspace.package]"
    return match.group(1)


def test_citation_and_changelog_name_the_workspace_version():
    version = _workspace_version()
    cff = re.search(r"^version:\s*['\"]?([^'\"\s]+)", (ROOT / "CITATION.cff").read_text(encoding="utf-8"), re.MULTILINE)
    assert cff and cff.group(1) == version, f"CITATION.cff version {cff and cff.group(1)!r}, Cargo.toml {version!r}"
    changelog = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    assert re.search(rf"^## \[?{re.escape(version)}\]?(\s|$)", changelog, re.MULTILINE), (
        f"CHANGELOG.md has no '## {version}' section"
    )
