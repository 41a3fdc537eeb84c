"""benches/report.py: the generated blocks of the Markdown files, rewritten by --write and checked by --check
(a changed number, an unknown block, a missing or broken results file, a broken block), on files in a temporary
folder; and the repository's own README.md, MODEL_CARD.md and docs/ as --write would write them. No torch, no data."""

import json
import shutil

import pytest

from benches import report, report_sources, report_tables

PEERS = {
    "versions": {"cores": 2, "cpu": "x86_64", "cpu_simd_flags": ["avx2"]},
    "rows": [
        {
            "L": 75,
            "K": 66,
            "threads": 1,
            "reps": 3,
            "ms": {"tcd": 50.0, "torch": 200.0},
            "peer_over_tcd": {"torch": 4.0},
        }
    ],
}
WHOLE = {
    "whole_forecast": {
        "ddpm50_x5": {"seconds": 12.25, "peak_rss_mib": 70.2},
        "ddim10_x1": {"seconds": 0.5, "peak_rss_mib": 60.0},
    }
}
BLOCK = (
    "# Page\n\nbefore\n\n<!-- report:speed-peers -->\n<!-- /report:speed-peers -->\n\n"
    "<!-- report:speed-whole -->\n<!-- /report:speed-whole -->\n\nafter\n"
)


@pytest.fixture
def results(tmp_path):
    d = tmp_path / "results"
    d.mkdir()
    (d / "peers.json").write_text(json.dumps(PEERS))
    (d / "whole_forecast_tcd.json").write_text(json.dumps(WHOLE))
    return d


def run(capsys, *argv):
    rc = report.main([str(a) for a in argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_write_then_check_then_a_changed_number(tmp_path, results, capsys):
    page = tmp_path / "page.md"
    page.write_text(BLOCK)
    assert run(capsys, "--check", page, "--results", results)[0] == 1  # an empty block differs
    rc, out, _ = run(capsys, "--write", page, "--results", results)
    assert rc == 0 and "speed-peers" in out
    text = page.read_text()
    assert text.startswith("# Page\n\nbefore\n\n<!-- report:speed-peers -->\n") and text.endswith(
        "<!-- /report:speed-whole -->\n\nafter\n"
    )
    assert "| DDPM-50 × 5 samples (the paper's sampler) | 12.2 s | 70 MiB |" in text
    assert "| tcd | 50.0 |" in text and "| PyTorch eager | 200.0 (4.00 ×) |" in text
    assert run(capsys, "--check", page, "--results", results)[0] == 0
    assert run(capsys, "--write", page, "--results", results)[1] == ""  # nothing left to rewrite

    page.write_text(text.replace("| tcd | 50.0 |", "| tcd | 49.0 |"))  # a number edited by hand
    rc, out, err = run(capsys, "--check", page, "--results", results)
    assert rc == 1 and "-| tcd | 49.0 |" in out and "+| tcd | 50.0 |" in out and "speed-peers" in out
    assert "1 block(s) differ" in err

    page.write_text(text)
    PEERS2 = json.loads(json.dumps(PEERS))
    PEERS2["rows"][0]["ms"]["tcd"] = 51.0  # a results file rerun
    (results / "peers.json").write_text(json.dumps(PEERS2))
    rc, out, _ = run(capsys, "--check", page, "--results", results)
    assert rc == 1 and "+| tcd | 51.0 |" in out


def test_unknown_block_is_an_error(tmp_path, results, capsys):
    page = tmp_path / "page.md"
    page.write_text("text\n\n<!-- report:no-such-table -->\n<!-- /report:no-such-table -->\n")
    rc, _, err = run(capsys, "--check", page, "--results", results)
    assert rc == 2 and "page.md:3" in err and "unknown block 'no-such-table'" in err
    assert run(capsys, "--write", page, "--results", results)[0] == 2
    assert "no-such-table" in page.read_text()


def test_missing_results_file_is_an_error_naming_it(tmp_path, results, capsys):
    page = tmp_path / "page.md"
    page.write_text(BLOCK)
    (results / "whole_forecast_tcd.json").unlink()
    rc, _, err = run(capsys, "--write", page, "--results", results)
    assert rc == 2 and "missing results file" in err and "whole_forecast_tcd.json" in err
    assert page.read_text() == BLOCK  # nothing written


@pytest.mark.parametrize(
    "text,message",
    [
        ("<!-- report:speed-peers -->\nno end\n", "not closed"),
        ("<!-- report:speed-peers -->\n<!-- report:speed-peers -->\n<!-- /report:speed-peers -->\n", "not closed"),
        ("x <!-- /report:speed-peers --> y\n", "closes no block"),
        ("<!-- report:speed-peers -->text\n<!-- /report:speed-peers -->\n", "a line of its own"),
    ],
)
def test_broken_blocks_are_errors(tmp_path, results, capsys, text, message):
    page = tmp_path / "page.md"
    page.write_text(text)
    rc, _, err = run(capsys, "--check", page, "--results", results)
    assert rc == 2 and message in err


def test_inline_block(tmp_path, capsys):
    """An inline block is rewritten within its line; a generator that writes lines cannot fill one."""
    page = tmp_path / "page.md"
    page.write_text("It samples with <!-- report:h36m-sampler -->?<!-- /report:h36m-sampler --> by default.\n")
    assert run(capsys, "--write", page)[0] == 0
    sampling = json.loads((report_sources.ROOT / report_sources.H36M_DIR / "sampling.json").read_text())["forecast"]
    text = page.read_text()
    assert text.count("\n") == 1 and f"{sampling['sampler'].upper()}, " in text
    assert run(capsys, "--check", page)[0] == 0
    page.write_text("<!-- report:convention --><!-- /report:convention -->\n")
    rc, _, err = run(capsys, "--check", page)
    assert rc == 2 and "inline" in err


def test_recipes_cost_lists_every_recipe_and_the_runs_that_ended(tmp_path):
    """Every recipe of training/recipes/ gets a row with its recorded cost; a recipe whose run ended (its results
    file) also gets that run's CPU-hours and its paired verdicts against the bundled file."""
    results = tmp_path / "results"
    (results / "recipes").mkdir(parents=True)
    md = report_tables.recipes_cost(report_sources.Sources(results))
    names = sorted(p.stem for p in (report_sources.ROOT / "training" / "recipes").glob("*.json"))
    assert names and all(f"[{n}](training/recipes/{n}.json)" in md for n in names)
    assert md.count("not run from scratch yet") == len(names)
    verdict = {"exit": 1, "report": ['  "mean_difference": 0.0,', '  "verdict": "within noise"', "}"]}
    (results / "recipes" / "h36m-prior.json").write_text(
        json.dumps({"recipe": "h36m-prior", "cpu_hours": 3.456, "comparisons": [{"keys": {"average": verdict}}]})
    )
    md = report_tables.recipes_cost(report_sources.Sources(results))
    row = next(line for line in md.splitlines() if line.startswith("| [h36m-prior]"))
    assert "| 3.46 |" in row and "average: within noise" in row
    assert md.count("not run from scratch yet") == len(names) - 1


def test_stale_results_are_refused(tmp_path, capsys):
    """A results file measured on other weights than the bundled ones is an error, not a table."""
    results = tmp_path / "results"
    results.mkdir()
    for name in ("repair_quality_joint_inbetween_256.json", "repair_quality_joint_inbetween_256_ddpm10.json"):
        shutil.copy(report_sources.RESULTS / name, results / name)
    d = json.loads((results / "repair_quality_joint_inbetween_256.json").read_text())
    d["model_sha256"] = "0" * 64
    (results / "repair_quality_joint_inbetween_256.json").write_text(json.dumps(d))
    with pytest.raises(report_sources.ReportError, match="run its benchmark again"):
        report_tables.h36m_repair(report_sources.Sources(results))


def test_every_generator_runs_on_the_repository_results():
    for name, gen in report_tables.GENERATORS.items():
        assert isinstance(gen(report_sources.Sources()), str), name
        assert gen.__doc__, name


def test_repository_docs_are_as_generated(capsys):
    """README.md, MODEL_CARD.md and docs/**/*.md hold what `python -m benches.report --write` writes."""
    rc, out, err = run(capsys, "--check")
    assert rc == 0, out + err
