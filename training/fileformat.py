"""The file format every exported network shares (the denoisers, the prior forecaster and the repair fill, the MLP
generator): safetensors of float32 tensors under their PyTorch ``state_dict`` names, and the network's whole
configuration as JSON in the ``tcd_config`` metadata entry, format_version 1; the names of a model directory's
files and roles, the ``data`` block of each dataset, and the revision the file came from. ``training.export``
writes model directories with it; ``training.prior`` and ``training.generator`` their networks' files. The
engine's reader is ``tcd_core::Network``; the schema, docs/tcd_config.schema.json."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import save_file

FORMAT_VERSION = 1
ROLES = ("short", "long", "repair")  # the denoisers' roles
PRIOR_ROLE = "prior"  # the prior forecaster's role, in PRIOR_FILE
PRIOR_FILE = "prior.safetensors"
REPAIR_FILL_FILE = "repair_fill.safetensors"  # a prior with anchor "window": the repair model's fill (role "prior")
GENERATOR_ROLE = "generator"  # the MLP sample generator's role (training/generator.py), in GENERATOR_FILE
GENERATOR_FILE = "generator.safetensors"
SAMPLING_FILE = "sampling.json"  # a model directory's default samplers (tcd._model reads it)
CONFIG_KEY = "tcd_config"
#: the model joints of each dataset (Human3.6M: 22; HumanEva-I: joints 1..14 of 15; Human3.6M Setting-A: joints
#: 1..16 of the 17 of the ``h36m17`` layout)
DATASET_JOINTS = {"h36m": 22, "humaneva": 14, "h36m-a": 16}


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


def setting_a_data_meta(training_data: str = "Human3.6M S1,S5,S6,S7,S8 (exp-map, 50 fps)") -> dict:
    """The ``data`` block of a Human3.6M Setting-A model (``training.data.h36m_setting_a``): joints 1..16 of the
    ``h36m17`` layout relative to the pelvis (the protocol's 48 dimensions), 50 Hz, metres, the world rotation
    kept (+y up)."""
    from tcd.layouts import get_layout

    return {
        "dataset": "h36m-setting-a",
        "fps": 50.0,
        "units": "m",
        "root_relative": True,
        "joint_names": list(get_layout("h36m17").joint_names[1:]),
        "layout": "h36m17",
        "root_joint": "pelvis",
        "up": "y",
        "training_data": training_data,
        "licence": "Human3.6M: academic non-commercial research use only",
    }


def data_meta(dataset: str, training_data: str | None = None, h36m_share: float = 0.0) -> dict:
    """The ``data`` block of a model trained on ``dataset`` ("h36m", "humaneva" or "h36m-a"; a HumanEva-I model
    with ``h36m_share`` > 0 learnt from Human3.6M too, and its block says so)."""
    if dataset == "humaneva":
        if h36m_share:
            from .data.humaneva import mix_description

            return humaneva_data_meta(mix_description(h36m_share), with_h36m=True)
        return humaneva_data_meta() if training_data is None else humaneva_data_meta(training_data)
    if dataset == "h36m":
        return h36m_data_meta() if training_data is None else h36m_data_meta(training_data)
    if dataset == "h36m-a":
        return setting_a_data_meta() if training_data is None else setting_a_data_meta(training_data)
    raise ValueError(f"unknown dataset {dataset!r}: {' or '.join(map(repr, DATASET_JOINTS))}")


def save_model_file(path: str | Path, model: torch.nn.Module, config: dict) -> None:
    tensors = {k: v.detach().to("cpu", torch.float32).contiguous() for k, v in model.state_dict().items()}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_file(tensors, str(path), metadata={CONFIG_KEY: json.dumps(config)})


def read_config(path: str | Path, role: str | None = None, what: str = "") -> dict:
    """The ``tcd_config`` of a weight file; with ``role``, refused (``ValueError``) unless the file is a ``what``
    file of that role and of this format version."""
    with safe_open(str(path), framework="pt") as f:
        meta = f.metadata() or {}
    if CONFIG_KEY not in meta:
        raise ValueError(f"{path}: no '{CONFIG_KEY}' entry in the safetensors metadata")
    cfg = json.loads(meta[CONFIG_KEY])
    if role is not None and (cfg.get("format_version") != FORMAT_VERSION or cfg.get("role") != role):
        raise ValueError(
            f"{path}: not a {what} file of format_version {FORMAT_VERSION} "
            f"(role {cfg.get('role')!r}, format_version {cfg.get('format_version')!r})"
        )
    return cfg
