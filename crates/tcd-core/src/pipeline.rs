//! The pipelines: the TCD cascade (TCD_REFERENCE.md section 5) and observation repair, around the fills of
//! [`crate::fill`].
//!
//! # Layout
//! Inputs and outputs are **(B, K, frames)** row-major f32 in model units (K = joints·3, frame
//! fastest), like every other array of the engine; samples are (S, B, K, frames). A pose array
//! (B, T, J, 3) becomes (B, K, T) by moving the frame axis last.
//!
//! # Cascade
//! 1. Short-term model (L_s = 55): x₀ = observation padded with zero frames, mask padded with
//!    zeros; S chains per sequence; **mean over samples** of the merged outputs → (B, K, L_s)
//!    (observed entries exact).
//! 2. Long-term model (L_l = 75): x₀ = that mean in frames 0..L_s (mask 1 there), zeros after;
//!    S chains per sequence.
//! 3. Forecast = frames O..L_l of the long samples (TCD: 25 future frames) and their mean; the
//!    repaired observation = frames 0..O of the short mean.
//!
//! Noise: injected arrays (S, n + 1, B, K, L) per stage ((S, 1, B, K, L) for dpmpp2m), or one seed: the short stage uses stream
//! stage [`stage::SHORT`] (the same streams as [`crate::sampler::sample`]), the long stage
//! [`stage::LONG`].
//!
//! # Conditioning on the prior forecaster
//! A model with `cond_fill` [`CondFill::Prior`] sees, at its masked entries, the prior's fill of its
//! stage's observation ([`crate::prior_fill`]: `training.model.prior_fill`). The fill depends on the
//! observation only, the same at every step and for every sample, so it is computed once per stage,
//! before the chains, and written into the masked entries of the stage's `observed`, where the
//! denoiser reads it (as its observed channel and as the base of the `prior_residual` target). The
//! short stage fills its padded observation; the long stage fills its window (the short mean over the
//! first L_s frames, mask 1) from its first `prior.obs_len` frames, so only its frames L_s..L_l change.

use crate::config::CondFill;
use crate::control::Control;
use crate::denoiser::Denoiser;
use crate::error::{Error, Result};
use crate::fill::{fill_with_prior, gap_forecaster};
use crate::observation::Observation;
use crate::prior::{Anchor, Prior};
use crate::rng::{stage, Noise, Sequences};
use crate::sampler::{run_job, validate_job, SamplerConfig};
use crate::weights::Network;

/// Sampling options shared by both stages.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForecastOptions {
    /// S: chains per sequence (per stage). TCD: 5.
    pub num_samples: usize,
    pub sampler: SamplerConfig,
}

impl Default for ForecastOptions {
    /// The paper's setting: 5 samples, DDPM over all training steps.
    fn default() -> Self {
        ForecastOptions {
            num_samples: 5,
            sampler: SamplerConfig::ddpm(),
        }
    }
}

/// The noise of a cascade: one [`Noise`] per stage. A seeded stage draws its own streams (stage
/// [`stage::SHORT`] or [`stage::LONG`] of its seed), so one seed for both is [`CascadeNoise::seeded`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CascadeNoise<'a> {
    /// The short-term stage's: injected (S, n + 1, B, K, L_s) or seeded.
    pub short: Noise<'a>,
    /// The long-term stage's: injected (S, n + 1, B, K, L_l) or seeded.
    pub long: Noise<'a>,
}

impl<'a> CascadeNoise<'a> {
    /// Both stages from `seed`'s streams, sequences numbered alike.
    pub fn seeded(seed: u64, sequences: Sequences<'a>) -> Self {
        let noise = Noise::Seeded { seed, sequences };
        CascadeNoise {
            short: noise,
            long: noise,
        }
    }

    /// Caller-supplied standard normals per stage.
    pub fn injected(short: &'a [f32], long: &'a [f32]) -> Self {
        CascadeNoise {
            short: Noise::Injected(short),
            long: Noise::Injected(long),
        }
    }
}

/// What [`cascade`] returns.
#[derive(Clone, Debug, PartialEq)]
pub struct CascadeOutput {
    pub batch: usize,
    pub num_features: usize,
    pub num_samples: usize,
    /// O: observed frames given.
    pub obs_len: usize,
    /// L_s: the short-term window.
    pub short_len: usize,
    /// P = L_l − O: forecast frames.
    pub future_len: usize,
    /// Mean forecast, (B, K, P).
    pub mean: Vec<f32>,
    /// Forecast samples, (S, B, K, P).
    pub samples: Vec<f32>,
    /// Repaired observation (short-stage mean over frames 0..O), (B, K, O).
    pub repaired: Vec<f32>,
    /// The short-stage mean, (B, K, L_s): what the long model was conditioned on.
    pub short_mean: Vec<f32>,
}

/// What [`repair`] returns.
#[derive(Clone, Debug, PartialEq)]
pub struct RepairOutput {
    pub batch: usize,
    pub num_features: usize,
    pub num_samples: usize,
    pub obs_len: usize,
    /// Mean over samples, (B, K, O).
    pub mean: Vec<f32>,
    /// Samples, (S, B, K, O).
    pub samples: Vec<f32>,
}

/// Frames `start..end` of every row of `src` (rows × len).
fn take_frames(src: &[f32], len: usize, start: usize, end: usize) -> Vec<f32> {
    src.chunks_exact(len)
        .flat_map(|row| row[start..end].iter().copied())
        .collect()
}

/// Every row of `src` (rows × len) extended to `new_len` frames with `fill`.
fn pad_frames(src: &[f32], len: usize, new_len: usize, fill: f32) -> Vec<f32> {
    let mut out = Vec::with_capacity(src.len() / len.max(1) * new_len);
    for row in src.chunks_exact(len) {
        out.extend_from_slice(row);
        out.extend(std::iter::repeat_n(fill, new_len - len));
    }
    out
}

/// Mean over the leading sample axis of (S × n) in sample order.
fn mean_over_samples(samples: &[f32], num_samples: usize, n: usize) -> Vec<f32> {
    let mut acc = vec![0.0f32; n];
    for s in samples.chunks_exact(n).take(num_samples) {
        for (a, v) in acc.iter_mut().zip(s) {
            *a += v;
        }
    }
    let inv = num_samples as f32;
    acc.iter_mut().for_each(|a| *a /= inv);
    acc
}

/// `observed` with 0 wherever mask = 0 (drops NaN markers of missing values).
fn zero_unobserved(observed: &[f32], mask: &[f32]) -> Vec<f32> {
    observed
        .iter()
        .zip(mask)
        .map(|(&o, &m)| if m == 1.0 { o } else { 0.0 })
        .collect()
}

/// The prior a model of the `which` stage (`"short-term"`, `"long-term"`) runs with: `None` for a model
/// not conditioned on it; for a [`CondFill::Prior`] model `prior`, which must be given, have the model's
/// `num_features` and read fewer frames (`obs_len`) than the model's window.
fn stage_prior<'p>(
    model: &Denoiser,
    prior: Option<&'p Prior>,
    which: &str,
) -> Result<Option<&'p Prior>> {
    if model.config().model.cond_fill != CondFill::Prior {
        return Ok(None);
    }
    let Some(p) = prior else {
        return Err(Error::invalid_input(
            "prior",
            format!(
                "the prior forecaster (prior.safetensors): the {which} model is conditioned on it (cond_fill \"prior\")"
            ),
            "none",
        ));
    };
    let (k, l) = (model.num_features(), model.seq_len());
    if p.config().model.anchor != Anchor::Last {
        return Err(Error::invalid_input(
            "prior",
            format!("the prior forecaster (anchor \"last\") the {which} model is conditioned on"),
            "a repair fill (anchor \"window\")",
        ));
    }
    if p.num_features() != k || p.obs_len() >= l {
        return Err(Error::invalid_input(
            "prior",
            format!(
                "a prior forecaster with the {which} model's num_features = {k} and an obs_len below its seq_len = {l}"
            ),
            format!("num_features = {}, obs_len = {}", p.num_features(), p.obs_len()),
        ));
    }
    Ok(Some(p))
}

/// Runs the short-term → long-term cascade on `observed`, (B, K, O) with K the models' `num_features` and
/// O the short model's `obs_len`; `long` must have `obs_len` equal to the short model's `seq_len`.
/// `prior`: the prior forecaster, required where either model is conditioned on it (`cond_fill`
/// [`CondFill::Prior`]; see the module's notes), unused otherwise.
pub fn cascade(
    short: &Denoiser,
    long: &Denoiser,
    prior: Option<&Prior>,
    observed: &Observation<'_>,
    options: &ForecastOptions,
    noise: CascadeNoise<'_>,
    control: &Control,
) -> Result<CascadeOutput> {
    let k = short.num_features();
    if long.num_features() != k {
        return Err(Error::invalid_input(
            "long",
            format!("a long-term model with the short-term model's num_features = {k}"),
            format!("num_features = {}", long.num_features()),
        ));
    }
    let (o, ls, ll) = (short.obs_len(), short.seq_len(), long.seq_len());
    if long.obs_len() != ls || ll <= o {
        return Err(Error::invalid_input(
            "long",
            format!("a long-term model whose obs_len equals the short-term model's seq_len = {ls}"),
            format!("obs_len = {}, seq_len = {ll}", long.obs_len()),
        ));
    }
    observed.expect(k, "the short-term model's", Some((o, "obs_len")))?;
    let batch = observed.batch();
    let short_prior = stage_prior(short, prior, "short-term")?;
    let long_prior = stage_prior(long, prior, "long-term")?;
    let s = options.num_samples;
    let rows = batch * k;

    // Stage 1: short-term model on the padded observation (its masked entries the prior's fill, for a
    // model conditioned on it).
    let mut x_short = pad_frames(
        &zero_unobserved(observed.values(), observed.mask()),
        o,
        ls,
        0.0,
    );
    let m_short = pad_frames(observed.mask(), o, ls, 0.0);
    if let Some(p) = short_prior {
        fill_with_prior(p, None, &mut x_short, &m_short, batch, ls, control)?;
    }
    let m_long = pad_frames(&vec![1.0f32; rows * ls], ls, ll, 0.0);
    // Validate the long stage (sizes, plan, noise) before the expensive short stage runs.
    let x_long_placeholder = vec![0.0f32; rows * ll];
    let long_noise_name = "noise.long";
    let long_shape = [batch, k, ll];
    let long_forwards = validate_job(
        long,
        Observation::checked_by_construction(&x_long_placeholder, &m_long, long_shape),
        s,
        &options.sampler,
        noise.long,
        long_noise_name,
        stage::LONG,
    )?
    .forwards();
    drop(x_long_placeholder);
    let job = validate_job(
        short,
        Observation::checked_by_construction(&x_short, &m_short, [batch, k, ls]),
        s,
        &options.sampler,
        noise.short,
        "noise.short",
        stage::SHORT,
    )?;
    control.expect(job.forwards() + long_forwards);
    let short_samples = run_job(short, &job, control)?;
    let mut short_mean = mean_over_samples(&short_samples, s, rows * ls);
    crate::sampler::merge_observed(&mut short_mean, &x_short, &m_short);

    // Stage 2: long-term model conditioned on the short mean (frames 0..L_s, mask 1), its frames after
    // them the prior's fill from the first obs_len frames, for a model conditioned on it.
    let mut x_long = pad_frames(&short_mean, ls, ll, 0.0);
    if let Some(p) = long_prior {
        fill_with_prior(p, None, &mut x_long, &m_long, batch, ll, control)?;
    }
    let job = validate_job(
        long,
        Observation::checked_by_construction(&x_long, &m_long, long_shape),
        s,
        &options.sampler,
        noise.long,
        long_noise_name,
        stage::LONG,
    )?;
    let long_samples = run_job(long, &job, control)?;
    let samples = take_frames(&long_samples, ll, o, ll);
    let future_len = ll - o;
    let mean = mean_over_samples(&samples, s, rows * future_len);
    let repaired = take_frames(&short_mean, ls, 0, o);
    Ok(CascadeOutput {
        batch,
        num_features: k,
        num_samples: s,
        obs_len: o,
        short_len: ls,
        future_len,
        mean,
        samples,
        repaired,
        short_mean,
    })
}

/// Repairs (imputes) the mask-0 entries of an observation: runs `model` on `observed`, (B, K, O) with K
/// the model's `num_features` and O its `obs_len`, padded to its `seq_len` with mask-0 frames, and returns
/// the samples and their mean over the observed frames 0..O (mask-1 entries exact). A model conditioned
/// on a fill (`cond_fill` [`CondFill::Prior`]) needs `fill`: a repair fill (anchor [`Anchor::Window`])
/// with the model's K and `obs_len` = its `seq_len`, whose correction of the spline-filled window
/// ([`crate::prior_fill`]) the masked entries hold, computed once before the chains as the cascade does with
/// the prior forecaster; `fill` is unused otherwise. `forecaster`: the prior forecaster, required where
/// the fill fills whole-frame gaps with it (`gap_fill` [`crate::GapFill::Forecaster`]), unused otherwise.
/// `options.num_samples` 0 returns that fill alone, no samples ([`fill_alone`]).
pub fn repair(
    model: &Denoiser,
    fill: Option<&Prior>,
    forecaster: Option<&Prior>,
    observed: &Observation<'_>,
    options: &ForecastOptions,
    noise: Noise<'_>,
    control: &Control,
) -> Result<RepairOutput> {
    let (k, o, l) = (model.num_features(), model.obs_len(), model.seq_len());
    let fill = repair_fill(model, fill)?;
    let gaps = match fill {
        Some(f) => gap_forecaster(f, forecaster)?,
        None => None,
    };
    observed.expect(k, "the model's", Some((o, "obs_len")))?;
    let batch = observed.batch();
    let s = options.num_samples;
    let mut x = pad_frames(
        &zero_unobserved(observed.values(), observed.mask()),
        o,
        l,
        0.0,
    );
    let m = pad_frames(observed.mask(), o, l, 0.0);
    if let Some(f) = fill {
        fill_with_prior(f, gaps, &mut x, &m, batch, l, control)?;
    }
    if s == 0 {
        return fill_alone(fill.is_some(), &x, noise, [batch, k, o, l]);
    }
    let job = validate_job(
        model,
        Observation::checked_by_construction(&x, &m, [batch, k, l]),
        s,
        &options.sampler,
        noise,
        "noise",
        stage::SHORT,
    )?;
    control.expect(job.forwards());
    let all = run_job(model, &job, control)?;
    let samples = take_frames(&all, l, 0, o);
    let mut mean = mean_over_samples(&samples, s, batch * k * o);
    crate::sampler::merge_observed(&mut mean, &take_frames(&x, l, 0, o), observed.mask());
    Ok(RepairOutput {
        batch,
        num_features: k,
        num_samples: s,
        obs_len: o,
        mean,
        samples,
    })
}

/// A repair of no samples (`num_samples` 0): the repair fill alone, the window `x` (B, K, L) the chains would
/// start from, over its first O frames; no chain runs, so the sampler and the seed are unused. The fill is
/// deterministic and, on the repair benchmark, below the mean of 5 samples around it on every pattern
/// (docs/repair.md, "The fill alone"): the diffusion adds more spread than its mean corrects. A model
/// without a fill has nothing to return but its input, so 0 is an error for it.
fn fill_alone(
    has_fill: bool,
    x: &[f32],
    noise: Noise<'_>,
    [batch, k, o, l]: [usize; 4],
) -> Result<RepairOutput> {
    if !has_fill {
        return Err(Error::invalid_input(
            "num_samples",
            "at least 1 (0, the repair fill alone, needs a repair model conditioned on a repair fill, cond_fill \"prior\")",
            "0",
        ));
    }
    if let Noise::Injected(data) = noise {
        crate::error::check_len(
            "noise",
            data.len(),
            0,
            "(0, n + 1, B, K, L): no samples, no noise",
        )?;
    }
    Ok(RepairOutput {
        batch,
        num_features: k,
        num_samples: 0,
        obs_len: o,
        mean: take_frames(x, l, 0, o),
        samples: Vec::new(),
    })
}

/// The repair fill a repair `model` runs with: `None` for a model not conditioned on a fill; for a
/// [`CondFill::Prior`] model `fill`, which must be given, be a repair fill (anchor [`Anchor::Window`]) and
/// have the model's `num_features` and `obs_len` = its `seq_len`.
fn repair_fill<'p>(model: &Denoiser, fill: Option<&'p Prior>) -> Result<Option<&'p Prior>> {
    if model.config().model.cond_fill != CondFill::Prior {
        return Ok(None);
    }
    let (k, l) = (model.num_features(), model.seq_len());
    let Some(f) = fill else {
        return Err(Error::invalid_input(
            "fill",
            "the repair fill (repair_fill.safetensors): the repair model is conditioned on it (cond_fill \"prior\")",
            "none",
        ));
    };
    if f.config().model.anchor != Anchor::Window || f.num_features() != k || f.obs_len() != l {
        return Err(Error::invalid_input(
            "fill",
            format!("a repair fill (anchor \"window\") with the repair model's num_features = {k} and obs_len = its seq_len = {l}"),
            format!(
                "anchor {:?}, num_features = {}, obs_len = {}",
                f.config().model.anchor,
                f.num_features(),
                f.obs_len()
            ),
        ));
    }
    Ok(Some(f))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_helpers() {
        let src = [1.0, 2.0, 3.0, 4.0];
        assert_eq!(
            pad_frames(&src, 2, 3, 0.0),
            vec![1.0, 2.0, 0.0, 3.0, 4.0, 0.0]
        );
        assert_eq!(
            take_frames(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 3, 1, 3),
            vec![2.0, 3.0, 5.0, 6.0]
        );
        assert_eq!(
            mean_over_samples(&[1.0, 2.0, 3.0, 6.0], 2, 2),
            vec![2.0, 4.0]
        );
        assert_eq!(
            zero_unobserved(&[f32::NAN, 2.0], &[0.0, 1.0]),
            vec![0.0, 2.0]
        );
    }
}
