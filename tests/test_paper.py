"""benches/paper.py: the registered tables, a table made from small fake results files (``--from``: no torch, no
data) and printed with the paper's rows beside ours, and a --from file of another run refused."""

import json

import pytest

from benches import paper

H = list(paper.HORIZONS)


def evaluate_result(method: str, mask: str = "none", windows: int = 2, scale: float = 1.0, **sampling) -> dict:
    """A small stand-in for a ``training.evaluate --json`` result (Human3.6M)."""
    avg = {h: scale * (10.0 + i) for i, h in enumerate(H)}
    d = {
        "protocol": {"dataset": "h36m", "actions": ["walking"], "windows_per_action": windows, "mask": mask},
        "method": method,
        "zero_velocity": {"average": {h: 2 * v for h, v in avg.items()}},
        "command": f"python -m training.evaluate --fake {method}",
    }
    if sampling:
        d["sampling"] = sampling
        d["best_of_n"] = {"average": avg}
        d["mean_of_n"] = {"average": {h: v + 1 for h, v in avg.items()}}
    else:
        d["average"] = avg
    return d


def bundled_cascade(mask="none", windows=2):
    s = json.loads((paper.ROOT / paper.H36M / "sampling.json").read_text())["forecast"]
    return evaluate_result(
        f"tcd {paper.H36M}",
        mask,
        windows,
        engine="tcd",
        samples=5,
        sampler=s["sampler"],
        steps=s["num_inference_steps"],
        noise_coupling=s.get("noise_coupling", "independent"),
    )


def test_the_paper_tables_are_registered():
    assert {"table1", "table2", "table3"} <= set(paper.TABLES)
    for name, t in paper.TABLES.items():
        assert t.out == f"benches/results/paper_{name}.json" and t.runs and t.make.__doc__


def test_a_registered_table_made_from_files_and_printed(tmp_path, monkeypatch, capsys):
    """One function and one registration make a table; --from takes its run from a file; the output holds the
    paper's rows above ours, and the results file what the report reads."""
    src = tmp_path / "run.json"
    src.write_text(json.dumps(evaluate_result("prior m", windows=3)))

    def fake(run):
        """A fake table: the prior of directory m."""
        d = run.evaluate("point", ["--prior", "m", "--mask", "none"])
        return {
            "title": "a fake",
            "units": "mm",
            "columns": H,
            "paper_rows": [paper.row("P", "their method", {"80": 9.0, "1000": 99.0}, H)],
            "our_rows": [paper.row("ours", "our method", d["average"], H)],
        }

    monkeypatch.setitem(paper.TABLES, "fake", paper.Table(fake, "benches/results/paper_fake.json", ("point",)))
    out = tmp_path / "fake.json"
    assert paper.main(["fake", "--windows-per-action", "3", "--from", f"point={src}", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert lines[0] == "fake: a fake (mm)"
    assert lines.index("the paper") < lines.index("ours")
    their = next(line for line in lines if "their method" in line).split()
    assert their[2:] == ["9.0", "—", "—", "—", "—", "—", "—", "99.0"]
    assert next(line for line in lines if "our method" in line).split()[2:] == [f"{10.0 + i:.1f}" for i in range(8)]
    d = json.loads(out.read_text())
    assert d["table"] == "fake" and d["our_rows"][0]["values"]["1000"] == 17.0
    assert d["runs"]["point"]["from"].endswith("run.json")
    assert d["runs"]["point"]["command"] == "python -m training.evaluate --fake prior m"
    assert d["command"].startswith("python -m benches.paper fake")


def test_table1_from_files(tmp_path, capsys):
    """table1 itself on fake runs: the published rows from training.metrics, ours from the files."""
    from training.metrics import PUBLISHED_H36M

    cascade, prior = tmp_path / "cascade.json", tmp_path / "prior.json"
    cascade.write_text(json.dumps(bundled_cascade()))
    prior.write_text(json.dumps(evaluate_result(f"prior {paper.H36M}", scale=0.5)))
    out = tmp_path / "t1.json"
    assert (
        paper.main(
            ["table1", "--windows-per-action", "2", "--from", f"cascade={cascade}", f"prior={prior}", "--out", str(out)]
        )
        == 0
    )
    d = json.loads(out.read_text())
    ours = {r["key"]: r["values"] for r in d["our_rows"]}
    assert ours["best_of_5"]["80"] == 10.0 and ours["mean_of_5"]["80"] == 11.0 and ours["prior"]["80"] == 5.0
    assert ours["zero_velocity"]["1000"] == 34.0
    assert {r["key"]: r["values"] for r in d["paper_rows"]} == PUBLISHED_H36M
    assert d["models"][paper.H36M] == paper.model_sha256(paper.H36M)
    assert "TCD (best of 5)" in capsys.readouterr().out


@pytest.mark.parametrize(
    "change,message",
    [
        (dict(mask="random_leg_arm"), "protocol.mask"),
        (dict(windows=256), "protocol.windows_per_action"),
        (dict(method="tcd models/other"), "method"),
    ],
)
def test_a_file_of_another_run_is_refused(tmp_path, capsys, change, message):
    d = bundled_cascade(change.get("mask", "none"), change.get("windows", 2))
    if "method" in change:
        d["method"] = change["method"]
    f = tmp_path / "cascade.json"
    f.write_text(json.dumps(d))
    prior = tmp_path / "prior.json"
    prior.write_text(json.dumps(evaluate_result(f"prior {paper.H36M}")))
    rc = paper.main(
        [
            "table1",
            "--windows-per-action",
            "2",
            "--from",
            f"cascade={f}",
            f"prior={prior}",
            "--out",
            str(tmp_path / "t1.json"),
        ]
    )
    assert rc == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "t1.json").exists()


def test_command_line_errors(tmp_path, capsys):
    assert paper.main(["no-such-table", "--out", str(tmp_path / "x.json")]) == 2
    assert "unknown table" in capsys.readouterr().err
    assert paper.main(["table1", "--from", f"nope={tmp_path}/x.json", "--out", str(tmp_path / "x.json")]) == 2
    assert "has no run 'nope'" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # a quick look must not overwrite the protocol's file
        paper.main(["table1", "--windows-per-action", "2"])
    assert paper.main(["--list"]) == 0 and "paper_table1.json" in capsys.readouterr().out


def stochastic_result(method: str, dataset: str, windows: int, scale: float = 1.0, **sampling) -> dict:
    """A small stand-in for a ``training.evaluate --protocol ... --json`` result (the stochastic protocol)."""

    def metrics(k: float) -> dict:
        return {c: k * (0.1 + 0.01 * i) for i, c in enumerate(paper.KEEP)}

    return {
        "protocol": {
            "dataset": dataset,
            "split": "test",
            "t_his": 25,
            "t_pred": 100,
            "fps": 50,
            "windows": windows,
            "windows_in_protocol": windows,
        },
        "method": method,
        "model": metrics(scale),
        "prior": metrics(2 * scale),
        "neighbours": metrics(3 * scale),
        "zero_velocity": metrics(4 * scale),
        "per_action": {"walking": {"windows": windows, **metrics(scale)}},
        "sampling": {"engine": "tcd", "samples": 50, **sampling},
        "command": f"python -m training.evaluate --fake {method}",
    }


def test_table3_has_both_halves(tmp_path, monkeypatch, capsys):
    """table3 on fake runs: Setting-A's half from the generator directory's run (the published rows of
    training.metrics beside it), HumanEva-I's from its mixture, cascade and generator runs; both printed."""
    from training.metrics import PUBLISHED_H36M_A

    gen_dir = tmp_path / "weights_h36m_stochastic"
    gen_dir.mkdir()
    (gen_dir / "generator.safetensors").write_bytes(b"")
    monkeypatch.setattr(paper, "SETTING_A", str(gen_dir))
    s = json.loads((paper.ROOT / paper.HUMANEVA / "sampling.json").read_text())["forecast"]
    he = dict(sampler=s["sampler"], steps=s["num_inference_steps"])
    files = {
        "setting_a": stochastic_result(f"tcd {gen_dir}", "h36m-setting-a", 3),
        "mixture": stochastic_result(f"tcd {paper.HUMANEVA}", "humaneva-i", 3, 0.5, **he),
        "cascade": stochastic_result(f"tcd {paper.HUMANEVA}", "humaneva-i", 3, 0.6, generator_share=0, **he),
        "generator": stochastic_result(f"tcd {paper.HUMANEVA}", "humaneva-i", 3, 0.7, generator_share=1, **he),
    }
    sources = []
    for name, d in files.items():
        (tmp_path / f"{name}.json").write_text(json.dumps(d))
        sources.append(f"{name}={tmp_path / name}.json")
    out = tmp_path / "t3.json"
    assert paper.main(["table3", "--max-windows", "3", "--from", *sources, "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    a, h = d["halves"]["h36m-a"], d["halves"]["humaneva"]
    assert {r["key"]: r["values"]["ADE"] for r in a["our_rows"]} == pytest.approx(
        {"tcd": 0.1, "prior": 0.2, "neighbours": 0.3, "zero_velocity": 0.4}
    )
    assert {r["key"] for r in a["paper_rows"]} == set(PUBLISHED_H36M_A)
    assert [r["key"] for r in h["our_rows"]][:3] == ["tcd", "cascade", "generator"]
    assert h["our_rows"][1]["values"]["ADE"] == pytest.approx(0.06)
    text = capsys.readouterr().out
    assert "table3, h36m-a: Human3.6M Setting-A (m)" in text and "table3, humaneva: HumanEva-I (m)" in text
    (gen_dir / "generator.safetensors").unlink()
    assert paper.main(["table3", "--max-windows", "3", "--from", *sources, "--out", str(out)]) == 2
    assert "h36m-stochastic" in capsys.readouterr().err
