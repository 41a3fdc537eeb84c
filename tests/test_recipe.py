"""The recipe runner (training.recipe): every bundled weight file has a recipe, recipes load and are refused when
malformed, a run resumes where it stopped and records what each stage cost, and every recipe's stages wire up (a
smoke run of a few steps each, on the real data)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import DATA, ROOT

from training import carry as C
from training import recipe as R
from training import recipe_file as RF

BUNDLED = sorted(str(p.relative_to(RF.PACKAGE)) for p in RF.PACKAGE.glob("weights*/*.safetensors"))


def test_every_bundled_weight_file_has_exactly_one_recipe():
    recipes = RF.all_recipes()
    produced = [p for r in recipes.values() for p in r.produces]
    assert sorted(set(produced)) == sorted(produced), "a file is produced by two recipes"
    missing = sorted(set(BUNDLED) - set(produced))
    assert not missing, f"bundled files without a recipe: {missing}"


def test_list_names_every_bundled_file():
    out = subprocess.run(
        [sys.executable, "-m", "training.recipe", "--list"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    for path in BUNDLED:
        assert path in out


def test_recipes_name_only_stages_inputs_and_results_that_exist():
    recipes = RF.all_recipes()
    for r in recipes.values():
        for need in r.needs:
            if need.endswith(".safetensors"):
                RF.producer(need, recipes)  # raises when no recipe produces it
            else:
                assert (RF.PACKAGE / need).is_file(), f"{r.name} needs {need}, which is not shipped"
        for c in r.compare:  # a committed results file, or one the recipe's own evaluation writes ({run}/...)
            assert c["bundled"].startswith("{run}/") or (ROOT / c["bundled"]).is_file(), (
                f"{r.name}: compares against missing {c['bundled']}"
            )
        assert r.cost.get("cpu_hours"), f"{r.name}: say what a run from scratch costs"


# ------------------------------------------------------------------------------------------ a recipe of its own


def write_recipe(tmp_path: Path, stages: list, produces=("weights_test/a.json",), **extra) -> RF.Recipe:
    d = {
        "name": "toy",
        "description": "a toy",
        "produces": list(produces),
        "stages": stages,
        "cost": {"cpu_hours": 0.001},
        **extra,
    }
    p = tmp_path / "toy.json"
    p.write_text(json.dumps(d))
    return RF.Recipe.load(p)


def copy_stage(name, src, dst):
    """A module stage that writes ``dst`` from the JSON file ``src`` (python -m json.tool)."""
    return {"name": name, "run": "module", "module": "json.tool", "args": [src, dst]}


def test_a_run_writes_its_files_records_each_stage_and_resumes(tmp_path, monkeypatch):
    monkeypatch.setattr(R, "RESULTS", tmp_path / "results")
    src = tmp_path / "src.json"
    src.write_text('{"x": 1}')
    rec = write_recipe(
        tmp_path,
        [
            copy_stage("one", str(src), "{stage:one}/a.json"),
            copy_stage("two", "{stage:one}/a.json", "{out}/weights_test/a.json"),
        ],
    )
    logs = []
    result = R.Runner(rec, tmp_path / "run", log=logs.append).run()
    assert json.loads((tmp_path / "run" / "out" / "weights_test" / "a.json").read_text()) == {"x": 1}
    assert [s["stage"] for s in result["stages"]] == ["one", "two"]
    assert all(s["attempts"] == 1 and s["cpu_hours"] >= 0 for s in result["stages"])
    assert result["files"]["weights_test/a.json"]["bundled_sha256"] is None
    assert json.loads((tmp_path / "results" / "toy.json").read_text())["recipe"] == "toy"
    logs.clear()
    R.Runner(rec, tmp_path / "run", log=logs.append).run()
    assert sum("done before, skipped" in m for m in logs) == 2
    # a stage the recipe now runs with another command runs again, not the record of the old one
    other = tmp_path / "other.json"
    other.write_text('{"x": 2}')
    rec = write_recipe(
        tmp_path,
        [
            copy_stage("one", str(src), "{stage:one}/a.json"),
            copy_stage("two", str(other), "{out}/weights_test/a.json"),
        ],
    )
    logs.clear()
    R.Runner(rec, tmp_path / "run", log=logs.append).run()
    assert sum("done before, skipped" in m for m in logs) == 1
    assert any("two: done before as another command, run again" in m for m in logs)
    assert json.loads((tmp_path / "run" / "out" / "weights_test" / "a.json").read_text()) == {"x": 2}


def test_a_failed_stage_stops_the_run_and_runs_again_next_time(tmp_path, monkeypatch):
    monkeypatch.setattr(R, "RESULTS", tmp_path / "results")
    src = tmp_path / "src.json"
    rec = write_recipe(tmp_path, [copy_stage("one", str(src), "{out}/weights_test/a.json")])
    with pytest.raises(RF.RecipeError, match="stage one failed"):
        R.Runner(rec, tmp_path / "run", log=lambda m: None).run()
    assert not (tmp_path / "run" / "one" / "done.json").exists()
    src.write_text("[1]")
    result = R.Runner(rec, tmp_path / "run", log=lambda m: None).run()
    assert result["stages"][0]["attempts"] == 2


def test_a_silent_stage_has_its_cost_and_progress_written_as_it_runs(tmp_path, monkeypatch):
    """A trainer may print nothing for an hour (a long epoch): the runner still writes its cost and progress every
    POLL_S, so a run killed then counts what it spent (written on output lines alone, it counted seconds of hours)."""
    monkeypatch.setattr(R, "RESULTS", tmp_path / "results")
    monkeypatch.setattr(R, "POLL_S", 0.05)
    calls = []
    monkeypatch.setattr(R.Runner, "write_progress", lambda self, *a: calls.append(a))
    busy = {
        "name": "busy",
        "run": "module",
        "module": "timeit",
        "args": ["-n", "1", "-r", "1", "sum(range(6 * 10**7))"],
    }
    src = tmp_path / "src.json"
    src.write_text("[1]")
    rec = write_recipe(tmp_path, [busy, copy_stage("copy", str(src), "{out}/weights_test/a.json")])
    R.Runner(rec, tmp_path / "run", log=lambda m: None).run()
    assert len(calls) >= 5  # one line of output, at the end
    assert "loop" in (tmp_path / "run" / "busy" / "log.txt").read_text()


def test_malformed_recipes_are_refused_naming_the_problem(tmp_path):
    ok = copy_stage("one", "a", "b")
    with pytest.raises(RF.RecipeError, match="unknown stage keys"):
        write_recipe(tmp_path, [{**ok, "stpes": 3}])
    with pytest.raises(RF.RecipeError, match="no earlier stage"):
        write_recipe(
            tmp_path,
            [
                {"name": "a", "run": "prior", "config": {"iterations": 2}, "from": "b"},
                {"name": "b", "run": "prior", "config": {"iterations": 2}},
            ],
        )
    with pytest.raises(RF.RecipeError, match="not config.init_from"):
        write_recipe(tmp_path, [{"name": "a", "run": "prior", "config": {"init_from": "x.pt"}}])
    with pytest.raises(RF.RecipeError, match="'run' must be one of"):
        write_recipe(tmp_path, [{"name": "a", "run": "shell", "module": "x"}])
    with pytest.raises(RF.RecipeError, match="stage names repeat"):
        write_recipe(tmp_path, [ok, ok])
    p = tmp_path / "other.json"
    p.write_text(json.dumps({"name": "toy", "description": "d", "produces": ["x"], "stages": [ok]}))
    with pytest.raises(RF.RecipeError, match="is not its file's"):
        RF.Recipe.load(p)


def test_placeholders_resolve_and_unknown_ones_are_refused(tmp_path):
    rec = write_recipe(tmp_path, [copy_stage("one", "a", "b")], needs=["weights/prior.safetensors"])
    run = R.Runner(rec, tmp_path / "run", threads=3)
    assert run.resolve(["{stage:one}/x", "{threads}", "{input:weights/prior.safetensors}"]) == [
        str(tmp_path / "run" / "one" / "x"),
        "3",
        str(RF.PACKAGE / "weights" / "prior.safetensors"),
    ]
    with pytest.raises(RF.RecipeError, match="unknown placeholder"):
        run.resolve("{nope}")
    with pytest.raises(RF.RecipeError, match="not in its 'needs'"):
        run.resolve("{input:weights/long.safetensors}")


def test_a_trainer_stage_warm_starts_from_the_stage_it_names(tmp_path):
    rec = write_recipe(
        tmp_path,
        [
            {"name": "a", "run": "prior", "config": {"iterations": 5}},
            {"name": "b", "run": "prior", "config": {"iterations": 5}, "from": "a/best.pt"},
        ],
    )
    run = R.Runner(rec, tmp_path / "run")
    assert run.stage_config(rec.stages[1])["init_from"] == str(tmp_path / "run" / "a" / "best.pt")
    assert "init_from" not in run.stage_config(rec.stages[0])
    # a fine-tune of another recipe's file: "from" names it by a placeholder
    tuned = write_recipe(
        tmp_path,
        [{"name": "a", "run": "prior", "config": {"iterations": 5}, "from": "{input:weights/prior.safetensors}"}],
        needs=["weights/prior.safetensors"],
    )
    assert R.Runner(tuned, tmp_path / "run").stage_config(tuned.stages[0])["init_from"] == str(
        RF.PACKAGE / "weights" / "prior.safetensors"
    )
    assert R.Runner(tuned, tmp_path / "run").resolve("{package}/weights") == str(RF.PACKAGE / "weights")
    assert rec.stages[1].windows() == 5 * 256
    smoke = R.Runner(rec, tmp_path / "run", smoke=True).stage_config(rec.stages[0])
    assert smoke["iterations"] == 2


def test_the_trainers_progress_lines_are_read():
    assert R.parse_progress("epoch 3 batch 200/400 loss 0.0312 lr 1.0e-03 55s") == {"step": 1400, "loss": 0.0312}
    assert R.parse_progress("iteration 300/4000: loss 0.04512, 12.0 it/s") == {
        "step": 300,
        "total": 4000,
        "loss": 0.04512,
    }
    assert R.parse_progress("step 120 (5.0 min): loss 0.1234; ADE 0.2") == {"step": 120, "loss": 0.1234}
    assert R.parse_progress("loaded 2612 windows") is None


def test_an_unfinished_run_is_carried_and_restored(tmp_path, monkeypatch):
    monkeypatch.setattr(C, "CARRIED", tmp_path / "carried")
    rec = write_recipe(
        tmp_path,
        [copy_stage("one", "a", "b"), {"name": "two", "run": "prior", "config": {"iterations": 5}, "from": "one"}],
    )
    run_dir = tmp_path / "run"
    (run_dir / "one").mkdir(parents=True)
    (run_dir / "one" / "done.json").write_text(json.dumps({"stage": "one", "cpu_hours": 0.5}))
    (run_dir / "one" / "best.pt").write_bytes(b"weights")
    (run_dir / "two").mkdir()
    (run_dir / "two" / "last.pt").write_bytes(b"state")
    (run_dir / "two" / "cost.json").write_text(json.dumps([{"cpu_s": 7.0}]))
    dest = C.carry(R.Runner(rec, run_dir))
    assert sorted(p.name for p in dest.iterdir()) == ["one.best.pt", "state.json", "two.last.pt"]
    C.restore(R.Runner(rec, tmp_path / "smoke", smoke=True, log=lambda m: None))
    assert not (tmp_path / "smoke").exists() or not any((tmp_path / "smoke").iterdir())
    fresh = tmp_path / "fresh"
    C.restore(R.Runner(rec, fresh, log=lambda m: None))
    assert (fresh / "two" / "last.pt").read_bytes() == b"state"
    assert (fresh / "one" / "best.pt").read_bytes() == b"weights"
    assert json.loads((fresh / "one" / "done.json").read_text())["cpu_hours"] == 0.5
    # a finished command stage before the last finished one runs again (its files are not carried)
    (run_dir / "two" / "done.json").write_text(json.dumps({"stage": "two", "cpu_hours": 1.0}))
    state = json.loads(C.carry(R.Runner(rec, run_dir)).joinpath("state.json").read_text())
    assert sorted(state) == ["two"]


def test_a_carry_after_a_finished_command_stage_keeps_the_trainer_weights_it_reads(tmp_path, monkeypatch):
    """A trainer, then an export that finished, then a fit running: the carry holds the trainer's weights and
    leaves the export to run again (its files are not carried)."""
    monkeypatch.setattr(C, "CARRIED", tmp_path / "carried")
    trainer = {"name": "one", "run": "prior", "config": {"iterations": 5}}
    rec = write_recipe(tmp_path, [trainer, copy_stage("two", "a", "b"), copy_stage("three", "b", "c")])
    run_dir = tmp_path / "run"
    for name in ("one", "two"):
        (run_dir / name).mkdir(parents=True)
        (run_dir / name / "done.json").write_text(json.dumps({"stage": name, "cpu_hours": 0.5}))
    (run_dir / "one" / "best.pt").write_bytes(b"weights")
    dest = C.carry(R.Runner(rec, run_dir))
    assert sorted(p.name for p in dest.iterdir()) == ["one.best.pt", "state.json"]
    assert sorted(json.loads((dest / "state.json").read_text())) == ["one"]


def test_a_checkpoint_over_the_limit_is_carried_compacted_and_resumes(tmp_path, monkeypatch):
    """A running stage's last.pt over the committed-file limit is carried as STAGE.last.pt.xz (Adam's moments in
    bfloat16, the weights exact) and restored to a last.pt that an optimizer loads; one still over it is refused."""
    torch = pytest.importorskip("torch")
    monkeypatch.setattr(C, "CARRIED", tmp_path / "carried")
    rec = write_recipe(tmp_path, [{"name": "one", "run": "prior", "config": {"iterations": 5}}])
    net = torch.nn.Linear(64, 64)
    opt = torch.optim.Adam(net.parameters())
    net(torch.randn(8, 64)).square().sum().backward()
    opt.step()
    run_dir = tmp_path / "run"
    (run_dir / "one").mkdir(parents=True)
    torch.save({"model": net.state_dict(), "optimizer": opt.state_dict(), "step": 1}, run_dir / "one" / "last.pt")
    size = (run_dir / "one" / "last.pt").stat().st_size
    monkeypatch.setattr(C, "LIMIT", size - 1)
    dest = C.carry(R.Runner(rec, run_dir))
    assert sorted(p.name for p in dest.iterdir()) == ["one.last.pt.xz", "state.json"]
    fresh = tmp_path / "fresh"
    C.restore(R.Runner(rec, fresh, log=lambda m: None))
    ck = torch.load(fresh / "one" / "last.pt", weights_only=False)
    for k, v in net.state_dict().items():
        assert torch.equal(ck["model"][k], v)
    moments = ck["optimizer"]["state"][0]
    assert moments["exp_avg"].dtype == torch.bfloat16
    exact = opt.state_dict()["state"][0]["exp_avg"]
    assert torch.equal(moments["exp_avg"], exact.to(torch.bfloat16))
    assert not torch.equal(moments["exp_avg"].float(), exact)
    again = torch.optim.Adam(net.parameters())
    again.load_state_dict(ck["optimizer"])
    assert again.state_dict()["state"][0]["exp_avg_sq"].dtype == torch.float32
    monkeypatch.setattr(C, "LIMIT", 100)
    with pytest.raises(RF.RecipeError, match="cannot be carried"):
        C.carry(R.Runner(rec, run_dir))


# ------------------------------------------------------------------------------------------ every recipe, smoked


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    """The data root cut to the first 400 frames (8 s at 50 fps) of every Human3.6M recording, with HumanEva-I
    whole (1.6 MB): what a smoke run reads, so that it tests the wiring, not the data's size."""
    np = pytest.importorskip("numpy")
    h36m, humaneva = DATA / "h36m" / "h36m_expmap_50fps.npz", DATA / "humaneva" / "humaneva_i_15j_60hz.npz"
    for f in (h36m, humaneva, DATA / "h36m" / "skeleton32.json"):
        if not f.is_file():
            pytest.skip(f"{f} is absent")
    root = tmp_path_factory.mktemp("tiny_data")
    (root / "h36m").mkdir()
    (root / "humaneva").mkdir()
    with np.load(h36m) as z:
        np.savez(root / "h36m" / h36m.name, **{k: z[k][:400] for k in z.files})
    for src, dst in ((DATA / "h36m" / "skeleton32.json", root / "h36m"), (humaneva, root / "humaneva")):
        (dst / src.name).write_bytes(src.read_bytes())
    return root


@pytest.mark.slow
@pytest.mark.data
@pytest.mark.parametrize("name", sorted(p.stem for p in RF.RECIPES.glob("*.json")))
def test_every_recipe_smoke_runs(name, tmp_path, tiny_data):
    """Every stage of the recipe (and of those it reads from) for two steps on tiny data, then its export and its
    scoring on a window or two: what a run from scratch does, but for the budgets."""
    pytest.importorskip("torch", reason="the trainers need torch")
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "training.recipe",
            name,
            "--smoke",
            "--run-dir",
            str(tmp_path),
            "--data",
            str(tiny_data),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    result = json.loads((tmp_path / "result.json").read_text())
    assert sorted(result["files"]) == sorted(RF.all_recipes()[name].produces)
    assert all((tmp_path / "out" / p).is_file() for p in result["files"])
