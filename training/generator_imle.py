"""The trainer of the MLP sample generator (``generator.safetensors``; recipes
``training/recipes/humaneva-generator.json`` and ``h36m-stochastic.json``), by IMLE around the prior's forecast, on
a stochastic protocol's dataset (``--protocol``: HumanEva-I, 15 -> 60 frames of 14 joints, or Human3.6M Setting-A,
25 -> 100 of 16; ``training.evaluate_stochastic.DATASETS``).

* input: the observation's DCT coefficients and the first ``--coefs`` of the prior's forecast (both relative to the
  last observed pose) and a noise vector z ~ N(0, I) of ``--z``;
* an MLP of ``--layers`` x ``--hidden`` (GELU) to the first ``--coefs`` DCT coefficients of a residual over the
  prior's forecast; its last layer starts at zero, so the untrained generator is the prior;
* IMLE (Li and Malik 2018): each training window draws ``--cands`` z, and each of its targets (its own future and,
  with ``--targets`` T > 1, the futures of its T - 1 nearest training windows by arrival pose and velocity, joined to
  its last pose: ``training.augment.swap_futures``) pulls the candidate nearest to it, by the per-frame L2 error's
  mean plus ``--fde-weight`` x its last frame's (the protocol's ADE and FDE);
* with ``--rotate`` each window and its targets turned about the data's vertical by an angle in [0, 2 pi)
  (``training.augment.rotate_about``), with ``--mirror`` half of them reflected (``training.augment.mirror``), with
  ``--speed-range`` played faster or slower (``training.augment.resample``); Adam at ``--lr``, x 0.1 for the last
  20 % of the run;
* with ``--complement``, for a mixture with a model directory's cascade: the cascade's samples of every training
  window (turned and reflected with it) compete with the MLP's draws, and a target counts the nearer of the two, so
  the MLP learns to reach what the cascade's samples miss; ``--mix M`` scores the mixture of the cascade's first M
  protocol samples and the MLP's first 50 - M.

It scores 50 samples per window on the protocol's windows (``training.evaluate_stochastic.StochasticCases``: the
same metrics and per-window values as ``python -m training.evaluate --protocol PROTOCOL``, so ``training.compare``
pairs them), in PyTorch. The generator is ``training.generator.Generator``; ``python -m training.generator
--state-dict`` writes a ``--save``d one as ``generator.safetensors``, which the engine runs
(``tcd.engine.Generator``) and a model directory mixes into its forecasts. ``--steps`` (with ``--threads 1``) makes
a run reproducible; ``--minutes`` bounds a run by time instead::

    python -m training.generator_imle --steps 1674 --rotate --targets 4 --threads 1 --save runs/gen/generator.pt
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from .evaluate_stochastic import DATASETS, StochasticDataset, dataset_of
from .generator import COEFS, HIDDEN, LAYERS, Z_DIM, Generator  # the model it trains

ROOT = Path(__file__).resolve().parents[1]

SAMPLES = 50  # the protocol's samples per window
COMPLEMENT_SEED = 7  # the engine's seed for --complement's samples of the training windows (not the scoring's)


def distance(x: torch.Tensor, y: torch.Tensor, fde_weight: float) -> torch.Tensor:
    """(..., P, K) pairs -> (...): the mean over frames of the per-frame L2 error plus ``fde_weight`` x the last's."""
    e = torch.linalg.vector_norm(x - y, dim=-1)
    return e.mean(-1) + fde_weight * e[..., -1]


def imle_loss(
    gen: Generator,
    obs: torch.Tensor,
    prior: torch.Tensor,
    targets: torch.Tensor,
    cands: int,
    fde_weight: float,
    rival: torch.Tensor | None = None,
) -> torch.Tensor:
    """``targets`` (B, T, P, K): each pulls the nearest of ``cands`` draws of its window (searched without
    gradients, then generated again with them), the mean of those distances. With ``rival`` (B, T), the distance
    from each target to another generator's nearest sample, the mean of the smaller of the two: the best of a
    mixture of both generators' samples, so a target the rival already reaches pulls nothing."""
    B = len(obs)
    z = torch.randn(B, cands, gen.z_dim)
    with torch.no_grad():
        best = distance(gen(obs, prior, z)[:, :, None], targets[:, None], fde_weight).argmin(1)  # (B, T)
    chosen = gen(obs, prior, z[torch.arange(B)[:, None], best])  # (B, T, P, K)
    d = distance(chosen, targets, fde_weight)
    return (d if rival is None else torch.minimum(d, rival)).mean()


def engine_samples(ds: StochasticDataset, model: str, obs: np.ndarray, samples: int, seed: int) -> np.ndarray:
    """(S, W, P, J, 3): ``samples`` one-step DDIM samples of the model directory ``model``'s cascade (no generator
    samples) for obs (W, O, J, 3), through the engine exactly as ``python -m training.evaluate --protocol PROTOCOL
    --engine tcd --sampler ddim --steps 1 --seed SEED --generator-share 0`` draws them."""
    from .evaluate import build_parser
    from .evaluate_stochastic import model_samples

    args = build_parser().parse_args(
        [
            "--protocol",
            ds.protocol,
            "--model",
            model,
            "--engine",
            "tcd",
            "--samples",
            str(samples),
            "--sampler",
            "ddim",
            "--steps",
            "1",
            "--seed",
            str(seed),
            "--generator-share",
            "0",
            "--json",
            "unused",
        ]
    )
    return model_samples(ds, args, np.asarray(obs, np.float64))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--protocol", default="humaneva", choices=sorted(DATASETS), help="the dataset and its protocol")
    ap.add_argument(
        "--minutes",
        type=float,
        default=0.0,
        help="the training clock's budget, learning rate x 0.1 for "
        "its last 20 %% (0 with no --steps: score --init only)",
    )
    ap.add_argument(
        "--steps",
        type=int,
        default=0,
        help="instead of --minutes: exactly this many steps, learning "
        "rate x 0.1 for the last 20 %% of them (with --threads 1, the same run gives the same weights)",
    )
    ap.add_argument("--init", default=None, help="start from this state dict (--save of an earlier run)")
    ap.add_argument(
        "--checkpoint",
        default=None,
        help="with --steps: the run's state (weights, optimizer, step, random streams), written every "
        "--checkpoint-minutes and at a stop; a run whose checkpoint exists resumes from it and reaches the weights "
        "of one that never stopped",
    )
    ap.add_argument("--checkpoint-minutes", type=float, default=5.0)
    ap.add_argument(
        "--stop-after-steps",
        type=int,
        default=0,
        metavar="N",
        help="with --checkpoint: stop (resumably) after step N of the --steps schedule",
    )
    ap.add_argument(
        "--seed",
        type=int,
        default=0,
        help="the scoring noise's seed (recorded as the result's "
        "seeds.sampling, which training.compare checks; the runs of 2026-11-29 scored with 123 as they "
        "trained)",
    )
    ap.add_argument("--hidden", type=int, default=HIDDEN)
    ap.add_argument("--layers", type=int, default=LAYERS)
    ap.add_argument("--z", type=int, default=Z_DIM, help="the noise vector's size")
    ap.add_argument("--coefs", type=int, default=COEFS, help="DCT coefficients of the residual (of its frames)")
    ap.add_argument(
        "--stride",
        type=int,
        default=1,
        help="frames between the starts of two training windows (Setting-A's every window, at 50 Hz, would hold 7 GB)",
    )
    ap.add_argument("--cands", type=int, default=50, help="IMLE candidates per window")
    ap.add_argument("--targets", type=int, default=1, help="targets per window: its own future and T - 1 others")
    ap.add_argument(
        "--exclude-frames",
        type=int,
        default=30,
        help="other targets: not of the window's own sequence within this many frames of it",
    )
    ap.add_argument("--rotate", action="store_true", help="turn each window (and its targets) about the vertical")
    ap.add_argument(
        "--mirror",
        action="store_true",
        help="reflect half the windows (and their targets) through a "
        "vertical plane, left and right joints swapped (training.augment.mirror)",
    )
    ap.add_argument(
        "--speed-range",
        type=float,
        nargs=2,
        default=None,
        metavar=("LO", "HI"),
        help="play each window (and its other targets) at a speed drawn log-uniformly from [LO, HI], as "
        "the prior's speed_range does (training.augment.resample; default: as recorded)",
    )
    ap.add_argument(
        "--complement",
        default=None,
        help="an .npy (N, C, 60, K) of the --model's one-step samples of "
        "each training window (in Windows order; written first, with --complement-samples, where it does "
        "not exist): train the MLP to reach the targets they do not, for a mixture of both (imle_loss's "
        "rival)",
    )
    ap.add_argument("--complement-samples", type=int, default=25, help="samples per window of a new --complement")
    ap.add_argument(
        "--mix",
        type=int,
        default=0,
        help="score a mixture: the --model's first MIX protocol samples "
        "(the engine, DDIM-1, seed --seed: those of benches/results/humaneva_cascade.json) and the MLP's "
        "first 50 - MIX; the result's model and stochastic are then the mixture's, generator_alone the "
        "MLP's 50",
    )
    ap.add_argument("--dropout", type=float, default=0.0, help="dropout before each hidden layer but the first")
    ap.add_argument("--fde-weight", type=float, default=1.0)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--eval-every", type=float, default=5.0, help="minutes between interim scores (stderr)")
    ap.add_argument(
        "--model",
        default=None,
        help="the model directory whose prior.safetensors the generator forecasts around (default for "
        "HumanEva-I: the bundled weights_humaneva)",
    )
    ap.add_argument("--data", default=None, help="the dataset's file or directory (default under ../shared/data)")
    ap.add_argument("--json", required=True, help="the result: the protocol's metrics, per window and per action")
    ap.add_argument("--save", default=None, help="also save the generator's state dict here")
    args = ap.parse_args(argv)
    if args.targets < 1 or args.cands < 1 or args.stride < 1 or args.minutes < 0 or args.steps < 0:
        raise SystemExit("--targets, --cands and --stride must be >= 1, --minutes and --steps >= 0")
    if args.minutes and args.steps:
        raise SystemExit("--minutes or --steps, not both")
    if (args.checkpoint or args.stop_after_steps) and not args.steps:
        raise SystemExit("--checkpoint and --stop-after-steps go with --steps (a clock's run does not resume)")
    if args.stop_after_steps and not args.checkpoint:
        raise SystemExit("--stop-after-steps needs --checkpoint (where the run resumes from)")
    if not 0 <= args.mix < SAMPLES:
        raise SystemExit(f"--mix must be in [0, {SAMPLES})")
    if args.complement and args.speed_range:
        raise SystemExit("--complement holds samples of the windows as recorded: not with --speed-range")

    ds = dataset_of(args.protocol)
    if args.model is None:
        if ds.protocol != "humaneva":
            raise SystemExit(f"--model: the directory of the {ds.title} prior (no bundled default)")
        args.model = str(ROOT / "python" / "tcd" / "weights_humaneva")
    import tcd
    from .augment import mirror, mirror_permutation, resample, rotate_about, sequence_ends, swap_futures
    from .batches import Windows
    from .evaluate_stochastic import StochasticCases
    from .prior import dataset_joint_names

    OBS, PRED, up = ds.t_his, ds.t_pred, ds.up
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    prior = tcd.engine.Prior.load(Path(args.model) / "prior.safetensors")
    cases = StochasticCases.load(ds, args.data)
    J = cases.obs.shape[2]
    K = 3 * J

    def forecast(obs: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.asarray(prior.predict(np.ascontiguousarray(obs, np.float32), PRED), np.float32))

    windows = Windows(ds.training(ds.data_path(args.data)), OBS + PRED, args.stride)
    train = windows.gather(np.arange(len(windows))).reshape(len(windows), OBS + PRED, K)
    frames = np.concatenate(windows.seqs).reshape(-1, K).astype(np.float32)  # every sequence, end to end
    first = np.r_[0, np.cumsum([len(q) for q in windows.seqs])][windows.index[:, 0]] + windows.index[:, 1]
    ends = sequence_ends(first, OBS + PRED)  # each window's sequence's end

    def read(rows: np.ndarray, speeds: np.ndarray | None) -> np.ndarray:
        """(B, O + P, K) training windows, played at ``speeds`` (None: as recorded)."""
        return train[rows] if speeds is None else resample(frames, first[rows], ends[rows], OBS + PRED, speeds)

    others = windows.future_neighbours(OBS, args.targets - 1, args.exclude_frames) if args.targets > 1 else None
    if args.complement and not Path(args.complement).is_file():
        print(f"writing {args.complement}: {args.complement_samples} samples of each training window", file=sys.stderr)
        c = engine_samples(
            ds, args.model, train[:, :OBS].reshape(-1, OBS, J, 3), args.complement_samples, COMPLEMENT_SEED
        )
        np.save(
            args.complement,
            np.ascontiguousarray(c.transpose(1, 0, 2, 3, 4).reshape(len(train), -1, PRED, K), np.float32),
        )
    rivals = np.load(args.complement) if args.complement else None
    if rivals is not None and (rivals.ndim != 4 or rivals.shape[0] != len(train) or rivals.shape[2:] != (PRED, K)):
        raise SystemExit(f"--complement: shape {rivals.shape}, not ({len(train)}, C, {PRED}, {K})")
    gen = Generator(K, args.hidden, args.layers, args.z, args.coefs, args.dropout, obs_len=OBS, pred_len=PRED)
    perm = mirror_permutation(dataset_joint_names(ds.protocol))
    if args.init:
        gen.load_state_dict(torch.load(args.init))
    opt = torch.optim.Adam(gen.parameters(), lr=args.lr)
    val_obs = torch.from_numpy(cases.obs.reshape(len(cases.obs), OBS, K).astype(np.float32))
    val_prior = forecast(val_obs.numpy())

    val_z = torch.randn(len(val_obs), SAMPLES, args.z, generator=torch.Generator().manual_seed(args.seed))

    def samples(lo: int = 0, hi: int | None = None) -> np.ndarray:
        """The MLP's 50 samples of the protocol's windows lo..hi (50, W, P, J, 3), noise seeded by --seed."""
        rows = slice(lo, len(val_obs) if hi is None else hi)
        gen.eval()
        with torch.no_grad():
            s = gen(val_obs[rows], val_prior[rows], val_z[rows]).numpy().astype(np.float64)  # (W, S, P, K)
        gen.train()
        return s.transpose(1, 0, 2, 3).reshape(SAMPLES, len(s), PRED, J, 3)

    def score() -> dict:
        # a block of windows at a time: Setting-A's 4,313 windows' 50 samples are 8 GB at once (HumanEva-I's 188
        # are one block)
        return cases.score_by(lambda obs, lo: samples(lo, lo + len(obs)), block=256)

    def brief(sc: dict) -> str:
        return " ".join(f"{k} {sc[k]:.4f}" for k in ("ADE", "FDE", "MMADE", "MMFDE", "APD", "mean_ADE"))

    print(f"{len(train)} training windows, {sum(p.numel() for p in gen.parameters())} parameters", file=sys.stderr)
    rng = np.random.default_rng(0)
    t0 = last = logged = saved = time.time()
    step = 0

    def save_state() -> None:
        state = {
            "steps": args.steps,
            "step": step,
            "generator": gen.state_dict(),
            "optimizer": opt.state_dict(),
            "rng": rng.bit_generator.state,
            "torch_rng": torch.get_rng_state(),
        }
        tmp = Path(args.checkpoint).with_suffix(".tmp")
        torch.save(state, tmp)
        tmp.replace(args.checkpoint)  # atomic: a kill mid-write leaves the previous checkpoint

    if args.checkpoint and Path(args.checkpoint).is_file():
        state = torch.load(args.checkpoint, weights_only=False)
        if state["steps"] != args.steps:
            raise SystemExit(f"--checkpoint {args.checkpoint} is of a {state['steps']}-step run, not {args.steps}")
        gen.load_state_dict(state["generator"])
        opt.load_state_dict(state["optimizer"])
        rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        step = state["step"]
        print(f"resumed from {args.checkpoint} at step {step}", file=sys.stderr, flush=True)

    def progress() -> float:
        """The schedule's fraction done: of --steps, or of --minutes' clock."""
        if args.steps:
            return step / args.steps
        return (time.time() - t0) / (args.minutes * 60) if args.minutes else 1.0  # 0: no training

    while progress() < 1:
        rows = rng.integers(0, len(train), args.batch)
        speeds = np.exp(rng.uniform(*np.log(args.speed_range), args.batch)) if args.speed_range else None
        own = read(rows, speeds)
        w = own[:, None]
        if others is not None:
            w = np.concatenate(
                [
                    w,
                    np.stack(
                        [swap_futures(own, read(others[rows, j], speeds), OBS) for j in range(args.targets - 1)], 1
                    ),
                ],
                1,
            )  # (B, T, O + P, K)
        T = w.shape[1]
        if rivals is not None:  # the rival's samples after the window's observation, turned and reflected with it
            r = rivals[rows]
            w = np.concatenate([w, np.concatenate([np.repeat(own[:, None, :OBS], r.shape[1], 1), r], 2)], 1)
        if args.mirror:  # every target of a window reflected with it
            flip = np.repeat(rng.random(args.batch) < 0.5, w.shape[1])
            w = mirror(w.reshape(-1, OBS + PRED, J, 3), up, perm, flip).reshape(w.shape)
        if args.rotate:  # every target of a window turned with it
            w = rotate_about(w.reshape(args.batch, w.shape[1], OBS + PRED, J, 3), up, rng).reshape(w.shape)
        obs = np.ascontiguousarray(w[:, 0, :OBS])
        lr = args.lr * (0.1 if progress() >= 0.8 else 1.0)
        for group in opt.param_groups:
            group["lr"] = lr
        targets = torch.from_numpy(np.ascontiguousarray(w[:, :T, OBS:]))
        rival = (
            None
            if rivals is None
            else distance(
                torch.from_numpy(np.ascontiguousarray(w[:, T:, OBS:]))[:, :, None], targets[:, None], args.fde_weight
            ).amin(1)
        )  # (B, T)
        loss = imle_loss(gen, torch.from_numpy(obs), forecast(obs), targets, args.cands, args.fde_weight, rival)
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        now = time.time()
        if now - last > args.eval_every * 60:
            last = logged = now
            print(
                f"step {step} ({(now - t0) / 60:.1f} min): loss {loss.item():.4f}; {brief(score())}",
                file=sys.stderr,
                flush=True,
            )
        elif now - logged > 60:  # a progress line a minute between the scores (the recipe runner reads it)
            logged = now
            print(f"step {step} ({(now - t0) / 60:.1f} min): loss {loss.item():.4f}", file=sys.stderr, flush=True)
        if args.checkpoint and (now - saved > 60 * args.checkpoint_minutes or step == args.stop_after_steps):
            saved = now
            save_state()
        if step == args.stop_after_steps:
            print(f"stopped after step {step} of {args.steps}: resume with the same --checkpoint", file=sys.stderr)
            return 0
    minutes = (time.time() - t0) / 60
    sc = alone = score()
    print(f"final, step {step} ({minutes:.1f} min): {brief(sc)}", file=sys.stderr)
    method = "IMLE MLP generator around the prior (training/generator_imle.py)"
    if args.mix:  # the engine's first MIX samples as the protocol's evaluation draws them, then the MLP's
        theirs = engine_samples(ds, args.model, cases.obs, SAMPLES, args.seed)[: args.mix]
        sc = cases.score(np.concatenate([theirs, samples()[: SAMPLES - args.mix]]))
        method = (
            f"{args.mix} samples of {Path(args.model).name} (the engine, DDIM-1) and {SAMPLES - args.mix} "
            f"of an {method}"
        )
        print(f"mixture with {args.mix} of the model's: {brief(sc)}", file=sys.stderr)
    out = {
        "method": method,
        "protocol": cases.protocol(),
        "options": {
            k: v
            for k, v in vars(args).items()
            if k not in ("json", "save", "checkpoint", "checkpoint_minutes", "stop_after_steps")
        },
        "seeds": {"sampling": args.seed},
        "steps": step,
        "minutes": minutes,
        "stochastic": sc,
        "model": sc,
        "per_action": cases.per_action(sc),
        **({"generator_alone": alone} if args.mix else {}),
    }
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=1))
    if args.save:
        torch.save(gen.state_dict(), args.save)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
