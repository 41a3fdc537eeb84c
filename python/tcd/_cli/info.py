"""``tcd info``: describe a model directory."""

from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Any, List

from ..engine import supported_kernels
from .._cascade import as_dict
from .common import EXIT_OK, add_model_flag, load_model


def add_parser(sub: Any) -> argparse.ArgumentParser:
    p = sub.add_parser("info", help="describe a model directory")
    add_model_flag(p)
    p.add_argument("--json", action="store_true", help="print the full configuration as JSON")
    return p


def run(args: argparse.Namespace) -> int:
    m = load_model(args.model)
    if args.json:
        print(
            json.dumps(
                {
                    "path": str(m.path),
                    "obs_len": m.obs_len,
                    "horizon": m.horizon,
                    "num_joints": m.num_joints,
                    "sampling": {t: dataclasses.asdict(o) for t, o in m.sampling.items()},
                    "forecast_mode": as_dict(m.forecast_mode),
                    "config": m.config,
                },
                indent=2,
            )
        )
        return EXIT_OK
    data = m.data
    lines: List[str] = [
        f"model directory: {m.path}",
        f"observed frames (obs_len): {m.obs_len}",
        f"forecast frames (horizon): {m.horizon}",
        f"joints: {m.num_joints}" + (f" ({', '.join(m.joint_names)})" if m.joint_names else ""),
        f"fps: {data.get('fps', 'unknown')}",
        f"units: {data.get('units', 'unknown')}, root-relative: {data.get('root_relative', 'unknown')}",
        f"dataset: {data.get('dataset', 'unknown')}; training data: {data.get('training_data', 'unknown')}",
    ]
    for role, d in (("short", m.short), ("long", m.long), ("repair", m.repair_model)):
        if d is None:
            lines.append(f"{role}: none")
            continue
        c = d.config
        mc, diff = c.get("model", {}), c.get("diffusion", {})
        lines.append(
            f"{role}: window {d.obs_len} + {d.pred_len} frames, channels {mc.get('channels')}, "
            f"layers {mc.get('num_layers')}, heads {mc.get('num_heads')}, "
            f"T = {d.num_train_timesteps} ({diff.get('beta_schedule')})"
            + ("" if mc.get("cond_fill", "zero") == "zero" else f", conditioning {mc['cond_fill']}-filled")
            + (
                ""
                if mc.get("target", "absolute") == "absolute"
                else f", target {mc['target']} (scale {mc.get('target_scale', 1.0):g})"
            )
        )
    for task, o in m.sampling.items() if m.short is not None else ():  # a generator directory runs no sampler
        lines.append(f"default sampler, {task}: {o.describe(m.num_train_timesteps)}")
    lines.append(f"default forecast mode: {m.forecast_mode.describe()}")
    g = m.generator
    lines.append(
        "generator: none"
        if g is None
        else f"generator: MLP {g.layers} x {g.hidden}, z {g.z_dim}, {g.coefs} DCT coefficients around the prior "
        "(tcd.Mixture draws from it)"
    )
    lines.append(f"kernels: {m._front.kernel} (this CPU supports: {', '.join(supported_kernels())})")
    print("\n".join(lines))
    return EXIT_OK
