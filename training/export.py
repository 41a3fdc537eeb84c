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
import subprocess
import sys
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import save_file

from .diffusion import DiffusionConfig, Schedule
from .model import ModelConfig, TCDModel, randomize_output_layer

FORMAT_VERSION = 1
ROLES = ("short", "long", "repair")  # the denoisers' roles
PRIOR_ROLE = "prior"  # the prior forecaster's role, in PRIOR_FILE
PRIOR_FILE = "prior.safetensors"
REPAIR_FILL_FILE = "repair_fill.safetensors"  # a prior with anchor "window": the repair model's fill (role "prior")
GENERATOR_ROLE = "generator"  # the MLP sample generator's role (training/generator.py), in GENERATOR_FILE
GENERATOR_FILE = "generator.safetensors"
SAMPLING_FILE = "sampling.json"  # a model directory's default samplers (tcd._model reads it)
CONFIG_KEY = "tcd_config"

# Windows of the Human3.6M cascade (spec section 5) and the repair model.
WINDOWS = {"short": (50, 5), "long": (55, 20), "repair": (50, 0)}
# HumanEva-I's cascade, 15 observed -> 60 at 60 Hz (configs/humaneva_short.json says why its first stage is one
# frame), and a repair model of its observation; and the model joints of each dataset.
HUMANEVA_WINDOWS = {"short": (15, 1), "long": (16, 59), "repair": (15, 0)}
DATASET_WINDOWS = {"h36m": WINDOWS, "humaneva": HUMANEVA_WINDOWS}
DATASET_JOINTS = {"h36m": 22, "humaneva": 14}

PRESETS = {
    "full": ModelConfig(),
    "tiny": ModelConfig(channels=16, num_layers=2, num_heads=2, ffn_dim=16),
    "reduced": ModelConfig(channels=32, num_layers=3, num_heads=4, ffn_dim=32),  # the bundled model's size
}


def source_revision() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent, capture_output=True, text=True, timeout=5
        )
        rev = out.stdout.strip()
        if out.returncode == 0 and rev:
            dirty = subprocess.run(
                ["git", "status", "--porcelain", "--untracked-files=no"],
                cwd=Path(__file__).parent,
                capture_output=True,
                text=True,
                timeout=5,
            ).stdout.strip()
            return rev + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        pass
    return "unknown"


def h36m_data_meta(training_data: str = "Human3.6M S1,S6,S7,S8,S9 (exp-map, 25 fps)") -> dict:
    from .data.h36m import joint_names_22, joints_used

    return {
        "dataset": "h36m",
        "fps": 25.0,
        "units": "m",
        "root_relative": True,
        "joint_names": joint_names_22(),
        "joint_index_32": joints_used(),
        "training_data": training_data,
        "licence": "Human3.6M: academic non-commercial research use only",
    }


def humaneva_data_meta(
    training_data: str = "HumanEva-I Train split, S1,S2,S3 (60 Hz)", with_h36m: bool = False
) -> dict:
    """The ``data`` block of a HumanEva-I model: 14 joints (joints 1..14 of the 15-joint VideoPose3D layout
    relative to the pelvis, the protocol's 42 dimensions), 60 Hz, metres, world axes with +z up (the global
    rotation is kept, as the DLow / GSPS protocol does; only the translation is removed)."""
    from .data.humaneva import HUMANEVA_FPS, HUMANEVA_MODEL_JOINT_NAMES

    return {
        "dataset": "humaneva",
        "fps": float(HUMANEVA_FPS),
        "units": "m",
        "root_relative": True,
        "joint_names": list(HUMANEVA_MODEL_JOINT_NAMES),
        "layout": "humaneva15",
        "root_joint": "pelvis",
        "up": "z",
        "training_data": training_data,
        "licence": "HumanEva-I: research use only (registration required)"
        + ("; Human3.6M: academic non-commercial use" if with_h36m else ""),
    }


def data_meta(dataset: str, training_data: str | None = None, h36m_share: float = 0.0) -> dict:
    """The ``data`` block of a model trained on ``dataset`` ("h36m" or "humaneva"; a HumanEva-I model with
    ``h36m_share`` > 0 learnt from Human3.6M too, and its block says so)."""
    if dataset == "humaneva":
        if h36m_share:
            from .data.humaneva import mix_description

            return humaneva_data_meta(mix_description(h36m_share), with_h36m=True)
        return humaneva_data_meta() if training_data is None else humaneva_data_meta(training_data)
    if dataset == "h36m":
        return h36m_data_meta() if training_data is None else h36m_data_meta(training_data)
    raise ValueError(f"unknown dataset {dataset!r}: 'h36m' or 'humaneva'")


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
        "source_revision": source_revision(),
    }


def save_model_file(path: str | Path, model: torch.nn.Module, config: dict) -> None:
    tensors = {k: v.detach().to("cpu", torch.float32).contiguous() for k, v in model.state_dict().items()}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_file(tensors, str(path), metadata={CONFIG_KEY: json.dumps(config)})


def read_config(path: str | Path) -> dict:
    with safe_open(str(path), framework="pt") as f:
        meta = f.metadata() or {}
    if CONFIG_KEY not in meta:
        raise ValueError(f"{path}: no '{CONFIG_KEY}' entry in the safetensors metadata")
    return json.loads(meta[CONFIG_KEY])


def load_model_file(path: str | Path, device: str = "cpu", prior=None) -> tuple[TCDModel, Schedule, dict]:
    """Load a safetensors model file strictly into the reference classes (eval mode). The config's
    ``cond_fill`` / ``target`` and ``diffusion.prediction_type`` come back with it; ``prior`` (a
    ``training.prior.PriorNet``, e.g. from :func:`load_prior_file`) is attached to a ``cond_fill="prior"``
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


def prior_data_meta(cfg) -> dict:
    """The ``data`` block of a prior trained with ``cfg`` (a ``training.prior.PriorConfig``): the denoisers'
    description of its dataset, naming the subjects the prior was trained on."""
    subjects = ",".join(f"S{s}" for s in cfg.subjects)
    if getattr(cfg, "dataset", "h36m") == "humaneva":
        from .data.humaneva import mix_description

        share = getattr(cfg, "h36m_share", 0.0)
        return humaneva_data_meta(mix_description(share, cfg.subjects), with_h36m=bool(share))
    return h36m_data_meta(training_data=f"Human3.6M {subjects} (exp-map, 25 fps)")


def build_prior_config(model, data: dict, training: dict | None = None) -> dict:
    """The ``tcd_config`` of a ``training.prior.PriorNet`` (docs/tcd_config.schema.json, role ``prior``)."""
    k = model.fc_in.in_features
    eps = {float(b.eps) for b in model.blocks}
    if len(eps) != 1:
        raise ValueError(f"the prior's blocks must share one layer-norm epsilon, got {sorted(eps)}")
    m = {
        "num_joints": k // 3,
        "coords": 3,
        "num_features": k,
        "obs_len": model.cfg.obs_len,
        "chunk": model.cfg.chunk,
        "blocks": len(model.blocks),
        "layer_norm_eps": eps.pop(),
    }
    if model.cfg.anchor != "last":  # a forecaster's file stays as before anchor existed (its default)
        m["anchor"] = model.cfg.anchor
    if model.cfg.gap_fill != "none":  # likewise every file written before gap_fill existed
        m["gap_fill"] = model.cfg.gap_fill
    for prefix in ("inbetween", "joint_inbetween"):  # and before the in-betweeners
        if getattr(model.cfg, f"{prefix}_max_gap"):
            m[f"{prefix}_context"] = getattr(model.cfg, f"{prefix}_context")
            m[f"{prefix}_max_gap"] = getattr(model.cfg, f"{prefix}_max_gap")
    return {
        "format_version": FORMAT_VERSION,
        "role": PRIOR_ROLE,
        "model": m,
        "data": data,
        "training": training or {},
        "source_revision": source_revision(),
    }


def load_prior_file(path: str | Path):
    """(``training.prior.PriorNet`` in eval mode, its config) from a prior file, loaded strictly."""
    from safetensors.torch import load_file

    from .prior import PriorConfig, PriorNet

    cfg = read_config(path)
    if cfg.get("format_version") != FORMAT_VERSION or cfg.get("role") != PRIOR_ROLE:
        raise ValueError(
            f"{path}: not a prior file of format_version {FORMAT_VERSION} "
            f"(role {cfg.get('role')!r}, format_version {cfg.get('format_version')!r})"
        )
    m = cfg["model"]
    if m["coords"] != 3 or m["num_features"] != 3 * m["num_joints"]:
        raise ValueError(f"{path}: PriorNet takes 3 coordinates per joint, got {m}")
    model = PriorNet(
        PriorConfig(
            obs_len=m["obs_len"],
            chunk=m["chunk"],
            blocks=m["blocks"],
            anchor=m.get("anchor", "last"),
            gap_fill=m.get("gap_fill", "none"),
            **{
                k: m.get(k, 0)
                for k in (
                    "inbetween_context",
                    "inbetween_max_gap",
                    "joint_inbetween_context",
                    "joint_inbetween_max_gap",
                )
            },
        ),
        joints=m["num_joints"],
    )  # (files before anchor, gap_fill, the in-betweener)
    for b in model.blocks:
        b.eps = float(m["layer_norm_eps"])
    model.load_state_dict(load_file(str(path)), strict=True)
    if model.cfg.gap_fill == "forecaster":  # its forecaster is the model directory's, beside it
        forecaster = Path(path).parent / PRIOR_FILE
        if not forecaster.is_file():
            raise ValueError(
                f"{path}: the repair fill fills whole-frame gaps with the prior forecaster (gap_fill "
                f'"forecaster"), but {forecaster} is missing'
            )
        from .prior import attach_gap_forecaster

        attach_gap_forecaster(model, load_prior_file(forecaster)[0])
    return model.eval(), cfg


def save_prior(path: str | Path, model, training: dict | None = None) -> Path:
    """Writes a ``training.prior.PriorNet`` as a prior file (its data block from its config's subjects)."""
    path = Path(path)
    save_model_file(path, model.eval(), build_prior_config(model, prior_data_meta(model.cfg), training))
    return path


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
    cfg.setdefault("training", {})[what] = {**record, "source_revision": source_revision()}
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
    from .prior import GAP_FILLS

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


def random_prior(
    blocks: int = 24, seed: int = 0, obs_len: int = 50, chunk: int = 10, joints: int = 22, anchor: str = "last"
):
    """A ``training.prior.PriorNet`` with every weight drawn from a seeded normal of unit-gain scale (std
    1/sqrt(fan_in) for the matrices, 0.1 for the biases, 1 + 0.1 N(0, 1) for the norm weights), fc_out then
    scaled by 1/20 so that the forecast lies a few tenths of a metre (rms) from the last pose, the scale of
    real motion (unscaled: metres): unlike the trained init (fc_out ~ 1e-8, i.e. Zero-Velocity) every
    weight shapes the output. ``anchor="window"`` (chunk = obs_len): a repair fill, its correction as far from
    its input window. A fixture for parity tests and benchmarks."""
    from .prior import PriorConfig, PriorNet

    model = PriorNet(PriorConfig(obs_len=obs_len, chunk=chunk, blocks=blocks, anchor=anchor), joints=joints)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in model.named_parameters():
            z = torch.randn(p.shape, generator=g)
            if p.dim() == 2:
                p.copy_(z / math.sqrt(p.shape[1]))
            elif name.endswith("norm_weight"):
                p.copy_(1.0 + 0.1 * z)
            else:
                p.copy_(0.1 * z)
        model.fc_out.weight.mul_(0.05)
        model.fc_out.bias.mul_(0.05)
    return model.eval()


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
