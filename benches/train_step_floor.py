"""The floor of one training step and of one sampling forward, counted on the CPU: FLOPs and the bytes the
operations move, per window, and the windows/s those allow on a GPU (the device method's "two numbers
first"); from the forwards, the minutes of the whole evaluation protocol at each floor.

    python benches/train_step_floor.py [--roles long short repair] [--batch 2] [--json OUT]

One step of ``training.train.train_step`` (forward through the channels-last forward, masked eps loss,
backward, Adam, EMA update) for each role's window at the paper's size (12 x 64), traced operation by
operation under a ``TorchDispatchMode``:

* FLOPs: ``torch.utils.flop_counter.FlopCounterMode`` (matrix products and attention, forward and backward);
* bytes, unfused: each ATen operation reads its tensor inputs once and writes its outputs once (views
  move nothing); what eager PyTorch moves at best;
* bytes, fused: only the operations no compiler fuses away (matrix products, attention, normalisation,
  the optimizer's and EMA's reads and writes of the parameters); elementwise operations are assumed to
  run inside their neighbours. What a perfectly fused step would still move.

Bytes are counted at the precision of each tensor as run here (fp32); the bf16 floors halve the bytes of
the matrix products and attention (what bf16 autocast casts) and keep everything else at fp32. Attention
is traced as the fused kernel a GPU runs (see ``trace``). The per-window cost is a slope: the step is
traced at ``--batch`` and at 1 and the difference divided by B - 1, so the parameters' fixed cost per
step (optimizer, EMA) is reported apart.

The GPU rates are the device machine's measured ceilings (KINDS.md, H100: 798 TFLOP/s bf16 matrix
products on random data, 3.0 TB/s device-to-device copy counting bytes read and written). The floor
time is the larger of FLOPs / rate and bytes / bandwidth; no implementation runs much faster.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten
from torch.utils.flop_counter import FlopCounterMode, flop_registry

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from training.batches import DeviceBatchSource, Windows  # noqa: E402
from training.diffusion import DiffusionConfig, Schedule  # noqa: E402
from training.export import PRESETS  # noqa: E402
from training.model import ModelConfig, TCDModel  # noqa: E402
from training.throughput import synthetic_sequences  # noqa: E402
from training.train import TrainConfig, make_ema, make_optimizer, train_step, training_forward  # noqa: E402

H100 = {"bf16_flops": 798e12, "bytes_per_s": 3.0e12, "memory_bytes": 81559 * 2 ** 20,
        "source": "KINDS.md, nvidia-h100-x1, seen 2026-11-13"}
# of the device memory, what saved activations may take: the rest for the CUDA context, the backward's
# transient buffers and the caching allocator's slack (a margin, not a measurement)
MEMORY_SHARE = 0.85
# operations no compiler fuses into a neighbour: their inputs and outputs cross device memory
UNFUSABLE = ("mm", "bmm", "addmm", "_scaled_dot_product", "native_layer_norm", "_foreach", "_fused_adam",
             "embedding")
MATMUL_ATTENTION = ("mm", "bmm", "addmm", "_scaled_dot_product")
_aten = torch.ops.aten


def _as_raw(counted):
    """A registry formula (already taking shapes) passed as a custom mapping: marked raw, so that
    FlopCounterMode does not wrap it a second time."""
    def formula(*args, **kwargs):
        return counted(*args, **kwargs)
    formula._get_raw = True
    return formula


# The fused CPU attention kernel traced below has no FLOP formula in older PyTorch (2.11, the GPU machine's
# version, counts none): give it the GPU flash kernel's, whose leading arguments are the same.
CPU_ATTENTION_FLOPS = {} if _aten._scaled_dot_product_flash_attention_for_cpu in flop_registry else {
    _aten._scaled_dot_product_flash_attention_for_cpu:
        _as_raw(flop_registry[_aten._scaled_dot_product_flash_attention]),
    _aten._scaled_dot_product_flash_attention_for_cpu_backward:
        _as_raw(flop_registry[_aten._scaled_dot_product_flash_attention_backward])}


def _bytes(t: torch.Tensor) -> int:
    return min(t.numel() * t.element_size(), t.untyped_storage().nbytes())


class ByteCounter(TorchDispatchMode):
    """Bytes read and written per ATen operation (views and aliases excluded)."""

    def __init__(self):
        super().__init__()
        self.by_op = defaultdict(int)

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        ins = [a for a in tree_flatten((args, kwargs or {}))[0] if isinstance(a, torch.Tensor)]
        outs = [o for o in tree_flatten(out)[0] if isinstance(o, torch.Tensor)]
        in_ptrs = {a.untyped_storage().data_ptr() for a in ins}
        if outs and all(o.untyped_storage().data_ptr() in in_ptrs for o in outs) and func._schema.is_mutable is False:
            return out                                   # a view or alias: nothing moves
        self.by_op[str(func.overloadpacket.__name__)] += sum(map(_bytes, ins)) + sum(map(_bytes, outs))
        return out


def _step(role: str, batch: int, preset: str, inference: bool, amp: bool = False):
    """(model, step, L): one training step of ``batch`` windows as ``training.train`` runs it (eager, batches on
    the device, Adam and the EMA, ``amp``: bf16 autocast), Adam's state already made; or with ``inference``
    one forward of the denoiser in eval mode (what a sampler calls once per step and sample)."""
    cfg = TrainConfig.load(ROOT / "training" / "configs" / f"{role}.json")
    cfg = replace(cfg, model={**PRESETS[preset].to_dict(), **cfg.model}, batch_size=batch, ema_decay=0.999,
                  batches="device", compile=False, amp=amp)
    model_cfg = ModelConfig.from_dict(cfg.model)
    diff_cfg = DiffusionConfig.from_dict(cfg.diffusion)
    L = cfg.obs_len + cfg.pred_len
    torch.manual_seed(0)
    model = TCDModel(model_cfg, diff_cfg.num_train_timesteps).train()
    sched = Schedule(diff_cfg)
    opt = make_optimizer(model, cfg, "cpu")
    ema = make_ema(model, cfg)
    forward = training_forward(model, cfg, (batch, model_cfg.num_features, L), "cpu", lambda *a: None)
    source = DeviceBatchSource(cfg, Windows(synthetic_sequences(), L, cfg.train_stride), sched.T, 10 ** 9,
                               torch.device("cpu"))
    if inference:
        model.eval()
        x0, observed, mask, t, _ = source.batch(0, 0)
        return model, lambda: forward(x0, observed, mask, t), L
    train_step(forward, opt, sched, source.batch(0, 0), amp)        # Adam's state exists from here on
    ema.update(model)
    b = source.batch(0, 1)

    def step():
        train_step(forward, opt, sched, b, amp)
        ema.update(model)
    return model, step, L


@contextmanager
def fused_attention():
    """A GPU runs attention with dropout as one fused kernel (flash / memory-efficient: the mask drawn inside,
    the L x L scores never stored); the CPU falls back to the unfused math for dropout > 0. Inside this,
    the fused CPU kernel runs instead (dropout 0 inside attention only): its reads, writes and saved
    tensors are the GPU kernel's."""
    sdpa = torch.nn.functional.scaled_dot_product_attention
    torch.nn.functional.scaled_dot_product_attention = lambda q, k, v, dropout_p=0.0, **kw: sdpa(q, k, v, **kw)
    try:
        yield
    finally:
        torch.nn.functional.scaled_dot_product_attention = sdpa


def saved_bytes(role: str, batch: int, preset: str = "full", amp: bool = False) -> int:
    """Bytes of what one training step keeps for its backward: the storages autograd saves in the forward,
    parameters excluded, attention as the fused kernel. Device memory must hold them at the end of the
    forward, so they bound the batch; eager (a compiled step recomputes some elementwise results instead)
    and without the backward's transient buffers."""
    model, step, _ = _step(role, batch, preset, False, amp)
    params = {p.untyped_storage().data_ptr() for p in model.parameters()}
    seen = {}

    def pack(t):
        seen[t.untyped_storage().data_ptr()] = t.untyped_storage().nbytes()
        return t
    with fused_attention(), torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
        step()
    return sum(n for ptr, n in seen.items() if ptr not in params)


def trace(role: str, batch: int, preset: str = "full", inference: bool = False) -> dict:
    """FLOPs and bytes of one training step of ``batch`` windows, or with ``inference`` of one forward of
    the denoiser in eval mode on ``batch`` windows (what a sampler calls once per step and sample)."""
    _, step, L = _step(role, batch, preset, inference)
    flops, counter = FlopCounterMode(display=False, custom_mapping=CPU_ATTENTION_FLOPS), ByteCounter()
    with fused_attention(), flops, counter, torch.set_grad_enabled(not inference):
        step()
    by_op = dict(counter.by_op)
    return {"seq_len": L, "flops": flops.get_total_flops(), "bytes_unfused": sum(by_op.values()),
            "bytes_fused": sum(v for k, v in by_op.items() if k.startswith(UNFUSABLE)),
            "bytes_matmul_attention": sum(v for k, v in by_op.items() if k.startswith(MATMUL_ATTENTION)),
            "by_op": by_op}


def floor(role: str, batch: int, preset: str = "full", inference: bool = False) -> dict:
    big, one = trace(role, batch, preset, inference), trace(role, 1, preset, inference)
    keys = ("flops", "bytes_unfused", "bytes_fused", "bytes_matmul_attention")
    per = {k: (big[k] - one[k]) / (batch - 1) for k in keys}
    out = {"role": role, "seq_len": big["seq_len"], "per_window": per,
           "fixed_per_step": {k: one[k] - per[k] for k in keys}, "floors": {}}
    t_flop = per["flops"] / H100["bf16_flops"]
    for precision in ("fp32", "bf16"):
        # bf16 autocast: the matrix products and attention read and write bf16 (half the bytes); the
        # normalisations and elementwise operations are counted as fp32 (conservative)
        cut = per["bytes_matmul_attention"] / 2 if precision == "bf16" else 0.0
        for kind in ("unfused", "fused"):
            t_bytes = (per[f"bytes_{kind}"] - cut) / H100["bytes_per_s"]
            out["floors"][f"{precision}_{kind}"] = {"windows_per_s": 1.0 / max(t_flop, t_bytes),
                                                    "bound": "bytes" if t_bytes > t_flop else "flops"}
    if not inference:
        # bf16: CPU autocast, whose bf16 operation list is close to CUDA's, not equal
        saved = {precision: (saved_bytes(role, batch, preset, amp) - saved_bytes(role, 1, preset, amp)) / (batch - 1)
                 for precision, amp in (("fp32", False), ("bf16", True))}
        out["saved_per_window"] = saved
        out["largest_batch_h100"] = {k: int(MEMORY_SHARE * H100["memory_bytes"] // v) for k, v in saved.items()}
    out["top_ops_bytes"] = sorted(((k, (big["by_op"][k] - one["by_op"].get(k, 0)) / (batch - 1))
                                   for k in big["by_op"]), key=lambda kv: -kv[1])[:12]
    return out


def protocol_minutes(forwards: list[dict], windows: int = 13 * 256, samples: int = 5, steps: int = 50) -> dict:
    """Minutes of training.protocol's whole evaluation at each floor (short + long forwards for each of the
    5 forecast parts, the repair forward for each of the 4 repair parts); {} unless all three roles ran."""
    by_role = {r["role"]: r["floors"] for r in forwards}
    if set(by_role) != {"short", "long", "repair"}:
        return {}
    calls = windows * samples * steps
    return {kind: calls / 60 * (5 * sum(1 / by_role[r][kind]["windows_per_s"] for r in ("short", "long"))
                                + 4 / by_role["repair"][kind]["windows_per_s"])
            for kind in by_role["long"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--roles", nargs="+", choices=["short", "long", "repair"], default=["long", "short", "repair"])
    ap.add_argument("--batch", type=int, default=2)
    ap.add_argument("--preset", choices=sorted(PRESETS), default="full")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    if args.batch < 2:
        ap.error("--batch must be >= 2 (the per-window cost is a slope)")
    results = {"train_step": [floor(r, args.batch, args.preset) for r in args.roles],
               "forward": [floor(r, args.batch, args.preset, inference=True) for r in args.roles]}
    for what, rows in results.items():
        unit = "window" if what == "train_step" else "window-sample"
        print(f"\n{what.replace('_', ' ')}: per {unit}, floors in {unit}s/s on the H100")
        print("| role (L) | GFLOP | MB unfused | MB fused | fp32: unfused / fused | bf16: unfused / fused |")
        print("|---|---|---|---|---|---|")
        for r in rows:
            p, f = r["per_window"], r["floors"]
            print(f"| {r['role']} ({r['seq_len']}) | {p['flops'] / 1e9:.1f} | {p['bytes_unfused'] / 1e6:,.0f} | "
                  f"{p['bytes_fused'] / 1e6:,.0f} | {f['fp32_unfused']['windows_per_s']:,.0f} / "
                  f"{f['fp32_fused']['windows_per_s']:,.0f} | {f['bf16_unfused']['windows_per_s']:,.0f} / "
                  f"{f['bf16_fused']['windows_per_s']:,.0f} |")
    print("\nactivations a training step saves for its backward (eager, attention fused), per window, and the "
          f"largest batch whose activations fit {MEMORY_SHARE:.0%} of the H100's memory:")
    for r in results["train_step"]:
        saved, big = r["saved_per_window"], r["largest_batch_h100"]
        print(f"  {r['role']} (L = {r['seq_len']}): fp32 {saved['fp32'] / 2 ** 20:,.0f} MiB (batch <= {big['fp32']}), "
              f"bf16 {saved['bf16'] / 2 ** 20:,.0f} MiB (batch <= {big['bf16']})")
    protocol = protocol_minutes(results["forward"])
    if protocol:
        print("\nthe evaluation protocol (training.protocol: 3,328 windows x 5 samples x 50 steps; 5 forecast and "
              "4 repair parts), minutes at the floor: " + ", ".join(f"{k} {v:.0f}" for k, v in protocol.items()))
    if args.json:
        Path(args.json).write_text(json.dumps({"gpu": H100, "batch": args.batch, "preset": args.preset, "torch": torch.__version__,
                                               "command": " ".join(["python benches/train_step_floor.py"] + (argv or sys.argv[1:])),
                                               "protocol_minutes_at_floor": protocol, **results}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
