"""DDPM maths for TCD: schedules (float64), forward noising, the masked epsilon loss, samplers, cascade, repair.

Notation follows the MotionDiff supplement / DDPM: beta_t, alpha_t = 1 - beta_t,
alpha_bar_t = prod_{s<=t} alpha_s; the network predicts epsilon (TCD), or x0 where the config's
``prediction_type`` is ``"sample"`` (the samplers turn it into the noise: ``predicted_noise``).

Injected noise. Every sampler accepts ``noise`` of shape (num_noise_blocks, B, K, L): ``noise[0]`` is x_T
and ``noise[i + 1]`` is the z used at step i (ignored where the step adds no noise). ddpm and ddim take
num_steps + 1 blocks; dpmpp2m (DPM-Solver++(2M), deterministic) consumes no per-step noise and takes one
block, x_T. Another implementation fed the same array must produce the same numbers. Without ``noise``
a ``torch.Generator`` (or the global RNG) draws it in the same layout.

Target. A model whose config says ``target="linear_residual"`` diffuses ``target_scale * (x0 -
linear_fill(observed, mask))`` instead of x0 (training.model.to_target); samplers map the final x back
(from_target) before merging the observation. ``target="absolute"`` (TCD) diffuses x0.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch

from .model import from_target, to_target

SCHEDULES = ("cosine", "linear", "quad")
SPACINGS = ("leading", "trailing", "linspace")
SAMPLERS = ("ddpm", "ddim", "dpmpp2m")
PREDICTION_TYPES = ("epsilon", "sample")


@dataclass
class DiffusionConfig:
    num_train_timesteps: int = 50  # T
    beta_schedule: str = "cosine"  # cosine (TCD default) | linear (MotionDiff: T=100, 1e-4..0.05) | quad (CSDI)
    beta_start: float = 1e-4  # linear / quad only
    beta_end: float = 0.5  # linear / quad only
    max_beta: float = 0.5  # cosine clip (TCD clips at 0.5, not 0.999)
    prediction_type: str = "epsilon"  # what the network outputs: the noise (TCD, CSDI) or "sample": the clean
    # target x0 (the residual, for a residual target), as CoMusion and MDM do

    def __post_init__(self):
        if self.prediction_type not in PREDICTION_TYPES:
            raise ValueError(
                f"diffusion config: prediction_type must be one of {PREDICTION_TYPES}, got {self.prediction_type!r}"
            )

    def to_dict(self) -> dict:
        d = asdict(self)
        d["betas"] = make_betas(self).tolist()
        d["variance_type"] = "fixed_small"
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "DiffusionConfig":
        cfg = cls(
            **{
                k: d[k]
                for k in (
                    "num_train_timesteps",
                    "beta_schedule",
                    "beta_start",
                    "beta_end",
                    "max_beta",
                    "prediction_type",
                )
                if k in d
            }
        )
        if "betas" in d and not np.allclose(
            np.asarray(d["betas"], dtype=np.float64), make_betas(cfg), rtol=0, atol=1e-12
        ):
            raise ValueError("diffusion config: the stored betas disagree with the schedule they name")
        return cfg


def make_betas(cfg: DiffusionConfig) -> np.ndarray:
    """Betas in float64, shape (T,)."""
    T = cfg.num_train_timesteps
    if T < 1:
        raise ValueError(f"num_train_timesteps must be >= 1, got {T}")
    if cfg.beta_schedule == "cosine":

        def abar(s):
            return math.cos((s + 0.008) / 1.008 * math.pi / 2) ** 2

        return np.array([min(1.0 - abar((i + 1) / T) / abar(i / T), cfg.max_beta) for i in range(T)], dtype=np.float64)
    if cfg.beta_schedule == "linear":
        return np.linspace(cfg.beta_start, cfg.beta_end, T, dtype=np.float64)
    if cfg.beta_schedule == "quad":
        return np.linspace(cfg.beta_start**0.5, cfg.beta_end**0.5, T, dtype=np.float64) ** 2
    raise ValueError(f"beta_schedule must be one of {SCHEDULES}, got {cfg.beta_schedule!r}")


class Schedule:
    """Precomputed float64 schedule quantities."""

    def __init__(self, cfg: DiffusionConfig):
        self.cfg = cfg
        self.T = cfg.num_train_timesteps
        self.betas = make_betas(cfg)
        self.alphas = 1.0 - self.betas
        self.alphas_cumprod = np.cumprod(self.alphas)
        self._abar_on: dict[str, torch.Tensor] = {}

    def alphas_cumprod_on(self, device) -> torch.Tensor:
        """alpha_bar as a float32 tensor on ``device``, made once per device: a copy from the host in
        every training step would make the host wait for the GPU."""
        key = str(torch.device(device))
        if key not in self._abar_on:
            self._abar_on[key] = torch.as_tensor(self.alphas_cumprod, dtype=torch.float32, device=device)
        return self._abar_on[key]

    def abar(self, t: int) -> float:
        """alpha_bar_t, with alpha_bar_{-1} = 1."""
        return 1.0 if t < 0 else float(self.alphas_cumprod[t])


# --------------------------------------------------------------------------------------------
# Forward process and loss


def q_sample(sched: Schedule, x0: torch.Tensor, t: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
    """x_t = sqrt(abar_t) x0 + sqrt(1 - abar_t) eps, t of shape (B,)."""
    abar = sched.alphas_cumprod_on(x0.device)[t].view(-1, 1, 1)
    return abar.sqrt() * x0 + (1.0 - abar).sqrt() * eps


def masked_eps_loss(eps: torch.Tensor, eps_hat: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """sum(((eps - eps_hat)(1 - m))^2) / sum(1 - m): only entries that are not conditioned count."""
    target = 1.0 - mask
    denom = target.sum()
    return (((eps - eps_hat) * target) ** 2).sum() / torch.clamp(denom, min=1.0)


def training_loss(
    model,
    sched: Schedule,
    x0: torch.Tensor,
    mask: torch.Tensor,
    t: torch.Tensor | None = None,
    eps: torch.Tensor | None = None,
    generator: torch.Generator | None = None,
    observed: torch.Tensor | None = None,
) -> torch.Tensor:
    """The masked epsilon loss of section 2.1 for clean windows x0 (B, K, L) and conditioning mask (B, K, L).

    ``observed`` (default x0) is what the network sees on conditioned entries: for noisy-observation
    training it is the corrupted window while x0 stays the clean target.
    """
    B = x0.shape[0]
    if t is None:
        t = torch.randint(0, sched.T, (B,), generator=generator, device="cpu").to(x0.device)
    if eps is None:
        eps = torch.randn(x0.shape, generator=generator, device="cpu").to(x0.device)
    observed = x0 if observed is None else observed
    target = _to_target(model, x0, observed, mask)
    xt = q_sample(sched, target, t, eps)
    out = model(xt, observed, mask, t)
    # x0-prediction: the same masked mean square, on the clean target instead of the noise
    return masked_eps_loss(target if sched.cfg.prediction_type == "sample" else eps, out, mask)


def predicted_noise(sched: Schedule, out: torch.Tensor, x: torch.Tensor, t: int) -> torch.Tensor:
    """The network's output at step t as the noise the samplers step with: itself for epsilon-prediction;
    for x0-prediction ``(x - sqrt(abar_t) x0) * (1 / sqrt(1 - abar_t))``, coefficients rounded to float32
    from float64 (the Rust engine's operation order)."""
    if sched.cfg.prediction_type == "epsilon":
        return out
    a_t = sched.abar(t)
    a = torch.tensor(math.sqrt(a_t), dtype=torch.float32)
    inv_s = torch.tensor(1.0 / math.sqrt(1.0 - a_t), dtype=torch.float32)
    return (x - a * out) * inv_s


# --------------------------------------------------------------------------------------------
# Sampling


def timesteps(T: int, num_inference_steps: int, spacing: str = "trailing") -> list[int]:
    """Descending training steps used at inference (diffusers' timestep_spacing semantics)."""
    n = num_inference_steps
    if not isinstance(n, (int, np.integer)) or n < 1 or n > T:
        raise ValueError(f"num_inference_steps must be an integer in 1..{T}, got {n!r}")
    if spacing == "leading":
        ts = (np.arange(n) * (T // n)).round()[::-1]
    elif spacing == "trailing":
        ts = np.round(np.arange(T, 0, -T / n)) - 1
    elif spacing == "linspace":
        ts = np.linspace(0, T - 1, n).round()[::-1]
    else:
        raise ValueError(f"timestep_spacing must be one of {SPACINGS}, got {spacing!r}")
    out = [int(t) for t in ts]
    if len(set(out)) != len(out):
        raise ValueError(f"timestep_spacing={spacing!r} gives repeated steps for num_inference_steps={n}")
    return out


def step_pairs(T: int, sampler: str, num_inference_steps: int | None, spacing: str) -> list[tuple[int, int]]:
    """Explicit (t, t_next) pairs; t_next = -1 after the last step (alpha_bar = 1)."""
    if sampler == "ddpm" and num_inference_steps is None:
        num_inference_steps = T
    ts = timesteps(T, num_inference_steps, spacing)
    return list(zip(ts, ts[1:] + [-1]))


def num_noise_blocks(sampler: str, num_steps: int) -> int:
    """Leading axis of the injected noise of one chain: num_steps + 1 (x_T, then one z per step) for ddpm
    and ddim, 1 (x_T only) for the deterministic dpmpp2m."""
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler must be one of {SAMPLERS}, got {sampler!r}")
    return 1 if sampler == "dpmpp2m" else num_steps + 1


def dpmpp2m_coefficients(sched: Schedule, pairs: list[tuple[int, int]]) -> list[dict]:
    """Float64 coefficients of DPM-Solver++(2M) (Lu et al. 2022, data prediction, multistep, order 2) over
    explicit (t, t_next) pairs.

    With alpha = sqrt(abar), sigma = sqrt(1 - abar), lambda = log(alpha / sigma), a step from s = t to
    t' = t_next with h = lambda_t' - lambda_s is

        x0_i = (x - sigma_s eps) / alpha_s
        D    = x0_i                                         (first order: step 0)
        D    = (1 + 1/(2r)) x0_i - 1/(2r) x0_{i-1}          (second order, r = h_{i-1} / h_i)
        x   <- (sigma_t' / sigma_s) x - alpha_t' (exp(-h) - 1) D

    The last step (t_next = -1, abar = 1, sigma = 0, lambda = +inf) is taken first order, which in that
    limit returns x0_i exactly (diffusers: ``final_sigmas_type="zero"``, ``lower_order_final``).
    Each dict: ``a`` = sigma_s, ``b`` = alpha_s (x0_i = (x - a eps) / b), ``final``, and for the other
    steps ``cx`` = sigma_t'/sigma_s, ``c0`` = -alpha_t' expm1(-h), ``w_cur``, ``w_prev`` (D = w_cur x0_i
    + w_prev x0_{i-1}; w_prev = 0 at first order).
    """

    def lam(t):
        a = sched.abar(t)
        return 0.5 * math.log(a) - 0.5 * math.log(1.0 - a)

    out = []
    h_prev = None
    for i, (t, t_next) in enumerate(pairs):
        a_t = sched.abar(t)
        c = {"a": math.sqrt(1.0 - a_t), "b": math.sqrt(a_t), "final": t_next < 0}
        if t_next >= 0:
            a_n = sched.abar(t_next)
            h = lam(t_next) - lam(t)
            c["cx"] = math.sqrt(1.0 - a_n) / math.sqrt(1.0 - a_t)
            c["c0"] = -math.sqrt(a_n) * math.expm1(-h)
            if i == 0:
                c["w_cur"], c["w_prev"] = 1.0, 0.0
            else:
                r = h_prev / h
                c["w_cur"], c["w_prev"] = 1.0 + 0.5 / r, -0.5 / r
            h_prev = h
        out.append(c)
    return out


def draw_noise(num_steps: int, shape, generator: torch.Generator | None = None) -> torch.Tensor:
    """The injected-noise layout of ddpm / ddim: (num_steps + 1, *shape), standard normal, float32
    (``num_steps = 0`` gives the single x_T block of dpmpp2m), drawn on the generator's device (a GPU's
    noise never crosses from the host)."""
    device = generator.device if generator is not None else None
    return torch.randn((num_steps + 1, *shape), generator=generator, dtype=torch.float32, device=device)


@torch.no_grad()
def sample(
    model,
    sched: Schedule,
    observed: torch.Tensor,
    mask: torch.Tensor,
    *,
    sampler: str = "ddpm",
    num_inference_steps: int | None = None,
    eta: float = 0.0,
    timestep_spacing: str = "trailing",
    noise: torch.Tensor | None = None,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Draw one sample per batch element. observed, mask: (B, K, L). Returns the merged sample (B, K, L).

    ddpm: ancestral sampling with the posterior variance beta_tilde; with num_inference_steps = T (default)
    it is the reference sampler over all steps; fewer steps run respaced DDPM on the chosen subsequence
    (betas' = 1 - abar_t / abar_next).
    ddim: deterministic for eta = 0; x0_hat is not clipped; alpha_bar_prev = 1 after the last step.
    dpmpp2m: DPM-Solver++(2M) (see ``dpmpp2m_coefficients``), deterministic: ``noise`` is (1, B, K, L), x_T.
    """
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler must be one of {SAMPLERS}, got {sampler!r}")
    if num_inference_steps is None:
        num_inference_steps = sched.T
    pairs = step_pairs(sched.T, sampler, num_inference_steps, timestep_spacing)
    shape = tuple(observed.shape)
    blocks = num_noise_blocks(sampler, len(pairs))
    if noise is None:
        noise = draw_noise(blocks - 1, shape, generator)
    if tuple(noise.shape) != (blocks, *shape):
        raise ValueError(f"noise must have shape {(blocks, *shape)}, got {tuple(noise.shape)}")
    noise = noise.to(observed.device, torch.float32)
    x = noise[0].clone()
    B = shape[0]
    if sampler == "dpmpp2m":
        coefs = dpmpp2m_coefficients(sched, pairs)
        prev_x0 = None
    for i, (t, t_next) in enumerate(pairs):
        step = torch.full((B,), t, dtype=torch.long, device=observed.device)
        eps = predicted_noise(sched, model(x, observed, mask, step), x, t)
        a_t, a_next = sched.abar(t), sched.abar(t_next)
        if sampler == "ddpm":
            beta = 1.0 - a_t / a_next  # = beta_t when the steps are consecutive
            c1 = 1.0 / math.sqrt(1.0 - beta)
            c2 = beta / math.sqrt(1.0 - a_t)
            x = c1 * (x - c2 * eps)
            if t_next >= 0:
                sigma = math.sqrt(beta * (1.0 - a_next) / (1.0 - a_t))
                x = x + sigma * noise[i + 1]
        elif sampler == "dpmpp2m":
            c = coefs[i]
            x0_hat = (x - c["a"] * eps) / c["b"]
            if c["final"]:
                x = x0_hat
            else:
                d = x0_hat if c["w_prev"] == 0.0 else c["w_cur"] * x0_hat + c["w_prev"] * prev_x0
                x = c["cx"] * x + c["c0"] * d
            prev_x0 = x0_hat
        else:
            x0_hat = (x - math.sqrt(1.0 - a_t) * eps) / math.sqrt(a_t)
            sigma = eta * math.sqrt((1.0 - a_next) / (1.0 - a_t)) * math.sqrt(1.0 - a_t / a_next)
            dir_coef = math.sqrt(max(1.0 - a_next - sigma**2, 0.0))
            x = math.sqrt(a_next) * x0_hat + dir_coef * eps
            if sigma > 0:
                x = x + sigma * noise[i + 1]
    x = _from_target(model, x, observed, mask)
    return x * (1 - mask) + observed * mask


def _to_target(model, x0, observed, mask):
    cfg = getattr(model, "cfg", None)
    return x0 if cfg is None else to_target(cfg, x0, observed, mask, getattr(model, "prior", None))


def _from_target(model, x, observed, mask):
    cfg = getattr(model, "cfg", None)
    return x if cfg is None else from_target(cfg, x, observed, mask, getattr(model, "prior", None))


def couple_noise(noise: torch.Tensor, noise_coupling: str = "independent") -> torch.Tensor:
    """The chains' noise (S, num_noise_blocks, B, K, L) as a sampler with ``noise_coupling`` starts from
    (``tcd.SamplerOptions.noise_coupling``; the engine's ``NoiseCoupling``). ``"independent"``: as given.
    ``"centered"`` (S >= 2): each sequence's S blocks 0 (x_T) moved off their mean c and rescaled,
    ``(z_s - c) * sqrt(S / (S - 1))`` in float64 with c summed in chain order, rounded once to float32; the
    per-step blocks as given. Each x_T stays a standard normal; the S of a sequence sum to zero."""
    if noise_coupling not in ("independent", "centered"):
        raise ValueError(f"noise_coupling must be 'independent' or 'centered', got {noise_coupling!r}")
    s = noise.shape[0]
    if noise_coupling == "independent" or s < 2:
        return noise
    x_t = noise[:, 0].to(torch.float64)
    c = x_t[0].clone()
    for i in range(1, s):
        c += x_t[i]
    c /= s
    out = noise.clone()
    out[:, 0] = ((x_t - c) * math.sqrt(s / (s - 1))).to(noise.dtype)
    return out


def sample_many(
    model,
    sched: Schedule,
    observed: torch.Tensor,
    mask: torch.Tensor,
    num_samples: int,
    noise: torch.Tensor | None = None,
    generator: torch.Generator | None = None,
    batch_chains: bool = True,
    noise_coupling: str = "independent",
    **kw,
) -> torch.Tensor:
    """num_samples chains per window -> (S, B, K, L), independent but for ``noise_coupling``
    (:func:`couple_noise`).

    ``noise``: (S, num_noise_blocks, B, K, L) or None (num_noise_blocks: num_steps + 1, or 1 for
    dpmpp2m). With ``batch_chains`` the S chains run as one batch
    (same numbers as running them one by one, faster).
    """
    S, B = num_samples, observed.shape[0]
    if S < 1:
        raise ValueError(f"num_samples must be >= 1, got {S}")
    sampler = kw.get("sampler", "ddpm")
    n = len(
        step_pairs(sched.T, sampler, kw.get("num_inference_steps") or sched.T, kw.get("timestep_spacing", "trailing"))
    )
    blocks = num_noise_blocks(sampler, n)
    if noise is None:
        noise = torch.stack([draw_noise(blocks - 1, tuple(observed.shape), generator) for _ in range(S)])
    noise = couple_noise(noise, noise_coupling)
    if not batch_chains:
        return torch.stack([sample(model, sched, observed, mask, noise=noise[s], **kw) for s in range(S)])
    # (S, blocks, B, K, L) -> (blocks, S*B, K, L)
    flat = noise.permute(1, 0, 2, 3, 4).reshape(blocks, S * B, *observed.shape[1:])
    rep = lambda a: a.unsqueeze(0).expand(S, *a.shape).reshape(S * B, *a.shape[1:])  # noqa: E731
    out = sample(model, sched, rep(observed), rep(mask), noise=flat, **kw)
    return out.reshape(S, B, *observed.shape[1:])


# --------------------------------------------------------------------------------------------
# TCD cascade (section 5) and repair


def pad_frames(x: torch.Tensor, length: int) -> torch.Tensor:
    """(B, K, L0) -> (B, K, length) with zero frames appended."""
    B, K, L0 = x.shape
    if L0 > length:
        raise ValueError(f"cannot pad {L0} frames to {length}")
    return torch.cat([x, x.new_zeros(B, K, length - L0)], dim=2)


@torch.no_grad()
def cascade(
    short_model,
    short_sched: Schedule,
    long_model,
    long_sched: Schedule,
    observed: torch.Tensor,
    mask: torch.Tensor,
    *,
    short_len: int,
    long_len: int,
    num_samples: int = 5,
    noise_short: torch.Tensor | None = None,
    noise_long: torch.Tensor | None = None,
    generator: torch.Generator | None = None,
    **kw,
) -> dict:
    """Temporal cascade: short-term model (obs -> short_len frames), the mean of its samples overwrites
    frames 0..short_len-1 with mask 1, then the long-term model fills frames short_len..long_len-1.

    observed, mask: (B, K, O) observation (mask 0 = occluded). Returns dict with
    ``short_samples`` (S, B, K, short_len), ``short_mean`` (B, K, short_len) and ``samples`` (S, B, K, long_len).
    """
    obs_len = observed.shape[2]
    x_s, m_s = pad_frames(observed, short_len), pad_frames(mask, short_len)
    short = sample_many(short_model, short_sched, x_s, m_s, num_samples, noise=noise_short, generator=generator, **kw)
    mean = short.mean(dim=0)
    if obs_len > short_len:
        raise ValueError(f"observation has {obs_len} frames, more than the short-term window {short_len}")
    x_l = pad_frames(mean, long_len)
    m_l = pad_frames(torch.ones_like(mean), long_len)
    long = sample_many(long_model, long_sched, x_l, m_l, num_samples, noise=noise_long, generator=generator, **kw)
    return {"short_samples": short, "short_mean": mean, "samples": long}


@torch.no_grad()
def repair(
    model,
    sched: Schedule,
    observed: torch.Tensor,
    mask: torch.Tensor,
    *,
    seq_len: int,
    num_samples: int = 5,
    noise: torch.Tensor | None = None,
    generator: torch.Generator | None = None,
    **kw,
) -> torch.Tensor:
    """Observation-only inference: fill the occluded entries of (B, K, O) with the mean of the samples.

    The observation is padded to the model's window with masked frames; observed entries are returned
    unchanged.
    """
    obs_len = observed.shape[2]
    out = sample_many(
        model,
        sched,
        pad_frames(observed, seq_len),
        pad_frames(mask, seq_len),
        num_samples,
        noise=noise,
        generator=generator,
        **kw,
    )
    rep = out.mean(dim=0)[:, :, :obs_len]
    return rep * (1 - mask) + observed * mask
