"""Every table of numbers in README.md, MODEL_CARD.md and docs/ from the results files: one number, one source.

    python -m benches.report --write            # rewrite every generated block
    python -m benches.report --check            # exit 1, with a diff, where a block differs from what --write writes
    python -m benches.report --list             # the block names and the files each reads
    python -m benches.report --show NAME        # print one block's Markdown
    python -m benches.report --check README.md docs/usage.md --results DIR     # other files, other results

A generated block is Markdown between two HTML comments naming a generator::

    <!-- report:h36m-forecast -->
    | mm | 80 | ... |
    <!-- /report:h36m-forecast -->

or inline, within a line: ``best of 5 is <!-- report:NAME -->0.75<!-- /report:NAME --> × Zero-Velocity``. The
text between the comments is the generator's output and nothing else: edit the generator (or the results file,
by running its benchmark), never the block. An unknown name, an unclosed block or a missing results file is an
error (exit 2) naming the file and line.

The default files are README.md, MODEL_CARD.md and docs/**/*.md. Generators read JSON only (results files under
``benches/results``, ``--results`` for another folder, and the bundled model directories' ``model.json``,
``SHA256SUMS`` and safetensors headers): no torch, no motion data, so CI runs the check in a second.

Adding a generator: a function ``def name(src: Sources) -> str`` returning Markdown, and one line in
``GENERATORS`` (both in ``benches/report_tables.py``). Formats (``benches/report_sources.py``), one for each
kind of number: mm with 1 decimal (:func:`mm`), metres with 3 (:func:`metres`), ratios with 2 (:func:`ratio`),
counts with thousands separators (:func:`count`).
"""

from __future__ import annotations

import argparse
import difflib
import glob
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from .report_sources import DEFAULT_FILES, RESULTS, ROOT, ReportError, Sources
from .report_tables import GENERATORS


# ------------------------------------------------------------------------------------------ blocks


START = re.compile(r"<!-- report:([A-Za-z0-9_.-]+) -->")
ANY_END = re.compile(r"<!-- /report:([A-Za-z0-9_.-]+) -->")


@dataclass
class Block:
    name: str
    line: int  # 1-based line of the opening comment
    start: int  # offsets of the body (between the comments)
    end: int
    inline: bool


def find_blocks(text: str, where: str) -> list[Block]:
    """The generated blocks of a Markdown text, in order; a broken one is a ReportError naming ``where``:line."""
    blocks, pos = [], 0
    while True:
        m = START.search(text, pos)
        stray = ANY_END.search(text, pos, m.start() if m else len(text))
        if stray:
            raise ReportError(f"{where}:{text.count(chr(10), 0, stray.start()) + 1}: {stray.group(0)} closes no block")
        if not m:
            return blocks
        name, line = m.group(1), text.count("\n", 0, m.start()) + 1
        close = f"<!-- /report:{name} -->"
        end = text.find(close, m.end())
        nested = START.search(text, m.end(), end if end >= 0 else len(text))
        if end < 0 or nested:
            raise ReportError(f"{where}:{line}: block {name!r} is not closed by {close} before the next block")
        body = text[m.end() : end]
        inline = "\n" not in body
        if not inline and not (body.startswith("\n") and body.endswith("\n")):
            raise ReportError(
                f"{where}:{line}: block {name!r}: put each of its comments on a line of its own, or "
                "the whole block within one line"
            )
        blocks.append(Block(name, line, m.end(), end, inline))
        pos = end + len(close)


def render(text: str, where: str, src: Sources, cache: dict | None = None) -> tuple[str, list[tuple[Block, str]]]:
    """``text`` with every block regenerated, and the blocks whose body changed (with the new body)."""
    cache = {} if cache is None else cache
    out, last, changed = [], 0, []
    for b in find_blocks(text, where):
        if b.name not in GENERATORS:
            raise ReportError(f"{where}:{b.line}: unknown block {b.name!r}; the blocks: {', '.join(GENERATORS)}")
        if b.name not in cache:
            try:
                cache[b.name] = GENERATORS[b.name](src).strip("\n")
            except ReportError as e:
                raise ReportError(f"{where}:{b.line}: block {b.name!r}: {e}") from None
        content = cache[b.name]
        if b.inline:
            if "\n" in content:
                raise ReportError(f"{where}:{b.line}: block {b.name!r} is inline but its generator writes lines")
            body = content
        else:
            body = "\n" + content + "\n" if content else "\n"
        if text[b.start : b.end] != body:
            changed.append((b, body))
        out += [text[last : b.start], body]
        last = b.end
    out.append(text[last:])
    return "".join(out), changed


def default_files(root: Path = ROOT) -> list[Path]:
    files = []
    for pattern in DEFAULT_FILES:
        files += sorted(Path(p) for p in glob.glob(str(root / pattern), recursive=True))
    return [f for f in files if f.is_file()]


def _name(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benches.report", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    what = ap.add_mutually_exclusive_group(required=True)
    what.add_argument("--write", action="store_true", help="rewrite every generated block")
    what.add_argument("--check", action="store_true", help="exit 1 where a block differs from what --write writes")
    what.add_argument("--list", action="store_true", help="the block names and the files each reads")
    what.add_argument("--show", metavar="NAME", help="print block NAME's Markdown")
    ap.add_argument(
        "files", nargs="*", type=Path, help="Markdown files (default: README.md, MODEL_CARD.md, docs/**/*.md)"
    )
    ap.add_argument("--results", type=Path, default=RESULTS, help="the results folder (default benches/results)")
    args = ap.parse_args(argv)
    try:
        if args.list or args.show:
            names = [args.show] if args.show else list(GENERATORS)
            for name in names:
                if name not in GENERATORS:
                    raise ReportError(f"unknown block {name!r}; the blocks: {', '.join(GENERATORS)}")
                src = Sources(args.results)
                md = GENERATORS[name](src)
                if args.show:
                    print(md)
                else:
                    reads = sorted({_name(Path(p)) for p in src.read})
                    print(
                        f"{name}: {(GENERATORS[name].__doc__ or '').strip().splitlines()[0]}\n    reads "
                        + ", ".join(reads)
                    )
            return 0
        src, cache = Sources(args.results), {}
        files = args.files or default_files()
        differ = 0
        for f in files:
            if not f.is_file():
                raise ReportError(f"no such file {f}")
            text = f.read_text()
            new, changed = render(text, _name(f), src, cache)
            if args.check:
                for b, body in changed:
                    differ += 1
                    old = text[b.start : b.end]
                    for line in difflib.unified_diff(
                        old.strip("\n").splitlines(),
                        body.strip("\n").splitlines(),
                        f"{_name(f)}:{b.line} {b.name} (as written)",
                        f"{_name(f)}:{b.line} {b.name} (as generated)",
                        lineterm="",
                    ):
                        print(line)
            elif new != text:
                f.write_text(new)
                print(f"{_name(f)}: {len(changed)} block(s) rewritten: {', '.join(b.name for b, _ in changed)}")
        if args.check and differ:
            print(
                f"benches.report: {differ} block(s) differ from the results files; "
                "python -m benches.report --write rewrites them",
                file=sys.stderr,
            )
            return 1
        return 0
    except ReportError as e:
        print(f"benches.report: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
