"""Recipes: the whole lineage of a bundled weight file, from scratch, as code (``training/recipes/*.json``).

A recipe is an ordered list of stages. Each stage is one run of a trainer (``training.train``, ``training.prior``)
or one command (an export, a fit, a scoring), and names everything that run depends on: its data, windows, seed,
model config and loss options (the trainer's config, inline), its warm start (``"from"``: an earlier stage), and
its budget (the config's step count). The runner runs the stages in order in ``runs/recipes/NAME/`` and

* resumes: a finished stage (``done.json``) is skipped, a trainer stage killed mid-way continues from its
  ``last.pt`` (every trainer's draws are functions of (seed, step), so a resumed run reaches the same weights on the
  same machine), any other stage runs again from its start;
* reports progress (stage, step, loss, time left) in ``progress.json`` and on stdout, and runs in the background
  with ``--background`` (``--status`` reads the progress back);
* records each stage's cost (CPU-hours of its process tree, wall time, windows, the CPU) as it goes, so a killed
  run still counts what it spent;
* exports the files it ``produces`` under ``runs/recipes/NAME/out/`` (paths as under ``python/tcd``), scores
  them with the model's protocol, pairs the score with the bundled file's (``training.compare``), and writes
  ``benches/results/recipes/NAME.json``: the stages' cost, the files' sha256 beside the bundled ones', the score.

A stage's strings may hold placeholders: ``{run}`` (the recipe's run directory), ``{out}`` (its ``out/``),
``{stage:NAME}`` (an earlier stage's directory), ``{input:PATH}`` (a file another recipe produces, PATH as under
``python/tcd``: the bundled file by default, that recipe's run output with ``--inputs runs``, run first where it has
not), ``{recipe:NAME/STAGE}`` (another recipe's stage directory, for an input no bundled file holds: that recipe
runs up to that stage first where it has not), ``{data}`` (the data
root), ``{threads}``, ``{device}`` and ``{package}`` (``python/tcd``, whose ``weights*/`` are the bundled model
directories). A trainer stage's ``"from"`` may also name another recipe's file by a placeholder, to fine-tune it.

    python -m training.recipe --list                      # each recipe and the files it produces
    python -m training.recipe NAME [--background] [--threads 1] [--device cuda] [--inputs bundled|runs]
    python -m training.recipe NAME --status
    python -m training.recipe NAME --smoke --run-dir /tmp/smoke    # every stage for a few steps
    python -m training.recipe NAME --carry     # an unfinished run's state into training/checkpoints/NAME/
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import queue
import re
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path

from . import carry
from .recipe_file import LAST, PACKAGE, ROOT, TRAINERS, Recipe, RecipeError, Stage, all_recipes, producer

RESULTS = ROOT / "benches" / "results" / "recipes"
#: how often the runner samples a running stage's CPU time and writes its progress (seconds)
POLL_S = 10.0


# ------------------------------------------------------------------------------------------ the recipe file


# ------------------------------------------------------------------------------------------ running


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def tree_cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of ``pid`` and its waited-for children (Linux /proc; 0 elsewhere)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        utime, stime, cutime, cstime = (int(x) for x in fields[11:15])
        return (utime + stime + cutime + cstime) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return 0.0


#: the trainers' progress lines: training.train's "epoch E batch B/S loss L", training.prior's "iteration i/N: loss L",
#: the generator's "step N (M min): loss L"
PROGRESS = (
    re.compile(r"epoch (?P<epoch>\d+) batch (?P<batch>\d+)/(?P<per>\d+) loss (?P<loss>[\d.eE+-]+)"),
    re.compile(r"iteration (?P<step>\d+)/(?P<total>\d+): loss (?P<loss>[\d.eE+-]+)"),
    re.compile(r"^step (?P<step>\d+) \([\d.]+ min\): loss (?P<loss>[\d.eE+-]+)"),  # the generator's IMLE trainer
)


def stage_output(proc: subprocess.Popen):
    """The lines a stage prints, and an empty string each POLL_S seconds it prints none: a trainer silent for an
    hour (a long epoch) still has its cost and progress written as it runs, so a killed run counts what it spent."""
    lines: queue.Queue = queue.Queue()

    def pump():
        for line in proc.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
    while True:
        try:
            line = lines.get(timeout=POLL_S)
        except queue.Empty:
            line = ""
        if line is None:
            return
        yield line


def parse_progress(line: str) -> dict | None:
    for rx in PROGRESS:
        m = rx.search(line)
        if m:
            g = m.groupdict()
            if "epoch" in g:
                return {"step": int(g["epoch"]) * int(g["per"]) + int(g["batch"]), "loss": float(g["loss"])}
            return {
                "step": int(g["step"]),
                "loss": float(g["loss"]),
                **({"total": int(g["total"])} if g.get("total") else {}),
            }
    return None


class Runner:
    def __init__(
        self,
        recipe: Recipe,
        run_dir: Path,
        *,
        threads: int = 1,
        device: str = "cpu",
        inputs: str = "bundled",
        data: str | None = None,
        smoke: bool = False,
        log=print,
    ):
        self.recipe, self.dir, self.threads, self.device = recipe, Path(run_dir), threads, device
        self.inputs, self.data, self.smoke, self.log = inputs, data, smoke, log
        self.out = self.dir / "out"

    # placeholders --------------------------------------------------------------------------------------
    def resolve(self, value):
        if isinstance(value, dict):
            return {k: self.resolve(v) for k, v in value.items()}
        if isinstance(value, list):
            return [self.resolve(v) for v in value]
        if not isinstance(value, str):
            return value

        def sub(m: re.Match) -> str:
            key, _, arg = m.group(1).partition(":")
            if key == "run":
                return str(self.dir)
            if key == "out":
                return str(self.out)
            if key == "stage":
                return str(self.dir / arg)
            if key == "input":
                return str(self.input(arg))
            if key == "recipe":
                return str(self.dependency(*arg.split("/", 1)))
            if key == "data":
                return self.data or os.environ.get("TCD_DATA_DIR") or str(ROOT.parent / "shared" / "data")
            if key == "threads":
                return str(self.threads)
            if key == "device":
                return self.device
            if key == "package":  # python/tcd: its weights*/ are the bundled model directories
                return str(PACKAGE)
            raise RecipeError(f"{self.recipe.path}: unknown placeholder {{{m.group(1)}}}")

        return re.sub(r"\{([a-z]+(?::[^{}]+)?)\}", sub, value)

    def dependency(self, name: str, stage: str) -> Path:
        """Another recipe's stage directory ({recipe:NAME/STAGE}: a warm start or a prior that no bundled file
        holds), after running that recipe up to that stage where it has not run yet."""
        recipes = all_recipes()
        if name not in recipes or stage not in [s.name for s in recipes[name].stages]:
            raise RecipeError(f"{self.recipe.path}: {{recipe:{name}/{stage}}} names no stage of a recipe")
        other = self.sibling(recipes[name])
        if not (other.dir / stage / "done.json").is_file():
            self.log(f"[{self.recipe.name}] needs {name} up to its stage {stage}: running it in {other.dir}")
            other.run(until=stage)
        return other.dir / stage

    def sibling(self, recipe: Recipe) -> "Runner":
        """A runner of another recipe with this one's options, in its own run directory (inside this one's for a
        smoke run, which must not touch real runs)."""
        run_dir = self.dir / "deps" / recipe.name if self.smoke else runs_root() / recipe.name
        return Runner(
            recipe,
            run_dir,
            threads=self.threads,
            device=self.device,
            inputs=self.inputs,
            data=self.data,
            smoke=self.smoke,
            log=self.log,
        )

    def input(self, path: str) -> Path:
        if path not in self.recipe.needs:
            raise RecipeError(f"{self.recipe.path}: {{input:{path}}} is not in its 'needs'")
        if self.inputs == "bundled" or not path.endswith(".safetensors"):  # a sampling.json is shipped as written
            return PACKAGE / path
        maker = self.sibling(producer(path, all_recipes()))
        if not (maker.out / path).is_file():
            self.log(
                f"[{self.recipe.name}] --inputs runs: {path} comes from {maker.recipe.name}: running it in {maker.dir}"
            )
            maker.run()
        return maker.out / path

    # one stage -------------------------------------------------------------------------------------------
    def stage_config(self, stage: Stage) -> dict:
        cfg = dict(self.resolve(stage.config))
        if stage.init.startswith("{"):  # another recipe's file: {input:...} or {recipe:...}/FILE
            cfg["init_from"] = self.resolve(stage.init)
        elif stage.init:
            src, _, file = stage.init.partition("/")
            cfg["init_from"] = str(self.dir / src / (file or LAST))
        if self.smoke:
            cfg.update(smoke_overrides(stage.run, cfg))
        return cfg

    def module_args(self, stage: Stage) -> list:
        args = self.resolve(stage.args)
        if self.smoke:
            for flag, value in stage.smoke.items():
                if flag in args:
                    args[args.index(flag) + 1] = str(value)
                else:
                    args += [flag] + ([] if value is True else [str(value)])
        return args

    def module_command(self, stage: Stage) -> list:
        """The command of a module stage, as it runs (the record keeps it without the interpreter, relative)."""
        return [sys.executable, "-m", stage.module, *self.module_args(stage)]

    def run_stage(self, stage: Stage, index: int, total: int) -> dict:
        sdir = self.dir / stage.name
        done = sdir / "done.json"
        if done.is_file():
            record = json.loads(done.read_text())
            if stage.run in TRAINERS or record.get("command") == [relative(c) for c in self.module_command(stage)[1:]]:
                self.log(f"[{self.recipe.name}] stage {index + 1}/{total} {stage.name}: done before, skipped")
                return record
            # a module stage whose recorded command is not the recipe's now (the recipe changed): its output is
            # another stage's, so it runs again
            self.log(
                f"[{self.recipe.name}] stage {index + 1}/{total} {stage.name}: done before as another command, "
                "run again"
            )
            done.unlink()
        if stage.gpu and self.device == "cpu":
            self.log(
                f"[{self.recipe.name}] stage {stage.name} ran on a GPU ({stage.gpu}); on this CPU it takes "
                "its recorded CPU estimate instead (the recipe's 'cost')"
            )
        sdir.mkdir(parents=True, exist_ok=True)
        config_path = sdir / "config.json"
        if stage.run in TRAINERS:
            config_path.write_text(json.dumps(self.stage_config(stage), indent=1) + "\n")
            resume = (sdir / LAST).is_file()
            cmd = stage.command(config_path, sdir, resume, self.threads, self.device)
            if self.smoke and stage.run == "prior":
                cmd.append("--no-compile")  # compiling costs more than a smoke run's two steps
        else:
            resume = False
            cmd = self.module_command(stage)
        env = {**os.environ, "OMP_NUM_THREADS": str(self.threads), "PYTHONUNBUFFERED": "1"}
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        costs = json.loads((sdir / "cost.json").read_text()) if (sdir / "cost.json").is_file() else []
        attempt = {"started": time.time(), "cpu_s": 0.0, "wall_s": 0.0, "cpu": cpu_name(), "resumed": resume}
        costs.append(attempt)
        steps = stage.steps()
        self.log(f"[{self.recipe.name}] stage {index + 1}/{total} {stage.name}: {' '.join(cmd)}")
        t0, last_poll, progress, cpu0 = time.time(), 0.0, {}, children_cpu_seconds()
        with open(sdir / "log.txt", "a") as logf:
            proc = subprocess.Popen(
                cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1
            )
            last_line = ""
            for line in stage_output(proc):
                if line:
                    logf.write(line)
                    logf.flush()
                    last_line = line.strip()
                    progress = parse_progress(line) or progress
                now = time.time()
                if now - last_poll > POLL_S:
                    last_poll = now
                    attempt.update(cpu_s=tree_cpu_seconds(proc.pid), wall_s=now - t0)
                    (sdir / "cost.json").write_text(json.dumps(costs, indent=1))
                    self.write_progress(stage, index, total, progress, steps, t0, last_line)
            rc = proc.wait()
        attempt.update(wall_s=time.time() - t0, cpu_s=children_cpu_seconds() - cpu0)
        (sdir / "cost.json").write_text(json.dumps(costs, indent=1))
        if rc != 0:
            raise RecipeError(f"stage {stage.name} failed (exit {rc}): see {sdir / 'log.txt'}")
        record = {
            "stage": stage.name,
            "command": [relative(c) for c in cmd[1:]],
            "steps": steps,
            "windows": None if self.smoke else stage.windows(),
            "cpu_hours": sum(a["cpu_s"] for a in costs) / 3600,
            "wall_hours": sum(a["wall_s"] for a in costs) / 3600,
            "attempts": len(costs),
            "cpus": sorted({a["cpu"] for a in costs}),
            "device": self.device,
            "smoke": self.smoke,
        }
        done.write_text(json.dumps(record, indent=1) + "\n")
        return record

    def write_progress(self, stage, index, total, progress, steps, t0, line):
        p = {
            "recipe": self.recipe.name,
            "stage": stage.name,
            "stage_index": index + 1,
            "stages": total,
            "elapsed_s": round(time.time() - t0),
            "last_line": line[-200:],
            **progress,
        }
        done_steps, all_steps = progress.get("step"), progress.get("total", steps)
        if done_steps and all_steps:
            p["total"] = all_steps
            p["left_s"] = round((time.time() - t0) * (all_steps - done_steps) / done_steps)
        (self.dir / "progress.json").write_text(json.dumps(p, indent=1) + "\n")
        left = f", about {p['left_s'] / 60:.0f} min left in the stage" if "left_s" in p else ""
        loss = f", loss {progress['loss']:.5g}" if "loss" in progress else ""
        step = f" step {done_steps}/{all_steps}" if done_steps else ""
        self.log(f"[{self.recipe.name}] {stage.name} ({index + 1}/{total}){step}{loss}{left}")

    # the whole recipe ------------------------------------------------------------------------------------
    def run(self, until: str | None = None) -> dict:
        self.dir.mkdir(parents=True, exist_ok=True)
        carry.restore(self)
        for p in self.recipe.produces:  # the stages that write them need not make the folders
            (self.out / p).parent.mkdir(parents=True, exist_ok=True)
        stages = self.recipe.stages + self.recipe.evaluate
        records = []
        for i, stage in enumerate(stages):
            records.append(self.run_stage(stage, i, len(stages)))
            if stage.name == until:
                self.log(f"[{self.recipe.name}] stopped after stage {until}, as asked")
                return {"stages": records}
        missing = [p for p in self.recipe.produces if not (self.out / p).is_file()]
        if missing:
            raise RecipeError(f"{self.recipe.path}: its stages ran but did not write {missing} under {self.out}")
        result = self.result(records)
        target = (self.dir / "result.json") if self.smoke else RESULTS / f"{self.recipe.name}.json"
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(json.dumps(result, indent=1) + "\n")
        self.log(f"[{self.recipe.name}] done: {target}")
        return result

    def result(self, records: list) -> dict:
        files = {}
        for p in self.recipe.produces:
            bundled = PACKAGE / p
            files[p] = {
                "sha256": sha256(self.out / p),
                "bundled_sha256": sha256(bundled) if bundled.is_file() else None,
            }
            files[p]["identical"] = files[p]["sha256"] == files[p]["bundled_sha256"]
        comparisons = []
        for c in [] if self.smoke else self.recipe.compare:  # a smoke run's score is of other windows
            comparisons.append(
                compare(
                    self.resolve(c["new"]),
                    self.resolve(c["bundled"]),
                    c.get("keys", ["average"]),
                    c.get("horizon", "1000"),
                    c.get("bundled_key"),
                )
            )
        train = [
            r
            for r, s in zip(records, self.recipe.stages + self.recipe.evaluate, strict=True)
            if s in self.recipe.stages
        ]
        return {
            "recipe": self.recipe.name,
            "command": f"python -m training.recipe {self.recipe.name}",
            "inputs": self.inputs,
            "threads": self.threads,
            "files": files,
            "stages": records,
            "cpu_hours": sum(r["cpu_hours"] for r in train),
            "scoring_cpu_hours": sum(r["cpu_hours"] for r in records) - sum(r["cpu_hours"] for r in train),
            "windows": sum(r["windows"] or 0 for r in train),
            "comparisons": comparisons,
        }


def children_cpu_seconds() -> float:
    """CPU seconds of this process's waited-for children: the difference across a stage is its process tree's."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def smoke_overrides(run: str, cfg: dict) -> dict:
    """A trainer config cut to a couple of steps on a few windows (the recipe's wiring, not its result)."""
    if run == "prior":
        o = {"iterations": 2, "batch_size": 8, "val_windows": 8}
        if cfg.get("val_every"):
            o["val_every"] = 1
        return o
    o = {"epochs": 1, "steps_per_epoch": 2, "batch_size": 4, "val_every": 1, "val_timesteps": 2, "val_max_windows": 4}
    if cfg.get("imle_samples"):
        o["imle_samples"] = 2
    if cfg.get("warmup_steps"):
        o["warmup_steps"] = 1
    return o


def compare(new: str, bundled: str, keys: list, horizon: str, bundled_key: str | None) -> dict:
    """``training.compare``'s paired test of the reproduction's score against the bundled file's, per key."""
    out = {"new": relative(new), "bundled": relative(bundled), "keys": {}}
    for key in keys:
        cmd = [sys.executable, "-m", "training.compare", new, bundled, "--key", key, "--horizon", horizon]
        if bundled_key:
            cmd += ["--bundled-key", bundled_key]
        r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
        out["keys"][key] = {"exit": r.returncode, "report": (r.stdout + r.stderr).strip().splitlines()[-8:]}
    return out


def relative(arg: str) -> str:
    """An argument as the results file records it: paths inside the repository relative to it."""
    return arg.replace(str(ROOT) + os.sep, "")


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def runs_root() -> Path:
    return ROOT / "runs" / "recipes"


def status(run_dir: Path, recipe: Recipe) -> str:
    lines = [f"{recipe.name}: {run_dir}"]
    for s in recipe.stages + recipe.evaluate:
        sdir = run_dir / s.name
        if (sdir / "done.json").is_file():
            d = json.loads((sdir / "done.json").read_text())
            lines.append(f"  {s.name}: done, {d['cpu_hours']:.2f} CPU-h")
        elif sdir.exists():
            lines.append(f"  {s.name}: started")
        else:
            lines.append(f"  {s.name}: not started")
    if (run_dir / "progress.json").is_file():
        lines.append("  progress: " + (run_dir / "progress.json").read_text().strip().replace("\n", ""))
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m training.recipe", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("name", nargs="?", help="the recipe (training/recipes/NAME.json)")
    ap.add_argument("--list", action="store_true", help="each recipe and the files it produces")
    ap.add_argument("--run-dir", default=None, help="default runs/recipes/NAME")
    ap.add_argument("--threads", type=int, default=1, help="CPU threads per stage (default 1: keep a core free)")
    ap.add_argument("--device", default="cpu", help="cpu | cuda: the training.train stages' device")
    ap.add_argument(
        "--inputs",
        choices=("bundled", "runs"),
        default="bundled",
        help="other recipes' files ({input:...}): the bundled ones, or those recipes' runs",
    )
    ap.add_argument(
        "--data",
        default=None,
        help="the data root, with h36m/ and humaneva/ (default $TCD_DATA_DIR, else ../shared/data)",
    )
    ap.add_argument(
        "--smoke",
        action="store_true",
        help="every stage for a few steps (its result is not written to benches/results)",
    )
    ap.add_argument("--until", default=None, metavar="STAGE", help="stop after this stage")
    ap.add_argument("--background", action="store_true", help="run detached (nohup); the log is RUN_DIR/log.txt")
    ap.add_argument("--status", action="store_true", help="the run's stages and progress")
    ap.add_argument("--carry", action="store_true", help="an unfinished run's state into training/checkpoints/NAME/")
    args = ap.parse_args(argv)
    recipes = all_recipes()
    if args.list:
        for r in recipes.values():
            cost = r.cost.get("cpu_hours")
            print(f"{r.name}: {', '.join(r.produces)}" + (f"  ({cost} CPU-hours from scratch)" if cost else ""))
        return 0
    if not args.name:
        ap.error("name a recipe (--list lists them)")
    if args.name not in recipes:
        ap.error(f"no recipe {args.name!r}: the recipes are {sorted(recipes)}")
    recipe = recipes[args.name]
    run_dir = Path(args.run_dir) if args.run_dir else runs_root() / recipe.name
    if args.status:
        print(status(run_dir, recipe))
        return 0
    runner = Runner(
        recipe, run_dir, threads=args.threads, device=args.device, inputs=args.inputs, data=args.data, smoke=args.smoke
    )
    if args.carry:
        print(f"carried into {carry.carry(runner)}")
        return 0
    if args.background:
        run_dir.mkdir(parents=True, exist_ok=True)
        argv = [a for a in (sys.argv[1:] if argv is None else argv) if a != "--background"]
        with open(run_dir / "log.txt", "a") as log:
            p = subprocess.Popen(
                ["nohup", sys.executable, "-m", "training.recipe", *argv],
                cwd=ROOT,
                stdout=log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
            )
        print(
            f"{recipe.name}: running in the background, pid {p.pid}; log {run_dir / 'log.txt'}; "
            f"python -m training.recipe {recipe.name} --status"
        )
        return 0
    try:
        runner.run(until=args.until)
    except RecipeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
