"""The weight-file format has one schema, docs/tcd_config.schema.json: the exporter writes it, the engine
reads it, docs/weights.md describes it (see that page)."""
import copy
import json
import re
from pathlib import Path

import jsonschema
import pytest
import torch

import tcd
from tcd.exceptions import WeightsError

from training.diffusion import DiffusionConfig
from training.export import (PRESETS, ROLES, WINDOWS, build_config, h36m_data_meta, read_config,
                             save_model_file)
from training.model import ModelConfig, TCDModel

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = json.loads((ROOT / "docs" / "tcd_config.schema.json").read_text())
GOLDEN = ROOT / "tests" / "fixtures" / "tcd_config_golden.json"


def golden_config() -> dict:
    """What the exporter writes for the tiny preset's short-term model (without the source revision)."""
    cfg = build_config("short", PRESETS["tiny"], DiffusionConfig(), *WINDOWS["short"],
                       h36m_data_meta(training_data="none (random init)"), {"random_init": True, "preset": "tiny"})
    cfg.pop("source_revision")
    return cfg


def write(path: Path, cfg: dict) -> Path:
    """A weight file with the tiny preset's tensors (the same for every call) and ``cfg`` as given."""
    torch.manual_seed(0)
    save_model_file(path, TCDModel(PRESETS["tiny"], 50).eval(), cfg)
    return path


def schema_fields(schema: dict = SCHEMA, prefix: str = ""):
    """(dotted name, sub-schema, required) of every property the schema names."""
    required = set(schema.get("required", ()))
    for name, sub in schema.get("properties", {}).items():
        yield prefix + name, sub, name in required
        if sub.get("type") == "object" and "properties" in sub:
            yield from schema_fields(sub, prefix + name + ".")


def drop(cfg: dict, dotted: str) -> dict:
    out = copy.deepcopy(cfg)
    *parents, last = dotted.split(".")
    node = out
    for p in parents:
        node = node[p]
    del node[last]
    return out


def test_schema_is_a_valid_json_schema():
    jsonschema.Draft202012Validator.check_schema(SCHEMA)


@pytest.mark.parametrize("role", ROLES)
@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_every_exported_config_follows_the_schema(role, preset):
    overrides = [{}] if role != "repair" else [{}, {"cond_fill": "spline", "target": "spline_residual",
                                                    "target_scale": 4.0}]
    for o in overrides:
        mcfg = ModelConfig.from_dict({**PRESETS[preset].to_dict(), **o})
        cfg = build_config(role, mcfg, DiffusionConfig(), *WINDOWS[role], h36m_data_meta(), {"epochs": 1})
        jsonschema.validate(cfg, SCHEMA)


def test_fixture_and_bundled_files_follow_the_schema():
    files = sorted((ROOT / "tests" / "fixtures" / "golden_model").glob("*.safetensors"))
    files += sorted(tcd.default_model_dir().glob("*.safetensors")) if tcd.default_model_dir().is_dir() else []
    assert files
    for f in files:
        jsonschema.validate(read_config(f), SCHEMA)


def test_golden_config_is_what_the_exporter_writes_and_the_engine_reads(tmp_path):
    golden = json.loads(GOLDEN.read_text())
    assert golden_config() == golden, ("the exporter's output changed: if on purpose, update "
                                       "docs/tcd_config.schema.json, docs/weights.md and this fixture together")
    jsonschema.validate(golden, SCHEMA)
    d = tcd.Denoiser.load(write(tmp_path / "golden.safetensors", golden))
    assert d.config == golden
    assert (d.role, d.num_features, d.obs_len, d.pred_len, d.seq_len, d.num_train_timesteps) == (
        "short", 66, 50, 5, 55, 50)


def test_engine_requires_what_the_schema_requires_and_defaults_the_rest(tmp_path):
    golden = json.loads(GOLDEN.read_text())
    required = [name for name, _, req in schema_fields() if req]
    assert {"format_version", "model.channels", "window.seq_len", "diffusion.betas"} <= set(required)
    for name in required:
        path = write(tmp_path / f"no_{name}.safetensors", drop(golden, name))
        with pytest.raises(WeightsError) as e:
            tcd.Denoiser.load(path)
        assert name.split(".")[-1] in str(e.value), (name, str(e.value))
    # optional fields: the engine runs with the schema's default
    base = tcd.Denoiser.load(write(tmp_path / "base.safetensors", golden))
    x = base.sample(*_zeros(), 1, seed=0, sampler="ddim", num_inference_steps=2)
    for name, sub, req in schema_fields():
        if req or "default" not in sub or name.count(".") != 1 or name.split(".")[-1] not in golden[name.split(".")[0]]:
            continue
        d = tcd.Denoiser.load(write(tmp_path / f"default_{name}.safetensors", drop(golden, name)))
        assert (d.sample(*_zeros(), 1, seed=0, sampler="ddim", num_inference_steps=2) == x).all(), name


def _zeros():
    import numpy as np
    m = np.zeros((1, 66, 55), np.float32)
    m[:, :, :50] = 1.0
    return np.zeros((1, 66, 55), np.float32), m


def test_the_docs_name_every_field():
    text = (ROOT / "docs" / "weights.md").read_text()
    documented = set(re.findall(r"^\| `([a-z_0-9.]+)` \|", text, flags=re.M))
    leaves = {name for name, sub, _ in schema_fields() if "properties" not in sub}
    assert documented == leaves
