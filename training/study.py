"""What learns most per CPU-minute (issue 29, part 2): recipes of the long-term model compared at equal CPU
work on this CPU.

Every candidate is a long-term model (55 given frames -> 20 predicted, the cascade's second stage) trained
by ``training.train`` from its config in ``training/configs/study_*.json`` for the same number of
training windows per unit of forward cost (a step count: wall-clock under a shared CPU is not a fair
budget). It is then scored without the short-term model, which would add a second model's training to
every candidate: the long model is conditioned on the 50 observed frames of the S5 protocol windows
followed by the prior forecaster's first 5 frames (mask 1), the prior standing in for the short-term
model. No ground-truth future is given to any candidate.

    python -m training.study eval runs/study/<name> [--windows-per-action 8] [--samples 5] [--steps 10]
    python -m training.study table runs/study/*/study_eval.json

The errors are the protocol's (32-joint mean, mm) at 80 ... 1000 ms: the mean of the samples (deployable)
and the oracle best of them, beside the prior alone and Zero-Velocity on the same windows.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from .data.h36m import DEFAULT_DATA_ROOT, H36M, model_to_xyz32
from .evaluate import OBS, PRED, from_bkl, protocol_windows, summarize, to_bkl, zero_velocity
from .metrics import oracle_best, per_frame_error

GIVEN = 55   # frames the long-term model is conditioned on: 50 observed + 5 from the stage before


def load_run(run: Path):
    """(model with its prior attached, schedule, train config dict, checkpoint) of a training run."""
    from .diffusion import DiffusionConfig, Schedule
    from .export import checkpoint_weights
    from .model import ModelConfig, TCDModel
    from .train import load_prior
    ck = torch.load(run / "last.pt", map_location="cpu", weights_only=False)
    tc = ck["train_config"]
    mcfg, dcfg = ModelConfig.from_dict(tc["model"]), DiffusionConfig.from_dict(tc["diffusion"])
    model = TCDModel(mcfg, dcfg.num_train_timesteps)
    model.load_state_dict(checkpoint_weights(ck))
    if mcfg.cond_fill == "prior":
        model.attach_prior(load_prior(tc["prior"]))
    return model.eval(), Schedule(dcfg), tc, ck


def evaluate_run(run: Path, prior_path: str, *, windows_per_action: int, samples: int, steps: int, seed: int,
                 data: str | None = None, batch_size: int = 32) -> dict:
    from .channels_last import ChannelsLast
    from .diffusion import sample_many
    from .train import load_prior
    model, sched, tc, ck = load_run(run)
    forward = ChannelsLast(model)    # the same network (within 1e-5), about 2x faster on the CPU
    if tc["obs_len"] != GIVEN or tc["obs_len"] + tc["pred_len"] != OBS + PRED:
        raise ValueError(f"{run}: a study candidate is a long-term model ({GIVEN} + {OBS + PRED - GIVEN} frames), "
                         f"got {tc['obs_len']} + {tc['pred_len']}")
    prior = load_prior(prior_path)
    h = H36M(data or DEFAULT_DATA_ROOT / "h36m")
    best, mean, point, zv = {}, {}, {}, {}
    t0 = time.time()
    for ai, action in enumerate(h.test_actions()):
        gt32, _, obs, jmask = protocol_windows(h, action, ai, windows_per_action, "none", 0)
        W, _, J, _ = obs.shape
        with torch.no_grad():
            fut = prior.rollout(torch.from_numpy(obs.reshape(W, OBS, J * 3)).float(), PRED)   # (W, 25, K)
        pf = fut.double().numpy().reshape(W, PRED, J, 3)
        point[action] = per_frame_error(model_to_xyz32(pf, gt32), gt32).mean(axis=0)
        zv[action] = per_frame_error(model_to_xyz32(zero_velocity(obs, jmask), gt32), gt32).mean(axis=0)
        given = np.concatenate([obs, pf[:, :GIVEN - OBS]], axis=1)                              # (W, 55, J, 3)
        outs = []
        for b0 in range(0, W, batch_size):
            g = torch.Generator().manual_seed(seed * 1_000_003 + ai * 1009 + b0)
            x = to_bkl(np.concatenate([given[b0:b0 + batch_size],
                                       np.zeros((len(given[b0:b0 + batch_size]), OBS + PRED - GIVEN, J, 3))], axis=1))
            m = torch.zeros_like(x)
            m[..., :GIVEN] = 1.0
            s = sample_many(forward, sched, x, m, samples, generator=g, sampler="ddim", num_inference_steps=steps)
            outs.append(from_bkl(s[..., OBS:]))
        smp = np.concatenate(outs, axis=1)                                                      # (S, W, 25, J, 3)
        errs = np.stack([per_frame_error(model_to_xyz32(s, gt32), gt32) for s in smp])          # (S, W, 25)
        best[action] = oracle_best(errs).mean(axis=0)
        mean[action] = per_frame_error(model_to_xyz32(smp.mean(axis=0), gt32), gt32).mean(axis=0)
        print(f"[{ai + 1}] {action}: {time.time() - t0:.0f} s", file=sys.stderr)
    hist = ck.get("history", [])
    return {"run": str(run), "train_config": tc, "step": ck.get("step"), "elapsed_s": ck.get("elapsed_s"),
            "windows_seen": ck.get("step", 0) * tc["batch_size"], "last_val": hist[-1] if hist else None,
            "protocol": {"subject": "S5", "windows_per_action": windows_per_action, "samples": samples,
                         "sampler": f"ddim-{steps}", "seed": seed, "given": "50 observed + the prior's first 5 frames"},
            "mean_of_n": summarize(mean)["average"], "best_of_n": summarize(best)["average"],
            "prior": summarize(point)["average"], "zero_velocity": summarize(zv)["average"]}


def table(paths: list[str]) -> str:
    rows = [json.loads(Path(p).read_text()) for p in paths]
    hz = list(rows[0]["zero_velocity"])
    head = "| candidate | windows seen | wall min | " + " | ".join(f"{h} ms mean / best" for h in hz[-3:]) + " |"
    lines = [head, "|" + "---|" * (3 + 3)]
    for r in rows:
        cells = " | ".join(f"{r['mean_of_n'][h]:.1f} / {r['best_of_n'][h]:.1f}" for h in hz[-3:])
        lines.append(f"| {Path(r['run']).name} | {r['windows_seen']:,} | {r['elapsed_s'] / 60:.0f} | {cells} |")
    r = rows[0]
    lines.append("| prior alone | | | " + " | ".join(f"{r['prior'][h]:.1f}" for h in hz[-3:]) + " |")
    lines.append("| Zero-Velocity | | | " + " | ".join(f"{r['zero_velocity'][h]:.1f}" for h in hz[-3:]) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.study", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("eval", help="score one candidate run")
    e.add_argument("run")
    e.add_argument("--prior", default="python/tcd/weights/prior.safetensors",
                   help="the prior standing in for the short-term model (prior.safetensors or a prior last.pt)")
    e.add_argument("--windows-per-action", type=int, default=8)
    e.add_argument("--samples", type=int, default=5)
    e.add_argument("--steps", type=int, default=10, help="DDIM steps")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--data", default=None)
    t = sub.add_parser("table", help="the markdown table of scored candidates")
    t.add_argument("evals", nargs="+")
    args = ap.parse_args(argv)
    if args.cmd == "table":
        print(table(args.evals))
        return 0
    torch.set_num_threads(1)
    run = Path(args.run)
    out = evaluate_run(run, args.prior, windows_per_action=args.windows_per_action, samples=args.samples,
                       steps=args.steps, seed=args.seed, data=args.data)
    (run / "study_eval.json").write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps({k: out[k] for k in ("mean_of_n", "best_of_n", "prior", "zero_velocity")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
