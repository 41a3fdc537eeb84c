"""Helpers shared by test_api.py, test_parity.py, test_parity_trained.py and test_cli.py: random-init model
directories, a model on one kernel path, and deliberately broken weight files. Weight files are rewritten
with safetensors' numpy API (no torch)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

CONFIG_KEY = "tcd_config"
ALL_KERNELS = ["portable", "avx2", "avx512"]  # the engine's kernel paths, in tcd.engine.supported_kernels() order


def make_model_dir(out: Path, preset: str = "tiny", seed: int = 0, repair: dict | None = None) -> Path:
    """short.safetensors + long.safetensors (+ repair.safetensors with the model-config overrides
    ``repair``, + model.json) of a seeded random-init model."""
    from training.export import random_init_dir  # needs torch (a dev dependency)

    return random_init_dir(out, preset=preset, seed=seed, repair=repair)


def read_weights(path: Path) -> tuple[dict, dict]:
    """(tensors by name, metadata) of a safetensors file."""
    from safetensors import safe_open

    with safe_open(str(path), framework="np") as f:
        meta = dict(f.metadata() or {})
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    return tensors, meta


def write_weights(path: Path, tensors: dict, meta: dict) -> Path:
    from safetensors.numpy import save_file

    save_file({k: np.ascontiguousarray(v) for k, v in tensors.items()}, str(path), metadata=meta)
    return path


def copy_dir(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def config_of(meta: dict) -> dict:
    return json.loads(meta[CONFIG_KEY])


def with_config(meta: dict, cfg: dict) -> dict:
    out = dict(meta)
    out[CONFIG_KEY] = json.dumps(cfg)
    return out


def poses(
    rng: np.random.Generator, batch: int | None = None, frames: int = 50, joints: int = 22, missing: float = 0.2
) -> np.ndarray:
    """Random root-relative poses in metres, (T, J, 3) or (B, T, J, 3), with a fraction set to NaN
    (per joint: all three coordinates together)."""
    shape = (frames, joints) if batch is None else (batch, frames, joints)
    x = rng.normal(scale=0.3, size=(*shape, 3)).astype(np.float32)
    miss = rng.random(shape) < missing
    x[miss] = np.nan
    return x


def bad(argument: str, fn, *args, **kwargs):
    """Asserts that ``fn(*args, **kwargs)`` raises InvalidInputError (a TcdError and a ValueError) naming
    ``argument`` (its ``.argument`` and, in backquotes, its message); returns the error."""
    from tcd.exceptions import InvalidInputError, TcdError

    with pytest.raises(InvalidInputError) as ei:
        fn(*args, **kwargs)
    e = ei.value
    assert isinstance(e, TcdError) and isinstance(e, ValueError)
    assert e.argument == argument, (e.argument, str(e))
    assert f"`{argument}`" in str(e)
    return e


def load_kernel(path, kernel: str, monkeypatch, cls=None):
    """The model at ``path`` (a ``cls``: ``tcd.engine.Denoiser`` by default, or ``tcd.engine.Prior``) on one kernel path
    (``TCD_KERNEL`` is read at load); skips paths this CPU lacks."""
    import tcd

    if kernel not in tcd.engine.supported_kernels():
        pytest.skip(f"this CPU cannot run the {kernel} kernels")
    monkeypatch.setenv("TCD_KERNEL", kernel)
    model = (cls or tcd.engine.Denoiser).load(path)
    monkeypatch.delenv("TCD_KERNEL")
    assert model.kernel == kernel
    return model
