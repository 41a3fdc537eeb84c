"""A recipe file (``training/recipes/NAME.json``): its stages, what each runs and depends on, and the files the
recipe produces; read and checked here, run by ``training.recipe``."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECIPES = ROOT / "training" / "recipes"
PACKAGE = ROOT / "python" / "tcd"
#: the trainers a stage can run with an inline config; any other stage is a module and its arguments
TRAINERS = {"train": "training.train", "prior": "training.prior"}
#: where a killed trainer leaves its state, and what a warm start reads by default
LAST = "last.pt"


class RecipeError(ValueError):
    """A recipe file that does not say what the runner needs, or a run that cannot go on."""


@dataclass
class Stage:
    name: str
    run: str  # "train" | "prior" (an inline config) | "module" (``module`` with ``args``)
    config: dict = field(default_factory=dict)
    # "from": an earlier stage ("s1" -> its last.pt, "s1/best.pt" -> that file), or a file named by a placeholder
    # ("{input:weights/long.safetensors}": a model that another recipe produces, to fine-tune)
    init: str = ""
    module: str = ""
    args: list = field(default_factory=list)
    smoke: dict = field(default_factory=dict)  # a module stage's "--flag": value replacements for --smoke
    budget: dict = field(default_factory=dict)  # a module stage's {"steps", "windows"} (a trainer's are its config's)
    stop_after: int = 0  # a training.train stage whose weights were taken part-way through its schedule
    gpu: str = ""  # a stage that needs a GPU says so, and for how long on which one
    note: str = ""

    @classmethod
    def from_dict(cls, d: dict, where: str) -> "Stage":
        known = {"name", "run", "config", "from", "module", "args", "smoke", "budget", "stop_after", "gpu", "note"}
        unknown = set(d) - known
        if unknown:
            raise RecipeError(f"{where}: unknown stage keys {sorted(unknown)}")
        if "name" not in d or "run" not in d:
            raise RecipeError(f"{where}: a stage needs a 'name' and a 'run'")
        s = cls(
            name=d["name"],
            run=d["run"],
            config=d.get("config", {}),
            init=d.get("from", ""),
            module=d.get("module", ""),
            args=list(d.get("args", [])),
            smoke=d.get("smoke", {}),
            budget=d.get("budget", {}),
            stop_after=int(d.get("stop_after", 0)),
            gpu=d.get("gpu", ""),
            note=d.get("note", ""),
        )
        if s.run in TRAINERS:
            if not s.config or s.module or s.args:
                raise RecipeError(f"{where}: a {s.run!r} stage has a 'config' and no 'module' or 'args'")
            if s.stop_after and s.run != "train":
                raise RecipeError(f"{where}: stop_after is a training.train stage's")
            if "init_from" in s.config:
                raise RecipeError(f"{where}: name the warm start with the stage's 'from', not config.init_from")
        elif s.run == "module":
            if not s.module or s.config or s.init:
                raise RecipeError(f"{where}: a 'module' stage has a 'module' and 'args', no 'config' or 'from'")
        else:
            raise RecipeError(f"{where}: 'run' must be one of {sorted(TRAINERS) + ['module']}, got {s.run!r}")
        return s

    def command(self, config_path: Path, out: Path, resume: bool, threads: int, device: str) -> list:
        if self.run == "module":
            return [sys.executable, "-m", self.module, *self.args]
        cmd = [
            sys.executable,
            "-m",
            TRAINERS[self.run],
            "--config",
            str(config_path),
            "--out",
            str(out),
            "--threads",
            str(threads),
        ]
        if device != "cpu" and self.run == "train":  # training.prior runs on the CPU only
            cmd += ["--device", device]
        if self.stop_after:
            cmd += ["--stop-after-steps", str(self.stop_after)]
        return cmd + (["--resume"] if resume else [])

    def steps(self) -> int | None:
        """The stage's optimizer steps, from its config."""
        c = self.config
        if self.run == "prior":
            return int(c.get("iterations", 40_000))
        if self.stop_after:
            return self.stop_after
        if self.run == "train":
            return int(c.get("epochs", 50)) * int(c["steps_per_epoch"]) if c.get("steps_per_epoch") else None
        return self.budget.get("steps")

    def windows(self) -> int | None:
        """Training windows the stage draws (batch x steps), where its config says both."""
        if self.run == "module":
            return self.budget.get("windows")
        n = self.steps()
        return None if n is None else n * int(self.config.get("batch_size", 256 if self.run == "prior" else 32))


@dataclass
class Recipe:
    name: str
    description: str
    produces: list  # paths under python/tcd
    stages: list
    evaluate: list = field(default_factory=list)  # module stages that score the exported files
    compare: list = field(default_factory=list)  # [{"new": score json, "bundled": results json, "keys": [...]}]
    needs: list = field(default_factory=list)  # files of other recipes it reads ({input:PATH})
    cost: dict = field(default_factory=dict)  # what a run from scratch costs, as recorded (hours, hardware)
    path: Path | None = None

    @classmethod
    def load(cls, path: Path) -> "Recipe":
        d = json.loads(Path(path).read_text())
        known = {"name", "description", "produces", "stages", "evaluate", "compare", "needs", "cost"}
        unknown = set(d) - known
        if unknown:
            raise RecipeError(f"{path}: unknown recipe keys {sorted(unknown)}")
        for key in ("name", "description", "produces", "stages"):
            if not d.get(key):
                raise RecipeError(f"{path}: a recipe needs {key!r}")
        if d["name"] != Path(path).stem:
            raise RecipeError(f"{path}: its name {d['name']!r} is not its file's")
        stages = [Stage.from_dict(s, f"{path}: stage {i}") for i, s in enumerate(d["stages"])]
        evaluate = [Stage.from_dict(s, f"{path}: evaluate {i}") for i, s in enumerate(d.get("evaluate", []))]
        names = [s.name for s in stages + evaluate]
        if len(set(names)) != len(names):
            raise RecipeError(f"{path}: stage names repeat: {names}")
        for i, s in enumerate(stages):
            if s.init and not s.init.startswith("{") and s.init.split("/")[0] not in names[:i]:
                raise RecipeError(f"{path}: stage {s.name!r} starts from {s.init!r}, which is no earlier stage")
        return cls(
            name=d["name"],
            description=d["description"],
            produces=list(d["produces"]),
            stages=stages,
            evaluate=evaluate,
            compare=list(d.get("compare", [])),
            needs=list(d.get("needs", [])),
            cost=dict(d.get("cost", {})),
            path=Path(path),
        )


def all_recipes() -> dict:
    return {p.stem: Recipe.load(p) for p in sorted(RECIPES.glob("*.json"))}


def producer(path: str, recipes: dict) -> Recipe:
    for r in recipes.values():
        if path in r.produces:
            return r
    raise RecipeError(f"no recipe produces {path!r}")
