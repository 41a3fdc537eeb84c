"""The paper's tables on the bundled models: one command per table, the paper's rows printed beside ours.

    python -m benches.paper --list
    python -m benches.paper table1 [--windows-per-action N] [--out FILE]     # Human3.6M Setting-B, clean input
    python -m benches.paper table2 [--windows-per-action N] [--out FILE]     # imperfect observations
    python -m benches.paper table3 [--max-windows N] [--out FILE]            # stochastic: Setting-A, HumanEva-I
    python -m benches.paper table1 --from cascade=benches/results/protocol_bundled/full_none_ddim1_centred.json

Each table runs the evaluation protocol (``training.evaluate``, in this process) on the bundled model directories
with their default samplers (their ``sampling.json``), writes one results file named after what it measures
(``benches/results/paper_table1.json`` ...: the paper's rows, ours, and the command of every run behind them) and
prints the paper's rows beside ours. ``python -m benches.report`` reads those files into README.md and MODEL_CARD.md.

A table's runs are named (``--list`` shows them). ``--from NAME=FILE`` takes run NAME from a results file
``training.evaluate --json`` wrote before instead of running it again: the full Human3.6M protocol takes minutes per
input pattern. The file must be the run the table asks for (its model, sampler, mask and window count are checked);
its own command is recorded beside the table's. ``--windows-per-action`` (Human3.6M, 256: the protocol) and
``--max-windows`` (HumanEva-I, all 188 when not given) make a quick look, not the protocol: write it elsewhere
(``--out /tmp/...``). ``--max-windows`` applies to Setting-A's 4,313 windows too.

Adding a table: one function ``def tableN(run: Runner) -> dict`` (below, "The tables") that asks ``run.evaluate`` for
the runs it needs and returns its rows, and one line in ``TABLES``.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import shlex
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
H36M = "python/tcd/weights"
HUMANEVA = "python/tcd/weights_humaneva"
SETTING_A = "python/tcd/weights_h36m_stochastic"
HORIZONS = ("80", "160", "320", "400", "560", "720", "880", "1000")
STOCHASTIC = ("ADE", "FDE", "MMADE", "MMFDE", "APD")
PAPER = "Saadatnejad et al., ICRA 2023"


class PaperError(ValueError):
    """A table that cannot be made as asked (an unknown table or run, a --from file of another run)."""


# ------------------------------------------------------------------------------------------ the runs


def default_sampler_flags(model_dir: str) -> list[str]:
    """The ``training.evaluate`` flags of a model directory's default forecast sampler (its ``sampling.json``):
    the tables score the bundled models as ``tcd.load(DIR).forecast`` runs them."""
    f = ROOT / model_dir / "sampling.json"
    if not f.is_file():  # a generator directory: no sampler to name (its samples are one forward each)
        return []
    f = json.loads(f.read_text()).get("forecast", {})
    flags = ["--sampler", f.get("sampler", "ddpm")]
    if f.get("num_inference_steps") is not None:
        flags += ["--steps", str(f["num_inference_steps"])]
    if f.get("noise_coupling"):
        flags += ["--noise-coupling", f["noise_coupling"]]
    return flags


def _flags(argv: list[str]) -> dict[str, str]:
    """``--flag value`` pairs of an argument list (a flag without a value maps to "")."""
    out, i = {}, 0
    while i < len(argv):
        a = argv[i]
        if a.startswith("--"):
            if i + 1 < len(argv) and not argv[i + 1].startswith("--"):
                out[a] = argv[i + 1]
                i += 2
                continue
            out[a] = ""
        i += 1
    return out


def _same(a, b) -> bool:
    try:
        return float(a) == float(b)
    except (TypeError, ValueError):
        return str(a) == str(b)


def _dataset(protocol: str) -> str:
    """The ``protocol.dataset`` a ``training.evaluate --protocol PROTOCOL`` result names."""
    if protocol == "h36m":
        return "h36m"
    from training.evaluate_stochastic import dataset_of

    return dataset_of(protocol).dataset


def mismatches(argv: list[str], d: dict, windows_per_action: int, max_windows: int | None) -> list[str]:
    """How a ``training.evaluate --json`` result ``d`` differs from the run ``argv`` would make (empty: it is
    that run): the model or prior, the protocol, the mask, the sampling options given and the window count."""
    f, bad = _flags(argv), []

    def check(what: str, got, want) -> None:
        if not _same(got, want):
            bad.append(f"{what} is {got!r}, the table asks for {want!r}")

    proto = d.get("protocol", {})
    stochastic = f.get("--protocol", "h36m") != "h36m"
    check("protocol.dataset", proto.get("dataset"), _dataset(f.get("--protocol", "h36m")))
    if "--model" in f:
        check("method", d.get("method"), f"tcd {f['--model']}")
    if "--prior" in f:
        check("method", d.get("method"), f"prior {f['--prior']}")
    if stochastic:
        check("protocol.windows", proto.get("windows"), max_windows or proto.get("windows_in_protocol"))
    else:
        check("protocol.mask", proto.get("mask"), f.get("--mask", "none"))
        check("protocol.windows_per_action", proto.get("windows_per_action"), windows_per_action)
    sampling = d.get("sampling", {})
    for flag, key in (
        ("--engine", "engine"),
        ("--samples", "samples"),
        ("--steps", "steps"),
        ("--sampler", "sampler"),
        ("--noise-coupling", "noise_coupling"),
        ("--generator-share", "generator_share"),
    ):
        if flag in f:
            check(f"sampling.{key}", sampling.get(key), f[flag])
    return bad


class Runner:
    """The runs of one table: each from ``training.evaluate`` (run here) or from a ``--from`` file, recorded."""

    def __init__(
        self,
        windows_per_action: int = 256,
        max_windows: int | None = None,
        threads: int | None = None,
        sources: dict[str, str] | None = None,
        evaluate: Callable[[list[str]], dict] | None = None,
        log: Callable[[str], None] = lambda m: print(m, file=sys.stderr, flush=True),
    ):
        self.windows_per_action, self.max_windows, self.threads = windows_per_action, max_windows, threads
        self.sources = dict(sources or {})
        self._evaluate = evaluate or run_evaluate
        self.log = log
        self.records: dict[str, dict] = {}
        self.models: dict[str, str | None] = {}  # the model directories the runs score, and their checksums

    def evaluate(self, name: str, argv: list[str]) -> dict:
        """Run ``name``: ``python -m training.evaluate ARGV`` with this table's window count, or its --from file."""
        if name in self.records:
            raise PaperError(f"run {name!r} asked for twice")
        if _flags(argv).get("--protocol", "h36m") != "h36m":
            argv = argv + (["--max-windows", str(self.max_windows)] if self.max_windows else [])
        else:
            argv = argv + ["--windows-per-action", str(self.windows_per_action)]
        command = "python -m training.evaluate " + shlex.join(argv)
        if name in self.sources:
            path = self.sources[name]
            try:
                d = json.loads(Path(path).read_text())
            except FileNotFoundError:
                raise PaperError(f"--from {name}={path}: no such file") from None
            bad = mismatches(argv, d, self.windows_per_action, self.max_windows)
            if bad:
                raise PaperError(f"--from {name}={path} is not the run {command!r}: " + "; ".join(bad))
            self.records[name] = {"command": d.get("command"), "from": _relative(path), "asked": command}
            self.log(f"[{name}] from {path}")
        else:
            if self.threads:
                argv = argv + ["--threads", str(self.threads)]
                command = "python -m training.evaluate " + shlex.join(argv)
            self.log(f"[{name}] {command}")
            d = self._evaluate(argv)
            self.records[name] = {"command": command}
        f = _flags(argv)
        model = f.get("--model") or f.get("--prior")
        if model:
            self.records[name]["model"] = model
            self.models[model] = model_sha256(model)
        self.records[name]["protocol"] = d.get("protocol")
        if "sampling" in d:
            self.records[name]["sampling"] = d["sampling"]
        return d


def run_evaluate(argv: list[str]) -> dict:
    """``python -m training.evaluate ARGV --quiet --json TMP`` in this process (its printed tables hidden); the
    result it wrote."""
    from training import evaluate  # torch: only where a table runs a protocol here

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run.json"
        with contextlib.redirect_stdout(io.StringIO()):
            evaluate.main(argv + ["--quiet", "--json", str(out)])
        return json.loads(out.read_text())


def model_sha256(model_dir: str | Path) -> str | None:
    """A model directory's checksum as ``tcd.TCD.sha256`` computes it (the sha256 of its SHA256SUMS file), or None
    for a directory without one."""
    f = (ROOT / model_dir) / "SHA256SUMS"
    return hashlib.sha256(f.read_bytes()).hexdigest() if f.is_file() else None


def _relative(path: str | Path) -> str:
    p = Path(path).resolve()
    try:
        return str(p.relative_to(ROOT))
    except ValueError:
        return str(path)


# ------------------------------------------------------------------------------------------ rows


def row(key: str, name: str, values: dict, columns, **extra) -> dict:
    """One table row: ``values`` restricted to the table's columns (a missing column: not given)."""
    r = {"key": key, "name": name, "values": {c: float(values[c]) for c in columns if values.get(c) is not None}}
    r.update(extra)
    return r


def published_h36m() -> dict:
    from training.metrics import PUBLISHED_H36M

    return PUBLISHED_H36M


def published_humaneva() -> dict:
    from training.metrics import PUBLISHED_HUMANEVA

    return PUBLISHED_HUMANEVA


def published_setting_a() -> tuple[dict, dict]:
    """The published Human3.6M Setting-A rows and who published each (training.metrics)."""
    from training.metrics import PUBLISHED_H36M_A, PUBLISHED_H36M_A_SOURCES

    return PUBLISHED_H36M_A, PUBLISHED_H36M_A_SOURCES


#: who published each method's Human3.6M numbers (training.metrics): siMLPe's own paper, the others the TCD paper's
H36M_SOURCES = {"siMLPe": "Guo et al., WACV 2023"}

#: The TCD rows of the paper's Table 2 (imperfect observations, its upper block: the observation corrupted, the
#: corruption of the text available to us not stated beyond "noisy or occluded"), mm at the Table 1 horizons, and
#: Zero-Velocity on those observations (the paper's row gives 80 ms and 1 s alone) to read them by.
#: "Pre(ours) + TCD": the observation first repaired by the paper's diffusion repair, then forecast by TCD.
PUBLISHED_TABLE2 = {
    "TCD": {"80": 11.2, "320": 51.3, "560": 75.4, "720": 85.4, "880": 95.4, "1000": 104.5},
    "Pre(ours) + TCD": {"80": 10.8, "320": 49.9, "560": 74.4, "720": 84.9, "880": 95.1, "1000": 104.2},
    "Zero-Velocity": {"80": 84.9, "1000": 198.2},
}

#: the imperfect observations the bundled Human3.6M model is scored under (training.masks; docs/reference.md)
PATTERNS = ("random_leg_arm", "structured_leg", "consecutive_frames", "noisy_25")


# ------------------------------------------------------------------------------------------ the tables


def table1(run: Runner) -> dict:
    """Human3.6M Setting-B, clean input: the bundled cascade (oracle best of 5, the paper's figure, and the mean of
    5, what ``forecast`` returns), the prior's point forecast and Zero-Velocity, beside the published methods."""
    cascade = run.evaluate(
        "cascade",
        ["--model", H36M, "--engine", "tcd", "--samples", "5", "--mask", "none", *default_sampler_flags(H36M)],
    )
    prior = run.evaluate("prior", ["--prior", H36M, "--mask", "none"])
    pub = published_h36m()
    paper_rows = [row(k, k, v, HORIZONS, source=H36M_SOURCES.get(k, PAPER)) for k, v in pub.items()]
    ours = [
        row("best_of_5", "tcd forecast, oracle best of 5", cascade["best_of_n"]["average"], HORIZONS, run="cascade"),
        row("mean_of_5", "tcd forecast, mean of 5", cascade["mean_of_n"]["average"], HORIZONS, run="cascade"),
        row("prior", "tcd predict (the prior)", prior["average"], HORIZONS, run="prior"),
        row(
            "zero_velocity", "Zero-Velocity, same windows", cascade["zero_velocity"]["average"], HORIZONS, run="cascade"
        ),
    ]
    return {
        "title": "Human3.6M Setting-B, clean input (the paper's Table 1)",
        "units": "mm",
        "columns": list(HORIZONS),
        "column_unit": "ms",
        "paper_rows": paper_rows,
        "our_rows": ours,
        "protocol": {"ours": cascade["protocol"], "paper": "S5, 15 actions, 256 windows each"},
    }


def table2(run: Runner) -> dict:
    """Imperfect observations (the TCD rows of the paper's Table 2): the bundled cascade under each corruption
    pattern, oracle best of 5 and mean of 5, with Zero-Velocity on the same corrupted observations."""
    ours, repair = [], {}
    for p in PATTERNS:
        d = run.evaluate(
            p, ["--model", H36M, "--engine", "tcd", "--samples", "5", "--mask", p, *default_sampler_flags(H36M)]
        )
        ours += [
            row(f"best_of_5/{p}", f"{p}: tcd forecast, oracle best of 5", d["best_of_n"]["average"], HORIZONS, run=p),
            row(f"mean_of_5/{p}", f"{p}: tcd forecast, mean of 5", d["mean_of_n"]["average"], HORIZONS, run=p),
            row(
                f"zero_velocity/{p}",
                f"{p}: Zero-Velocity, same observations",
                d["zero_velocity"]["average"],
                HORIZONS,
                run=p,
            ),
        ]
        repair[p] = d.get("repair")
    paper_rows = [row(k, k, v, HORIZONS, source=f"{PAPER}, Table 2") for k, v in PUBLISHED_TABLE2.items()]
    return {
        "title": "Human3.6M Setting-B, imperfect observations (the TCD rows of the paper's Table 2)",
        "units": "mm",
        "columns": list(HORIZONS),
        "column_unit": "ms",
        "paper_rows": paper_rows,
        "our_rows": ours,
        "repair": repair,
        "protocol": {
            "ours": run.records[PATTERNS[0]]["protocol"],
            "patterns": list(PATTERNS),
            "paper": "S5, 15 actions; the corruption not stated in the text available",
        },
    }


def table3(run: Runner) -> dict:
    """Stochastic forecasting, 50 samples (the paper's Table 3, both halves): Human3.6M Setting-A (the bundled
    generator directory) and HumanEva-I (the bundled mixture, its cascade alone and its generator alone); the prior,
    the nearest training futures and Zero-Velocity on each; beside the published numbers."""
    return {
        "title": "stochastic forecasting, 50 samples (the paper's Table 3)",
        "halves": {"h36m-a": _setting_a(run), "humaneva": _humaneva(run)},
    }


def _stochastic_flags(protocol: str, model_dir: str) -> list[str]:
    """``training.evaluate`` on a bundled directory by the stochastic protocol, as ``tcd.load(DIR).forecast`` runs
    it: the engine, 50 samples, the directory's default sampler."""
    flags = ["--protocol", protocol, "--model", model_dir, "--engine", "tcd", "--samples", "50"]
    return flags + default_sampler_flags(model_dir)


#: the stochastic metrics a half's rows keep
KEEP = STOCHASTIC + ("mean_ADE", "mean_FDE")


def _baselines(d: dict, run_name: str) -> list[dict]:
    """The rows every half has from its model's run: the prior's point forecast, the nearest training futures,
    Zero-Velocity."""
    return [
        row("prior", "tcd predict (the prior)", d["prior"], KEEP, run=run_name),
        row("neighbours", "nearest training futures, joined", d["neighbours"], KEEP, run=run_name),
        row("zero_velocity", "Zero-Velocity", d["zero_velocity"], KEEP, run=run_name),
    ]


def _setting_a(run: Runner) -> dict:
    if not (ROOT / SETTING_A / "generator.safetensors").is_file():
        raise PaperError(f"{SETTING_A} holds no model: train it (python -m training.recipe h36m-stochastic)")
    gen = run.evaluate("setting_a", _stochastic_flags("h36m-a", SETTING_A))
    pub, sources = published_setting_a()
    return {
        "title": "Human3.6M Setting-A",
        "units": "m",
        "columns": list(STOCHASTIC),
        "column_unit": "",
        "paper_rows": [row(k, k, v, STOCHASTIC, source=sources[k]) for k, v in pub.items() if v],
        "our_rows": [
            row("tcd", "tcd forecast (the generator, its default)", gen["model"], KEEP, run="setting_a"),
            *_baselines(gen, "setting_a"),
        ],
        "per_action": {"tcd": gen.get("per_action")},
        "protocol": {"ours": gen["protocol"], "paper": "DLow / GSPS protocol, 50 samples"},
    }


def _humaneva(run: Runner) -> dict:
    base = _stochastic_flags("humaneva", HUMANEVA)
    mix = run.evaluate("mixture", base)
    cascade = run.evaluate("cascade", base + ["--generator-share", "0"])
    gen = run.evaluate("generator", base + ["--generator-share", "1"])
    ours = [
        row("tcd", "tcd forecast (the mixture, its default)", mix["model"], KEEP, run="mixture"),
        row("cascade", "the cascade alone", cascade["model"], KEEP, run="cascade"),
        row("generator", "the generator alone", gen["model"], KEEP, run="generator"),
        *_baselines(mix, "mixture"),
    ]
    pub = published_humaneva()
    return {
        "title": "HumanEva-I",
        "units": "m",
        "columns": list(STOCHASTIC),
        "column_unit": "",
        "paper_rows": [row(k, k, v, STOCHASTIC, source=PAPER) for k, v in pub.items() if v],
        "our_rows": ours,
        "not_given": [k for k, v in pub.items() if not v],
        "per_action": {"tcd": mix.get("per_action")},
        "protocol": {"ours": mix["protocol"], "paper": "DLow / GSPS protocol, 50 samples"},
    }


@dataclass
class Table:
    make: Callable[[Runner], dict]
    out: str  # the results file, relative to the repository root
    runs: tuple  # the names of its runs (for --list and --from)


# ------------------------------------------------------------------------------------------ registration
# One line per table: its function, its results file, its runs' names.
TABLES: dict[str, Table] = {
    "table1": Table(table1, "benches/results/paper_table1.json", ("cascade", "prior")),
    "table2": Table(table2, "benches/results/paper_table2.json", PATTERNS),
    "table3": Table(table3, "benches/results/paper_table3.json", ("setting_a", "mixture", "cascade", "generator")),
}


# ------------------------------------------------------------------------------------------ printing


def _cell(v, units: str) -> str:
    if v is None:
        return "—"
    return f"{v:.3f}" if units == "m" else f"{v:.1f}"


def format_table(result: dict) -> str:
    """The paper's rows above ours, aligned in plain text; a table of halves, each half so."""
    if "halves" in result:
        return "\n\n".join(
            format_table({**half, "table": f"{result['table']}, {key}"}) for key, half in result["halves"].items()
        )
    cols, units = result["columns"], result["units"]
    width = max(len(r["name"]) for r in result["paper_rows"] + result["our_rows"]) + 2
    unit = result.get("column_unit", "")
    head = " " * (width + 2) + "".join(f"{c + unit:>9}" for c in cols)
    lines = [f"{result['table']}: {result['title']} ({units})", head]
    for title, rows in (("the paper", result["paper_rows"]), ("ours", result["our_rows"])):
        lines.append(title)
        for r in rows:
            lines.append(f"  {r['name']:<{width}}" + "".join(f"{_cell(r['values'].get(c), units):>9}" for c in cols))
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ command line


def make(name: str, runner: Runner, command: str) -> dict:
    if name not in TABLES:
        raise PaperError(f"unknown table {name!r}; the tables: {', '.join(TABLES)}")
    t = TABLES[name]
    unknown = sorted(set(runner.sources) - set(t.runs))
    if unknown:
        raise PaperError(f"--from: {name} has no run {unknown[0]!r}; its runs: {', '.join(t.runs)}")
    result = {"table": name, **t.make(runner)}
    result["runs"] = runner.records
    # the checksums of the scored directories when the table was made: benches.report refuses a table whose
    # models have changed since (make it again)
    result["models"] = runner.models
    result["command"] = command
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m benches.paper", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("table", nargs="?", help="the table to make (--list: the tables)")
    ap.add_argument("--list", action="store_true", help="the tables, their results files and their runs")
    ap.add_argument(
        "--windows-per-action", type=int, default=256, help="Human3.6M windows per action (256: the protocol)"
    )
    ap.add_argument("--max-windows", type=int, default=None, help="HumanEva-I: this many of the 188 windows")
    ap.add_argument("--threads", type=int, default=None, help="passed to training.evaluate")
    ap.add_argument(
        "--from",
        dest="sources",
        nargs="+",
        default=[],
        metavar="RUN=FILE",
        help="take run RUN from a training.evaluate --json result instead of running it",
    )
    ap.add_argument("--out", default=None, help="the results file (default: the table's, under benches/results)")
    args = ap.parse_args(argv)
    if args.list or not args.table:
        for name, t in TABLES.items():
            print(
                f"{name}: {(t.make.__doc__ or '').split(':')[0].strip()}\n    writes {t.out}; runs: {', '.join(t.runs)}"
            )
        return 0
    sources = {}
    for s in args.sources:
        name, eq, path = s.partition("=")
        if not eq or not name or not path:
            ap.error(f"--from {s!r}: expected RUN=FILE")
        sources[name] = path
    protocol = args.windows_per_action == 256 and args.max_windows is None
    if not 1 <= args.windows_per_action <= 256:
        ap.error("--windows-per-action must be in 1..256")
    out = Path(args.out) if args.out else None
    if out is None:
        if args.table not in TABLES:
            ap.error(f"unknown table {args.table!r}; the tables: {', '.join(TABLES)}")
        if not protocol:
            ap.error("a quick look (--windows-per-action / --max-windows) is not the protocol: give --out")
        out = ROOT / TABLES[args.table].out
    runner = Runner(args.windows_per_action, args.max_windows, args.threads, sources)
    command = "python -m benches.paper " + shlex.join(argv if argv is not None else sys.argv[1:])
    try:
        result = make(args.table, runner, command)
    except PaperError as e:
        print(f"benches.paper: {e}", file=sys.stderr)
        return 2
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(format_table(result))
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
