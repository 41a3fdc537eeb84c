"""The generated table of docs/wild.md (``benches/report.py``): forecasts from the wild, per layout and source,
beside Zero-Velocity on the same input (``benches/in_the_wild.py``)."""

from __future__ import annotations

from .report_sources import H36M_DIR, Sources, mm, ratio, table

RESULTS = "in_the_wild.json"


def wild_layouts(src: Sources) -> str:
    """Each input path's forecast error, root-relative (the native input: its canonical space), at the first
    forecast frame, 0.5 s and 1 s, clean and with each noise level of the run."""
    d = src.json(RESULTS)
    p = d["protocol"]
    src.bundled(RESULTS, p.get("model_sha256"), H36M_DIR)
    rows = []
    for r in d["rows"]:
        if r["space"] not in ("canonical", "root-relative"):
            continue
        t, z = r["tcd_mm"], r["zero_velocity_mm"]
        rows.append(
            [r["input"], f"{mm(t['first'])} / {mm(z['first'])}", f"{mm(t['0.5s'])} / {mm(z['0.5s'])}"]
            + [f"{mm(t['1s'])} / {mm(z['1s'])}", ratio(r["ratio_first"]), ratio(r["ratio_1s"])]
        )
    caption = (
        f"**From the wild** (mm, mean of {p['samples']} samples, {p['sampler'].upper()}-{p['steps']}; Human3.6M S5's "
        f"first {p['windows_per_action']} windows per action; tcd / Zero-Velocity on the same input, each joint held "
        "where the input last showed it; root-relative, the native input in its canonical space):\n\n"
    )
    header = ["input", "first frame", "0.5 s", "1 s", "ratio, first", "ratio, 1 s"]
    return caption + table(header, rows)
