"""Two learned fills against the natural cubic spline, on benches/repair_quality.py's windows (issue 29, point 4).

    python benches/repair_learned_fills.py [--minutes 12] [--blocks 24] [--lr 3e-4] [--lr-final LR] [--windows 32]
                                           [--seed 0] [--threads 1] [--json OUT]

The bundled repair model fills 5 to 7 % worse than the spline it is conditioned on (docs/repair.md), so before
another diffusion repair model is trained this asks whether anything cheap learns a better fill than the spline
on this CPU:

* ``bidirectional prior``: for the consecutive-frames pattern only (every joint hidden over one block of frames),
  the bundled prior forecaster (``prior.safetensors``) run forward from the frames before the gap and backward
  (on the time-reversed frames after it: the prior was trained with time flips) from the frames after it, each
  history padded at its start by repeating its first frame to the prior's 50; each forecast corrected linearly
  so that it meets the observed frame at the gap's far end; the two blended with weights linear in time; and
  that blend averaged with the spline;
* ``learned residual``: a siMLPe-class network (``training.prior``'s DCT, temporal-FC and layer-norm blocks)
  over the whole 50-frame window, spline-filled, that outputs a residual added to the spline, trained for
  ``--minutes`` of wall clock on the training subjects' windows (batch 256, Adam at ``--lr``, dropped to
  ``--lr-final`` for the last quarter of the minutes when given, as siMLPe does; time flips) under the bundled
  repair model's mask mix (``training/configs/cpu_repair_spline_ft.json``), with the loss the mean per-joint
  L2 distance over the hidden entries. It does not see the mask.

Each is scored like the repair benchmark: ADE (mm) over the hidden entries, the same seeded S5 windows and masks
(``--windows``, ``--seed``), beside linear interpolation and the spline. Needs torch, scipy and the Human3.6M data.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import repair_quality as rq  # noqa: E402

from training import masks  # noqa: E402

L, J = 50, 22
K = 3 * J


def pad_history(h: np.ndarray) -> np.ndarray:
    """(t, K) -> the prior's (L, K) history: the last L frames, or the first frame repeated before them."""
    return h[-L:] if len(h) >= L else np.concatenate([np.repeat(h[:1], L - len(h), 0), h], 0)


def bidirectional_fill(prior, gt: np.ndarray, m: np.ndarray, spline: np.ndarray) -> dict:
    """The consecutive-frames gap of each window filled from the prior's forward and backward forecasts."""
    blend, mixed = spline.copy(), spline.copy()
    for b in range(len(gt)):
        gap = np.where(~m[b].any(-1))[0]
        s, e = int(gap[0]), int(gap[-1]) + 1
        n, x = e - s, gt[b].reshape(L, K)
        w = ((np.arange(n) + 1) / (n + 1))[:, None]
        fwd = bwd = None
        if s > 0:  # forward from the frames before the gap, meeting frame e
            f = prior.predict(pad_history(x[:s])[None], n + 1)[0]
            fwd = f[:n] + w * (x[e] - f[n]) if e < L else f[:n]
        if e < L:  # backward from the frames after it, meeting frame s - 1
            r = prior.predict(pad_history(x[e:][::-1].copy())[None], n + 1)[0]
            bwd = (r[:n] + w * (x[s - 1] - r[n]) if s > 0 else r[:n])[::-1]
        fwd = bwd if fwd is None else fwd
        bwd = fwd if bwd is None else bwd
        both = ((1 - w) * fwd + w * bwd).reshape(n, J, 3)
        blend[b, s:e] = both
        mixed[b, s:e] = 0.5 * (both + spline[b, s:e])
    return {"prior forward + backward": blend, "prior forward + backward, averaged with the spline": mixed}


def learned_residual(args) -> tuple:
    """Trains the residual network for ``args.minutes``; returns (fill function, training log)."""
    import torch
    from torch import nn

    from training.model import spline_fill
    from training.prior import PriorConfig, PriorNet, training_frames

    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    cfg_path = Path(__file__).resolve().parents[1] / "training/configs/cpu_repair_spline_ft.json"
    mix = [masks.mix_entry(e) for e in json.loads(cfg_path.read_text())["mask_mix"]]
    weights = np.array([w for _, w, _ in mix]) / sum(w for _, w, _ in mix)

    class Residual(nn.Module):
        """The prior's network over the whole window (chunk = obs_len = L), its output a residual over the spline
        fill instead of over the last frame; it starts as the spline (the prior's output layer starts at zero)."""

        def __init__(self):
            super().__init__()
            self.net = PriorNet(PriorConfig(obs_len=L, chunk=L, blocks=args.blocks))

        def forward(self, fill):  # (B, L, K)
            return self.net(fill) - fill[:, -1:] + fill

    def filled(x, joint_mask):  # (B, L, K), (B, L, J) -> spline fill
        mc = joint_mask.repeat_interleave(3, -1).transpose(1, 2)
        return spline_fill(x.transpose(1, 2), mc).transpose(1, 2)

    frames, starts = training_frames(PriorConfig(obs_len=L, chunk=1, blocks=1))
    net = Residual()
    opt = torch.optim.Adam(net.parameters(), lr=args.lr, weight_decay=1e-4)
    log, it, t0, run = [], 0, time.time(), []
    while time.time() - t0 < 60 * args.minutes:
        if args.lr_final is not None and time.time() - t0 > 45 * args.minutes:  # the last quarter
            for group in opt.param_groups:
                group["lr"] = args.lr_final
        rng = np.random.default_rng([args.seed, it])
        wins = frames[starts[rng.integers(0, len(starts), 256)][:, None] + np.arange(L)]
        flip = rng.random(256) < 0.5
        wins[flip] = wins[flip, ::-1]
        m = np.stack(
            [masks.make_mask(mix[p][0], L, L, rng, rate=mix[p][2]) for p in rng.choice(len(mix), 256, p=weights)]
        )
        x, mj = torch.from_numpy(np.ascontiguousarray(wins)), torch.from_numpy(m)
        err = torch.linalg.vector_norm((net(filled(x, mj)) - x).reshape(-1, L, J, 3), dim=-1)
        loss = (err * (1 - mj)).sum() / (1 - mj).sum().clamp(min=1)
        opt.zero_grad()
        loss.backward()
        opt.step()
        it += 1
        run.append(loss.item())
        if it % 200 == 0:
            log.append({"iteration": it, "loss_mm": 1000 * float(np.mean(run)), "minutes": (time.time() - t0) / 60})
            print(f"iteration {it}: hidden-entry loss {log[-1]['loss_mm']:.2f} mm", file=sys.stderr, flush=True)
            run = []
    net.eval()

    def fill(obs, m):
        with torch.no_grad():
            x = torch.from_numpy(np.nan_to_num(obs).reshape(len(obs), L, K).astype(np.float32))
            out = net(filled(x, torch.from_numpy(m.astype(np.float32)))).numpy().reshape(obs.shape)
        return np.where(np.repeat(m[..., None], 3, -1), obs, out)

    return fill, {"iterations": it, "windows": 256 * it, "log": log}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=12.0, help="training wall clock of the learned residual")
    ap.add_argument("--blocks", type=int, default=24)
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument(
        "--lr-final",
        type=float,
        default=None,
        help="the learning rate of the last quarter of the minutes (default: --lr throughout)",
    )
    ap.add_argument("--windows", type=int, default=32, help="benchmark windows per pattern (repair_quality's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--data-dir", default=str(rq.h36m.DEFAULT_H36M_DIR))
    ap.add_argument("--json", default=None, metavar="OUT")
    args = ap.parse_args(argv)
    from tcd.engine import Prior

    gt = rq.draw_windows(args.windows, L, args.seed, Path(args.data_dir))
    cases = list(rq.masked_cases(gt, args.seed))
    prior = Prior.load(Path(rq.tcd.default_model_dir()) / "prior.safetensors")
    fill, training = learned_residual(args)
    rows = []
    for label, pattern, m, obs in cases:
        spline = rq.spline_fill(obs, m)
        fills = {"linear": rq.linear_fill(obs, m), "spline": spline, "learned residual over the spline": fill(obs, m)}
        if pattern == "consecutive_frames":
            fills.update(bidirectional_fill(prior, gt, m, spline))
        row = {"pattern": label, **{k: rq.ade_mm(v, gt, m) for k, v in fills.items()}}
        rows.append(row)
        print(f"{label}: " + ", ".join(f"{k} {v:.2f} mm" for k, v in row.items() if k != "pattern"), file=sys.stderr)
    print("\n| occlusion | fill | ADE (mm) | × linear | × spline |\n|---|---|---|---|---|")
    for row in rows:
        for k, v in row.items():
            if k != "pattern":
                print(f"| {row['pattern']} | {k} | {v:.2f} | {v / row['linear']:.2f} | {v / row['spline']:.2f} |")
    if args.json:
        out = {
            "settings": {k: v for k, v in vars(args).items() if k != "json"},
            "training": training,
            "results": rows,
            "command": " ".join(["python", *sys.argv]),
        }
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
