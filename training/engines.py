"""A model directory's samples through either engine, and the sampling settings of a run from its command line
(``python -m training.evaluate``'s flags): the PyTorch reference (:func:`tcd_predict`, the cascade of
``training.diffusion``) and the Rust engine (:func:`tcd_engine_predict`, ``tcd.TCD.forecast``), in parity. Poses
are (W, T, J, 3) metres; the engines' layout is (B, K, L)."""

from __future__ import annotations

import numpy as np
import torch


def to_bkl(x: np.ndarray) -> torch.Tensor:
    """(B, L, J, 3) -> (B, K, L) float32 tensor, K = 3 J in joint-major order."""
    B, L, J, _ = x.shape
    t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))
    return t.reshape(B, L, J * 3).permute(0, 2, 1).contiguous()


def from_bkl(x: torch.Tensor) -> np.ndarray:
    """(..., K, L) -> (..., L, J, 3) float64 numpy."""
    x = x.detach().cpu().double()
    *lead, K, L = x.shape
    return x.transpose(-1, -2).reshape(*lead, L, K // 3, 3).numpy()


def joint_to_coord_mask(jmask: np.ndarray) -> np.ndarray:
    """(..., J) -> (..., J, 3)"""
    return np.repeat(np.asarray(jmask)[..., None], 3, axis=-1)


def noise_coupling_of(args) -> str:
    """The noise coupling a run samples with (``tcd.SamplerOptions.noise_coupling``): ``--noise-coupling``, else the
    model directory's forecast default where ``--sampler`` is its sampler (``SamplerOptions.build``'s rule, what
    ``tcd.TCD.forecast`` does), else ``"independent"``; both engines are given it explicitly."""
    given = getattr(args, "noise_coupling", None)
    if given or not getattr(args, "model", None):
        return given or "independent"
    import tcd

    return tcd.SamplerOptions.build(tcd.load(args.model).sampling.get("forecast"), sampler=args.sampler).noise_coupling


def tcd_predict(
    models: dict,
    obs: np.ndarray,
    jmask: np.ndarray,
    *,
    samples: int,
    sampler,
    seed: int,
    device: str,
    batch_size: int = 16,
    horizon: int = 25,  # the Human3.6M protocol's (training.evaluate.PRED)
) -> dict:
    """Cascade forecast for windows obs (W, O, J, 3) metres (Human3.6M: O = 50) with joint mask (W, O, J), sampled
    by ``sampler`` (a ``tcd.SamplerOptions``: :func:`sampler_of`). Returns samples (S, W, horizon, J, 3) and the
    repaired observation (W, O, J, 3) (mean of short-term samples)."""
    import dataclasses

    from .diffusion import cascade

    short_m, short_s, short_cfg = models["short"]
    long_m, long_s, long_cfg = models["long"]
    short_len, long_len = short_cfg["window"]["seq_len"], long_cfg["window"]["seq_len"]
    obs_len = obs.shape[1]
    if short_cfg["window"]["obs_len"] != obs_len or long_len - obs_len != horizon:
        raise ValueError(
            f"models expect {short_cfg['window']['obs_len']} observed frames and {long_len} in all; "
            f"the protocol has {obs_len} + {horizon}"
        )
    obs = obs * joint_to_coord_mask(jmask)  # missing values are zero in the model input
    outs, reps = [], []
    for b0 in range(0, len(obs), batch_size):
        gen = torch.Generator(device=device).manual_seed(int(seed) * 1_000_003 + b0)
        x = to_bkl(obs[b0 : b0 + batch_size]).to(device)
        m = to_bkl(joint_to_coord_mask(jmask[b0 : b0 + batch_size])).to(device)
        res = cascade(
            short_m,
            short_s,
            long_m,
            long_s,
            x,
            m,
            short_len=short_len,
            long_len=long_len,
            num_samples=samples,
            generator=gen,
            **dataclasses.asdict(sampler),
        )
        outs.append(from_bkl(res["samples"][..., obs_len:]))
        reps.append(from_bkl(res["short_mean"][..., :obs_len]))
    return {"samples": np.concatenate(outs, axis=1), "repaired": np.concatenate(reps, axis=0)}


def tcd_engine_predict(
    model_dir: str,
    obs: np.ndarray,
    jmask: np.ndarray,
    *,
    samples: int,
    sampler,
    seed: int,
    mode=None,
) -> dict:
    """The same cascade through the Rust engine (``tcd``): fast on the CPU, in parity with the reference.
    Missing entries are passed as NaN; ``mode``: ``tcd.TCD.forecast``'s (None: the directory's)."""
    import tcd

    model = tcd.load(model_dir)
    x = np.where(joint_to_coord_mask(jmask) > 0.5, obs, np.nan)
    f = model.forecast(
        x,
        num_samples=samples,
        sampler=sampler,
        seed=int(seed),
        mode=mode,
    )
    return {"samples": np.asarray(f.samples, np.float64), "repaired": np.asarray(f.repaired, np.float64)}


def sampler_of(args):
    """The sampler of a run (``tcd.SamplerOptions``), both engines': --sampler, --steps, --eta, --timestep-spacing
    and :func:`noise_coupling_of`."""
    import tcd

    return tcd.SamplerOptions(
        sampler=args.sampler,
        num_inference_steps=args.steps,
        eta=args.eta,
        timestep_spacing=args.timestep_spacing,
        noise_coupling=noise_coupling_of(args),
    )


def mode_of(args):
    """The forecast mode of a run with --engine tcd (``tcd.TCD.forecast``'s ``mode``): --tempo (``tcd.Tempo``),
    --generator-share (``tcd.Mixture``; 0: ``tcd.Cascade``), else None, the model directory's default
    (``tcd.TCD.forecast_mode``: its sampling.json)."""
    import tcd

    if args.tempo is not None:
        return tcd.Tempo(*args.tempo)
    share = getattr(args, "generator_share", None)
    if share is not None:
        return tcd.Mixture(share) if share else tcd.Cascade()
    return None


def _run_mode(args):
    """The mode the samples ran with: :func:`mode_of`, the directory's where it is None; None with --engine torch
    (the cascade alone, no generator)."""
    if args.engine != "tcd":
        return None
    import tcd

    mode = mode_of(args)
    return tcd.load(args.model).forecast_mode if mode is None else mode


def generator_share_of(args) -> float:
    """The share of each window's samples the model directory's MLP generator draws in this run (a results file's
    ``sampling.generator_share``; 0 with --engine torch, which runs no generator)."""
    import tcd

    mode = _run_mode(args)
    return mode.share if isinstance(mode, tcd.Mixture) else 0.0


def tempo_run(args) -> list | None:
    """The tempo range the samples ran with (a results file's ``sampling.tempo``; None: none)."""
    import tcd

    mode = _run_mode(args)
    return [mode.lo, mode.hi] if isinstance(mode, tcd.Tempo) and (mode.lo, mode.hi) != (1.0, 1.0) else None
