"""The benchmark scripts' own logic: benches/steps.py (accuracy pass, latency pass, the two-phase merge with
--accuracy-from) and benches/peers.py's markdown tables. Timing values are never asserted."""

from __future__ import annotations

import importlib.util
import json
import math
import sys

import numpy as np
import pytest

from conftest import H36M_DIR, ROOT, import_torch, needs_data, needs_h36m
from fixtures_util import make_model_dir


def load_bench(name: str):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", ROOT / "benches" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


@needs_h36m
def test_steps_two_phases_merge(tiny_model_dir, tmp_path):
    """--latency-reps 0 writes accuracy only (latency NaN); --accuracy-from copies those rows unchanged and
    adds the latency; a JSON of another model, other samples or missing configurations is refused."""
    import_torch("benches/steps.py (it reads the data through training/evaluate.py)")
    steps = load_bench("steps")
    common = [
        "--model",
        str(tiny_model_dir),
        "--data",
        str(H36M_DIR),
        "--actions",
        "walking",
        "--only",
        "DDIM-5",
        "--windows-per-action",
        "1",
        "--samples",
        "2",
    ]
    acc = tmp_path / "acc.json"
    assert steps.main(common + ["--latency-reps", "0", "--json", str(acc)]) == 0
    a = json.loads(acc.read_text())
    assert [r["name"] for r in a["results"]] == ["DDIM-5 eta=0", "DDIM-5 eta=1"]
    for r in a["results"]:
        assert math.isnan(r["latency_s"]["median"]) and r["latency_s"]["all"] == []
        assert math.isfinite(r["mean_of_n"]["average"]["1000"]) and r["repair"]["occluded_entries"] > 0

    merged = tmp_path / "merged.json"
    assert steps.main(common + ["--latency-reps", "1", "--accuracy-from", str(acc), "--json", str(merged)]) == 0
    m = json.loads(merged.read_text())
    for ra, rm in zip(a["results"], m["results"]):
        assert rm["mean_of_n"] == ra["mean_of_n"] and rm["repair"] == ra["repair"]
        assert rm["latency_s"]["median"] > 0 and len(rm["latency_s"]["all"]) == 1
    assert m["protocol"]["accuracy_from"] == str(acc)
    assert m["protocol"]["windows"] == a["protocol"]["windows"]

    with pytest.raises(SystemExit):  # other --samples than the accuracy run
        steps.main(common[:-1] + ["3", "--latency-reps", "1", "--accuracy-from", str(acc)])
    with pytest.raises(SystemExit):  # a configuration the accuracy run lacks
        steps.main(
            common[:7]
            + [
                "DDPM-10",
                "--windows-per-action",
                "1",
                "--samples",
                "2",
                "--latency-reps",
                "1",
                "--accuracy-from",
                str(acc),
            ]
        )
    other = make_model_dir(tmp_path / "other", preset="tiny", seed=4)
    with pytest.raises(SystemExit):  # another model
        steps.main(["--model", str(other)] + common[2:] + ["--latency-reps", "1", "--accuracy-from", str(acc)])
    with pytest.raises(SystemExit):  # nothing to measure
        steps.main(common + ["--latency-reps", "0", "--accuracy-from", str(acc)])


def test_peers_markdown_tables():
    """The README tables come from a saved result: one column per (L, threads), ratio peer / tcd in brackets,
    the whole-forecast rows and the peak memory line."""
    import_torch("benches/peers.py (PyTorch is one of its peers)")
    peers = load_bench("peers")
    result = {
        "rows": [
            {
                "L": 75,
                "threads": 2,
                "ms": {"tcd": 50.0, "torch": 200.0, "openvino": 100.0},
                "peer_over_tcd": {"torch": 4.0, "openvino": 2.0},
            },
            {
                "L": 55,
                "threads": 2,
                "ms": {"tcd": 40.0, "torch": 120.0, "openvino": 80.0},
                "peer_over_tcd": {"torch": 3.0, "openvino": 2.0},
            },
        ],
        "whole_forecast": {
            "ddpm50_x5": {
                "seconds": 12.5,
                "peak_rss_mib": 61.0,
                "peers_estimated_seconds": {"torch": 80.0, "openvino": 45.0},
            },
            "ddim10_x1": {"seconds": 0.31, "peak_rss_mib": 40.0},
        },
    }
    md = peers.markdown(result)
    lines = md.splitlines()
    assert lines[0] == "| ms per forward | L = 75, 2 thr. | L = 55, 2 thr. |"
    assert "| tcd | 50.0 | 40.0 |" in lines
    assert "| PyTorch eager | 200.0 (4.00×) | 120.0 (3.00×) |" in lines
    assert "| OpenVINO | 100.0 (2.00×) | 80.0 (2.00×) |" in lines
    assert not any(line.startswith("| ONNX Runtime") for line in lines)  # a peer not in the result
    assert "| DDPM-50 × 5 samples, both stages (s) | 12.5 | 45.0 | 80.0 |" in lines
    assert any(line.startswith("| DDIM-10 × 1 sample (s) | 0.31 |") for line in lines)
    assert lines[-1] == "Peak resident memory of a forecast (fresh process): ddpm50_x5 61 MiB, ddim10_x1 40 MiB."


def test_repair_quality_baselines_fill_only_hidden_entries():
    """benches/repair_quality.py's classical peers: linear interpolation is exact on a straight line; the
    spline baseline is the natural cubic spline the bundled repair model is conditioned on (the engine's fill,
    tcd.interpolate, equal to training.model.spline_fill up to float32 rounding); both keep observed entries
    and hold the ends."""
    pytest.importorskip("scipy")
    rq = load_bench("repair_quality")
    t = np.arange(50, dtype=np.float64)
    curve = (1e-5 * (t - 20) ** 3 + 0.002 * t + 0.01 * np.sin(t / 3))[None, :, None, None] * np.ones((1, 50, 2, 3))
    m = np.ones((1, 50, 2), dtype=bool)
    m[0, 10:14, 0] = False  # an interior gap of joint 0
    m[0, [25, 31, 40], 1] = False  # single frames of joint 1
    m[0, 45:, 1] = False  # trailing frames of joint 1: held at the last observed value
    keep = np.repeat(m[..., None], 3, -1)
    x = np.where(keep, curve, np.nan)
    lin, spl = rq.linear_fill(x, m), rq.spline_fill(x, m)
    np.testing.assert_array_equal(spl[keep], curve[keep])
    np.testing.assert_allclose(spl[0, 45:, 1], np.repeat(curve[0, 44:45, 1], 5, 0), rtol=0, atol=1e-8)
    assert np.abs(spl[0, 10:14, 0] - lin[0, 10:14, 0]).max() > 1e-4  # the spline is not the linear fill
    line = 0.01 * t[None, :, None, None] * np.ones((1, 50, 2, 3))
    np.testing.assert_allclose(
        rq.linear_fill(np.where(keep, line, np.nan), m)[0, 10:14, 0], line[0, 10:14, 0], atol=1e-8
    )
    # the training fill, last: it needs torch
    torch = import_torch("the comparison with training.model.spline_fill")
    from training.model import spline_fill

    ref = spline_fill(
        torch.from_numpy(x.transpose(0, 2, 3, 1).copy()),
        torch.from_numpy(keep.transpose(0, 2, 3, 1).astype(np.float64).copy()),
    )
    ref = ref.numpy().transpose(0, 3, 1, 2)
    np.testing.assert_allclose(spl, ref, rtol=0, atol=1e-8)  # values ~0.1: float32 rounding ~1e-8


def test_repair_dataset_occlusion_blocks_cycle_the_patterns():
    """benches/repair_dataset.py hides entries in 50-frame blocks, one benchmark pattern per block in turn
    (seeded), the last block cut to the sequence's length."""
    import numpy as np

    rd = load_bench("repair_dataset")
    m = rd.occlusion_mask(170, 22, np.random.default_rng([0, 0]))
    assert m.shape == (170, 22) and m.dtype == bool and (~m).any() and m.any()
    np.testing.assert_array_equal(m, rd.occlusion_mask(170, 22, np.random.default_rng([0, 0])))
    # block 1 is "consecutive frames (20 %)": 10 frames with every joint hidden, the others fully observed
    hidden_frames = (~m[50:100]).all(axis=1)
    assert hidden_frames.sum() == 10 and m[50:100][~hidden_frames].all()


@needs_h36m
def test_repair_dataset_runs_tcd_repair_on_a_directory(tiny_model_dir, tmp_path):
    """The end-to-end bench writes occluded S5 recordings (mm, 50 fps), runs the `tcd repair` command on the
    directory, checks the observed values came back unchanged and reports ADE against the baselines."""
    rd = load_bench("repair_dataset")
    out = tmp_path / "r.json"
    assert (
        rd.main(
            [
                "--model",
                str(tiny_model_dir),
                "--files",
                "2",
                "--max-frames",
                "120",
                "--steps",
                "2",
                "--samples",
                "1",
                "--data-dir",
                str(H36M_DIR),
                "--work",
                str(tmp_path / "w"),
                "--json",
                str(out),
            ]
        )
        == 0
    )
    r = json.loads(out.read_text())
    assert r["files"] == 2 and r["fps"] == 50 and r["frames"] == 240 and 0 < r["hidden_fraction"] < 1
    assert r["provenance"]["units"] == "mm" and r["provenance"]["fps"] == 50.0 and r["provenance"]["steps"] == 2
    assert all(math.isfinite(v) and v > 0 for v in r["ade_mm"].values())
    assert sorted(p.name for p in (tmp_path / "w" / "out").iterdir()) == sorted(
        p.name for p in (tmp_path / "w" / "in").iterdir()
    )


@needs_h36m
def test_in_the_wild_smoke(tiny_model_dir, tmp_path):
    """benches/in_the_wild.py runs every input path through the public API and writes its table."""
    bench = load_bench("in_the_wild")
    out = tmp_path / "wild.json"
    assert (
        bench.main(
            [
                "--data",
                str(H36M_DIR),
                "--model",
                str(tiny_model_dir),
                "--windows-per-action",
                "1",
                "--steps",
                "1",
                "--noise",
                "25",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    rows = json.loads(out.read_text())["rows"]
    cmu = bench.DEFAULT_CMU.is_file()
    amass = (bench.DEFAULT_AMASS / "smpl_skeleton.npz").is_file()
    # 2 native rows; each wild input (3 of Human3.6M, 2 of CMU, 1 of AMASS) in 4 variants x 3 spaces, clean and noisy
    assert len(rows) == 2 + 2 * (36 + 24 * cmu + 12 * amass)
    assert sum("25 mm noise" in r["input"] for r in rows) == 36 + 24 * cmu + 12 * amass
    assert {r["space"] for r in rows} == {"canonical", "root-relative", "world", "root"}
    assert any(r["input"].startswith("CMU h36m32 world 120fps") for r in rows) == cmu
    assert all(r["tcd_mm"]["1s"] > 0 and r["zero_velocity_mm"]["1s"] > 0 for r in rows)


@pytest.mark.slow
def test_repair_scaling_smoke(tmp_path):
    """benches/repair_scaling.py runs the local and the Ray paths on the same files and reports the overhead."""
    pytest.importorskip("ray")
    bench = load_bench("repair_scaling")
    out = tmp_path / "scaling.json"
    assert bench.main(["--files", "2", "--frames", "60", "--small-files", "2", "--steps", "2", "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert [row["path"] for row in r["rows"]] == [
        "local, --jobs 1",
        "local, --jobs 2",
        "ray, 1 worker(s)",
        "ray, 2 worker(s)",
    ]
    assert all(row["frames_per_s"] > 0 for row in r["rows"]) and "overhead_per_file_ms" in r["small_files"]


def test_root_extrapolation_reads_the_root_at_the_callers_frames(monkeypatch):
    """benches/root_extrapolation.py's root path: a walker at 50 fps (a fixed pose sliding 1 cm a frame) is
    continued at its speed by the constant-velocity rule (without a dead zone; with 0.2 m/s, at 0.3 of its
    0.5 m/s), held by the 0 rule, and in between by a decay, read at every one of the caller's 50 future
    frames."""
    from test_wild import h36m32
    from tcd import wild

    bench = load_bench("root_extrapolation")
    monkeypatch.setattr(wild, "ROOT_DEAD_ZONE_MPS", 0.0)
    pose = h36m32(1)[0]
    t = np.arange(100)[:, None, None]
    x = (pose[None] + t * np.array([0.01, 0.0, 0.0]))[None]  # (1, 100, 32, 3) at 50 fps
    last = x[0, -1, 0]
    ahead = np.arange(1, 51)[:, None] * np.array([0.01, 0.0, 0.0])
    np.testing.assert_allclose(bench.root_forecast(x, "h36m32", 50.0, "y", None)[0], last + ahead, atol=1e-9)
    np.testing.assert_allclose(
        bench.root_forecast(x, "h36m32", 50.0, "y", 0.0)[0], np.repeat(last[None], 50, 0), atol=1e-9
    )
    damped = bench.root_forecast(x, "h36m32", 50.0, "y", 0.4)[0, :, 0] - last[0]
    assert np.all(np.diff(damped) > 0) and 0 < damped[-1] < ahead[-1, 0]
    monkeypatch.setattr(wild, "ROOT_DEAD_ZONE_MPS", 0.2)
    np.testing.assert_allclose(bench.root_forecast(x, "h36m32", 50.0, "y", None)[0], last + 0.6 * ahead, atol=1e-9)
    slow = (pose[None] + t * np.array([0.003, 0.0, 0.0]))[None]  # 0.15 m/s: inside the dead zone
    np.testing.assert_allclose(
        bench.root_forecast(slow, "h36m32", 50.0, "y", None)[0], np.repeat(slow[0, -1, :1], 50, 0), atol=1e-9
    )


def test_prior_speed_smoke(tmp_path):
    """benches/prior_speed.py times tcd.engine.Prior and PyTorch eager on the same model and inputs (outputs compared
    first) for one forecast and a batch, at each thread count, and writes its table and JSON. Timings are not
    asserted."""
    import_torch("benches/prior_speed.py (it times PyTorch beside the engine)")
    import tcd

    bench = load_bench("prior_speed")
    out = tmp_path / "prior_speed.json"
    assert (
        bench.main(
            [
                "--random",
                "--blocks",
                "2",
                "--reps",
                "1",
                "--batch",
                "5",
                "--threads",
                "1",
                "2",
                "--pause",
                "0",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    r = json.loads(out.read_text())
    assert [(row["batch"], row["threads"], row["horizon"]) for row in r["rows"]] == [
        (1, 1, 25),
        (1, 2, 25),
        (5, 1, 25),
        (5, 2, 25),
    ]
    for row in r["rows"]:
        assert row["median_s"]["tcd"] > 0 and row["median_s"]["torch"] > 0 and row["max_abs_diff"] < 1e-4
    assert r["model"] == {"weights": "random, 2 blocks", "blocks": 2, "obs_len": 50, "chunk": 10, "num_features": 66}
    assert r["machine"]["cpu"] and r["machine"]["tcd_kernel"] in tcd.engine.supported_kernels()
    assert r["goals"]["batch_met"] is None  # only a batch of 1,000 is judged
    md = bench.markdown(r)
    assert md.splitlines()[0] == (
        "| median | 1 forecast, 1 thr. | 1 forecast, 2 thr. | batch of 5, 1 thr. | batch of 5, 2 thr. |"
    )
    assert md.splitlines()[2].startswith("| tcd (Rust) | ") and "×) |" in md.splitlines()[3]


@needs_data("humaneva/humaneva_i_15j_60hz.npz")
def test_train_speed_smoke(tmp_path):
    """benches/train_speed.py times the real training step of a config (here HumanEva-I's long model around its
    bundled prior) and writes one row per cell; the speed itself is never asserted."""
    import_torch("benches/train_speed.py (it times the PyTorch training step)")
    bench = load_bench("train_speed")
    prior = ROOT / "python" / "tcd" / "weights_humaneva" / "prior.safetensors"
    if not prior.is_file():
        pytest.skip("no bundled HumanEva-I prior in this build")
    out = tmp_path / "speed.json"
    assert (
        bench.main(
            [
                "--config",
                str(ROOT / "training/configs/humaneva_long_2.json"),
                "--prior",
                str(prior),
                "--batch",
                "2",
                "--variants",
                "eager",
                "--seconds",
                "0.5",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    d = json.loads(out.read_text())
    assert [(r["batch"], r["variant"], r["threads"]) for r in d["rows"]] == [(2, "eager", 1)]
    assert d["rows"][0]["windows_per_s"] > 0 and len(d["rows"][0]["blocks"]) == 5


def test_repair_gap_lengths_hides_n_whole_frames_per_window():
    """benches/repair_gap_lengths.py: each window hides every joint of exactly n consecutive frames, inside the
    window, starts seeded by (seed, n)."""
    gl = load_bench("repair_gap_lengths")
    for n in (1, 10, 49):
        m = gl.gap_masks(64, 50, n, 0)
        hidden = ~m.any(2)
        assert (hidden.sum(1) == n).all() and ((~m).sum((1, 2)) == 22 * n).all()
        runs = np.diff(np.concatenate([np.zeros((64, 1)), hidden, np.zeros((64, 1))], 1).astype(int), axis=1)
        assert ((runs == 1).sum(1) == 1).all()  # one run each
        assert np.array_equal(m, gl.gap_masks(64, 50, n, 0)) and not np.array_equal(m, gl.gap_masks(64, 50, n, 1))


def test_repair_gap_refiner_starts_as_the_fill_and_moves_hidden_frames_only():
    """benches/repair_gap_refiner.py: the untrained refiner returns the fill bit for bit; once its output layer is
    non-zero it changes the hidden frames and no seen one."""
    torch = import_torch("benches/repair_gap_refiner.py (a PyTorch network)")
    gr = load_bench("repair_gap_refiner")
    torch.manual_seed(0)
    net = gr.refiner(8, 2)
    fill = torch.randn(3, 50, 66)
    seen = torch.ones(3, 50, dtype=torch.bool)
    seen[:, 10:20] = False
    assert torch.equal(net(fill, seen), fill)
    torch.nn.init.normal_(net.out.weight)
    out = net(fill, seen)
    assert torch.equal(out[seen], fill[seen]) and not torch.equal(out[~seen], fill[~seen])


def test_generator_imle_starts_as_the_prior_and_pulls_each_target_s_nearest_draw():
    """training/generator_imle.py: the untrained generator is the prior's forecast whatever the noise, and the
    IMLE loss is the mean over targets of the distance to the nearest of the draws (the same seeded draws,
    searched by brute force here), or, given a rival's distances, of the nearer of the two."""
    torch = import_torch("training/generator_imle.py")
    import training.generator_imle as bench

    gen = bench.Generator(coords=6, hidden=16, layers=2, z_dim=4, coefs=5)
    g = torch.Generator().manual_seed(0)
    obs, prior = torch.randn(3, 15, 6, generator=g), torch.randn(3, 60, 6, generator=g)
    out = gen(obs, prior, torch.randn(3, 7, 4, generator=g))
    assert out.shape == (3, 7, 60, 6)
    torch.testing.assert_close(out, prior[:, None].expand(-1, 7, -1, -1), rtol=0, atol=0)
    torch.nn.init.normal_(gen.head.weight, std=0.5)  # now the draws differ
    targets = torch.randn(3, 2, 60, 6, generator=g)
    torch.manual_seed(5)
    loss = bench.imle_loss(gen, obs, prior, targets, cands=9, fde_weight=2.0)
    torch.manual_seed(5)
    draws = gen(obs, prior, torch.randn(3, 9, 4))  # (3, 9, 60, 6)
    err = torch.linalg.vector_norm(draws[:, :, None] - targets[:, None], dim=-1)  # (3, 9, 2, 60)
    nearest = (err.mean(-1) + 2.0 * err[..., -1]).min(dim=1).values  # (3, 2)
    torch.testing.assert_close(loss, nearest.mean())
    assert nearest.std() > 0 and loss > 0
    # with a rival generator's distances, each target counts the nearer of its draw and the rival
    rival = nearest * torch.tensor([[0.5, 2.0], [2.0, 0.5], [0.5, 0.5]])
    torch.manual_seed(5)
    mixed = bench.imle_loss(gen, obs, prior, targets, cands=9, fde_weight=2.0, rival=rival)
    torch.testing.assert_close(mixed, torch.minimum(nearest, rival).mean())
    assert mixed < loss


def test_repair_inbetween_features_are_aligned_on_the_gap():
    """benches/repair_inbetween.py: the segment starts ``context`` frames before the gap (its indices clamped at
    the window's edges), is relative to the frame before the gap, and says how much context each side has; a
    window without a whole-frame gap is refused. A segment off by a frame, or not clamped, would differ."""
    ib = load_bench("repair_inbetween")
    t, c = 50, 3
    fill = np.broadcast_to(np.arange(t, dtype=np.float64)[None, :, None], (2, t, 2)).copy()  # frame index
    starts = np.array([20, 0])
    x = ib.features(fill, starts, c)
    seg = x[:, :-2].reshape(2, 2 * c + ib.GAP, 2)[..., 0]
    np.testing.assert_array_equal(seg[0], np.arange(20 - c, 20 + ib.GAP + c) - 19)
    np.testing.assert_array_equal(seg[1], np.clip(np.arange(-c, ib.GAP + c), 0, None))  # frame 0 repeated
    np.testing.assert_array_equal(x[:, -2:], [[1.0, 1.0], [0.0, 1.0]])
    mask = np.ones((2, t, 4), bool)
    mask[0, 5:15] = False
    mask[1, 40:] = False
    np.testing.assert_array_equal(ib.gap_starts(mask), [5, 40])
    mask[1] = True
    with pytest.raises(ValueError, match="whole-frame gap"):
        ib.gap_starts(mask)


@needs_h36m
def test_repair_inbetween_with_an_infinite_penalty_is_the_fill(tmp_path):
    """A ridge map with an overwhelming penalty corrects nothing: its row equals the fill's window by window, and
    the file pairs in training.compare; a small penalty moves the fill (the map is applied on the gap)."""
    ib = load_bench("repair_inbetween")
    out = tmp_path / "ib.json"
    assert ib.main(["--train", "40", "--lambdas", "1e12", "1e-3", "--data-dir", str(H36M_DIR), "--json", str(out)]) == 0
    res = json.loads(out.read_text())["results"][0]
    np.testing.assert_allclose(res["ridge_1e+12"]["per_window_mm"], res["fill"]["per_window_mm"], atol=1e-6)
    assert not np.allclose(res["ridge_0.001"]["per_window_mm"], res["fill"]["per_window_mm"], atol=1e-3)
    from training.compare import compare

    r = compare(
        json.loads(out.read_text()),
        json.loads(out.read_text()),
        key="consecutive_frames:ridge_1e+12",
        old_key="consecutive_frames:fill",
    )
    assert r["windows"] == 256 and abs(r["mean_difference"]) < 1e-6
    # the kernel shared by every coordinate: the same limit
    assert (
        ib.main(["--train", "40", "--shared", "--lambdas", "1e12", "--data-dir", str(H36M_DIR), "--json", str(out)])
        == 0
    )
    res = json.loads(out.read_text())["results"][0]
    np.testing.assert_allclose(res["shared_1e+12"]["per_window_mm"], res["fill"]["per_window_mm"], atol=1e-6)


def test_repair_inbetween_shared_rows_are_one_coordinate_each():
    """``--shared``'s rows: row (window b, coordinate f) holds that coordinate's segment, then the two context
    fractions, then the segment times each; the normal equations accumulated in chunks equal the whole ones."""
    ib = load_bench("repair_inbetween")
    c, f, seg = 2, 3, 2 * 2 + ib.GAP
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(size=(5, seg * f)), rng.uniform(size=(5, 2))], 1)
    rows = ib.per_coordinate(x, c)
    assert rows.shape == (5 * f, 3 * seg + 2)
    b, k = 3, 1
    segment = x[b, :-2].reshape(seg, f)[:, k]
    np.testing.assert_array_equal(
        rows[b * f + k], np.concatenate([segment, x[b, -2:], segment * x[b, -2], segment * x[b, -1]])
    )
    y = rng.normal(size=(5, ib.GAP * f))
    xtx, xty = ib.normal_equations(x, y, c, True, chunk=2)
    t = y.reshape(5, ib.GAP, f).transpose(0, 2, 1).reshape(-1, ib.GAP)
    np.testing.assert_allclose(xtx, rows.T @ rows)
    np.testing.assert_allclose(xty, rows.T @ t)
