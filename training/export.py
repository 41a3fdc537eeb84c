"""Export trained (or random-init) models to a model directory of safetensors files.

A model directory holds ``short.safetensors`` (50 -> 5 frames), ``long.safetensors`` (55 -> 20) and,
when trained, ``repair.safetensors``, plus a readable ``model.json``. Each safetensors file carries its
full configuration as JSON in the ``tcd_config`` metadata entry (format_version 1):

    {"format_version": 1, "role": "short",
     "model": {num_joints, coords, num_features, channels, num_layers, num_heads, ffn_dim,
               diffusion_embedding_dim, time_embedding_dim, feature_embedding_dim, side_dim, layer_norm_eps},
     "window": {"obs_len", "pred_len", "seq_len"},
     "diffusion": {num_train_timesteps, beta_schedule, beta_start, beta_end, max_beta, betas, prediction_type,
                   variance_type},
     "data": {dataset, fps, units, root_relative, joint_names, joint_index_32, training_data, licence},
     "training": {...}, "source_revision": "<git sha>"}

Tensors are float32 with the PyTorch state_dict names (spec section 10.1).

The deterministic prior forecaster (``training/prior.py``) goes into the same directory as
``prior.safetensors``: the ``PriorNet`` state_dict (the DCT matrix is no tensor: the engine computes it)
and ``{"format_version": 1, "role": "prior", "model": {num_joints, coords, num_features, obs_len, chunk,
blocks, layer_norm_eps}, "data": {...}, "training": {...}, "source_revision"}``.

    python -m training.export --checkpoint runs/short/best.pt runs/long/best.pt --out models/h36m
    python -m training.export --random-init --out fixtures/tiny --preset tiny --seed 0
    python -m training.export --prior runs/prior/last.pt --out models/h36m
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
from pathlib import Path

import torch
from safetensors.torch import save_file

from .diffusion import DiffusionConfig, Schedule
from . import fileformat  # source_revision through the module: tests fix it in one place
from .fileformat import (
    CONFIG_KEY,
    DATASET_JOINTS,
    FORMAT_VERSION,
    GENERATOR_FILE,
    GENERATOR_ROLE,
    PRIOR_FILE,
    PRIOR_ROLE,
    REPAIR_FILL_FILE,
    ROLES,
    SAMPLING_FILE,
    data_meta,
    read_config,
    save_model_file,
)
from .model import ModelConfig, TCDModel, randomize_output_layer
from .prior_net import GAP_FILLS, build_prior_config, load_prior_file, random_prior, save_prior


# Windows of the Human3.6M cascade (spec section 5) and the repair model.
WINDOWS = {"short": (50, 5), "long": (55, 20), "repair": (50, 0)}
# HumanEva-I's cascade, 15 observed -> 60 at 60 Hz (configs/humaneva_short.json says why its first stage is one
# frame), and a repair model of its observation.
HUMANEVA_WINDOWS = {"short": (15, 1), "long": (16, 59), "repair": (15, 0)}
DATASET_WINDOWS = {"h36m": WINDOWS, "humaneva": HUMANEVA_WINDOWS}

PRESETS = {
    "full": ModelConfig(),
    "tiny": ModelConfig(channels=16, num_layers=2, num_heads=2, ffn_dim=16),
    "reduced": ModelConfig(channels=32, num_layers=3, num_heads=4, ffn_dim=32),  # the bundled model's size
}


def build_config(
    role: str,
    model_cfg: ModelConfig,
    diff_cfg: DiffusionConfig,
    obs_len: int,
    pred_len: int,
    data: dict,
    training: dict | None = None,
) -> dict:
    if role not in ROLES:
        raise ValueError(f"role must be one of {ROLES}, got {role!r}")
    return {
        "format_version": FORMAT_VERSION,
        "role": role,
        "model": model_cfg.to_dict(),
        "window": {"obs_len": obs_len, "pred_len": pred_len, "seq_len": obs_len + pred_len},
        "diffusion": diff_cfg.to_dict(),
        "data": data,
        "training": training or {},
        "source_revision": fileformat.source_revision(),
    }


def load_model_file(path: str | Path, device: str = "cpu", prior=None) -> tuple[TCDModel, Schedule, dict]:
    """Load a safetensors model file strictly into the reference classes (eval mode). The config's
    ``cond_fill`` / ``target`` and ``diffusion.prediction_type`` come back with it; ``prior`` (a
    ``training.prior_net.PriorNet``, e.g. from :func:`load_prior_file`) is attached to a ``cond_fill="prior"``
    model (the file holds the denoiser only; :func:`load_model_dir` attaches the directory's prior)."""
    from safetensors.torch import load_file

    cfg = read_config(path)
    if cfg.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{path}: format_version {cfg.get('format_version')} is not {FORMAT_VERSION}")
    model_cfg = ModelConfig.from_dict(cfg["model"])
    diff_cfg = DiffusionConfig.from_dict(cfg["diffusion"])
    model = TCDModel(model_cfg, diff_cfg.num_train_timesteps)
    model.load_state_dict(load_file(str(path)), strict=True)
    if prior is not None and model_cfg.cond_fill == "prior":
        model.attach_prior(prior.to(device))
    return model.to(device).eval(), Schedule(diff_cfg), cfg


def load_model_dir(path: str | Path, device: str = "cpu") -> dict[str, tuple[TCDModel, Schedule, dict]]:
    """Every denoiser of a model directory (:func:`load_model_file`); where one is conditioned on the prior
    forecaster (``cond_fill="prior"``) the directory's ``prior.safetensors`` is loaded
    (:func:`load_prior_file`) and attached to it (a missing one is a ``FileNotFoundError``)."""
    d = Path(path)
    files = {role: d / f"{role}.safetensors" for role in ROLES if (d / f"{role}.safetensors").is_file()}
    if "short" not in files or "long" not in files:
        raise FileNotFoundError(f"{d} must hold short.safetensors and long.safetensors")

    def fill_file(role: str) -> str:  # what a cond_fill 'prior' model of this role is conditioned on
        return REPAIR_FILL_FILE if role == "repair" else PRIOR_FILE

    needs = {role: fill_file(role) for role, f in files.items() if read_config(f)["model"].get("cond_fill") == "prior"}
    fills = {}
    for name in dict.fromkeys(needs.values()):
        if not (d / name).is_file():
            roles = [r for r, n in needs.items() if n == name]
            raise FileNotFoundError(
                f"{d}: the {', '.join(roles)} model(s) are conditioned on a fill (cond_fill "
                f"'prior'), but the directory has no {name}"
            )
        fills[name] = load_prior_file(d / name)[0]
    return {role: load_model_file(f, device, prior=fills.get(needs.get(role))) for role, f in files.items()}


def write_model_json(d: Path) -> None:
    """A readable summary of every model file in the directory (the denoisers' without their betas)."""
    summary = {}
    for role in ROLES:
        p = d / f"{role}.safetensors"
        if p.is_file():
            cfg = read_config(p)
            cfg["diffusion"] = {k: v for k, v in cfg["diffusion"].items() if k != "betas"}
            summary[role] = cfg
    if (d / PRIOR_FILE).is_file():
        summary[PRIOR_ROLE] = read_config(d / PRIOR_FILE)
    if (d / REPAIR_FILL_FILE).is_file():
        summary["repair_fill"] = read_config(d / REPAIR_FILL_FILE)
    if (d / GENERATOR_FILE).is_file():
        summary[GENERATOR_ROLE] = read_config(d / GENERATOR_FILE)
    (d / "model.json").write_text(json.dumps(summary, indent=2) + "\n")


def random_init_dir(
    out: str | Path,
    preset: str = "tiny",
    seed: int = 0,
    diff_cfg: DiffusionConfig | None = None,
    repair: dict | None = None,
    model: dict | None = None,
    prior_blocks: int = 0,
    dataset: str = "h36m",
) -> Path:
    """Seeded random-init short and long models (the last conv gets a small random weight, so that
    outputs are non-trivial): fixtures for parity tests and benchmarks. With ``repair`` (model-config
    overrides, e.g. ``{"cond_fill": "linear"}``; ``{}`` for the preset as it is) a repair model
    (50 + 0 frames) is written too. ``model``: model-config overrides of the short and long models (e.g.
    ``{"cond_fill": "prior", "target": "prior_residual", "target_scale": 10.0}``); ``prior_blocks`` > 0
    writes a random prior forecaster of that many blocks (:func:`random_prior`) as ``prior.safetensors``; a
    repair model with ``cond_fill`` ``"prior"`` gets a random 4-block repair fill (``repair_fill.safetensors``).
    The weights depend on the seed and the sizes only, not on the overrides of fill, target or
    ``diff_cfg.prediction_type``. ``dataset`` ``"humaneva"``: HumanEva-I's 14 joints, its windows
    (:data:`HUMANEVA_WINDOWS`) and data block, and a prior of its 15 observed frames."""
    if dataset not in DATASET_WINDOWS:
        raise ValueError(f"unknown dataset {dataset!r}: one of {sorted(DATASET_WINDOWS)}")
    d = Path(out)
    diff_cfg = diff_cfg or DiffusionConfig()
    roles = ("short", "long") + (("repair",) if repair is not None else ())
    windows, joints = DATASET_WINDOWS[dataset], DATASET_JOINTS[dataset]
    for i, role in enumerate(roles):
        torch.manual_seed(seed * 1000 + i)
        mcfg = PRESETS[preset]
        if joints != mcfg.num_joints:
            sizes = {k: v for k, v in mcfg.to_dict().items() if k not in ("num_features", "side_dim")}
            mcfg = ModelConfig.from_dict({**sizes, "num_joints": joints})
        if role == "repair":
            mcfg = ModelConfig.from_dict({**mcfg.to_dict(), **repair})
        elif model:
            mcfg = ModelConfig.from_dict({**mcfg.to_dict(), **model})
        net = TCDModel(mcfg, diff_cfg.num_train_timesteps)
        randomize_output_layer(net, seed=seed * 1000 + i)
        obs, pred = windows[role]
        cfg = build_config(
            role,
            net.cfg,
            diff_cfg,
            obs,
            pred,
            data_meta(dataset, "none (random init)"),
            {"random_init": True, "preset": preset, "seed": seed},
        )
        save_model_file(d / f"{role}.safetensors", net.eval(), cfg)
    if prior_blocks > 0:
        prior = random_prior(blocks=prior_blocks, seed=seed, obs_len=windows["short"][0], joints=joints)
        save_model_file(d / PRIOR_FILE, prior, build_prior_config(prior, data_meta(dataset, "none (random init)")))
    if repair is not None and repair.get("cond_fill") == "prior":  # the repair model's fill, random too
        n = sum(windows["repair"])
        fill = random_prior(blocks=4, seed=seed + 1, obs_len=n, chunk=n, joints=joints, anchor="window")
        save_model_file(d / REPAIR_FILL_FILE, fill, build_prior_config(fill, data_meta(dataset, "none (random init)")))
    write_model_json(d)
    return d


def write_checksums(d: str | Path) -> Path:
    """``SHA256SUMS`` for the weight files of a model directory: the file ``tcd.load`` checks (and requires
    for the bundled model). One implementation, the package's."""
    from tcd._directory import write_checksums as _write  # the built package (installed by the dev set-up)

    return _write(d)


def named_checkpoint_weights(ck: dict) -> tuple[str, dict]:
    """(name, weights) a training checkpoint stands for: its moving average when the run kept one (``ema``,
    the weights that were validated), else the trained weights (``raw``). A ``chosen`` entry (the weights a
    run chose by validation with the option removed at git tag gpu-workflow-before-removal, named e.g.
    ``ema_0.99``) still comes first, so that such a checkpoint exports what it was validated as."""
    if ck.get("chosen") is not None:
        return ck["chosen"]["name"], ck["chosen"]["weights"]
    return ("ema", ck["ema"]) if ck.get("ema") is not None else ("raw", ck["model"])


def checkpoint_weights(ck: dict) -> dict:
    """The weights of ``named_checkpoint_weights``."""
    return named_checkpoint_weights(ck)[1]


def export_checkpoint(ckpt_path: str | Path, out_dir: str | Path, description: str | None = None) -> Path:
    ck = torch.load(str(ckpt_path), map_location="cpu", weights_only=False)
    model_cfg = ModelConfig.from_dict(ck["model_config"])
    diff_cfg = DiffusionConfig.from_dict(ck["diffusion_config"])
    model = TCDModel(model_cfg, diff_cfg.num_train_timesteps)
    name, weights = named_checkpoint_weights(ck)
    model.load_state_dict(weights, strict=True)
    role = ck["role"]
    training = {k: ck.get(k) for k in ("epoch", "step", "best_val", "train_config", "elapsed_s")}
    training["weights"] = name
    if not (isinstance(training["best_val"], float) and math.isfinite(training["best_val"])):
        training["best_val"] = None  # no validation yet (an early last.pt): JSON has no Infinity
    if description:
        training["description"] = description
    cfg = build_config(
        role, model_cfg, diff_cfg, ck["window"]["obs_len"], ck["window"]["pred_len"], ck["data"], training
    )
    path = Path(out_dir) / f"{role}.safetensors"
    save_model_file(path, model.eval(), cfg)
    return path


def copy_model_files(files: list[Path], out: Path) -> None:
    """Copies model files named ``ROLE.safetensors`` (or ``prior.safetensors``, ``repair_fill.safetensors``,
    ``generator.safetensors``) into ``out`` after loading each strictly (a file that does not load replaces
    nothing)."""
    names = [r + ".safetensors" for r in ROLES] + [PRIOR_FILE, REPAIR_FILL_FILE, GENERATOR_FILE, SAMPLING_FILE]
    for f in files:
        if f.name not in names:
            raise SystemExit(f"{f}: the file name must be one of {', '.join(names)}")
        if f.name == SAMPLING_FILE:
            json.loads(f.read_text())  # tcd.load checks its keys; here, that it is JSON at all
        elif f.name in (PRIOR_FILE, REPAIR_FILL_FILE):
            load_prior_file(f)
        elif f.name == GENERATOR_FILE:
            from .generator import load_generator_file

            load_generator_file(f)
        else:
            load_model_file(f)
    out.mkdir(parents=True, exist_ok=True)
    for f in files:
        tmp = out / (f.name + ".tmp")
        shutil.copyfile(f, tmp)
        os.replace(tmp, out / f.name)
        print(f"copied {f} -> {out / f.name}")


# ------------------------------------------------------------------------------- the prior forecaster


def export_prior(ckpt_path: str | Path, out_dir: str | Path, description: str | None = None) -> Path:
    """``out_dir/prior.safetensors`` from a ``training.prior`` checkpoint (``last.pt``: its trained weights);
    ``out_dir/repair_fill.safetensors`` for a repair fill (anchor ``"window"``).
    The checkpoint is read once into memory, so a training run that replaces it meanwhile cannot mix two
    versions."""
    import io

    from . import prior

    data = Path(ckpt_path).read_bytes()
    ck = torch.load(io.BytesIO(data), map_location="cpu", weights_only=False)
    model = prior.load(io.BytesIO(data))
    history = ck.get("history") or []
    training = {
        "train_config": ck["config"],
        "iteration": ck["iteration"],
        "elapsed_s": ck.get("elapsed_s"),
        "loss": next((h["loss"] for h in reversed(history) if "loss" in h), None),
        "weights": "raw",
    }
    vals = [h["val"] for h in history if "val" in h and h["iteration"] <= ck["iteration"]]
    if vals:  # a run with validation (best.pt: the weights of the lowest)
        training["val"] = vals[-1]
    if description:
        training["description"] = description
    name = REPAIR_FILL_FILE if model.cfg.anchor == "window" else PRIOR_FILE
    return save_prior(Path(out_dir) / name, model, training)


def _rewrite_repair_fill(out_dir: str | Path, edit, what: str) -> Path:
    """Rewrites ``out_dir/repair_fill.safetensors`` with ``edit(cfg, tensors)`` applied to its config and tensors
    (in place), the run recorded in its ``training`` block under ``what``; the result is loaded strictly (with the
    ``prior.safetensors`` beside it, where its gap fill needs it) before it replaces the file."""
    from safetensors.torch import load_file

    path = Path(out_dir) / REPAIR_FILL_FILE
    cfg, tensors = read_config(path), load_file(str(path))
    if cfg["model"].get("anchor") != "window":
        raise ValueError(f'{path}: not a repair fill (anchor "window")')
    record = edit(cfg, tensors)
    cfg.setdefault("training", {})[what] = {**record, "source_revision": fileformat.source_revision()}
    tmp = path.with_name(path.name + ".tmp")
    save_file(tensors, str(tmp), metadata={CONFIG_KEY: json.dumps(cfg)})
    try:
        load_prior_file(tmp)
    except Exception:
        tmp.unlink()
        raise
    os.chmod(tmp, path.stat().st_mode & 0o777)  # the file's own mode (the writer's temporary one is 0600)
    os.replace(tmp, path)
    return path


def set_gap_fill(out_dir: str | Path, gap_fill: str) -> Path:
    """Rewrites ``out_dir/repair_fill.safetensors`` with ``model.gap_fill`` set to ``gap_fill`` (``"none"``
    removes the key, as in a file written before it existed); its weights and the rest of its config stay as
    they are (:func:`_rewrite_repair_fill`)."""

    if gap_fill not in GAP_FILLS:
        raise ValueError(f"gap_fill must be one of {list(GAP_FILLS)}, got {gap_fill!r}")

    def edit(cfg: dict, tensors: dict) -> dict:
        cfg["model"].pop("gap_fill", None)
        if gap_fill != "none":
            cfg["model"]["gap_fill"] = gap_fill
        return {"value": gap_fill}

    return _rewrite_repair_fill(out_dir, edit, "gap_fill_set")


def set_inbetween(out_dir: str | Path, kernels_path: str | Path | None, prefix: str = "inbetween") -> Path:
    """Rewrites ``out_dir/repair_fill.safetensors`` with the in-betweener's kernels of ``kernels_path``
    (``training.inbetween``'s file: kernels for n = 1 .. max_gap, their context) as tensors ``{prefix}_{n}`` and its
    config's ``{prefix}_context`` / ``{prefix}_max_gap`` (``prefix`` "inbetween", the whole-frame gaps', or
    "joint_inbetween", the joint runs'); ``None`` removes them. The fill's own weights stay as they are."""
    from .inbetween import kernel_width, load_kernels

    if prefix not in ("inbetween", "joint_inbetween"):
        raise ValueError(f'prefix must be "inbetween" or "joint_inbetween", got {prefix!r}')
    kernels, context, meta = load_kernels(kernels_path) if kernels_path else ({}, 0, {})
    if kernels and sorted(kernels) != list(range(1, max(kernels) + 1)):
        raise ValueError(f"{kernels_path}: kernels for gaps of 1 .. n frames expected, got {sorted(kernels)}")
    for n, w in kernels.items():
        if w.shape != (n, kernel_width(n, context)):
            raise ValueError(f"{kernels_path}: {prefix}_{n} has shape {w.shape}, not ({n}, {kernel_width(n, context)})")

    def edit(cfg: dict, tensors: dict) -> dict:
        for k in [k for k in tensors if k.startswith(prefix + "_")]:
            del tensors[k]
        cfg["model"].pop(f"{prefix}_context", None)
        cfg["model"].pop(f"{prefix}_max_gap", None)
        if kernels:
            cfg["model"][f"{prefix}_context"], cfg["model"][f"{prefix}_max_gap"] = context, max(kernels)
            tensors.update(
                {f"{prefix}_{n}": torch.tensor(w, dtype=torch.float32).contiguous() for n, w in kernels.items()}
            )
        return {
            "kernels": str(kernels_path) if kernels_path else None,
            "max_gap": max(kernels, default=0),
            "context": context,
            "fit": meta,
        }

    return _rewrite_repair_fill(out_dir, edit, f"{prefix}_set")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m training.export", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--checkpoint", nargs="+", help="training checkpoint(s) (.pt); each records its role")
    ap.add_argument("--random-init", action="store_true", help="write seeded random-init short and long models")
    ap.add_argument(
        "--files",
        nargs="+",
        metavar="ROLE.safetensors",
        help="exported model files to copy into --out, each checked to load strictly first (how a "
        "candidate's files replace the bundled ones of their roles)",
    )
    ap.add_argument(
        "--prior",
        metavar="CKPT",
        help="a training.prior checkpoint (last.pt): writes prior.safetensors "
        "(the deterministic prior forecaster) into --out beside the denoisers",
    )
    ap.add_argument(
        "--gap-fill",
        choices=("none", "forecaster"),
        help="rewrites --out's repair_fill.safetensors "
        'with this gap_fill (its weights as they are): "forecaster" fills whole-frame gaps from the '
        "prior.safetensors beside it (docs/repair.md)",
    )
    ap.add_argument(
        "--inbetween",
        metavar="KERNELS",
        help="rewrites --out's repair_fill.safetensors with the "
        "in-betweener's kernels (training.inbetween's .npz; \"none\" removes them), its weights as they "
        "are",
    )
    ap.add_argument(
        "--joint-inbetween",
        metavar="KERNELS",
        help="the same for the joint in-betweener's kernels (training.inbetween --joints)",
    )
    ap.add_argument("--preset", choices=sorted(PRESETS), default="tiny", help="model size for --random-init")
    ap.add_argument(
        "--dataset",
        choices=sorted(DATASET_WINDOWS),
        default="h36m",
        help="--random-init: the dataset's joints and windows (humaneva: 14 joints, 15 -> 1 -> 60 frames)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True, help="model directory to write")
    ap.add_argument(
        "--description", help="free text recorded in each file's training metadata (e.g. how the model was trained)"
    )
    args = ap.parse_args(argv)
    if (
        sum(
            map(
                bool,
                (
                    args.checkpoint,
                    args.random_init,
                    args.files,
                    args.prior,
                    args.gap_fill,
                    args.inbetween,
                    args.joint_inbetween,
                ),
            )
        )
        != 1
    ):
        ap.error(
            "give exactly one of --checkpoint, --random-init, --files, --prior, --gap-fill, --inbetween or "
            "--joint-inbetween"
        )
    out = Path(args.out)
    if args.random_init:
        random_init_dir(out, args.preset, args.seed, dataset=args.dataset)
    elif args.files:
        copy_model_files([Path(f) for f in args.files], out)
        write_model_json(out)
    elif args.prior:
        print(f"exported {export_prior(args.prior, out, args.description)}")
        write_model_json(out)
    elif args.gap_fill:
        print(f"rewrote {set_gap_fill(out, args.gap_fill)} with gap_fill {args.gap_fill!r}")
        write_model_json(out)
    elif args.inbetween or args.joint_inbetween:
        prefix, given = ("inbetween", args.inbetween) if args.inbetween else ("joint_inbetween", args.joint_inbetween)
        kernels = None if given == "none" else given
        print(f"rewrote {set_inbetween(out, kernels, prefix)} with the {prefix.replace('_', ' ')}er {kernels}")
        write_model_json(out)
    else:
        for ck in args.checkpoint:
            print(f"exported {export_checkpoint(ck, out, args.description)}")
        write_model_json(out)
    print(f"wrote {write_checksums(out)}")
    print(f"model directory: {out.resolve()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
