"""The generators of ``benches/report.py``: one function ``name(src: Sources) -> str`` for each kind of generated
block, and ``GENERATORS``, the block names they serve (one line each)."""

from __future__ import annotations

import glob
import json
import math
from pathlib import Path
from typing import Callable

from .report_wild import wild_layouts
from .report_sources import (
    H36M_DIR,
    HORIZONS,
    BUNDLED_DIRS,
    HUMANEVA_DIR,
    NONE,
    count,
    divide,
    hours,
    metres,
    mm,
    ms,
    paper_table,
    ratio,
    ReportError,
    rows_by_key,
    secs,
    Sources,
    table,
)


# ------------------------------------------------------------------------------------------ generators
# Each returns the Markdown of one block from the results files it names. Labels say what a row is; the numbers
# come from the files.

PATTERN_LABELS = {
    "random_leg_arm": "random leg + arm",
    "structured_leg": "right leg, consecutive frames",
    "consecutive_frames": "consecutive frames",
    "noisy_25": "noise (25 mm) + leg joints hidden",
}


def _horizon_rows(rows: list[tuple[str, dict, float | None]]) -> list[list[str]]:
    """(label, {horizon: mm}, the Zero-Velocity at 1 s to divide by) -> table rows, with the ratio at 1 s."""
    return [[label] + [mm(v.get(h)) for h in HORIZONS] + [ratio(divide(v.get("1000"), zv))] for label, v, zv in rows]


def h36m_forecast(src: Sources) -> str:
    """Human3.6M Setting-B, clean input: the bundled models beside Zero-Velocity and the published methods."""
    d = paper_table(src, "paper_table1.json")
    ours, pub = rows_by_key(d), rows_by_key(d, "paper_rows")
    zv = ours["zero_velocity"]["values"]["1000"]
    pzv = pub["Zero-Velocity"]["values"]["1000"]
    p = d["protocol"]["ours"]
    rows = [
        ("**tcd `forecast`: the mean of 5 samples** (what it returns)", ours["mean_of_5"]["values"], zv),
        ("tcd `forecast`: the oracle best of 5 (the paper's figure)", ours["best_of_5"]["values"], zv),
        ("tcd `predict`: the prior's point forecast", ours["prior"]["values"], zv),
        ("Zero-Velocity, same windows", ours["zero_velocity"]["values"], zv),
    ]
    names = {"TCD (best of 5)": "TCD, oracle best of 5"}
    for k, r in pub.items():
        if k != "Zero-Velocity":
            rows.append((f"{names.get(k, k)} (published)", r["values"], pzv))
    rows.append(("Zero-Velocity (published)", pub["Zero-Velocity"]["values"], pzv))
    caption = (
        f"**Human3.6M, clean input** (Setting-B, the paper's Table 1): mm at each horizon (ms); S5, "
        f"{len(p['actions'])} actions × {p['windows_per_action']} windows, the bundled models with their "
        f"default sampler; published numbers are on all 15 actions. "
        f"÷ ZV: the error at 1 s over Zero-Velocity's on the same windows (published rows: over the "
        f"published Zero-Velocity)."
    )
    return caption + "\n\n" + table(["mm"] + list(HORIZONS) + ["÷ ZV"], _horizon_rows(rows))


def h36m_imperfect(src: Sources) -> str:
    """Human3.6M Setting-B under imperfect observations (the TCD rows of the paper's Table 2)."""
    d = paper_table(src, "paper_table2.json")
    ours, pub = rows_by_key(d), rows_by_key(d, "paper_rows")
    rows = []
    for p in d["protocol"]["patterns"]:
        zv = ours[f"zero_velocity/{p}"]["values"]["1000"]
        label = PATTERN_LABELS.get(p, p)
        rows += [
            (f"{label}: tcd, oracle best of 5", ours[f"best_of_5/{p}"]["values"], zv),
            (f"{label}: tcd, mean of 5", ours[f"mean_of_5/{p}"]["values"], zv),
            (f"{label}: Zero-Velocity", ours[f"zero_velocity/{p}"]["values"], zv),
        ]
    pzv = pub["Zero-Velocity"]["values"]["1000"]
    for k, r in pub.items():
        rows.append((f"{k} (published, imperfect input)", r["values"], pzv))
    p = d["protocol"]["ours"]
    caption = (
        f"**Human3.6M, imperfect observations** (the TCD rows of the paper's Table 2): mm at each horizon "
        f"(ms); S5, {len(p['actions'])} actions × {p['windows_per_action']} windows, each observation "
        f"corrupted (`training.masks`: {', '.join(d['protocol']['patterns'])}); "
        f"Zero-Velocity holds each joint where it was last seen. The paper does not say which corruption its "
        f"rows are on: its Zero-Velocity row shows a harsher one than ours."
    )
    return caption + "\n\n" + table(["mm"] + list(HORIZONS) + ["÷ ZV"], _horizon_rows(rows))


STOCHASTIC_COLS = ("ADE", "FDE", "MMADE", "MMFDE", "APD")
STOCHASTIC_CAPTION = (
    "ADE / FDE: the best sample's mean / final error; MMADE / MMFDE: the same against the multimodal futures; "
    "APD: the samples' diversity (higher is more diverse); mean ADE: the ADE of the samples' mean (a point forecast)."
)


def _half(src: Sources, key: str) -> tuple[dict, dict]:
    """One half of ``paper_table3.json`` (``"h36m-a"`` or ``"humaneva"``) and the whole file (its runs)."""
    d = paper_table(src, "paper_table3.json")
    return d["halves"][key], d


def _protocol_line(half: dict, d: dict, run: str) -> str:
    p = half["protocol"]["ours"]
    return (
        f"`{p['split']}`, {count(p['windows'])} windows, {p['t_his']} observed → {p['t_pred']} forecast frames at "
        f"{p['fps']:g} Hz, {d['runs'][run]['sampling']['samples']} samples per window"
    )


def _stochastic_rows(half: dict, labels: list[tuple[str, str]]) -> list[list[str]]:
    """Our rows by label, then the published ones, each in the stochastic columns and the mean ADE."""
    ours, pub = rows_by_key(half), rows_by_key(half, "paper_rows")
    cols = STOCHASTIC_COLS + ("mean_ADE",)
    rows = [[label] + [metres(ours[k]["values"].get(c)) for c in cols] for k, label in labels]
    return rows + [[f"{k} (published)"] + [metres(r["values"].get(c)) for c in cols] for k, r in pub.items()]


BASELINE_LABELS = [
    ("prior", "tcd `predict`: the prior's point forecast"),
    ("neighbours", "the nearest training futures, joined (learns nothing)"),
    ("zero_velocity", "Zero-Velocity"),
]


def _stochastic_block(src: Sources, key: str, run: str, title: str, labels: list, what: str = "") -> str:
    """One half of Table 3 as a captioned table: our rows by label, the baselines, the published."""
    half, d = _half(src, key)
    caption = f"**{title}, stochastic** (the paper's Table 3): metres; {_protocol_line(half, d, run)}{what}. "
    rows = _stochastic_rows(half, labels + BASELINE_LABELS)
    return caption + STOCHASTIC_CAPTION + "\n\n" + table(["m"] + list(STOCHASTIC_COLS) + ["mean ADE"], rows)


def setting_a_forecast(src: Sources) -> str:
    """Human3.6M Setting-A, stochastic: the bundled generator directory and the baselines beside the published."""
    labels = [("tcd", '**tcd `forecast`** (`tcd.load("h36m-stochastic")`: the generator around the prior)')]
    return _stochastic_block(src, "h36m-a", "setting_a", "Human3.6M Setting-A", labels, ", 16 joints")


def humaneva_forecast(src: Sources) -> str:
    """HumanEva-I, stochastic: the bundled mixture, its halves and the baselines beside the published numbers."""
    labels = [
        ("tcd", "**tcd `forecast`: the mixture** (its default)"),
        ("cascade", "its diffusion cascade alone (`mode=tcd.Cascade()`)"),
        ("generator", "its MLP generator alone (`mode=tcd.Mixture(1)`)"),
    ]
    return _stochastic_block(src, "humaneva", "mixture", "HumanEva-I", labels)


def stochastic_summary(src: Sources) -> str:
    """Both halves of Table 3 side by side: each bundled model's default, the paper's TCD and the best published
    number of each column (training.metrics), Zero-Velocity."""
    halves = {k: _half(src, k)[0] for k in ("h36m-a", "humaneva")}
    head = ["m"] + [f"{c} {tag}" for tag in ("H36M", "HE") for c in STOCHASTIC_COLS]

    def cells(rows: dict, key: str) -> list[str]:
        return [metres(rows.get(key, {}).get("values", {}).get(c)) for c in STOCHASTIC_COLS]

    def best(half: dict) -> list[str]:
        pub = rows_by_key(half, "paper_rows").values()
        out = []
        for c in STOCHASTIC_COLS:
            vals = [r["values"][c] for r in pub if c in r["values"]]
            out.append(metres(min(vals)) if vals and c != "APD" else NONE)  # more spread is not better by itself
        return out

    ours = {k: rows_by_key(h) for k, h in halves.items()}
    pub = {k: rows_by_key(h, "paper_rows") for k, h in halves.items()}
    rows = [
        ["**tcd `forecast`**, the bundled model's default"]
        + cells(ours["h36m-a"], "tcd")
        + cells(ours["humaneva"], "tcd"),
        ["TCD (published)"] + cells(pub["h36m-a"], "TCD") + cells(pub["humaneva"], "TCD"),
        ["the best published, per column"] + best(halves["h36m-a"]) + best(halves["humaneva"]),
        ["Zero-Velocity"] + cells(ours["h36m-a"], "zero_velocity") + cells(ours["humaneva"], "zero_velocity"),
    ]
    caption = (
        "**Stochastic forecasting** (the paper's Table 3, `python -m benches.paper table3`): metres, 50 samples; "
        'Human3.6M Setting-A (`tcd.load("h36m-stochastic")`, 25 → 100 frames at 50 Hz, S9 and S11) and '
        'HumanEva-I (`tcd.load("humaneva")`, 15 → 60 frames at 60 Hz). ADE / FDE: the best sample\'s; MMADE / '
        "MMFDE: against the multimodal futures; APD: the samples' diversity (no best: more is not better by "
        "itself). The best published of MotionDiff, HumanMAC, SkeletonDiffusion, KHMP and TCD: MODEL_CARD.md."
    )
    return caption + "\n\n" + table(head, rows)


def humaneva_per_action(src: Sources) -> str:
    """The bundled HumanEva-I mixture per action (its windows' means)."""
    half, _ = _half(src, "humaneva")
    per = half["per_action"]["tcd"]
    rows = [[a, count(v["windows"])] + [metres(v[c]) for c in STOCHASTIC_COLS] for a, v in per.items()]
    return (
        "**HumanEva-I, per action**: the bundled mixture, the means over each action's windows (metres).\n\n"
        + table(["action", "windows"] + list(STOCHASTIC_COLS), rows)
    )


def _repair_rows(src: Sources) -> tuple[dict, dict]:
    fill = src.json("repair_quality_joint_inbetween_256.json")
    diff = src.json("repair_quality_joint_inbetween_256_ddpm10.json")
    for name, d in (
        ("repair_quality_joint_inbetween_256.json", fill),
        ("repair_quality_joint_inbetween_256_ddpm10.json", diff),
    ):
        src.bundled(name, d.get("model_sha256"), H36M_DIR)
    return fill, diff


def h36m_repair(src: Sources) -> str:
    """Repair of occluded Human3.6M windows against interpolation (benches/repair_quality.py)."""
    fill, diff = _repair_rows(src)
    if [r["pattern"] for r in fill["results"]] != [r["pattern"] for r in diff["results"]]:
        raise ReportError("repair_quality_joint_inbetween_256.json and its _ddpm10 run score other patterns")
    rows = []
    for a, b in zip(fill["results"], diff["results"]):
        rows.append(
            [
                a["pattern"],
                f"**{mm(a['tcd']['ade_mm'])}**",
                mm(b["tcd"]["ade_mm"]),
                mm(a["linear"]["ade_mm"]),
                mm(a["spline"]["ade_mm"]),
                ratio(a["tcd_over_linear"]),
                ratio(a["tcd_over_spline"]),
            ]
        )
    caption = (
        f"**Human3.6M, repair** against interpolation (`benches/repair_quality.py`): mm, the mean error over "
        f"the hidden entries; S5, {count(fill['windows'])} windows of "
        f"{fill['window_frames']} frames per pattern, the bundled model. tcd `repair` by default returns its "
        f"repair fill (deterministic); `num_samples={diff['samples']}` averages that many diffusion samples "
        f"({diff['sampler'].upper()}-{diff['steps']}) around it."
    )
    return (
        caption
        + "\n\n"
        + table(
            [
                "hidden",
                "**tcd `repair`** (default)",
                f"tcd, mean of {diff['samples']} samples",
                "linear interpolation",
                "natural cubic spline",
                "÷ linear",
                "÷ spline",
            ],
            rows,
        )
    )


def repair_dataset(src: Sources) -> str:
    """`tcd repair` on whole recordings (benches/repair_dataset.py): throughput and error."""
    runs = [("repair_dataset_fill_alone.json", "the default (the repair fill)"), ("repair_dataset_ddpm10x5.json", None)]
    rows, first = [], None
    for name, label in runs:
        d = src.json(name)
        pv = d["provenance"]
        src.bundled(name, pv.get("model_sha256"), H36M_DIR)
        first = first or d
        label = label or f"`--samples {pv['num_samples']} --steps {pv['steps']}`"
        rows.append(
            [
                label,
                count(d["frames_per_second"]),
                mm(d["ade_mm"]["tcd"]),
                mm(d["ade_mm"]["linear"]),
                mm(d["ade_mm"]["spline"]),
            ]
        )
    caption = (
        f"**Whole recordings** (`benches/repair_dataset.py`): `tcd repair` on {first['files']} occluded "
        f"recordings ({count(first['frames'])} frames at "
        f"{first['fps']} fps, {round(100 * first['hidden_fraction'])} % of the entries hidden) on "
        f"{first['cores']} cores; ADE in mm over the hidden entries."
    )
    return caption + "\n\n" + table(["`tcd repair`", "frames / s", "ADE tcd", "linear", "spline"], rows)


PEERS = {"tcd": "tcd", "torch": "PyTorch eager", "ort": "ONNX Runtime", "openvino": "OpenVINO"}


def speed_peers(src: Sources) -> str:
    """One full-size denoiser forward: tcd against PyTorch, ONNX Runtime and OpenVINO (benches/peers.py)."""
    d = src.json("peers.json")
    rows = d["rows"]
    body = []
    for p, name in PEERS.items():
        cells = []
        for r in rows:
            v = r["ms"].get(p)
            x = r.get("peer_over_tcd", {}).get(p)
            cells.append(NONE if v is None else f"{v:.1f}" + ("" if x is None else f" ({ratio(x)} ×)"))
        body.append([name] + cells)
    v = d["versions"]
    caption = (
        f"**Speed against peers** (`benches/peers.py`): ms per forward of the paper's full-size denoiser "
        f"(random weights, {rows[0]['K']} features), "
        f"median of {rows[0]['reps']} interleaved runs on a {v['cores']}-core {v['cpu']} CPU "
        f"({', '.join(v.get('cpu_simd_flags', []))}); in brackets, the peer's time over tcd's. Every peer's "
        f"output is checked against PyTorch's."
    )
    return caption + "\n\n" + table(["ms per forward"] + [f"{r['L']} frames, {r['threads']} thr." for r in rows], body)


def speed_whole(src: Sources) -> str:
    """A whole forecast of the paper's full-size model through tcd (benches/peers.py --whole-forecast)."""
    wf = src.json("whole_forecast_tcd.json")["whole_forecast"]
    return table(
        ["a whole full-size forecast, tcd", "seconds", "peak memory"],
        [
            [
                "DDPM-50 × 5 samples (the paper's sampler)",
                secs(wf["ddpm50_x5"]["seconds"]),
                f"{wf['ddpm50_x5']['peak_rss_mib']:.0f} MiB",
            ],
            ["DDIM-10 × 1 sample", secs(wf["ddim10_x1"]["seconds"]), f"{wf['ddim10_x1']['peak_rss_mib']:.0f} MiB"],
        ],
    )


def speed_bundled(src: Sources) -> str:
    """What the bundled models cost per call (benches/steps.py, benches/prior_speed.py, benches/repair_dataset.py)."""
    st = src.json("steps_ddim1_centred.json")
    src.bundled("steps_ddim1_centred.json", st["protocol"].get("model_sha256"), H36M_DIR)
    sampling = src.repo_json(f"{H36M_DIR}/sampling.json")["forecast"]
    default = [
        r
        for r in st["results"]
        if r["sampler"] == sampling["sampler"]
        and r["steps"] == sampling["num_inference_steps"]
        and r.get("noise_coupling") == sampling.get("noise_coupling")
    ]
    if not default:
        raise ReportError(
            f"results file {src.results / 'steps_ddim1_centred.json'} has no run of the bundled "
            f"default sampler {sampling}"
        )
    r = default[0]
    ps = src.json("prior_speed.json")
    one = next(x for x in ps["rows"] if x["batch"] == 1 and x["threads"] == 1)
    big = next(x for x in ps["rows"] if x["batch"] == 1000 and x["threads"] == 1)
    rd = src.json("repair_dataset_fill_alone.json")
    src.bundled("repair_dataset_fill_alone.json", rd["provenance"].get("model_sha256"), H36M_DIR)
    rows = [
        [
            f"`forecast`, {st['protocol']['samples']} samples, the default sampler "
            f"({r['sampler'].upper()}-{r['steps']})",
            secs(r["latency_s"]["median"]),
            NONE,
            f"{st['protocol']['cpu_count']} cores",
        ],
        ["`predict`, one window", ms(one["median_s"]["tcd"]), ms(one["median_s"]["torch"]), "1 thread"],
        [
            f"`predict`, {count(big['batch'])} windows",
            secs(big["median_s"]["tcd"]),
            secs(big["median_s"]["torch"]),
            "1 thread",
        ],
        ["`tcd repair`, the default", f"{count(rd['frames_per_second'])} frames / s", NONE, f"{rd['cores']} cores"],
    ]
    return (
        "**What a call costs** (`benches/steps.py`, `benches/prior_speed.py`, `benches/repair_dataset.py`):\n\n"
        + table(["the bundled Human3.6M model", "tcd", "PyTorch eager", "on"], rows)
    )


def _params(header: dict, prefix: str | None = None) -> int:
    return sum(math.prod(v["shape"]) for k, v in header.items() if prefix is None or k.startswith(prefix))


def _network(cfg: dict) -> str:
    m, role = cfg.get("model", {}), cfg.get("role")
    if role in ("short", "long", "repair"):
        pred = "x0" if cfg.get("diffusion", {}).get("prediction_type") == "sample" else "ε"
        return (
            f"transformer denoiser, {m['num_layers']} layers × {m['channels']} channels, {m['num_heads']} heads; "
            f"{cfg['diffusion']['num_train_timesteps']} diffusion steps, {pred}-prediction"
        )
    if role == "generator":
        return f"MLP, {m['layers']} layers × {m['hidden']}, latent {m['z_dim']}"
    return f"MLP (siMLPe-class), {m['blocks']} blocks"


def _predicts(cfg: dict) -> str:
    m, role, w = cfg.get("model", {}), cfg.get("role"), cfg.get("window", {})
    if role == "short":
        return f"{w['obs_len']} frames → the next {w['pred_len']}"
    if role == "long":
        return f"{w['obs_len']} frames → the next {w['pred_len']}"
    if role == "repair":
        return f"the missing entries of {w['seq_len']} frames"
    if role == "generator":
        return f"{m['obs_len']} frames → {m['pred_len']} (one sample per noise draw)"
    if m.get("anchor") == "window":
        return f"the missing entries of {m['obs_len']} frames (the repair fill)"
    return f"{m['obs_len']} frames → {m['chunk']} (rolled out to the horizon; a point forecast)"


def model_details(src: Sources) -> str:
    """Each bundled weight file: its network, its size (parameters, from the safetensors) and what it predicts."""
    rows = []
    for d in BUNDLED_DIRS:
        names = list(src.repo_json(f"{d}/model.json"))
        total = 0
        for role in names:
            f = f"{d}/{role}.safetensors"
            header, cfg = src.safetensors(f)
            n = _params(header)
            extra = ""
            kernels = _params(header, "inbetween_") + _params(header, "joint_inbetween_")
            if kernels:
                extra = f" (of which {count(kernels)} in the in-betweeners' kernels)"
            total += n
            rows.append([f"`{f.removeprefix('python/tcd/')}`", _network(cfg), count(n) + extra, _predicts(cfg)])
        rows.append([f"`{d.removeprefix('python/tcd/')}/` in all", "", f"**{count(total)}**", ""])
    return "Files under `python/tcd/`; parameters counted from their safetensors headers.\n\n" + table(
        ["file", "network", "parameters", "predicts"], rows
    )


def training_data(src: Sources) -> str:
    """What each bundled directory was trained on and the licence its weights inherit (their metadata)."""
    rows = []
    for d in BUNDLED_DIRS:
        seen: dict[tuple, list] = {}
        for role in src.repo_json(f"{d}/model.json"):
            _, cfg = src.safetensors(f"{d}/{role}.safetensors")
            data = cfg.get("data", {})
            seen.setdefault((data.get("training_data"), data.get("licence")), []).append(role)
        for (what, licence), roles in seen.items():
            rows.append([f"`{d.removeprefix('python/tcd/')}/`: {', '.join(roles)}", what or NONE, licence or NONE])
    return table(["weights", "trained on", "licence (inherited from the data)"], rows)


def convention(src: Sources) -> str:
    """The input / output convention of each bundled directory (its model.json)."""
    rows = []
    for d in BUNDLED_DIRS:
        m = src.repo_json(f"{d}/model.json")
        data = m["prior"]["data"]
        if "short" in m:
            frames = m["short"]["window"]["obs_len"], m["long"]["window"]["seq_len"] - m["short"]["window"]["obs_len"]
        else:  # a generator directory: the generator's window
            frames = m["generator"]["model"]["obs_len"], m["generator"]["model"]["pred_len"]
        rows.append(
            [
                f"`{d.removeprefix('python/tcd/')}`",
                f"{len(data['joint_names'])}: " + ", ".join(data["joint_names"]),
                f"{data['fps']:g} fps",
                data["units"],
                "yes" if data.get("root_relative") else "no",
                f"+{data.get('up', 'y')}",
                f"{frames[0]} → {frames[1]}",
            ]
        )
    return table(
        ["model", "joints, in order", "rate", "units", "root-relative", "up", "frames observed → forecast"], rows
    )


def recipes_cost(src: Sources) -> str:
    """Every recipe (training/recipes/NAME.json): the files it produces, what a run from scratch costs by its stages'
    recorded times (and GPU time, where a stage ran on one), and, where ``python -m training.recipe NAME`` has run to
    its end (benches/results/recipes/NAME.json), that run's measured CPU-hours and its paired comparison with the
    bundled file."""
    runs = dict(src.glob("recipes/*.json"))
    rows = []
    for path in sorted(glob.glob(str(src.root / "training" / "recipes" / "*.json"))):
        r = json.loads(Path(path).read_text())
        src.read.append(path)
        name, cost = r["name"], r.get("cost", {})
        run = runs.get(name)
        if run is None:
            measured, verdict = NONE, "not run from scratch yet"
        else:
            measured = hours(run.get("cpu_hours"))
            verdicts = sorted(
                {
                    "; ".join(f"{k}: {_verdict(v)}" for k, v in c.get("keys", {}).items())
                    for c in run.get("comparisons", [])
                }
            )
            verdict = "; ".join(verdicts) or NONE
        rows.append(
            [
                f"[{name}](training/recipes/{name}.json)",
                ", ".join(f"`{f}`" for f in r["produces"]),
                hours(cost.get("cpu_hours")),
                "yes" if cost.get("gpu") else "",
                measured,
                verdict,
            ]
        )
    return table(
        [
            "recipe",
            "produces",
            "CPU-hours from scratch",
            "a GPU stage",
            "reproduced here (CPU-hours)",
            "reproduction against the bundled (paired)",
        ],
        rows,
    )


def _verdict(key: dict) -> str:
    """training.compare's verdict from the last lines of its report, as the runner keeps them."""
    for line in key.get("report", []):
        if '"verdict"' in line:
            return line.split(":", 1)[1].strip().strip('",')
    return "failed"


def _sampler(s: dict) -> str:
    text = f"{s['sampler'].upper()}, {count(s['num_inference_steps'])} step" + (
        "s" if s["num_inference_steps"] != 1 else ""
    )
    if s.get("noise_coupling") == "centered":
        text += ", from centred noise"
    return text


def h36m_sampler(src: Sources) -> str:
    """Inline: the bundled Human3.6M model's default forecast sampler (its sampling.json)."""
    return _sampler(src.repo_json(f"{H36M_DIR}/sampling.json")["forecast"])


def h36m_repair_sampler(src: Sources) -> str:
    """Inline: the sampler of a bundled Human3.6M repair asked for diffusion samples (its sampling.json)."""
    return _sampler(src.repo_json(f"{H36M_DIR}/sampling.json")["repair"])


def humaneva_sampler(src: Sources) -> str:
    """Inline: the bundled HumanEva-I model's default forecast: its sampler and its mode (the generator's share)."""
    s = src.repo_json(f"{HUMANEVA_DIR}/sampling.json")
    return f"{_sampler(s['forecast'])}; `mode=tcd.Mixture({s.get('forecast_generator_share', 0):g})`"


# ------------------------------------------------------------------------------------------ registration
# NAME -> generator. One line per block name; a generator may serve several blocks in several files.

GENERATORS: dict[str, Callable[[Sources], str]] = {
    # README.md and MODEL_CARD.md
    "h36m-forecast": h36m_forecast,
    "h36m-imperfect": h36m_imperfect,
    "h36m-repair": h36m_repair,
    "repair-dataset": repair_dataset,
    "humaneva-forecast": humaneva_forecast,
    "setting-a-forecast": setting_a_forecast,
    "stochastic-summary": stochastic_summary,
    "humaneva-per-action": humaneva_per_action,
    "speed-peers": speed_peers,
    "speed-whole": speed_whole,
    "speed-bundled": speed_bundled,
    "model-details": model_details,
    "training-data": training_data,
    "convention": convention,
    "recipes-cost": recipes_cost,
    "h36m-sampler": h36m_sampler,
    "h36m-repair-sampler": h36m_repair_sampler,
    "humaneva-sampler": humaneva_sampler,
    # docs/*.md: add yours here, one line each
    "wild-layouts": wild_layouts,
}
