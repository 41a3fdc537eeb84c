"""The weight-file format has one schema, docs/tcd_config.schema.json: the exporter writes it, the engine
reads it, docs/weights.md describes it (see that page). The engine's side runs on the committed tiny weights
(tests/fixtures) without torch; that the exporter writes the golden configs needs torch (the training code)."""

import copy
import json
import re
from pathlib import Path

import jsonschema
import numpy as np
import pytest

import tcd
from conftest import FIXTURES, import_torch
from fixtures_util import CONFIG_KEY, config_of, read_weights, write_weights
from tcd.exceptions import WeightsError
from tcd import SamplerOptions

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = json.loads((ROOT / "docs" / "tcd_config.schema.json").read_text())
GOLDEN = FIXTURES / "tcd_config_golden.json"
EXPORTER = "the exporter (training/export.py)"


def golden_config() -> dict:
    """What the exporter writes for the tiny preset's short-term model (without the source revision)."""
    from training.diffusion import DiffusionConfig
    from training.export import PRESETS, WINDOWS, build_config
    from training.fileformat import h36m_data_meta

    cfg = build_config(
        "short",
        PRESETS["tiny"],
        DiffusionConfig(),
        *WINDOWS["short"],
        h36m_data_meta(training_data="none (random init)"),
        {"random_init": True, "preset": "tiny"},
    )
    cfg.pop("source_revision")
    return cfg


def write(path: Path, cfg: dict) -> Path:
    """A weight file with the tiny preset's short-term tensors (tests/fixtures/tiny_model, the same for every
    call) and ``cfg`` as given."""
    tensors, _ = read_weights(FIXTURES / "tiny_model" / "short.safetensors")
    return write_weights(path, tensors, {CONFIG_KEY: json.dumps(cfg)})


def role_schema(role: str) -> dict:
    """The schema's rules for a file of ``role`` as one object: the top level with the branch of its
    ``if role == "prior"`` / ``else if role == "generator"`` / ``else`` applied (the model block taken from
    ``$defs``; no window or diffusion for the prior and the generator)."""
    branch = (
        SCHEMA["then"] if role == "prior" else SCHEMA["else"]["then"] if role == "generator" else SCHEMA["else"]["else"]
    )
    props = dict(SCHEMA["properties"])
    for name, sub in branch.get("properties", {}).items():
        if sub is False:
            del props[name]
        else:
            props[name] = SCHEMA["$defs"][sub["$ref"].rsplit("/", 1)[-1]]
    return {"required": SCHEMA["required"] + branch.get("required", []), "properties": props}


def schema_fields(role: str = "short", schema: dict | None = None, prefix: str = ""):
    """(dotted name, sub-schema, required) of every property the schema names for a file of ``role``."""
    schema = role_schema(role) if schema is None else schema
    required = set(schema.get("required", ()))
    for name, sub in schema.get("properties", {}).items():
        yield prefix + name, sub, name in required
        if sub.get("type") == "object" and "properties" in sub:
            yield from schema_fields(role, sub, prefix + name + ".")


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


def test_every_exported_config_follows_the_schema():
    import_torch(EXPORTER)
    from training.diffusion import DiffusionConfig
    from training.export import PRESETS, WINDOWS, build_config
    from training.fileformat import ROLES, h36m_data_meta
    from training.model import ModelConfig

    for role in ROLES:
        overrides = (
            [{}]
            if role != "repair"
            else [{}, {"cond_fill": "spline", "target": "spline_residual", "target_scale": 4.0}]
        )
        for preset in sorted(PRESETS):
            for o in overrides:
                mcfg = ModelConfig.from_dict({**PRESETS[preset].to_dict(), **o})
                cfg = build_config(role, mcfg, DiffusionConfig(), *WINDOWS[role], h36m_data_meta(), {"epochs": 1})
                jsonschema.validate(cfg, SCHEMA)


def test_fixture_and_bundled_files_follow_the_schema():
    files = sorted(FIXTURES.glob("*/*.safetensors")) + sorted(FIXTURES.glob("*.safetensors"))
    files += sorted(tcd.default_model_dir().glob("*.safetensors")) if tcd.default_model_dir().is_dir() else []
    assert {f.parent.name for f in files} >= {"golden_model", "tiny_model", "tiny_humaneva_model", "fixtures"}
    for f in files:
        jsonschema.validate(config_of(read_weights(f)[1]), SCHEMA)


def test_golden_config_is_what_the_exporter_writes():
    import_torch(EXPORTER)
    assert golden_config() == json.loads(GOLDEN.read_text()), (
        "the exporter's output changed: if on purpose, update docs/tcd_config.schema.json, docs/weights.md and "
        "this fixture together"
    )


def test_the_engine_reads_the_golden_config(tmp_path):
    golden = json.loads(GOLDEN.read_text())
    jsonschema.validate(golden, SCHEMA)
    d = tcd.engine.Denoiser.load(write(tmp_path / "golden.safetensors", golden))
    assert d.config == golden
    assert (d.role, d.num_features, d.obs_len, d.pred_len, d.seq_len, d.num_train_timesteps) == (
        "short",
        66,
        50,
        5,
        55,
        50,
    )


def test_engine_requires_what_the_schema_requires_and_defaults_the_rest(tmp_path):
    golden = json.loads(GOLDEN.read_text())
    required = [name for name, _, req in schema_fields() if req]
    assert {"format_version", "model.channels", "window.seq_len", "diffusion.betas"} <= set(required)
    for name in required:
        path = write(tmp_path / f"no_{name}.safetensors", drop(golden, name))
        with pytest.raises(WeightsError) as e:
            tcd.engine.Denoiser.load(path)
        assert name.split(".")[-1] in str(e.value), (name, str(e.value))
    # optional fields: the engine runs with the schema's default
    base = tcd.engine.Denoiser.load(write(tmp_path / "base.safetensors", golden))
    x = base.sample(*_zeros(), 1, seed=0, sampler=SamplerOptions(sampler="ddim", num_inference_steps=2))
    for name, sub, req in schema_fields():
        if req or "default" not in sub or name.count(".") != 1 or name.split(".")[-1] not in golden[name.split(".")[0]]:
            continue
        d = tcd.engine.Denoiser.load(write(tmp_path / f"default_{name}.safetensors", drop(golden, name)))
        assert (
            d.sample(*_zeros(), 1, seed=0, sampler=SamplerOptions(sampler="ddim", num_inference_steps=2)) == x
        ).all(), name


def _zeros():
    import numpy as np

    m = np.zeros((1, 66, 55), np.float32)
    m[:, :, :50] = 1.0
    return np.zeros((1, 66, 55), np.float32), m


def test_the_docs_name_every_field():
    text = (ROOT / "docs" / "weights.md").read_text()
    documented = set(re.findall(r"^\| `([a-z_0-9.]+)` \|", text, flags=re.M))
    leaves = {
        name
        for role in ("short", "prior", "generator")
        for name, sub, _ in schema_fields(role)
        if "properties" not in sub
    }
    assert documented == leaves


# ------------------------------------------------------------------------------- the prior (role "prior")

PRIOR_GOLDEN = FIXTURES / "tcd_config_prior_golden.json"


def prior_golden_config() -> dict:
    """What the exporter writes for a 2-block prior of the default config (without the source revision)."""
    from training.prior_net import build_prior_config, prior_data_meta, random_prior
    from training.prior_net import PriorConfig

    cfg = build_prior_config(random_prior(blocks=2), prior_data_meta(PriorConfig()), {"random_init": True})
    cfg.pop("source_revision")
    return cfg


def write_prior(path: Path, cfg: dict) -> Path:
    """A prior file with a 2-block prior's tensors (tests/fixtures/tiny_prior.safetensors) and ``cfg`` as given."""
    tensors, _ = read_weights(FIXTURES / "tiny_prior.safetensors")
    return write_weights(path, tensors, {CONFIG_KEY: json.dumps(cfg)})


def test_prior_golden_config_is_what_the_exporter_writes():
    import_torch(EXPORTER)
    assert prior_golden_config() == json.loads(PRIOR_GOLDEN.read_text()), (
        "the exporter's prior config changed: if on purpose, update docs/tcd_config.schema.json, docs/weights.md "
        "and this fixture together"
    )


def test_the_engine_reads_the_prior_golden_config(tmp_path):
    golden = json.loads(PRIOR_GOLDEN.read_text())
    jsonschema.validate(golden, SCHEMA)
    assert golden["data"]["training_data"] == "Human3.6M S1,S6,S7,S8,S9,S11 (exp-map, 25 fps)"
    p = tcd.engine.Prior.load(write_prior(tmp_path / "prior.safetensors", golden))
    assert p.config == golden
    assert (p.num_features, p.num_joints, p.obs_len, p.chunk, p.blocks) == (66, 22, 50, 10, 2)


def test_engine_requires_what_the_schema_requires_of_a_prior(tmp_path):
    golden = json.loads(PRIOR_GOLDEN.read_text())
    required = [name for name, _, req in schema_fields("prior") if req]
    assert {"format_version", "role", "model.obs_len", "model.chunk", "model.blocks"} <= set(required)
    assert not any(name.startswith(("window", "diffusion")) for name, _, _ in schema_fields("prior"))
    for name in required:
        path = write_prior(tmp_path / f"no_{name}.safetensors", drop(golden, name))
        with pytest.raises(WeightsError) as e:
            tcd.engine.Prior.load(path)
        assert name.split(".")[-1] in str(e.value), (name, str(e.value))
    # six fields default, and only to what every file before them was: anchor "last" (a forecaster), gap_fill
    # "none" and no in-betweeners (0, 0); the golden file (a forecaster) leaves them out, and a value other than
    # theirs is refused naming it
    defaults = [name for name, sub, req in schema_fields("prior") if not req and "default" in sub]
    assert defaults == [
        "model.anchor",
        "model.gap_fill",
        "model.inbetween_context",
        "model.inbetween_max_gap",
        "model.joint_inbetween_context",
        "model.joint_inbetween_max_gap",
    ]
    assert not {
        "anchor",
        "gap_fill",
        "inbetween_context",
        "inbetween_max_gap",
        "joint_inbetween_context",
        "joint_inbetween_max_gap",
    } & set(golden["model"])
    p = tcd.engine.Prior.load(write_prior(tmp_path / "p.safetensors", golden))
    assert (p.anchor, p.gap_fill) == ("last", "none")
    for field, value in (("anchor", "first"), ("gap_fill", "linear")):
        bad = json.loads(json.dumps(golden))
        bad["model"][field] = value
        with pytest.raises(WeightsError, match=f"model.{field}: unknown variant `{value}`"):
            tcd.engine.Prior.load(write_prior(tmp_path / "bad.safetensors", bad))
    # and gap_fill "forecaster" is a repair fill's only: on a forecaster it is refused naming the field
    bad = json.loads(json.dumps(golden))
    bad["model"]["gap_fill"] = "forecaster"
    with pytest.raises(WeightsError, match="model.gap_fill"):
        tcd.engine.Prior.load(write_prior(tmp_path / "bad.safetensors", bad))
    # and so is an in-betweener (which needs a gap fill)
    bad = json.loads(json.dumps(golden))
    bad["model"].update(inbetween_context=2, inbetween_max_gap=3)
    with pytest.raises(WeightsError, match="model.inbetween_max_gap"):
        tcd.engine.Prior.load(write_prior(tmp_path / "bad.safetensors", bad))


def test_the_schema_tells_the_roles_apart():
    prior = json.loads(PRIOR_GOLDEN.read_text())
    short = json.loads(GOLDEN.read_text())
    generator = generator_config()
    for bad in (
        {**prior, "window": short["window"]},  # a prior has no window
        {**prior, "model": short["model"]},  # nor the denoiser's model fields
        {**short, "role": "prior"},
        {k: v for k, v in short.items() if k != "diffusion"},  # a denoiser needs its diffusion
        {**short, "model": prior["model"]},
        {**generator, "window": short["window"]},  # a generator has no window
        {**generator, "model": prior["model"]},  # nor another kind's model fields
        {**prior, "role": "generator"},
        {**short, "role": "generator"},
        {**generator, "role": "prior"},
    ):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, SCHEMA)


def test_a_file_of_one_kind_does_not_load_as_the_other(tmp_path):
    prior = write_prior(tmp_path / "prior.safetensors", json.loads(PRIOR_GOLDEN.read_text()))
    short = write(tmp_path / "short.safetensors", json.loads(GOLDEN.read_text()))
    generator = write_generator(tmp_path / "generator.safetensors", generator_config())
    with pytest.raises(WeightsError, match="prior forecaster") as e:
        tcd.engine.Denoiser.load(prior)
    assert e.value.path == str(prior)
    with pytest.raises(WeightsError, match="Denoiser") as e:
        tcd.engine.Prior.load(short)
    assert e.value.path == str(short)
    for load in (tcd.engine.Denoiser.load, tcd.engine.Prior.load):
        with pytest.raises(WeightsError, match="sample generator.*`tcd.engine.Generator.load`") as e:
            load(generator)
        assert e.value.path == str(generator)
    for path, kind in ((short, "Denoiser"), (prior, "Prior")):
        with pytest.raises(WeightsError, match=f"`tcd.engine.{kind}.load`"):
            tcd.engine.Generator.load(path)


# ------------------------------------------------------------------------------- the generator (role "generator")


def generator_config() -> dict:
    """A small generator's config with the keys training/generator.py's ``build_generator_config`` writes."""
    data = {"dataset": "humaneva", "fps": 60.0, "units": "m", "root_relative": True, "layout": "humaneva15"}
    return {
        "format_version": 1,
        "role": "generator",
        "model": {
            "num_joints": 2,
            "coords": 3,
            "num_features": 6,
            "obs_len": 5,
            "pred_len": 12,
            "hidden": 8,
            "layers": 2,
            "z_dim": 4,
            "coefs": 3,
        },
        "data": data,
        "training": {"random_init": True},
        "source_revision": "0123abc",
    }


def write_generator(path: Path, cfg: dict) -> Path:
    """A generator file with random tensors of the shapes ``generator_config()``'s sizes imply and ``cfg`` as
    given."""
    m = generator_config()["model"]
    rng = np.random.default_rng(0)
    k, width = m["num_features"], (m["obs_len"] + m["coefs"]) * m["num_features"] + m["z_dim"]
    shapes = {}
    for i in range(m["layers"]):
        shapes[f"layers.{i}.weight"], shapes[f"layers.{i}.bias"] = (m["hidden"], width), (m["hidden"],)
        width = m["hidden"]
    shapes["head.weight"], shapes["head.bias"] = (m["coefs"] * k, m["hidden"]), (m["coefs"] * k,)
    tensors = {name: rng.normal(0, 0.3, shape).astype(np.float32) for name, shape in shapes.items()}
    return write_weights(path, tensors, {CONFIG_KEY: json.dumps(cfg)})


def test_the_generator_exporter_follows_the_schema():
    import_torch(EXPORTER)
    from training.fileformat import humaneva_data_meta
    from training.generator import Generator, build_generator_config

    jsonschema.validate(build_generator_config(Generator(42, 16, 2, 8, 5), humaneva_data_meta(), {"steps": 1}), SCHEMA)


def test_engine_requires_what_the_schema_requires_of_a_generator(tmp_path):
    cfg = generator_config()
    jsonschema.validate(cfg, SCHEMA)
    g = tcd.engine.Generator.load(write_generator(tmp_path / "g.safetensors", cfg))
    assert g.config == cfg
    assert (g.num_features, g.obs_len, g.pred_len, g.hidden, g.layers, g.z_dim, g.coefs) == (6, 5, 12, 8, 2, 4, 3)
    fields = list(schema_fields("generator"))
    assert not any(name.startswith(("window", "diffusion")) for name, _, _ in fields)
    required = [name for name, _, req in fields if req]
    assert set(required) == {"format_version", "role", "model"} | {f"model.{f}" for f in cfg["model"]}
    for name in required:
        with pytest.raises(WeightsError) as e:
            tcd.engine.Generator.load(write_generator(tmp_path / f"no_{name}.safetensors", drop(cfg, name)))
        assert name.split(".")[-1] in str(e.value), (name, str(e.value))
    # a size the schema refuses, and the relations between sizes that it cannot state (coefs <= pred_len,
    # num_features = num_joints x coords): the engine refuses each naming the field
    for field, value, schema_refuses in (("z_dim", 0, True), ("coefs", 13, False), ("num_features", 7, False)):
        bad = copy.deepcopy(cfg)
        bad["model"][field] = value
        if schema_refuses:
            with pytest.raises(jsonschema.ValidationError):
                jsonschema.validate(bad, SCHEMA)
        with pytest.raises(WeightsError, match=f"model.{field}"):
            tcd.engine.Generator.load(write_generator(tmp_path / "bad.safetensors", bad))
