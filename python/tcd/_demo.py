"""``tcd demo``: forecast and repair the bundled demo clip with the bundled model.

The clip (``tcd/data/demo_walking.npz``) is 5 s of walking from the CMU Graphics Lab Motion Capture
Database (mocap.cs.cmu.edu, free for research and products, with attribution), converted to the model's
22-joint Human3.6M layout (CMU bone directions, Human3.6M bone lengths, metres, root-relative, 25 fps) by
``python -m training.make_demo_clip``. It is not Human3.6M data, so the numbers the demo prints measure
generalisation to another capture setup and subject.

What it does, with its default settings:

1. **forecast**: the first ``obs_len`` (50) frames are observed, the next ``horizon`` (25) are forecast and
   compared with the clip's true continuation; Zero-Velocity (the last observed pose held) is printed beside;
2. **occluded forecast**: the same, with the right leg hidden during 0.8 s, the left arm during 0.8 s and
   5 % of the other joint-frames dropped at random (seeded), the paper's in-the-wild setting;
3. **repair**: the occluded observation's missing entries filled by the model (with its own sample count,
   :attr:`TCD.repair_samples`: the bundled model's repair fill alone), scored against the true values (ADE
   over the occluded entries) beside linear interpolation in time.

With more than one sample, the demo also prints how diverse the samples are (APD, the stochastic benchmarks'
diversity) and the error of the best one (an oracle: chosen against the truth).

The HumanEva-I model (``tcd demo --model humaneva``) gets the same clip converted to its layout
(``tcd/data/demo_walking_humaneva.npz``: 60 Hz, +z up, HumanEva-I's bone lengths; ``python -m
training.make_demo_clip --layout humaneva``): 15 observed frames, 60 forecast (1 s).

It writes ``demo.npz`` (every array, the joint names and the timings) and, with ``--plot demo.gif`` and
matplotlib installed (``pip install "tcd-forecast[plot]"``), an animation of observed, repaired, forecast
and true skeletons.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np

from ._files import write_named_atomic, write_npz_atomic
from ._interpolation import interpolate
from ._model import TCD
from ._sampler import SamplerOptions
from ._cascade import Cascade, as_dict
from ._mixture import Mixture, generator_samples

CLIP_PATH = Path(__file__).resolve().parent / "data" / "demo_walking.npz"
#: the same walk for the HumanEva-I model (its 14 joints, 60 Hz, +z up)
HUMANEVA_CLIP_PATH = CLIP_PATH.with_name("demo_walking_humaneva.npz")
#: the same walk for the Setting-A model (joints 1..16 of h36m17, 50 Hz, +y up)
SETTING_A_CLIP_PATH = CLIP_PATH.with_name("demo_walking_setting_a.npz")
#: the clip of each model's dataset (its ``data.dataset``), the Human3.6M one for any other
CLIPS = {"humaneva": HUMANEVA_CLIP_PATH, "h36m-setting-a": SETTING_A_CLIP_PATH}
#: the layout each clip is in, for the demo's summary
CLIP_LAYOUTS = {"humaneva": "HumanEva-I layout", "h36m-setting-a": "Human3.6M Setting-A layout"}
HORIZONS_MS = (80, 160, 320, 400, 560, 720, 880, 1000)

# Demo defaults: 5 samples; each task samples with the model's own defaults (TCD.sampling: the bundled
# Human3.6M model forecasts with one DDIM step and repairs with DDPM over 10 steps; docs/samplers.md).
DEFAULT_SAMPLES = 5
DEFAULT_SEED = 0

# The model's skeleton (Human3.6M 22-joint layout): limb joints by name, for the occlusion.
RIGHT_LEG = ("right_knee", "right_ankle", "right_toe", "right_toe_site")
LEFT_ARM = ("left_shoulder", "left_elbow", "left_wrist", "left_thumb", "left_hand")
# Bones of the 22-joint layout, for drawing (joint names; the root/hips are not in the model).
BONES = (
    ("right_knee", "right_ankle"),
    ("right_ankle", "right_toe"),
    ("right_toe", "right_toe_site"),
    ("left_knee", "left_ankle"),
    ("left_ankle", "left_toe"),
    ("left_toe", "left_toe_site"),
    ("thorax", "neck"),
    ("neck", "head"),
    ("head", "head_site"),
    ("neck", "left_shoulder"),
    ("left_shoulder", "left_elbow"),
    ("left_elbow", "left_wrist"),
    ("left_wrist", "left_thumb"),
    ("left_wrist", "left_hand"),
    ("neck", "right_shoulder"),
    ("right_shoulder", "right_elbow"),
    ("right_elbow", "right_wrist"),
    ("right_wrist", "right_thumb"),
    ("right_wrist", "right_hand"),
)


def clip_for(model: TCD) -> Path:
    """The bundled clip in the model's layout (:data:`CLIPS`): the HumanEva-I clip for a HumanEva-I model, the
    Setting-A one for a Setting-A model, else the Human3.6M one."""
    return CLIPS.get(str(model.data.get("dataset")), CLIP_PATH)


def apd(samples: np.ndarray) -> float:
    """Average pairwise distance (m) between samples (S, H, J, 3), each flattened: DLow's diversity (APD)."""
    flat = np.asarray(samples, np.float64).reshape(len(samples), -1)
    d = [np.linalg.norm(flat[a + 1 :] - flat[a], axis=1) for a in range(len(flat) - 1)]
    return float(np.concatenate(d).mean()) if d else 0.0


def load_clip(path: Path = CLIP_PATH) -> Dict[str, Any]:
    """The bundled demo clip: ``poses`` (T, 22, 3) metres at ``fps``, ``joint_names``, ``source`` (dict)."""
    with np.load(path, allow_pickle=False) as f:
        return {
            "poses": np.asarray(f["poses"], dtype=np.float32),
            "fps": float(f["fps"]),
            "joint_names": [str(n) for n in f["joint_names"]],
            "source": json.loads(str(f["source"])),
        }


def occlusion_mask(obs_len: int, joint_names: List[str], seed: int = DEFAULT_SEED) -> np.ndarray:
    """(obs_len, J) mask, 1 = observed: the right leg hidden over frames [10, 30), the left arm over
    [25, 45), and 5 % of the remaining joint-frames dropped at random. The last observed frame keeps at
    least its torso, so that a forecast has an anchor."""
    j = len(joint_names)
    m = np.ones((obs_len, j), dtype=np.float32)
    idx = {n: i for i, n in enumerate(joint_names)}
    leg = [idx[n] for n in RIGHT_LEG if n in idx]
    arm = [idx[n] for n in LEFT_ARM if n in idx]
    m[int(0.2 * obs_len) : int(0.6 * obs_len), leg] = 0.0
    m[int(0.5 * obs_len) : int(0.9 * obs_len), arm] = 0.0
    rng = np.random.default_rng(seed)
    m[rng.random((obs_len, j)) < 0.05] = 0.0
    return m


def mpjpe_mm(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per-frame mean per-joint position error in mm, (..., T, J, 3) metres -> (..., T)."""
    return 1000.0 * np.linalg.norm(pred - gt, axis=-1).mean(axis=-1)


def horizon_row(per_frame: np.ndarray, fps: float) -> Dict[int, float]:
    """Errors at the standard horizons (ms) the forecast reaches."""
    out = {}
    for ms in HORIZONS_MS:
        k = int(round(ms * fps / 1000.0)) - 1
        if 0 <= k < len(per_frame):
            out[ms] = float(per_frame[k])
    return out


def _say(msg: str, quiet: bool) -> None:
    if not quiet:
        print(msg, file=sys.stderr, flush=True)


def run(
    model: TCD,
    *,
    samples: int = DEFAULT_SAMPLES,
    seed: int = DEFAULT_SEED,
    threads: Optional[int] = None,
    quiet: bool = False,
    clip_path: Optional[Path] = None,
    sampling: Optional[Dict[str, SamplerOptions]] = None,
) -> Dict[str, Any]:
    """Runs the demo; returns every array and number (what ``tcd demo`` prints and saves). ``clip_path``:
    by default the bundled clip in the model's layout (:func:`clip_for`). ``sampling``: the sampler of each
    task (``"forecast"``, ``"repair"``), those not given the model's (:attr:`TCD.sampling`)."""
    sampling = {**model.sampling, **(sampling or {})}
    o = sampling["forecast"]  # shown and recorded
    steps, sampler_name = o.num_inference_steps, o.sampler
    clip = load_clip(clip_for(model) if clip_path is None else clip_path)
    poses, fps, names = clip["poses"], clip["fps"], clip["joint_names"]
    if model.joint_names is not None and list(model.joint_names) != names:
        raise ValueError(
            "the demo clip's joints do not match the model's: the demo needs a 22-joint "
            "Human3.6M-layout model, a HumanEva-I model or a Setting-A model"
        )
    if model.fps is not None and abs(float(model.fps) - fps) > 1e-6:
        raise ValueError(f"the demo clip is at {fps:g} fps, the model at {model.fps:g} fps")
    n_obs, h = model.obs_len, model.horizon
    if poses.shape[0] < n_obs + h:
        raise ValueError(f"the demo clip has {poses.shape[0]} frames; the model needs {n_obs + h}")
    obs, future = poses[:n_obs], poses[n_obs : n_obs + h]
    kw = dict(num_samples=samples, seed=seed, threads=threads, sampler=o)
    # the repairs (TCD.repair, TCD.predict's fill) with the model's own sample count: the bundled model's fill alone
    repair_kw = dict(kw, num_samples=model.repair_samples, sampler=sampling["repair"])
    res: Dict[str, Any] = {
        "fps": fps,
        "joint_names": names,
        "observed": obs,
        "future": future,
        "settings": {
            "samples": samples,
            "repair_samples": model.repair_samples,
            "steps": steps,
            "sampler": sampler_name,
            "seed": seed,
            "mode": as_dict(model.forecast_mode),
            "generator_samples": generator_samples(model.forecast_mode, samples),
            "sampling": {t: dataclasses.asdict(o_t) for t, o_t in sampling.items()},
        },
        "timings_s": {},
    }
    zv = np.repeat(obs[-1:], h, axis=0)
    res["zero_velocity_mm"] = horizon_row(mpjpe_mm(zv, future), fps)

    stages = 4 if model.prior is not None else 3
    _say(
        f"[1/{stages}] forecasting {h} frames from {n_obs} observed ({samples} samples, {drawn_by(model, o)})...", quiet
    )
    t0 = time.perf_counter()
    f = model.forecast(obs, **kw)
    res["timings_s"]["forecast"] = time.perf_counter() - t0
    res["forecast_mean"], res["forecast_samples"] = f.mean, f.samples
    res["forecast_mm"] = horizon_row(mpjpe_mm(f.mean, future), fps)
    if samples > 1:
        errs = mpjpe_mm(f.samples, future)  # (S, H)
        res["best_sample_mm"] = horizon_row(errs[int(errs.mean(axis=1).argmin())], fps)
        res["samples_apd_m"] = apd(f.samples)
    _say(f"      done in {res['timings_s']['forecast']:.1f} s", quiet)

    mask = occlusion_mask(n_obs, names, seed)
    occluded = np.where(mask[..., None] > 0, obs, np.nan).astype(np.float32)
    res["occlusion_mask"] = mask
    res["occluded_fraction"] = float(1.0 - mask.mean())
    _say(
        f"[2/{stages}] forecasting from an occluded observation ({100 * res['occluded_fraction']:.0f} % of "
        "the joint-frames hidden)...",
        quiet,
    )
    t0 = time.perf_counter()
    fo = model.forecast(occluded, **kw)
    res["timings_s"]["forecast_occluded"] = time.perf_counter() - t0
    res["occluded_forecast_mean"] = fo.mean
    res["occluded_forecast_mm"] = horizon_row(mpjpe_mm(fo.mean, future), fps)
    _say(f"      done in {res['timings_s']['forecast_occluded']:.1f} s", quiet)

    if model.prior is not None:
        _say(
            f"[3/{stages}] point forecasts of the prior (TCD.predict), clean and occluded (repair then predict)...",
            quiet,
        )
        t0 = time.perf_counter()
        p = model.predict(obs, seed=seed, threads=threads)
        res["timings_s"]["point_forecast"] = time.perf_counter() - t0
        po = model.predict(occluded, **repair_kw)
        res["point_mean"], res["occluded_point_mean"] = p.mean, po.mean
        res["point_mm"] = horizon_row(mpjpe_mm(p.mean, future), fps)
        res["occluded_point_mm"] = horizon_row(mpjpe_mm(po.mean, future), fps)
        _say(f"      done in {res['timings_s']['point_forecast'] * 1000:.1f} ms (clean)", quiet)

    if not can_repair(model):
        res["repair_skipped"] = (
            "this model has no repair model, and its short-term model is conditioned on the "
            "prior forecaster, which a repair does not run"
            if model.short is not None
            else "this model has neither a repair model nor a cascade to repair with"
        )
        _say(f"[{stages}/{stages}] repair skipped: {res['repair_skipped']}", quiet)
        return res
    _say(f"[{stages}/{stages}] repairing the occluded observation...", quiet)
    t0 = time.perf_counter()
    rep = model.repair(occluded, **repair_kw).poses
    res["timings_s"]["repair"] = time.perf_counter() - t0
    res["repaired"] = rep
    hidden = mask == 0
    res["repair_ade_mm"] = float(1000.0 * np.linalg.norm(rep - obs, axis=-1)[hidden].mean())
    lin = interpolate(occluded, method="linear")
    res["linear_interpolation_ade_mm"] = float(1000.0 * np.linalg.norm(lin - obs, axis=-1)[hidden].mean())
    res["repaired_observed_unchanged"] = bool(np.array_equal(rep[~hidden], obs[~hidden]))
    _say(f"      done in {res['timings_s']['repair']:.1f} s", quiet)
    return res


def drawn_by(model: TCD, sampler: SamplerOptions) -> str:
    """What draws a forecast's samples, for people: the cascade's sampler, or the generator of a directory
    without a cascade."""
    if model.short is None:
        return "the MLP generator, one forward each"
    return sampler.describe(model.num_train_timesteps)  # type: ignore[arg-type]


def can_repair(model: TCD) -> bool:
    """Whether :meth:`TCD.repair` runs on this model: it has a repair model (with its repair fill, when it is
    conditioned on one: :func:`tcd.load` checks that), or its short-term model (which repairs without one) is not
    conditioned on the prior forecaster (a repair never runs the forecaster)."""
    if model.repair_model is not None:
        return True
    return model.short is not None and (model.short.config.get("model") or {}).get("cond_fill", "zero") != "prior"


def summary(res: Dict[str, Any], model: TCD) -> str:
    """The short text ``tcd demo`` prints."""
    ms = [m for m in HORIZONS_MS if m in res["forecast_mm"]]
    blocks = (
        ("forecast_mm", "occluded_forecast_mm", "zero_velocity_mm")
        + (("point_mm", "occluded_point_mm") if "point_mm" in res else ())
        + (("best_sample_mm",) if "best_sample_mm" in res else ())
    )
    # wide enough for every number (an untrained model's errors reach metres), one space between columns
    w = 1 + max(7, *(len(f"{res[b][m]:.1f}") for b in blocks for m in ms))
    head = "".join(f"{m:>{w}}" for m in ms)
    row = lambda name, d: f"  {name:<32}" + "".join(f"{d[m]:>{w}.1f}" for m in ms)  # noqa: E731
    s = res["settings"]
    lines = [
        f"tcd demo: model {model.path} (sha256 {str(model.sha256)[:12]}), clip: CMU walking "
        f"({CLIP_LAYOUTS.get(str(model.data.get('dataset')), 'Human3.6M layout')}), "
        f"{len(res['observed'])} observed frames at {res['fps']:g} fps",
        f"forecast by {drawn_by(model, SamplerOptions(**s['sampling']['forecast']))}, "
        + (
            ""
            if isinstance(model.forecast_mode, Cascade) or model.short is None
            else f"{model.forecast_mode.describe()}, "
        )
        + f"{s['samples']} samples"
        + (
            f" ({s['generator_samples']} of them from the MLP generator)"
            if s.get("generator_samples") and model.short is not None
            else ""
        )
        + f", seed {s['seed']}",
        "",
        "forecast error, mm (mean per-joint position error of the mean of the samples):",
        f"  {'horizon (ms)':<32}" + head,
        row("tcd, clean observation", res["forecast_mm"]),
        row("tcd, occluded observation", res["occluded_forecast_mm"]),
        *(
            [
                row("prior point forecast, clean", res["point_mm"]),
                row("prior, occluded (repair+predict)", res["occluded_point_mm"]),
            ]
            if "point_mm" in res
            else []
        ),
        row("zero-velocity (clean)", res["zero_velocity_mm"]),
        *(
            [
                row(f"best of the {s['samples']} samples (oracle)", res["best_sample_mm"]),
                "",
                f"the {s['samples']} samples of the clean forecast differ by {res['samples_apd_m']:.3f} m on average "
                "(APD: the flattened poses' mean pairwise distance, the stochastic benchmarks' diversity)",
            ]
            if "best_sample_mm" in res
            else []
        ),
        "",
        (
            f"repair of the occluded observation ({100 * res['occluded_fraction']:.0f} % hidden), "
            + ("by the repair fill alone" if s["repair_samples"] == 0 else f"mean of {s['repair_samples']} samples")
            + f": ADE {res['repair_ade_mm']:.1f} mm over the hidden entries "
            f"(linear interpolation: {res['linear_interpolation_ade_mm']:.1f} mm); observed entries unchanged: "
            f"{'yes' if res['repaired_observed_unchanged'] else 'NO'}"
        )
        if "repair_ade_mm" in res
        else f"repair skipped: {res['repair_skipped']}",
        "",
        "time: " + ", ".join(f"{k.replace('_', ' ')} {v:.2f} s" for k, v in res["timings_s"].items()),
        "",
        "The table is the forecast error in mm at each horizon (lower is better) from a clean and from an occluded "
        "observation, beside Zero-Velocity (the last observed pose held) and, where the model has one, the "
        "deterministic prior's point forecast"
        + (
            "; the repair line compares the model's filling of hidden joints with linear interpolation."
            if "repair_ade_mm" in res
            else "."
        ),
        verdict(res, model),
    ]
    return "\n".join(lines)


#: The paper's model size (layers, channels): what "full size" means below.
PAPER_SIZE = (12, 64)


def verdict(res: Dict[str, Any], model: TCD) -> str:
    """One sentence on how good this model is, from its own metadata (each stage's size) and this run's numbers."""
    ms = [m for m in HORIZONS_MS if m in res["forecast_mm"]]
    wins = sum(res["forecast_mm"][m] < res["zero_velocity_mm"][m] for m in ms)
    g = model.generator
    if model.short is None:  # a generator directory: the network is the generator around the prior
        return (
            f"This is an MLP generator ({g.layers} x {g.hidden}) around a prior forecaster, no cascade: on this clip "
            f"it beats Zero-Velocity at {wins} of {len(ms)} horizons; one clip is not a benchmark (MODEL_CARD.md "
            "has the stochastic protocol's numbers)."
        )
    sizes = {
        role: (stage.config["model"]["num_layers"], stage.config["model"]["channels"])
        for role, stage in (("short-term", model.short), ("long-term", model.long))
    }
    full = all(layers >= PAPER_SIZE[0] and channels >= PAPER_SIZE[1] for layers, channels in sizes.values())
    if len(set(sizes.values())) == 1:
        layers, channels = sizes["short-term"]
        shape = f"{layers} layers x {channels} channels"
    else:  # the stages may differ (the bundled long-term model is larger than the short-term one)
        shape = ", ".join(f"{role} {layers} layers x {channels} channels" for role, (layers, channels) in sizes.items())
    if g is not None and isinstance(model.forecast_mode, Mixture) and model.forecast_mode.share:
        share = model.forecast_mode.share
        shape += f"; and an MLP generator of {g.layers} x {g.hidden} drawing {share:g} of the samples"
    kind = (
        f"a full-size model ({shape}, the paper's size)"
        if full
        else f"a reduced model ({shape}; the paper's is {PAPER_SIZE[0]} x {PAPER_SIZE[1]})"
    )
    caveat = (
        "one clip is not a benchmark (docs/reference.md has the evaluation protocol)"
        if full
        else "its forecasts show how the package works, not the paper's accuracy"
    )
    return f"This is {kind}: on this clip it beats Zero-Velocity at {wins} of {len(ms)} horizons; {caveat}."


#: What the demo writes into its .npz's summary, so that a later `tcd demo` knows the file is its own.
DEMO_TOOL = "tcd demo"


def sha256_of(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def is_own_output(path: Path, npz: Path) -> bool:
    """Whether ``path`` is an earlier output of ``tcd demo`` (the only existing file a re-run replaces
    without ``--overwrite``): the demo .npz ``npz`` itself (its summary names the tool), or the GIF whose
    SHA-256 that summary records."""
    try:
        with np.load(npz, allow_pickle=False) as z:
            summary = json.loads(str(z["summary"]))
    except Exception:  # anything unreadable, or not ours, is not the demo's output
        return False
    if summary.get("tool") != DEMO_TOOL:
        return False
    if Path(path) == Path(npz):
        return True
    return path.is_file() and summary.get("plot_sha256") == sha256_of(path)


def save(
    res: Dict[str, Any], path: Path, model: TCD, overwrite: bool = True, plot_sha256: Optional[str] = None
) -> None:
    """Writes the demo's arrays and numbers to ``path`` (.npz) atomically (``FileExistsError`` when it exists
    and not ``overwrite``); ``plot_sha256``: that of the GIF written beside it, recorded in the summary."""
    meta = {
        k: res[k]
        for k in (
            "settings",
            "timings_s",
            "forecast_mm",
            "occluded_forecast_mm",
            "zero_velocity_mm",
            "occluded_fraction",
            "fps",
        )
    }
    meta.update(
        {
            k: res[k]
            for k in (
                "point_mm",
                "occluded_point_mm",
                "best_sample_mm",
                "samples_apd_m",
                "repair_ade_mm",
                "linear_interpolation_ade_mm",
                "repair_skipped",
            )
            if k in res
        }
    )
    meta["model_sha256"] = model.sha256
    meta["tool"] = DEMO_TOOL
    meta["plot_sha256"] = plot_sha256
    arrays = {
        k: res[k]
        for k in (
            "observed",
            "future",
            "forecast_mean",
            "forecast_samples",
            "occlusion_mask",
            "occluded_forecast_mean",
            "repaired",
            "point_mean",
            "occluded_point_mean",
        )
        if k in res
    }
    write_npz_atomic(
        path, overwrite, joint_names=np.array(res["joint_names"]), summary=np.array(json.dumps(meta)), **arrays
    )


def plot(res: Dict[str, Any], path: Path, fps: float, overwrite: bool = True) -> None:
    """Renders observed / repaired (left) and forecast vs truth (right) as an animated GIF, written
    atomically (``FileExistsError`` when it exists and not ``overwrite``)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.animation import FuncAnimation, PillowWriter
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("--plot needs matplotlib: pip install 'tcd-forecast[plot]'") from e
    names = list(res["joint_names"])
    humaneva = "pelvis" not in names and "right_hip" in names  # the HumanEva-I model's joints
    # the pelvis and hips are not model joints (root-relative, rotation removed: they are fixed); add them
    # at their Human3.6M positions for drawing (the HumanEva-I model: the pelvis, at the origin)
    fixed = (
        {"pelvis": (0.0, 0.0, 0.0)}
        if humaneva
        else {"pelvis": (0.0, 0.0, 0.0), "right_hip": (-0.1329, 0.0, 0.0), "left_hip": (0.1329, 0.0, 0.0)}
    )
    extra = np.array(list(fixed.values()), dtype=np.float32)

    def with_hips(p):
        return np.concatenate([p, np.broadcast_to(extra, p.shape[:-2] + extra.shape)], axis=-2)

    names += list(fixed)
    idx = {n: i for i, n in enumerate(names)}
    hip_bones = (
        ("pelvis", "right_hip"),
        ("right_hip", "right_knee"),
        ("pelvis", "left_hip"),
        ("left_hip", "left_knee"),
        ("pelvis", "thorax"),
    )
    bones = [(idx[a], idx[b]) for a, b in BONES + hip_bones if a in idx and b in idx]
    if humaneva:  # its own tree (tcd.layouts humaneva15)
        from .layouts import LAYOUTS

        lay = LAYOUTS["humaneva15"]
        bones = [(idx[lay.joint_names[p]], idx[n]) for n, p in zip(lay.joint_names, lay.parents) if p >= 0]
    up, depth = (2, 1) if humaneva else (1, 2)  # +z up (HumanEva-I) or +y up
    # without a repair (skipped: demo.can_repair) the left panel shows the occluded observation's known joints
    obs, rep = with_hips(res["observed"]), with_hips(res.get("repaired", res["observed"]))
    fut, fc = with_hips(res["future"]), with_hips(res["forecast_mean"])
    smp = res.get("forecast_samples")
    smp = with_hips(smp[:5]) if smp is not None and len(smp) > 1 else None  # a few samples, drawn faintly
    mask = np.concatenate([res["occlusion_mask"], np.ones((len(obs), len(fixed)), np.float32)], axis=1)
    n_obs, h = len(obs), len(fut)
    fig = plt.figure(figsize=(9, 4.5))
    axes = [fig.add_subplot(1, 2, i + 1, projection="3d") for i in range(2)]
    allp = np.concatenate([obs, fut, fc], axis=0)
    lo, hi = allp.min(axis=(0, 1)), allp.max(axis=(0, 1))

    def draw(ax, pose, color, style="-"):
        for a, b in bones:
            # model axes: x left, y up, z forward -> plot x, z, y so that up is up
            ax.plot(
                [pose[a, 0], pose[b, 0]],
                [pose[a, depth], pose[b, depth]],
                [pose[a, up], pose[b, up]],
                style,
                color=color,
                lw=2,
            )

    def frame(i):
        for ax in axes:
            ax.cla()
            ax.set_xlim(lo[0], hi[0])
            ax.set_ylim(lo[depth], hi[depth])
            ax.set_zlim(lo[up], hi[up])  # noqa: E702
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_zticks([])  # noqa: E702
        if i < n_obs:
            draw(axes[0], obs[i], "0.6", "--")
            draw(axes[0], rep[i], "tab:blue")
            hid = mask[i] == 0
            if hid.any():
                axes[0].scatter(rep[i, hid, 0], rep[i, hid, depth], rep[i, hid, up], color="tab:red", s=12)
            title = (
                f"repair: frame {i + 1}/{n_obs}\nblue repaired, red = was hidden, grey truth"
                if "repaired" in res
                else f"observation: frame {i + 1}/{n_obs}\nred = hidden (no repair)"
            )
            axes[0].set_title(title, fontsize=8)
            draw(axes[1], obs[i], "0.3")
            axes[1].set_title("clean observation (ground truth)", fontsize=8)
        else:
            k = i - n_obs
            draw(axes[1], fut[k], "0.6", "--")
            for sample in () if smp is None else smp:
                draw(axes[1], sample[k], "#a6dba0")
            draw(axes[1], fc[k], "tab:green")
            axes[1].set_title(
                f"forecast +{1000 * (k + 1) / fps:.0f} ms\ngreen tcd (light: samples), grey truth", fontsize=8
            )
            draw(axes[0], rep[-1], "tab:blue")
            axes[0].set_title("last repaired frame" if "repaired" in res else "last observed frame", fontsize=8)
        return []

    anim = FuncAnimation(fig, frame, frames=n_obs + h, interval=1000 / fps)
    try:
        write_named_atomic(path, lambda tmp: anim.save(str(tmp), writer=PillowWriter(fps=fps)), overwrite)
    finally:
        plt.close(fig)
