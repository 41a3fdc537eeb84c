"""The MLP sample generator (issue 31): forecast samples around the prior's forecast, one MLP forward each.

The HumanEva-I model of the DLow / GSPS protocol scores the best of 50 samples. The bundled TCD transformer,
sampled with one DDIM step, and this generator miss different windows (MODEL_CARD.md, "Half the samples from the
MLP"), so the bundled directory draws half its samples from each. The generator::

    past  = DCT_O(obs - last)                   (O, K): the observation's O DCT coefficients, relative to its last pose
    ahead = DCT_P(prior - last)[:C]             (C, K): the first C of the prior's P-frame forecast's
    y     = head(GELU(W_n ... GELU(W_1 [past, ahead, z])))   z ~ N(0, I) of z_dim, one per sample
    out   = prior + IDCT_P(y)                   y (C, K): the first C DCT coefficients of a residual

Its head starts at zero, so the untrained generator is the prior. It is trained with IMLE (Li and Malik 2018) by
``training/generator_imle.py``: each window's targets pull the nearest of its candidates' samples.

Its file, ``generator.safetensors`` in a model directory, holds the MLP's tensors ``layers.{i}.weight`` /
``layers.{i}.bias`` (i < layers) and ``head.weight`` / ``head.bias`` (PyTorch's (out, in) layout; the DCT is no
tensor: the engine computes it) and the config::

    {"format_version": 1, "role": "generator",
     "model": {num_joints, coords, num_features, obs_len, pred_len, hidden, layers, z_dim, coefs},
     "data": {...}, "training": {...}, "source_revision"}

The Rust engine runs it (``tcd.engine.Generator``), its noise from its own seeded streams (stage
``tcd.engine.STAGE_GENERATOR``); ``tests/test_generator_parity.py`` checks the two agree.

    python -m training.generator --state-dict runs/he_mlp/stageC.pt --out models/humaneva \\
        --description "IMLE, 7,149 steps, training/generator_imle.py"
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch
from torch import nn

from .data.humaneva import HUMANEVA_T_HIS, HUMANEVA_T_PRED
from . import fileformat  # source_revision through the module: tests fix it in one place
from .fileformat import (
    CONFIG_KEY,
    FORMAT_VERSION,
    GENERATOR_FILE,
    GENERATOR_ROLE,
    data_meta,
    read_config,
)
from .prior_net import dct_matrix

#: the bundled HumanEva-I generator's sizes: hidden width, hidden layers, noise values, DCT coefficients (the
#: defaults of ``training/generator_imle.py`` and of this module's command line)
HIDDEN, LAYERS, Z_DIM, COEFS = 768, 3, 64, 20


class Generator(nn.Module):
    """(obs (B, O, K), the prior's forecast (B, P, K), z (B, S, Z)) -> S forecasts (B, S, P, K).

    ``body`` is [Linear, GELU, (Dropout, Linear, GELU) x (layers - 1)] (a Dropout is the identity at 0 and in
    eval()); its Linears are the file's ``layers.{i}``."""

    def __init__(
        self,
        coords: int,
        hidden: int,
        layers: int,
        z_dim: int,
        coefs: int,
        dropout: float = 0.0,
        obs_len: int = HUMANEVA_T_HIS,
        pred_len: int = HUMANEVA_T_PRED,
    ):
        super().__init__()
        if not 1 <= coefs <= pred_len or min(coords, hidden, layers, z_dim, obs_len) < 1:
            raise ValueError(
                f"Generator: sizes must be >= 1 and coefs <= pred_len, got coords {coords}, hidden "
                f"{hidden}, layers {layers}, z_dim {z_dim}, coefs {coefs}, obs_len {obs_len}, "
                f"pred_len {pred_len}"
            )
        self.coords, self.hidden, self.z_dim, self.coefs = coords, hidden, z_dim, coefs
        self.obs_len, self.pred_len = obs_len, pred_len
        self.register_buffer("dct_obs", torch.from_numpy(dct_matrix(obs_len)).float(), persistent=False)
        self.register_buffer("dct_pred", torch.from_numpy(dct_matrix(pred_len)[:coefs]).float(), persistent=False)
        width = obs_len * coords + coefs * coords + z_dim
        body: list[nn.Module] = [nn.Linear(width, hidden), nn.GELU()]
        for _ in range(layers - 1):
            body += [nn.Dropout(dropout), nn.Linear(hidden, hidden), nn.GELU()]
        self.body = nn.Sequential(*body)
        self.head = nn.Linear(hidden, coefs * coords)
        nn.init.zeros_(self.head.weight)  # the untrained generator is the prior's forecast
        nn.init.zeros_(self.head.bias)

    def linears(self) -> dict[str, nn.Linear]:
        """The hidden layers' Linears in order, by their name in ``body``: the file's ``layers.{i}``."""
        return {name: m for name, m in self.body.named_children() if isinstance(m, nn.Linear)}

    def forward(self, obs: torch.Tensor, prior: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        B, S = len(obs), z.shape[1]
        last = obs[:, -1:]
        past = torch.einsum("ft,btk->bfk", self.dct_obs, obs - last).reshape(B, -1)
        ahead = torch.einsum("ft,btk->bfk", self.dct_pred, prior - last).reshape(B, -1)
        h = torch.cat([past, ahead], 1)[:, None].expand(-1, S, -1)
        y = self.head(self.body(torch.cat([h, z], -1))).reshape(B, S, self.coefs, self.coords)
        return prior[:, None] + torch.einsum("cf,bsck->bsfk", self.dct_pred, y)


def build_generator_config(gen: Generator, data: dict, training: dict | None = None) -> dict:
    """The ``tcd_config`` of a :class:`Generator` (docs/tcd_config.schema.json, role ``generator``)."""
    m = {
        "num_joints": gen.coords // 3,
        "coords": 3,
        "num_features": gen.coords,
        "obs_len": gen.obs_len,
        "pred_len": gen.pred_len,
        "hidden": gen.hidden,
        "layers": len(gen.linears()),
        "z_dim": gen.z_dim,
        "coefs": gen.coefs,
    }
    return {
        "format_version": FORMAT_VERSION,
        "role": GENERATOR_ROLE,
        "model": m,
        "data": data,
        "training": training or {},
        "source_revision": fileformat.source_revision(),
    }


def generator_tensors(gen: Generator) -> dict[str, torch.Tensor]:
    """The file's tensors: ``layers.{i}.*`` and ``head.*``, contiguous float32 copies."""
    out = {}
    for i, lin in enumerate(gen.linears().values()):
        out[f"layers.{i}.weight"], out[f"layers.{i}.bias"] = lin.weight, lin.bias
    out["head.weight"], out["head.bias"] = gen.head.weight, gen.head.bias
    return {k: v.detach().float().contiguous().clone() for k, v in out.items()}


def save_generator(path: str | Path, gen: Generator, data: dict, training: dict | None = None) -> Path:
    """Writes ``gen`` as a generator file (its config in the metadata)."""
    from safetensors.torch import save_file

    if gen.coords % 3:
        raise ValueError(f"Generator: {gen.coords} coordinates is not joints x 3")
    path = Path(path)
    save_file(
        generator_tensors(gen),
        str(path),
        metadata={CONFIG_KEY: json.dumps(build_generator_config(gen, data, training))},
    )
    return path


def load_generator_file(path: str | Path) -> tuple[Generator, dict]:
    """(:class:`Generator` in eval mode, its config) from a generator file, loaded strictly."""
    from safetensors.torch import load_file

    cfg = read_config(path, GENERATOR_ROLE, "generator")
    m = cfg["model"]
    gen = Generator(
        m["num_features"],
        m["hidden"],
        m["layers"],
        m["z_dim"],
        m["coefs"],
        obs_len=m["obs_len"],
        pred_len=m["pred_len"],
    )
    tensors = load_file(str(path))
    names = {f"layers.{i}.{p}": f"body.{name}.{p}" for i, name in enumerate(gen.linears()) for p in ("weight", "bias")}
    gen.load_state_dict({names.get(k, k): v for k, v in tensors.items()}, strict=True)
    return gen.eval(), cfg


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--state-dict", required=True, help="a Generator state dict (training.generator_imle --save)")
    ap.add_argument("--out", required=True, help="the model directory (or .safetensors file) to write")
    ap.add_argument("--hidden", type=int, default=HIDDEN)
    ap.add_argument("--layers", type=int, default=LAYERS)
    ap.add_argument("--z", type=int, default=Z_DIM)
    ap.add_argument("--coefs", type=int, default=COEFS)
    ap.add_argument(
        "--protocol",
        default="humaneva",
        help="the stochastic protocol's dataset it was trained on (training.evaluate_stochastic.DATASETS): its "
        "joints, frames and the file's data block",
    )
    ap.add_argument("--description", default=None, help="recorded in the file's training block")
    ap.add_argument(
        "--training-json",
        default=None,
        help="a JSON file whose content joins the training block (e.g. a bench result's options)",
    )
    args = ap.parse_args(argv)
    from .evaluate_stochastic import dataset_of

    try:
        ds = dataset_of(args.protocol)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    gen = Generator(ds.dims, args.hidden, args.layers, args.z, args.coefs, obs_len=ds.t_his, pred_len=ds.t_pred)
    gen.load_state_dict(torch.load(args.state_dict, map_location="cpu"), strict=True)
    training = json.loads(Path(args.training_json).read_text()) if args.training_json else {}
    if args.description:
        training["description"] = args.description
    out = Path(args.out)
    directory = out.suffix != ".safetensors"
    if directory:
        out.mkdir(parents=True, exist_ok=True)
        out = out / GENERATOR_FILE
    print(save_generator(out, gen.eval(), data_meta(ds.protocol), training), file=sys.stderr)
    if directory:  # a model directory: its summary and checksums name the new file too
        from .export import write_checksums, write_model_json

        write_model_json(out.parent)
        print(write_checksums(out.parent), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
