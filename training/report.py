"""Markdown tables from ``python -m training.evaluate --json`` outputs (for the model card and README).

    python -m training.report runs/eval/*.json [--per-frame]

One block per file: mean-of-n (deployable), oracle best-of-n and Zero-Velocity on the same windows, at
80 ... 1000 ms, with the ratio to Zero-Velocity at 1000 ms; the repair ADE when the run had a mask; the
command that produced the file.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HORIZONS = ("80", "160", "320", "400", "560", "720", "880", "1000")


def _row(name: str, avg: dict, zv1000: float | None) -> str:
    cells = " | ".join(f"{avg[h]:.1f}" for h in HORIZONS)
    ratio = f"{avg['1000'] / zv1000:.3f}" if zv1000 else ""
    return f"| {name} | {cells} | {ratio} |"


def table(d: dict, per_frame: bool = False) -> str:
    p = d["protocol"]
    zv = d["zero_velocity"]["average"]
    title = (
        f"**{d.get('method', 'baseline')}**, mask `{p.get('mask', 'none')}`, "
        f"{p['windows_per_action']} windows/action × {len(p['actions'])} actions"
    )
    if "sampling" in d:
        s = d["sampling"]
        title += f"; {s['sampler']} {s['steps']} steps, {s['samples']} samples, engine {s['engine']}"
    lines = [title, "", "| mm | " + " | ".join(HORIZONS) + " | ÷ ZV @1000 |", "|---" * (len(HORIZONS) + 2) + "|"]
    if "mean_of_n" in d:
        lines.append(_row(d["mean_of_n"]["label"], d["mean_of_n"]["average"], zv["1000"]))
        lines.append(_row(d["best_of_n"]["label"], d["best_of_n"]["average"], zv["1000"]))
    lines.append(
        _row("Zero-Velocity, same windows" + (" and observations" if p.get("mask", "none") != "none" else ""), zv, None)
    )
    if "zero_velocity_on_repaired" in d:
        lines.append(
            _row("Zero-Velocity on the tcd-repaired observation", d["zero_velocity_on_repaired"]["average"], zv["1000"])
        )
    if "repair" in d:
        r = d["repair"]
        lines += [
            "",
            f"Repair ADE over the occluded observation entries: **{r['ade_mm']:.2f} mm** "
            f"({r['occluded_entries']} entries).",
        ]
    if per_frame and "mean_of_n" in d:
        pf = d["mean_of_n"]["per_frame"]
        lines += ["", "Per frame (mean of n, 40 ms steps): " + ", ".join(f"{v:.1f}" for v in pf)]
    lines += ["", f"`{d.get('command', '?')}`"]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m training.report", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("files", nargs="+")
    ap.add_argument("--per-frame", action="store_true", help="also list the 25 per-frame errors")
    args = ap.parse_args(argv)
    for f in args.files:
        print(table(json.loads(Path(f).read_text()), args.per_frame))
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
