//! The TCD cascade (TCD_REFERENCE.md section 5) and observation repair.
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
//! stage's observation ([`prior_fill`]: `training.model.prior_fill`). The fill depends on the
//! observation only, the same at every step and for every sample, so it is computed once per stage,
//! before the chains, and written into the masked entries of the stage's `observed`, where the
//! denoiser reads it (as its observed channel and as the base of the `prior_residual` target). The
//! short stage fills its padded observation; the long stage fills its window (the short mean over the
//! first L_s frames, mask 1) from its first `prior.obs_len` frames, so only its frames L_s..L_l change.

use crate::config::CondFill;
use crate::control::Control;
use crate::denoiser::{fill_spline, Denoiser};
use crate::error::{Error, Result};
use crate::observation::Observation;
use crate::prior::{inbetween_width, Anchor, GapFill, Prior};
use crate::rng::{stage, Noise, Sequences};
use crate::sampler::{run_job, validate_job, SamplerConfig};

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

/// The noise of a cascade.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CascadeNoise<'a> {
    /// Standard normals per stage: `short` (S, n + 1, B, K, L_s), `long` (S, n + 1, B, K, L_l).
    Injected { short: &'a [f32], long: &'a [f32] },
    /// Seeded ChaCha8 streams (see [`Noise`]); both stages number sequences alike.
    Seeded { seed: u64, sequences: Sequences<'a> },
}

impl CascadeNoise<'_> {
    fn stage(&self, long: bool) -> Noise<'_> {
        match *self {
            CascadeNoise::Injected { short, long: l } => {
                Noise::Injected(if long { l } else { short })
            }
            CascadeNoise::Seeded { seed, sequences } => Noise::Seeded { seed, sequences },
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

/// `observed` with its mask-0 entries replaced by the prior's fill (`training.model.prior_fill`), (B, K, L)
/// like it: over the first O = `prior.obs_len()` frames of every row the natural cubic spline through
/// that row's observed entries among them ([`fill_spline`], the reference's bits), after them the prior's
/// rollout ([`Prior::predict`]) from those O filled frames (frame O + i is its i-th forecast frame).
/// A repair fill (anchor [`Anchor::Window`], L = O) corrects the spline-filled window instead: its
/// output fills every mask-0 entry, and one with `gap_fill` [`GapFill::Forecaster`] then fills the
/// window's whole-frame gaps from `forecaster` ([`fill_gaps`]; required for it, unused otherwise).
/// Mask-1 entries are kept (a long-term window's given frames after O too); mask-0 entries of
/// `observed` are never read. Needs the prior's K and L > O (L = O for a repair fill); `control` can
/// stop the rollout.
pub fn prior_fill(
    prior: &Prior,
    forecaster: Option<&Prior>,
    observed: &Observation<'_>,
    control: &Control,
) -> Result<Vec<f32>> {
    let (k, o) = (prior.num_features(), prior.obs_len());
    observed.expect(k, "the prior's", None)?;
    let [batch, _, length] = observed.shape();
    if prior.config().model.anchor == Anchor::Window && length != o {
        return Err(Error::invalid_input(
            "length",
            format!("the repair fill's window (obs_len = {o} frames)"),
            length.to_string(),
        ));
    }
    if prior.config().model.anchor == Anchor::Last && length <= o {
        return Err(Error::invalid_input(
            "length",
            format!("more frames than the prior reads (obs_len = {o})"),
            length.to_string(),
        ));
    }
    let gaps = gap_forecaster(prior, forecaster)?;
    let mut values = observed.values().to_vec();
    fill_with_prior(
        prior,
        gaps,
        &mut values,
        observed.mask(),
        batch,
        length,
        control,
    )?;
    Ok(values)
}

/// The forecaster a repair fill runs its gap fill with: `None` for a fill without one (`gap_fill`
/// [`GapFill::None`]); for [`GapFill::Forecaster`] `forecaster`, which must be given, be a forecaster
/// (anchor [`Anchor::Last`]) and have the fill's `num_features`.
fn gap_forecaster<'p>(fill: &Prior, forecaster: Option<&'p Prior>) -> Result<Option<&'p Prior>> {
    if fill.config().model.gap_fill == GapFill::None {
        return Ok(None);
    }
    let k = fill.num_features();
    match forecaster {
        None => Err(Error::invalid_input(
            "forecaster",
            "the prior forecaster (prior.safetensors): the repair fill fills whole-frame gaps with it \
             (gap_fill \"forecaster\")",
            "none",
        )),
        Some(f) if f.config().model.anchor != Anchor::Last || f.num_features() != k => {
            Err(Error::invalid_input(
                "forecaster",
                format!("a prior forecaster (anchor \"last\") with the repair fill's num_features = {k}"),
                format!(
                    "anchor {:?}, num_features = {}",
                    f.config().model.anchor,
                    f.num_features()
                ),
            ))
        }
        Some(f) => Ok(Some(f)),
    }
}

/// The maximal runs `[start, end)` of frames `0..length` where `hidden(t)`.
fn hidden_runs(length: usize, hidden: impl Fn(usize) -> bool) -> Vec<(usize, usize)> {
    let mut runs = Vec::new();
    let mut t = 0;
    while t < length {
        if !hidden(t) {
            t += 1;
            continue;
        }
        let start = t;
        while t < length && hidden(t) {
            t += 1;
        }
        runs.push((start, t));
    }
    runs
}

/// The runs of frames `[start, end)` of each sequence of a (B, K, L) `mask` in which every entry is
/// mask 0, as (sequence, start, end), except a run over the whole window (nothing to fill it from).
fn whole_frame_gaps(mask: &[f32], batch: usize, length: usize) -> Vec<(usize, usize, usize)> {
    let k = mask.len() / (batch * length);
    let mut gaps = Vec::new();
    for (b, m) in mask.chunks_exact(k * length).enumerate() {
        let hidden = |t: usize| (0..k).all(|kk| m[kk * length + t] <= 0.5);
        for (start, end) in hidden_runs(length, hidden) {
            if start > 0 || end < length {
                gaps.push((b, start, end));
            }
        }
    }
    gaps
}

/// Fills the whole-frame `gaps` ([`whole_frame_gaps`]) of a filled (B, K, L) window in place
/// (`training.model.fill_gaps`, the same steps). For a gap of n frames [s, e), with weights
/// w_i = (i + 1) / (n + 1):
/// * forward (s > 0): `forecaster` predicts n + 1 frames from the frames before the gap (its last
///   `obs_len`, the first repeated before them where fewer); frame s + i is its i-th frame, plus
///   w_i times the miss of its n-th frame against frame e where the window goes on (so it arrives there);
/// * backward (e < L): the same on the time-reversed frames after the gap (the prior trains with time
///   flips), reversed back, meeting frame s - 1;
/// * the two blended as (1 - w_i) forward + w_i backward (one alone at a window's edge), and that
///   averaged with the fill already there (the repair fill's correction of the spline).
///
/// Every history is read from the fill as it was before any gap is filled, and all of them are
/// predicted in one call. What it gains: docs/repair.md, "Whole-frame gaps".
fn fill_gaps(
    forecaster: &Prior,
    values: &mut [f32],
    gaps: &[(usize, usize, usize)],
    length: usize,
    control: &Control,
) -> Result<()> {
    if gaps.is_empty() {
        return Ok(());
    }
    let (k, o) = (forecaster.num_features(), forecaster.obs_len());
    let at = |b: usize, kk: usize, t: usize| (b * k + kk) * length + t;
    // One history (O, K) frame-major per side of each gap: frame `frame(j)` of the window at step j.
    let mut histories = Vec::new();
    let mut count = 0;
    let mut push = |b: usize, frame: &dyn Fn(usize) -> usize| {
        for j in 0..o {
            let t = frame(j);
            histories.extend((0..k).map(|kk| values[at(b, kk, t)]));
        }
        count += 1;
        count - 1
    };
    let mut sides = Vec::with_capacity(gaps.len());
    for &(b, s, e) in gaps {
        // The last O frames before s (forward), or of the frames after e read backwards, the first
        // repeated before them where there are fewer.
        let fwd = (s > 0).then(|| push(b, &|j| (s + j).saturating_sub(o)));
        let bwd = (e < length).then(|| {
            let after = length - e;
            push(b, &|j| length - 1 - (after + j).saturating_sub(o))
        });
        sides.push((fwd, bwd));
    }
    let horizon = gaps.iter().map(|&(_, s, e)| e - s + 1).max().unwrap_or(1);
    let out = forecaster.predict(&histories, count, o, horizon, control)?; // (count, horizon, K)
    let pred = |row: usize, i: usize, kk: usize| out[(row * horizon + i) * k + kk];
    for (&(b, s, e), &(fwd, bwd)) in gaps.iter().zip(&sides) {
        let n = e - s;
        for kk in 0..k {
            // Each side's miss at the frame it should arrive at (0 at a window's edge).
            let fwd_miss = match fwd {
                Some(r) if e < length => values[at(b, kk, e)] - pred(r, n, kk),
                _ => 0.0,
            };
            let bwd_miss = match bwd {
                Some(r) if s > 0 => values[at(b, kk, s - 1)] - pred(r, n, kk),
                _ => 0.0,
            };
            for i in 0..n {
                let w = (i + 1) as f32 / (n + 1) as f32;
                let forward = fwd.map(|r| pred(r, i, kk) + w * fwd_miss);
                // Backward frame i is its forecast's frame n - 1 - i, whose weight is 1 - w.
                let backward = bwd.map(|r| pred(r, n - 1 - i, kk) + (1.0 - w) * bwd_miss);
                let both = match (forward, backward) {
                    (Some(f), Some(g)) => (1.0 - w) * f + w * g,
                    (Some(f), None) => f,
                    (None, Some(g)) => g,
                    (None, None) => unreachable!("a gap over the whole window is not filled"),
                };
                let v = &mut values[at(b, kk, s + i)];
                *v = 0.5 * (both + *v);
            }
        }
    }
    Ok(())
}

/// [`prior_fill`] in place on `values` with `mask`, (B, K, L) of a checked observation with the prior's K
/// and L > its obs_len (L = obs_len for a repair fill, anchor [`Anchor::Window`]); `gaps`: the repair
/// fill's checked gap forecaster ([`gap_forecaster`]), whose [`fill_gaps`] then runs, `None` otherwise.
fn fill_with_prior(
    prior: &Prior,
    gaps: Option<&Prior>,
    values: &mut [f32],
    mask: &[f32],
    batch: usize,
    length: usize,
    control: &Control,
) -> Result<()> {
    let (k, o) = (prior.num_features(), prior.obs_len());
    let window = prior.config().model.anchor == Anchor::Window;
    // A forecaster rolls out the frames after O; a repair fill corrects the O frames it reads.
    let horizon = if window { o } else { length - o };
    // The filled first O frames, frame-major (B, O, K) as the prior reads them.
    let mut head = vec![0.0f32; batch * o * k];
    let mut row_head = vec![0.0f32; o];
    for (r, (row, m)) in values
        .chunks_exact(length)
        .zip(mask.chunks_exact(length))
        .enumerate()
    {
        row_head.copy_from_slice(&row[..o]);
        fill_spline(&m[..o], &row[..o], |ll, v| row_head[ll] = v);
        let (b, kk) = (r / k, r % k);
        for (t, &v) in row_head.iter().enumerate() {
            head[(b * o + t) * k + kk] = v;
        }
    }
    let out = prior.predict(&head, batch, o, horizon, control)?; // (B, horizon, K): the rollout, or the corrected window
    for (r, (row, m)) in values
        .chunks_exact_mut(length)
        .zip(mask.chunks_exact(length))
        .enumerate()
    {
        let (b, kk) = (r / k, r % k);
        for (ll, (v, &mv)) in row.iter_mut().zip(m).enumerate() {
            if mv > 0.5 {
                continue;
            }
            *v = if window {
                out[(b * o + ll) * k + kk]
            } else if ll < o {
                head[(b * o + ll) * k + kk]
            } else {
                out[(b * horizon + ll - o) * k + kk]
            };
        }
    }
    let m = &prior.config().model;
    if window && (gaps.is_some() || m.inbetween_max_gap > 0 || m.joint_inbetween_max_gap > 0) {
        // the window's whole-frame gaps, which the gap fill fills and the in-betweeners correct
        let frame_gaps = whole_frame_gaps(mask, batch, length);
        if let Some(f) = gaps {
            fill_gaps(f, values, &frame_gaps, length, control)?;
        }
        inbetween(prior, values, mask, &frame_gaps, batch, length);
    }
    Ok(())
}

/// A repair fill's in-betweeners on its gap-filled (B, K, L) window, in place (`training.inbetween`, the same
/// arithmetic in f64; what they gain: docs/repair.md): the whole-frame gaps ([`whole_frame_gaps`]) of a length
/// with a kernel (`inbetween_n`), every coordinate of the gap; then, per coordinate, each run of hidden frames
/// with no frame of a whole-frame gap, not the whole window, of a length with a joint kernel
/// (`joint_inbetween_n`). Every input is read from the window before any correction is added.
fn inbetween(
    prior: &Prior,
    values: &mut [f32],
    mask: &[f32],
    gaps: &[(usize, usize, usize)],
    batch: usize,
    length: usize,
) {
    let m = &prior.config().model;
    if m.inbetween_max_gap == 0 && m.joint_inbetween_max_gap == 0 {
        return;
    }
    let k = prior.num_features();
    let src = values.to_vec();
    for &(b, s, e) in gaps {
        if let Some(w) = prior.inbetween_kernel(e - s) {
            for kk in 0..k {
                let row = (b * k + kk) * length;
                let out = &mut values[row..row + length];
                run_correction(&src[row..row + length], out, (s, e), m.inbetween_context, w);
            }
        }
    }
    if m.joint_inbetween_max_gap == 0 {
        return;
    }
    let mut in_gap = vec![false; batch * length];
    for &(b, s, e) in gaps {
        in_gap[b * length + s..b * length + e].fill(true);
    }
    for (r, m_row) in mask.chunks_exact(length).enumerate() {
        let (b, row) = (r / k, r * length);
        for (s, t) in hidden_runs(length, |t| m_row[t] <= 0.5) {
            let whole = s == 0 && t == length;
            if whole || in_gap[b * length + s..b * length + t].iter().any(|&g| g) {
                continue;
            }
            if let Some(w) = prior.joint_inbetween_kernel(t - s) {
                let out = &mut values[row..row + length];
                run_correction(
                    &src[row..row + length],
                    out,
                    (s, t),
                    m.joint_inbetween_context,
                    w,
                );
            }
        }
    }
}

/// One row's correction over its frames [s, e) (n = e − s) by kernel `w` (n × [`inbetween_width`]) with
/// `c` context frames: the inputs are the row of `src` over frames s − c .. e + c (indices clamped to the
/// row) minus its frame s − 1 (clamped), the fractions of the c context frames inside the row before and
/// after, and that segment times each fraction; `out`[s + i] gets w_i · inputs added (f64 sums).
fn run_correction(src: &[f32], out: &mut [f32], (s, e): (usize, usize), c: usize, w: &[f32]) {
    let (length, n) = (src.len(), e - s);
    let (seg, d) = (2 * c + n, inbetween_width(n, c));
    let at = |t: isize| f64::from(src[t.clamp(0, length as isize - 1) as usize]);
    let before = s.min(c) as f64 / c as f64;
    let after = (length - e).min(c) as f64 / c as f64;
    let base = at(s as isize - 1);
    let mut x = vec![0.0f64; d];
    x[seg] = before;
    x[seg + 1] = after;
    for j in 0..seg {
        let r = at(s as isize - c as isize + j as isize) - base;
        x[j] = r;
        x[seg + 2 + j] = r * before;
        x[2 * seg + 2 + j] = r * after;
    }
    for (i, wi) in w.chunks_exact(d).enumerate() {
        let correction: f64 = wi.iter().zip(&x).map(|(&a, &v)| f64::from(a) * v).sum();
        out[s + i] = (f64::from(out[s + i]) + correction) as f32;
    }
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
        noise.stage(true),
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
        noise.stage(false),
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
        noise.stage(true),
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
/// ([`prior_fill`]) the masked entries hold, computed once before the chains as the cascade does with
/// the prior forecaster; `fill` is unused otherwise. `forecaster`: the prior forecaster, required where
/// the fill fills whole-frame gaps with it (`gap_fill` [`GapFill::Forecaster`]), unused otherwise.
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
