"""The exporter (training/export.py): random-init model directories, checkpoints to weight files, strict
loading, ``--files``; and the committed model fixtures are what it writes (tests/fixtures/README.md)."""

import importlib.util
import json

import pytest

from conftest import FIXTURES, import_torch

torch = import_torch("the exporter (training/export.py)")

from safetensors.torch import load_file, save_file  # noqa: E402

from training import fileformat  # noqa: E402
from training.export import load_model_dir, load_model_file, main, random_init_dir  # noqa: E402
from training.fileformat import CONFIG_KEY, read_config  # noqa: E402
from training.train import train  # noqa: E402
from test_train import synthetic_motion, tiny_cfg  # noqa: E402


def test_random_init_dir_is_complete_and_non_trivial(tmp_path):
    d = random_init_dir(tmp_path / "m", preset="tiny", seed=0)
    models = load_model_dir(d)
    assert set(models) == {"short", "long"}
    for role, (model, _sched, cfg) in models.items():
        assert cfg["role"] == role and cfg["format_version"] == 1
        assert cfg["window"]["seq_len"] == cfg["window"]["obs_len"] + cfg["window"]["pred_len"]
        assert len(cfg["diffusion"]["betas"]) == 50 and cfg["diffusion"]["beta_schedule"] == "cosine"
        assert cfg["model"]["num_features"] == 66 and len(cfg["data"]["joint_names"]) == 22
        assert cfg["data"]["units"] == "m" and cfg["data"]["fps"] == 25.0
        L = cfg["window"]["seq_len"]
        y = model(torch.randn(1, 66, L), torch.randn(1, 66, L), torch.ones(1, 66, L), 3)
        assert y.abs().mean() > 1e-3  # the last conv is not zero
    summary = json.loads((d / "model.json").read_text())
    assert set(summary) == {"short", "long"}
    # seeded: the same seed gives the same bytes
    d2 = random_init_dir(tmp_path / "m2", preset="tiny", seed=0)
    assert (d / "short.safetensors").read_bytes() == (d2 / "short.safetensors").read_bytes()


def test_export_reload_is_bit_exact(tmp_path):
    seqs = {"train": synthetic_motion(4, T=40, seed=0), "val": synthetic_motion(2, T=40, seed=1)}
    cfg = tiny_cfg(epochs=1, steps_per_epoch=3)
    train(cfg, tmp_path / "run", sequences=seqs, log=lambda *a: None)
    assert main(["--checkpoint", str(tmp_path / "run" / "best.pt"), "--out", str(tmp_path / "out")]) == 0
    ck = torch.load(tmp_path / "run" / "best.pt", weights_only=False)
    model, sched, meta = load_model_file(tmp_path / "out" / "short.safetensors")
    for k, v in ck["model"].items():
        assert torch.equal(model.state_dict()[k], v), k
    assert meta["window"] == {"obs_len": 10, "pred_len": 4, "seq_len": 14}
    assert meta["training"]["train_config"]["lr"] == cfg.lr
    assert meta["source_revision"]


def test_strict_loading_rejects_missing_and_extra_tensors(tmp_path):
    d = random_init_dir(tmp_path / "m", preset="tiny")
    path = d / "short.safetensors"
    meta = {CONFIG_KEY: json.dumps(read_config(path))}
    tensors = load_file(str(path))
    missing = dict(tensors)
    missing.pop("embed_layer.weight")
    save_file(missing, str(tmp_path / "missing.safetensors"), metadata=meta)
    with pytest.raises(RuntimeError, match="embed_layer.weight"):
        load_model_file(tmp_path / "missing.safetensors")
    extra = dict(tensors, surplus=torch.zeros(2))
    save_file(extra, str(tmp_path / "extra.safetensors"), metadata=meta)
    with pytest.raises(RuntimeError, match="surplus"):
        load_model_file(tmp_path / "extra.safetensors")
    save_file(tensors, str(tmp_path / "nometa.safetensors"))
    with pytest.raises(ValueError, match=CONFIG_KEY):
        load_model_file(tmp_path / "nometa.safetensors")


def test_cli_requires_one_source(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["--out", str(tmp_path)])
    assert e.value.code == 2 and "give exactly one of --checkpoint, --random-init" in capsys.readouterr().err


def test_files_replace_roles_only_when_they_load(tmp_path):
    """`--files`: how exported weights become the bundled ones; a file that does not load strictly, or
    is not named after a role, replaces nothing."""
    import tcd

    src = random_init_dir(tmp_path / "new", "tiny", seed=4)
    bundle = random_init_dir(tmp_path / "bundle", "tiny", seed=5)
    before = (bundle / "short.safetensors").read_bytes()
    assert main(["--files", str(src / "long.safetensors"), "--out", str(bundle)]) == 0
    assert (bundle / "long.safetensors").read_bytes() == (src / "long.safetensors").read_bytes()
    assert (bundle / "short.safetensors").read_bytes() == before
    tcd.load(bundle)  # checksums and model.json rewritten
    assert json.loads((bundle / "model.json").read_text()).keys() >= {"short", "long"}
    broken = tmp_path / "long.safetensors"
    broken.write_bytes(b"not a model")
    from safetensors import SafetensorError

    with pytest.raises(SafetensorError, match="header"):  # read_config's safe_open, before anything is copied
        main(["--files", str(broken), "--out", str(bundle)])
    assert (bundle / "long.safetensors").read_bytes() == (src / "long.safetensors").read_bytes()
    with pytest.raises(SystemExit, match="file name"):
        main(["--files", str(src / "model.json"), "--out", str(bundle)])


def test_gap_fill_rewrites_the_repair_fill_only(tmp_path):
    """``--gap-fill``: the directory's repair fill gets ``gap_fill`` (its tensors as they were, the change
    recorded in its training block) and loads with the forecaster beside it; ``none`` takes the key out again;
    without ``prior.safetensors`` beside it nothing is replaced."""
    import tcd

    d = random_init_dir(
        tmp_path / "m",
        "tiny",
        seed=2,
        prior_blocks=2,
        repair={"cond_fill": "prior", "target": "prior_residual", "target_scale": 10.0},
    )
    fill = d / "repair_fill.safetensors"
    before, tensors = fill.read_bytes(), load_file(str(fill))
    assert main(["--gap-fill", "forecaster", "--out", str(d)]) == 0
    cfg = read_config(fill)
    assert cfg["model"]["gap_fill"] == "forecaster" and cfg["training"]["gap_fill_set"]["value"] == "forecaster"
    after = load_file(str(fill))
    assert all(torch.equal(after[k], tensors[k]) for k in tensors) and after.keys() == tensors.keys()
    m = tcd.load(d)
    assert m.repair_fill.gap_fill == "forecaster"
    assert json.loads((d / "model.json").read_text())["repair_fill"]["model"]["gap_fill"] == "forecaster"
    assert main(["--gap-fill", "none", "--out", str(d)]) == 0
    assert "gap_fill" not in read_config(fill)["model"] and tcd.load(d).repair_fill.gap_fill == "none"
    (d / "prior.safetensors").unlink()
    now = fill.read_bytes()
    with pytest.raises(ValueError, match="prior.safetensors"):
        main(["--gap-fill", "forecaster", "--out", str(d)])
    assert fill.read_bytes() == now and not (d / "repair_fill.safetensors.tmp").exists()
    assert before != now  # (the training block records the change)


def test_committed_fixtures_are_what_make_fixtures_writes(tmp_path, monkeypatch):
    """``python3 tests/fixtures/make_fixtures.py`` writes the committed model fixtures byte for byte. The one
    thing that differs between commits, the source revision in each file's metadata (and in model.json), is
    pinned to the one the committed files record; everything else (tensors, config, header) must match."""
    spec = importlib.util.spec_from_file_location("make_fixtures", FIXTURES / "make_fixtures.py")
    make_fixtures = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_fixtures)
    recorded = json.loads((FIXTURES / "tiny_model" / "model.json").read_text())["short"]["source_revision"]
    monkeypatch.setattr(fileformat, "source_revision", lambda: recorded)
    out = make_fixtures.write(tmp_path / "fixtures")
    written = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    assert written == sorted(
        str((out / d / n).relative_to(out)) for d, names in make_fixtures.FILES.items() for n in names
    )
    for name in written:
        assert (out / name).read_bytes() == (FIXTURES / name).read_bytes(), (
            f"tests/fixtures/{name} is not what tests/fixtures/make_fixtures.py writes: if the exporter or the "
            "random init changed on purpose, run it and commit the new fixtures"
        )
