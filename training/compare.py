"""The paired comparison that decides whether new weights replace the bundled ones.

    python -m training.compare NEW.json BUNDLED.json [--key average] [--bundled-key KEY] [--horizon 1000]
        [--margin 0.01]

Both files are ``training.evaluate --json`` results of the same protocol (same windows, patterns and seeds:
checked). The test is paired over actions: for every action both evaluated, the difference of the two
per-action errors at ``--horizon`` ms (``--key``: ``average`` = what each run reported first, or
``mean_of_n`` / ``best_of_n`` for a TCD run; ``--bundled-key`` reads BUNDLED's under another key, e.g. a TCD run's
``mean_of_n`` against a prior's ``average``). NEW is better when its mean error is lower by more than
``--margin`` (relative) AND the mean paired difference is below zero by more than two standard errors;
BUNDLED is better in the mirror case; otherwise the difference is within sampling noise (keep what is
bundled). Exit status 0 when NEW is better, 1 otherwise, so a script can gate on it.

Results of the HumanEva-I protocol (``--protocol humaneva``) are paired over its windows instead: ``--key`` is
one of ADE (default for them), FDE, MMADE, MMFDE, or mean_ADE / mean_FDE (the samples' mean, where both runs
recorded it; lower is better), of the ``model`` each run scored, ``--horizon`` does not apply.

Results of ``benches/repair_quality.py --json`` are paired over its windows too: ``--key PATTERN[:METHOD]``, the
pattern (``random_leg_arm``, ``consecutive_frames``, ``random_joints``) and the method (``tcd``, the default, or
``linear``, ``savgol``, ``spline``), each window's ADE over its hidden entries; ``--bundled-key`` names BUNDLED's
(``--key random_leg_arm --bundled-key random_leg_arm:spline`` with the same file twice: the model against the
spline). ``new`` and ``bundled`` are then means over windows, not the table's mean over hidden entries.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


HUMANEVA_KEYS = ("ADE", "FDE", "MMADE", "MMFDE", "mean_ADE", "mean_FDE")  # mean_*: the samples' mean


def is_humaneva(result: dict) -> bool:
    return result.get("protocol", {}).get("dataset") == "humaneva-i"


def per_window(result: dict, key: str) -> dict[str, float]:
    """A HumanEva-I result's model metric on each window, keyed by the window's position."""
    if key not in HUMANEVA_KEYS:
        raise ValueError(f"--key for a HumanEva-I result is one of {HUMANEVA_KEYS}, got {key!r}")
    # a --model run scores its model; a --prior run (no model) scores the prior's point forecast
    scored = result["model"] if "model" in result else result.get("prior", {})
    if "per_window" not in scored:
        raise ValueError(
            "the HumanEva-I result has no per-window values of a model or a prior (run "
            "training.evaluate --protocol humaneva --model DIR or --prior DIR: they record them)"
        )
    return {str(i): float(v) for i, v in enumerate(scored["per_window"][key])}


def is_repair(result: dict) -> bool:
    return result.get("protocol", {}).get("task") == "repair"


def per_repair_window(result: dict, key: str) -> dict[str, float]:
    """A repair benchmark's ADE on each window of one pattern, for one method: ``key`` is ``PATTERN[:METHOD]``."""
    pattern, _, method = key.partition(":")
    rows = {p: r for (p, _), r in zip(result["protocol"]["patterns"], result["results"])}
    if pattern not in rows:
        raise ValueError(
            f"--key for a repair result is PATTERN[:METHOD] with PATTERN one of {sorted(rows)}, got {key!r}"
        )
    row = rows[pattern]
    method = method or "tcd"
    if "per_window_mm" not in row.get(method, {}):
        known = sorted(k for k, v in row.items() if isinstance(v, dict) and "per_window_mm" in v)
        raise ValueError(f"the repair result has no per-window values of method {method!r} (one of {known})")
    return {str(i): float(v) for i, v in enumerate(row[method]["per_window_mm"]) if v is not None}


def per_action(result: dict, key: str, horizon: str) -> dict[str, float]:
    if is_repair(result):
        return per_repair_window(result, key)
    if is_humaneva(result):
        return per_window(result, "ADE" if key == "average" else key)
    if key == "average":
        table = result["per_action"]
    elif key in result:
        table = result[key]["per_action"]
    else:
        raise ValueError(f"the result has no {key!r} (keys: {sorted(result)})")
    return {a: float(v[horizon]) for a, v in table.items()}


def compare(
    new: dict,
    old: dict,
    *,
    key: str = "average",
    horizon: str = "1000",
    margin: float = 0.01,
    old_key: str | None = None,
) -> dict:
    for what in ("protocol", "seeds"):
        for name, res in (("NEW", new), ("BUNDLED", old)):
            if not isinstance(res.get(what), dict):
                raise ValueError(
                    f"{name} has no {what!r}: not a result of training.evaluate --json or of "
                    "benches/repair_quality.py --json (repair results written before 2026-11-26 have "
                    "none)"
                )
        a = {k: v for k, v in new[what].items() if k != "data"}
        b = {k: v for k, v in old[what].items() if k != "data"}
        if a != b:
            raise ValueError(f"the two results were not measured on the same {what}: {a} against {b}")
    pa, pb = per_action(new, key, horizon), per_action(old, key if old_key is None else old_key, horizon)
    actions = sorted(set(pa) & set(pb))
    if len(actions) < 2:
        raise ValueError(f"a paired test needs at least 2 actions (or windows) in common, got {actions}")
    d = np.array([pa[a] - pb[a] for a in actions])
    se = float(d.std(ddof=1) / np.sqrt(len(d)))
    xa, xb = float(np.mean([pa[a] for a in actions])), float(np.mean([pb[a] for a in actions]))
    verdict = "within noise"
    if abs(xa - xb) > margin * max(xa, xb) and abs(d.mean()) > 2 * se:
        verdict = "new is better" if d.mean() < 0 else "bundled is better"
    unit = "windows" if is_humaneva(new) or is_repair(new) else "actions"
    return {
        "horizon_ms": None if unit == "windows" else horizon,
        "key": key,
        **({} if old_key is None else {"bundled_key": old_key}),
        unit: len(actions),
        "new": xa,
        "bundled": xb,
        "mean_difference": float(d.mean()),
        "standard_error": se,
        "new_better_on": int((d < 0).sum()),
        "margin": margin,
        "verdict": verdict,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m training.compare", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("new")
    ap.add_argument("bundled")
    ap.add_argument(
        "--key",
        default="average",
        help="average (default), mean_of_n or best_of_n; HumanEva-I: ADE (= average), FDE, MMADE, MMFDE; "
        "repair benchmark: PATTERN[:METHOD]",
    )
    ap.add_argument("--bundled-key", default=None, help="BUNDLED's key, when not --key's")
    ap.add_argument("--horizon", default="1000", help="ms (default 1000)")
    ap.add_argument("--margin", type=float, default=0.01, help="relative difference that counts (default 0.01)")
    args = ap.parse_args(argv)
    res = compare(
        *(json.loads(Path(p).read_text()) for p in (args.new, args.bundled)),
        key=args.key,
        horizon=args.horizon,
        margin=args.margin,
        old_key=args.bundled_key,
    )
    print(json.dumps(res, indent=1))
    return 0 if res["verdict"] == "new is better" else 1


if __name__ == "__main__":
    sys.exit(main())
