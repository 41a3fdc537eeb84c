"""Carrying an unfinished recipe run between machines (``python -m training.recipe NAME --carry``).

A session's machine goes away with its run directory, so the state a run needs to go on is committed under
``training/checkpoints/NAME/``: the finished stages' records (their cost), the last finished stage's weights (what
the next stage starts from) and the running trainer stage's ``last.pt``. The next ``python -m training.recipe NAME``
on a fresh machine restores them into its run directory and resumes.

A committed file must stay under :data:`LIMIT`. A trainer checkpoint over it is stored compacted
(``STAGE.last.pt.xz``): Adam's two moment estimates in bfloat16, the whole file xz-compressed. The weights, the
averaged weights, the step and the random streams stay exact; only the moments are rounded (to 8 significant
bits), so a run continued from a carry is close to, not bit for bit, the run that never stopped. A local resume
(same machine, uncompacted ``last.pt``) is still exact. A file that is still over the limit is refused by name.
"""

from __future__ import annotations

import io
import json
import lzma
import shutil
from pathlib import Path

from .recipe_file import LAST, ROOT, RecipeError

CARRIED = ROOT / "training" / "checkpoints"
#: the largest file the repository takes (bytes)
LIMIT = 5 * 1024 * 1024
#: the optimizer-state entries a compacted checkpoint rounds to bfloat16 (torch.optim.Adam's moment estimates;
#: ``Optimizer.load_state_dict`` casts them back to the parameters' float32 on resume)
MOMENTS = ("exp_avg", "exp_avg_sq")
COMPACT = ".xz"


def compact(src: Path, dest: Path) -> Path:
    """``src`` (a trainer checkpoint) written to ``dest`` + ``.xz`` with its moments in bfloat16; the path."""
    import torch

    ck = torch.load(src, map_location="cpu", weights_only=False)
    for state in ck.get("optimizer", {}).get("state", {}).values():
        for key in MOMENTS:
            if key in state and state[key].is_floating_point():
                state[key] = state[key].to(torch.bfloat16)
    buf = io.BytesIO()
    torch.save(ck, buf)
    out = dest.with_name(dest.name + COMPACT)
    out.write_bytes(lzma.compress(buf.getvalue(), preset=9 | lzma.PRESET_EXTREME))
    return out


def carry(runner) -> Path:
    """``runner``'s unfinished run into ``training/checkpoints/NAME/``; the folder."""
    dest = CARRIED / runner.recipe.name
    if dest.exists():
        shutil.rmtree(dest)
    dest.mkdir(parents=True)
    stages = runner.recipe.stages + runner.recipe.evaluate
    state, last_done = {}, None
    for s in stages:
        sdir = runner.dir / s.name
        if (sdir / "done.json").is_file():
            state[s.name] = {"done": json.loads((sdir / "done.json").read_text())}
            if any(sdir.glob("*.pt")):  # weights a later stage reads; an export's or a fit's files are not
                last_done = sdir
            continue
        if (sdir / "cost.json").is_file():
            state[s.name] = {"cost": json.loads((sdir / "cost.json").read_text())}
        if (sdir / LAST).is_file():
            _copy(sdir / LAST, dest / f"{s.name}.{LAST}")
        break
    if last_done is not None:
        for f in sorted(last_done.glob("*.pt")):
            _copy(f, dest / f"{last_done.name}.{f.name}")
    # a finished command stage without weights (an export, a fit) left files that are not carried: it runs again,
    # from the weights carried, those of the last finished stage that has any
    modules = {s.name for s in stages if s.run == "module"}
    carried = None if last_done is None else last_done.name
    state = {k: v for k, v in state.items() if k not in modules or "done" not in v or k == carried}
    (dest / "state.json").write_text(json.dumps(state, indent=1) + "\n")
    return dest


def _copy(src: Path, dest: Path) -> None:
    """``src`` to ``dest``, compacted where it is over :data:`LIMIT`; a file still over it is refused."""
    if src.stat().st_size <= LIMIT:
        shutil.copy2(src, dest)
        return
    out = compact(src, dest)
    size = out.stat().st_size
    if size > LIMIT:
        out.unlink()
        raise RecipeError(
            f"{src}: {src.stat().st_size / 2**20:.2f} MiB, {size / 2**20:.2f} MiB compacted, is over the "
            f"{LIMIT / 2**20:.0f} MiB a committed file may hold: it cannot be carried"
        )


def restore(runner) -> None:
    """Start ``runner`` from a carried run when its run directory has no stage yet. Only the last finished stage's
    weights are carried: a later stage that reads an earlier one's (a warm start from further back) needs the run
    directory itself."""
    src = CARRIED / runner.recipe.name
    if (
        runner.smoke
        or not (src / "state.json").is_file()
        or any((runner.dir / s.name).exists() for s in runner.recipe.stages)
    ):
        return  # a smoke run starts from nothing: a carried checkpoint is of the real schedule
    state = json.loads((src / "state.json").read_text())
    for stage in runner.recipe.stages + runner.recipe.evaluate:
        name, st = stage.name, state.get(stage.name, {})
        files = [*src.glob(f"{name}.*.pt"), *src.glob(f"{name}.*.pt{COMPACT}")]
        if not st and not files:
            continue
        sdir = runner.dir / name
        sdir.mkdir(parents=True, exist_ok=True)
        if "done" in st:
            (sdir / "done.json").write_text(json.dumps(st["done"], indent=1) + "\n")
        if "cost" in st:
            (sdir / "cost.json").write_text(json.dumps(st["cost"], indent=1))
        for f in src.glob(f"{name}.*.pt"):
            shutil.copy2(f, sdir / f.name[len(name) + 1 :])
        for f in src.glob(f"{name}.*.pt{COMPACT}"):
            (sdir / f.name[len(name) + 1 : -len(COMPACT)]).write_bytes(lzma.decompress(f.read_bytes()))
    runner.log(f"[{runner.recipe.name}] restored the carried run from {src}")
