"""The stochastic protocols of ``python -m training.evaluate --protocol humaneva|h36m-a``: the DLow / GSPS protocol
on HumanEva-I (``training.data.humaneva``: the 188 windows of the Validate split, 15 observed -> 60 predicted frames
at 60 Hz, 14 joints) and on Human3.6M Setting-A (``training.data.h36m_setting_a``: the 4,313 windows of S9 and S11
in our copy, 25 observed -> 100 predicted frames at 50 Hz, 16 joints). Each window's samples are scored by ADE,
FDE, MMADE, MMFDE and APD (``training.stochastic``) beside the baselines (Zero-Velocity, the nearest training
futures, the directory's prior) and the published numbers.

One dataset is one :class:`StochasticDataset` in ``DATASETS``; everything else (the windows and their multimodal
futures, the model's samples, the baselines, the scores, the printed table) is shared. The scores are computed a
block of windows at a time (:meth:`StochasticCases.score_by`): 50 samples of Setting-A's 4,313 windows would be
8 GB at once."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

# torch (through .engines) is imported where a model runs: the datasets, windows and baselines need numpy alone


# ------------------------------------------------------------------------------------------ the datasets


def _humaneva_windows(data, split: str) -> tuple[np.ndarray, list[str]]:
    from .data.humaneva import humaneva_file, humaneva_test_actions, humaneva_test_windows, load_humaneva

    d = load_humaneva(humaneva_file(data), split=split)
    return humaneva_test_windows(d), humaneva_test_actions(d)


def _humaneva_training(data) -> list[np.ndarray]:
    from .data.humaneva import training_sequences

    return list(training_sequences(data).values())


def _setting_a_windows(data, split: str) -> tuple[np.ndarray, list[str]]:
    from .data.h36m_setting_a import (
        SETTING_A_TEST_SUBJECTS,
        SETTING_A_TRAIN_SUBJECTS,
        setting_a_sequences,
        setting_a_test_windows,
    )

    subjects = SETTING_A_TEST_SUBJECTS if split == "S9+S11" else SETTING_A_TRAIN_SUBJECTS
    return setting_a_test_windows(setting_a_sequences(subjects, data))


def _setting_a_training(data) -> list[np.ndarray]:
    from .data.h36m_setting_a import SETTING_A_TRAIN_SUBJECTS, setting_a_sequences

    return [s.astype(np.float32) for s in setting_a_sequences(SETTING_A_TRAIN_SUBJECTS, data).values()]


@dataclass(frozen=True)
class StochasticDataset:
    """One dataset of the stochastic protocol: its windows, its training data and how results name it."""

    protocol: str  # the --protocol name
    dataset: str  # the results' protocol.dataset (training.compare pairs results only of one)
    title: str
    t_his: int
    t_pred: int
    fps: int
    num_joints: int  # the model's joints (the root dropped)
    up: str  # the data's vertical axis (the augmentations turn and reflect about it)
    data_dir: str  # under training.data.h36m.DEFAULT_DATA_ROOT
    splits: tuple  # the test split first; the next apply the same rule to the training data
    windows: Callable  # (data, split) -> ((N, t_his + t_pred, J, 3) metres, each window's action)
    training: Callable  # (data) -> the training sequences, each (T, J, 3) float32 metres
    published: str  # the name in training.metrics of its published numbers ({name}, {name}_SOURCES)

    @property
    def dims(self) -> int:
        return 3 * self.num_joints

    def data_path(self, data=None):
        """``data``, or where ``../shared/data`` holds this dataset."""
        if data is not None:
            return data
        from .data.h36m import DEFAULT_DATA_ROOT

        return DEFAULT_DATA_ROOT / self.data_dir

    def split_of(self, split: str | None) -> str:
        """``split`` (default the test split), checked: ValueError naming the splits there are."""
        split = split or self.splits[0]
        if split not in self.splits:
            raise ValueError(f"split: {self.title} has the splits {list(self.splits)}, not {split!r}")
        return split


HUMANEVA = StochasticDataset(
    "humaneva", "humaneva-i", "HumanEva-I", 15, 60, 60, 14, "z", "humaneva", ("Validate", "Train"),
    _humaneva_windows, _humaneva_training, "PUBLISHED_HUMANEVA",
)  # fmt: skip
SETTING_A = StochasticDataset(
    "h36m-a", "h36m-setting-a", "Human3.6M Setting-A", 25, 100, 50, 16, "y", "h36m", ("S9+S11", "S1+S5-S8"),
    _setting_a_windows, _setting_a_training, "PUBLISHED_H36M_A",
)  # fmt: skip
DATASETS = {d.protocol: d for d in (HUMANEVA, SETTING_A)}


def dataset_of(protocol: str) -> StochasticDataset:
    try:
        return DATASETS[protocol]
    except KeyError:
        raise ValueError(f"protocol: {protocol!r} is not a stochastic protocol; they are {sorted(DATASETS)}") from None


def published(ds: StochasticDataset) -> tuple[dict, dict]:
    """The dataset's published numbers (method -> metrics, or None where not given) and their sources."""
    from . import metrics

    return getattr(metrics, ds.published), getattr(metrics, ds.published + "_SOURCES")


# ------------------------------------------------------------------------------------------ the windows


class MultimodalSets:
    """Each window's multimodal futures (DLow's ``get_multimodal_gt``: the futures of the windows whose last observed
    pose lies within 0.5 of its own, itself included), as indices into one array of futures: Setting-A's sets hold
    59 futures on average, which as copies would be 10 GB. ``sets[i]`` is window i's (M_i, t_pred, D) array."""

    def __init__(self, windows: np.ndarray, t_his: int, threshold: float = 0.5):
        n = len(windows)
        flat = np.asarray(windows).reshape(n, windows.shape[1], -1)
        self.futures = flat[:, t_his:]
        start = flat[:, t_his - 1].astype(np.float64)
        # exact distances (no Gram-matrix cancellation: the threshold rule must pick DLow's sets), row by row
        self.members = [np.nonzero(np.linalg.norm(start - start[i], axis=1) < threshold)[0] for i in range(n)]

    def __len__(self) -> int:
        return len(self.members)

    def __getitem__(self, i: int) -> np.ndarray:
        return self.futures[self.members[i]]

    def sizes(self) -> np.ndarray:
        return np.asarray([len(m) for m in self.members])


@dataclass
class StochasticCases:
    """The protocol's windows an evaluation scores (all, or ``max_windows`` evenly spaced) and how: one place for
    the evaluator and the trainers that score samples (``training.generator_imle``)."""

    ds: StochasticDataset
    rows: np.ndarray  # which of the protocol's windows
    windows_in_protocol: int
    obs: np.ndarray  # (W, t_his, J, 3) metres
    gts: list  # each window's future (t_pred, D)
    gt_multi: "_Subset"  # each window's multimodal futures (M, t_pred, D), from every window as DLow does
    actions: np.ndarray  # each window's action ("Box", "walking", ...)
    split: str

    @classmethod
    def load(
        cls, ds: StochasticDataset | str, data=None, max_windows: int | None = None, split: str | None = None
    ) -> "StochasticCases":
        ds = dataset_of(ds) if isinstance(ds, str) else ds
        split = ds.split_of(split)
        wins, actions = ds.windows(ds.data_path(data), split)  # (N, T, J, 3) metres
        sets = MultimodalSets(wins, ds.t_his)
        rows = np.arange(len(wins))
        if max_windows:
            rows = np.unique(np.linspace(0, len(wins) - 1, min(max_windows, len(wins))).round().astype(int))
        return cls(
            ds,
            rows,
            len(wins),
            wins[rows, : ds.t_his].astype(np.float64),
            [wins[i, ds.t_his :].reshape(-1, ds.dims) for i in rows],
            _Subset(sets, rows),
            np.asarray(actions)[rows],
            split,
        )

    def protocol(self) -> dict:
        """The ``protocol`` block of a result: ``training.compare`` pairs two results only where it is equal."""
        return {
            "dataset": self.ds.dataset,
            "split": self.split,
            "t_his": self.ds.t_his,
            "t_pred": self.ds.t_pred,
            "fps": self.ds.fps,
            "windows": len(self.rows),
            "windows_in_protocol": self.windows_in_protocol,
            "units": f"m (DLow/GSPS: L2 norm of the flattened {self.ds.dims}-dim pose)",
        }

    def score(self, pred: np.ndarray) -> dict:
        """The protocol's metrics, with each window's, of samples ``pred`` (S, W, t_pred, J, 3)."""
        return self.score_by(lambda obs, lo: pred[:, lo : lo + len(obs)], block=len(self.rows))

    def score_by(self, draw: Callable[[np.ndarray, int], np.ndarray], block: int = 64) -> dict:
        """The protocol's metrics of the samples ``draw(obs, first)`` returns (S, B, t_pred, J, 3) for each block of
        ``block`` windows' observations ``obs`` (B, t_his, J, 3) from window ``first``; and beside them
        ``mean_ADE`` / ``mean_FDE``, the ADE / FDE of the samples' mean (what ``Forecast.mean`` returns: the point
        forecast a user deploys, not a protocol metric)."""
        from .stochastic import ade, evaluate_stochastic, fde

        parts = []
        for lo in range(0, len(self.rows), block):
            hi = min(lo + block, len(self.rows))
            pred = np.asarray(draw(self.obs[lo:hi], lo), np.float64)
            S = pred.shape[0]
            flat = [pred[:, w].reshape(S, self.ds.t_pred, -1) for w in range(hi - lo)]
            multi = [self.gt_multi[i] for i in range(lo, hi)]  # copies of one block's sets only
            part = evaluate_stochastic(flat, self.gts[lo:hi], multi, per_window=True)
            pw = part["per_window"]
            for name, metric in (("mean_ADE", ade), ("mean_FDE", fde)):
                pw[name] = [metric(f.mean(axis=0, keepdims=True), gt) for f, gt in zip(flat, self.gts[lo:hi])]
            parts.append(pw)
        per_window = {k: [v for p in parts for v in p[k]] for k in parts[0]}
        return {**{k: float(np.mean(v)) for k, v in per_window.items()}, "per_window": per_window}

    def per_action(self, scores: dict) -> dict:
        """Each action's windows and means of ``scores``' per-window values (where the error is)."""
        return {
            a: {
                "windows": int((self.actions == a).sum()),
                **{k: float(np.mean(np.asarray(v)[self.actions == a])) for k, v in scores["per_window"].items()},
            }
            for a in sorted(set(self.actions))
        }


class _Subset:
    """``sets[rows[i]]`` as item i: the multimodal sets of the windows scored, read when used (no copies)."""

    def __init__(self, sets: MultimodalSets, rows: np.ndarray):
        self.sets, self.rows = sets, rows

    def __len__(self) -> int:
        return len(self.rows)

    def sizes(self) -> np.ndarray:
        return self.sets.sizes()[self.rows]

    def __getitem__(self, i: int) -> np.ndarray:
        return self.sets[int(self.rows[i])]


# ------------------------------------------------------------------------------------------ the forecasters


def _check_model(ds: StochasticDataset, where: str, obs_len: int, horizon: int, num_joints: int) -> None:
    if (obs_len, horizon, num_joints) != (ds.t_his, ds.t_pred, ds.num_joints):
        raise SystemExit(
            f"{where}: the model reads {obs_len} frames and forecasts {horizon} of {num_joints} joints; the "
            f"{ds.title} protocol needs {ds.t_his} -> {ds.t_pred} frames of {ds.num_joints} joints"
        )


class ModelSampler:
    """``args.samples`` samples (S, W, t_pred, J, 3) metres of the model directory ``args.model`` from observations
    (W, t_his, J, 3): through the Rust engine (``--engine tcd``: ``tcd.load(DIR).forecast``, the cascade with the
    directory's prior where the models are conditioned on it) or the PyTorch reference (``--engine torch``).
    ``args.batch_size`` windows per call, each call seeded by (``args.seed``, its first window)."""

    def __init__(self, ds: StochasticDataset, args):
        from .engines import mode_of, sampler_of

        self.ds, self.args = ds, args
        self.sampler = sampler_of(args)
        if args.engine == "tcd":
            import tcd

            self.model = tcd.load(args.model)
            _check_model(ds, args.model, self.model.obs_len, self.model.horizon, self.model.num_joints)
            self.mode = mode_of(args)
        else:
            from .export import load_model_dir
            from .fileformat import GENERATOR_FILE

            if (Path(args.model) / GENERATOR_FILE).is_file() and getattr(args, "generator_share", None) != 0:
                raise SystemExit(
                    f"{args.model} holds an MLP generator ({GENERATOR_FILE}), whose samples only the engine "
                    "draws: score it with --engine tcd, or the cascade alone with --generator-share 0"
                )
            self.models = load_model_dir(args.model, args.device)
            w = self.models["short"][2]["window"]
            _check_model(
                ds,
                args.model,
                w["obs_len"],
                self.models["long"][2]["window"]["seq_len"] - w["obs_len"],
                self.models["short"][0].cfg.num_joints,
            )

    def __call__(self, obs: np.ndarray, first: int = 0, log=lambda m: None) -> np.ndarray:
        args, outs, t0 = self.args, [], time.time()
        for b0 in range(0, len(obs), args.batch_size):
            x = obs[b0 : b0 + args.batch_size]
            seed = args.seed * 1_000_003 + first + b0
            if args.engine == "tcd":
                f = self.model.forecast(x, num_samples=args.samples, sampler=self.sampler, seed=seed, mode=self.mode)
                outs.append(np.asarray(f.samples, np.float64))
            else:
                from .engines import tcd_predict

                res = tcd_predict(
                    self.models,
                    x,
                    np.ones(x.shape[:3], np.float32),
                    samples=args.samples,
                    sampler=self.sampler,
                    seed=seed,
                    device=args.device,
                    batch_size=len(x),
                    horizon=self.ds.t_pred,
                )
                outs.append(res["samples"])
            log(
                f"[{first + min(b0 + args.batch_size, len(obs))}] {args.samples} samples each, {time.time() - t0:.0f} s"
            )
        return np.concatenate(outs, axis=1)


def model_samples(ds: StochasticDataset, args, obs: np.ndarray, log=lambda m: None) -> np.ndarray:
    """:class:`ModelSampler`'s samples of all of ``obs`` (one call)."""
    return ModelSampler(ds, args)(obs, 0, log)


def prior_forecast(ds: StochasticDataset, path: str | Path, obs: np.ndarray) -> np.ndarray:
    """The prior's deterministic forecast (W, t_pred, J, 3) from obs (W, t_his, J, 3): ``path`` a directory holding
    ``prior.safetensors`` or that file (the engine, ``tcd.engine.Prior``), or a ``training.prior`` checkpoint
    (PyTorch)."""
    path = Path(path)
    W, T, J, _ = obs.shape
    x = np.ascontiguousarray(obs.reshape(W, T, J * 3), dtype=np.float32)
    if path.is_dir() or path.suffix == ".safetensors":
        import tcd

        prior = tcd.engine.Prior.load(path / "prior.safetensors" if path.is_dir() else path)
        if prior.num_features != J * 3 or prior.obs_len > T:
            raise SystemExit(
                f"{path}: the prior reads {prior.obs_len} frames of {prior.num_joints} joints; the "
                f"{ds.title} protocol gives {T} frames of {J}"
            )
        out = prior.predict(x, ds.t_pred)
    else:
        import torch

        from .prior import load

        net = load(path)
        with torch.no_grad():
            out = net.rollout(torch.from_numpy(x), ds.t_pred).numpy()
    return np.asarray(out, np.float64).reshape(W, ds.t_pred, J, 3)


class NeighbourForecaster:
    """A baseline that learns nothing: for each observation (W, t_his, J, 3), the futures of the ``n`` training
    windows (every window of t_his + t_pred frames) that arrive nearest to its last pose and velocity
    (``training.augment.arrival_keys``), each joined to the observation's last pose (``training.augment.swap_futures``,
    the augmentation ``future_swap`` trains with): (n, W, t_pred, J, 3). The futures similar pasts had, which is what
    the samples of a stochastic forecaster should cover. Only the keys of the training windows are held (Setting-A
    has 285,000 windows); their futures are gathered for the neighbours found."""

    def __init__(self, ds: StochasticDataset, n: int, data=None):
        from .augment import arrival_keys
        from .batches import Windows

        self.ds, self.n = ds, n
        self.windows = Windows(ds.training(ds.data_path(data)), ds.t_his + ds.t_pred, 1)
        if not 1 <= n <= len(self.windows):
            raise SystemExit(
                f"the nearest training futures: --samples must be in 1..{len(self.windows)} (the training windows), "
                f"got {n}"
            )
        ends = self.windows.gather(np.arange(len(self.windows)), slice(ds.t_his - 3, ds.t_his))
        self.keys = arrival_keys(ends, 3)

    def __call__(self, obs: np.ndarray, first: int = 0) -> np.ndarray:
        from .augment import arrival_keys, squared_distances, swap_futures

        t_his, t_pred, n = self.ds.t_his, self.ds.t_pred, self.n
        out = np.empty((n, len(obs), t_pred) + obs.shape[2:])
        for lo in range(0, len(obs), 128):  # 128 rows of distances to every training window at a time
            o = obs[lo : lo + 128]
            d = squared_distances(arrival_keys(o, t_his), self.keys)
            part = np.argpartition(d, n - 1, axis=1)[:, :n] if n < d.shape[1] else np.tile(np.arange(n), (len(o), 1))
            # nearest first, ties by index (a stable sort of all distances would give the same order)
            near = np.take_along_axis(part, np.lexsort((part, np.take_along_axis(d, part, 1)), axis=1), 1)
            past = np.concatenate([o, np.zeros((len(o), t_pred) + o.shape[2:])], axis=1)
            for i in range(n):
                donors = self.windows.gather(near[:, i]).astype(np.float64)
                out[i, lo : lo + len(o)] = swap_futures(past, donors, t_his)[:, t_his:]
        return out


# ------------------------------------------------------------------------------------------ the evaluation


def evaluate_stochastic_protocol(args) -> dict:
    """The stochastic protocol ``args.protocol`` for ``args`` (the options of ``training.evaluate``)."""
    from .engines import generator_share_of, noise_coupling_of, tempo_run

    ds = dataset_of(args.protocol)
    pub, pub_sources = published(ds)
    cases = StochasticCases.load(ds, args.data, getattr(args, "max_windows", None), getattr(args, "split", None))
    say = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))

    results = {"zero_velocity": cases.score_by(lambda o, lo: np.repeat(o[None, :, -1:], ds.t_pred, axis=2))}
    prior_path = args.prior or (
        args.model if args.model and (Path(args.model) / "prior.safetensors").is_file() else None
    )
    if prior_path:
        results["prior"] = cases.score(prior_forecast(ds, prior_path, cases.obs)[None])
    if cases.split == ds.splits[0]:  # on the training split each window would find itself
        say(f"the nearest training futures: {args.samples} per window")
        results["neighbours"] = cases.score_by(NeighbourForecaster(ds, args.samples, args.data))
    t0 = time.time()
    if args.model:
        sampler = ModelSampler(ds, args)
        results["model"] = cases.score_by(lambda o, lo: sampler(o, lo, log=say), block=max(64, args.batch_size))
    out = {
        "protocol": cases.protocol(),
        "seeds": {"sampling": args.seed} if args.model else {},
        **results,
        "multimodal_sets": {
            "mean": float(cases.gt_multi.sizes().mean()),
            "alone": int((cases.gt_multi.sizes() == 1).sum()),
        },
        "published": dict(pub),
        "published_sources": pub_sources,
    }
    if args.model:
        out.update(
            method=f"tcd {args.model}",
            stochastic=results["model"],
            seconds=time.time() - t0,
            sampling={
                "engine": args.engine,
                "samples": args.samples,
                "steps": args.steps,
                "sampler": args.sampler,
                "eta": args.eta,
                "timestep_spacing": args.timestep_spacing,
                "noise_coupling": noise_coupling_of(args),
                "tempo": tempo_run(args),
                "generator_share": generator_share_of(args),
            },
        )
    elif args.prior:
        out.update(method=f"prior {args.prior}", stochastic=results["prior"])
    elif args.baseline == "neighbours":
        if "neighbours" not in results:
            raise SystemExit(f"--baseline neighbours: on the {cases.split} split each window would find itself")
        out.update(method="nearest training futures", stochastic=results["neighbours"])
    else:
        out.update(method="zero-velocity", stochastic=results["zero_velocity"])
    if prior_path:
        out["prior_source"] = str(prior_path)
    out["per_action"] = cases.per_action(out["stochastic"])
    return out


def print_stochastic_table(out: dict) -> None:
    keys = ("ADE", "FDE", "MMADE", "MMFDE", "APD")
    p = out["protocol"]
    title = next(d.title for d in DATASETS.values() if d.dataset == p["dataset"])
    print(
        f"\n{title}, {p['windows']} of {p['windows_in_protocol']} {p['split']} windows, {p['t_his']} -> "
        f"{p['t_pred']} frames at {p['fps']} Hz; {p['units']}; lower is better but APD, the diversity"
    )
    print(f"{'method':<44}" + "".join(f"{k:>8}" for k in keys))

    def row(name: str, d: dict | None) -> None:
        cells = "".join(f"{d[k]:>8.3f}" if d and d.get(k) is not None else f"{'-':>8}" for k in keys)
        print(f"{name:<44}{cells}")

    if "model" in out:
        s = out["sampling"]
        share = s.get("generator_share") or 0
        row(
            f"tcd ({s['samples']} samples, {s['engine']}, {s['sampler']} {s['steps'] or 'all'} steps"
            + (f", {int(s['samples'] * share)} MLP" if share else "")
            + ")",
            out["model"],
        )
    if "prior" in out:
        row("prior (deterministic point forecast)", out["prior"])
    row("Zero-Velocity", out["zero_velocity"])
    if "neighbours" in out:
        row("nearest training futures, joined", out["neighbours"])
    print("published (50 samples; - : not given)")
    for name, d in out["published"].items():
        row(f"  {name}", d)
    if "per_action" in out:
        print(f"{out['method']}, per action (its windows' means)")
        for name, d in out["per_action"].items():
            row(f"  {name} ({d['windows']} windows)", d)
