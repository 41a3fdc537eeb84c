//! Samplers: timestep spacing, per-step plans, and the chain loop.
//!
//! A *chain* is one sample of one sequence: x_T → ... → x₀, then merged with the observation
//! (`x·(1−m) + x₀_obs·m`, observed entries returned bit-identical). Chains are independent and
//! run in parallel with rayon; each owns its noise stream (see [`crate::rng`]), so the results do
//! not depend on the number of threads.
//!
//! Every update steps with ε̂. A model that predicts x₀ (`prediction_type` `sample`) has its output
//! turned into ε̂ right after each forward ([`SampleToNoise`], set per step by [`Plan::for_prediction`]),
//! so ddpm, ddim and dpmpp2m serve both.

mod ddim;
mod ddpm;
mod dpmpp;

use std::str::FromStr;

use rayon::prelude::*;

use crate::config::{CondFill, PredictionType, VarianceType};
use crate::control::Control;
use crate::denoiser::{CondTables, Denoiser, SequenceInputs, Workspace};
use crate::error::{check_len, check_positive, Error, Result};
use crate::observation::Observation;
use crate::rng::{stage, Centres, ChainNoise, Noise, NoiseCoupling};
use crate::schedule::NoiseSchedule;
use crate::validate;

use ddim::DdimStep;
use ddpm::DdpmStep;
use dpmpp::DpmPp2mStep;

/// How `num_inference_steps` steps are placed among the T training steps (diffusers semantics).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimestepSpacing {
    /// t = arange(n) · (T // n), reversed (for n = 5, T = 50: 40, 30, 20, 10, 0).
    Leading,
    /// t = round(arange(T, 0, −T/n)) − 1 (for n = 5, T = 50: 49, 39, 29, 19, 9).
    Trailing,
    /// t = round(linspace(0, T − 1, n)), reversed.
    Linspace,
}

impl TimestepSpacing {
    /// Every spacing's name, the default (`trailing`) first.
    pub const NAMES: [&'static str; 3] = ["trailing", "leading", "linspace"];

    /// `leading` | `trailing` | `linspace`.
    pub fn as_str(self) -> &'static str {
        match self {
            TimestepSpacing::Leading => "leading",
            TimestepSpacing::Trailing => "trailing",
            TimestepSpacing::Linspace => "linspace",
        }
    }
}

impl FromStr for TimestepSpacing {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "leading" => Ok(TimestepSpacing::Leading),
            "trailing" => Ok(TimestepSpacing::Trailing),
            "linspace" => Ok(TimestepSpacing::Linspace),
            other => Err(Error::invalid_input(
                "timestep_spacing",
                "\"leading\", \"trailing\" or \"linspace\"",
                format!("{other:?}"),
            )),
        }
    }
}

/// The descending training steps visited by a sampler with `num_inference_steps` steps.
/// Rounding is numpy's (half to even).
pub(crate) fn timesteps(
    num_train_timesteps: usize,
    num_inference_steps: usize,
    spacing: TimestepSpacing,
) -> Result<Vec<usize>> {
    let (t_total, n) = (num_train_timesteps, num_inference_steps);
    if n == 0 || n > t_total {
        return Err(Error::invalid_input(
            "num_inference_steps",
            format!("an integer in 1..{t_total} (num_train_timesteps = {t_total})"),
            n.to_string(),
        ));
    }
    let ts: Vec<usize> = match spacing {
        TimestepSpacing::Leading => {
            let ratio = t_total / n;
            (0..n).rev().map(|i| i * ratio).collect()
        }
        TimestepSpacing::Trailing => {
            let ratio = t_total as f64 / n as f64;
            (0..n)
                .map(|i| {
                    let v = (t_total as f64 - i as f64 * ratio).round_ties_even();
                    (v as usize).saturating_sub(1)
                })
                .collect()
        }
        TimestepSpacing::Linspace => crate::schedule::linspace(0.0, (t_total - 1) as f64, n)
            .into_iter()
            .rev()
            .map(|v| v.round_ties_even() as usize)
            .collect(),
    };
    Ok(ts)
}

/// The stochastic part of a DDPM / DDIM step: x ← x + σ z, element-wise in f32, where σ > 0 (a
/// deterministic step, σ = 0, reads no noise).
fn add_noise(x: &mut [f32], z: &[f32], sigma: f64) {
    if sigma > 0.0 {
        let s = sigma as f32;
        for (xv, zv) in x.iter_mut().zip(z) {
            *xv += s * zv;
        }
    }
}

/// (t_i, t_{i+1}) pairs; `None` after the last step (ᾱ = 1).
fn step_pairs(timesteps: &[usize]) -> Vec<(usize, Option<usize>)> {
    timesteps
        .iter()
        .enumerate()
        .map(|(i, &t)| (t, timesteps.get(i + 1).copied()))
        .collect()
}

/// Which update rule a sampler uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SamplerKind {
    /// Ancestral DDPM; over all T steps it is the TCD reference.
    Ddpm,
    /// DDIM with stochasticity `eta` ∈ [0, 1].
    Ddim { eta: f64 },
    /// DPM-Solver++(2M): deterministic multistep solver (one noise block per chain, x_T).
    DpmPp2m,
}

impl SamplerKind {
    /// Every sampler's name, the default (`ddpm`, the paper's) first.
    pub const NAMES: [&'static str; 3] = ["ddpm", "ddim", "dpmpp2m"];
}

/// A sampler: update rule, number of steps and their spacing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SamplerConfig {
    pub kind: SamplerKind,
    /// `None`: every training step (n = T).
    pub num_inference_steps: Option<usize>,
    pub timestep_spacing: TimestepSpacing,
    /// How the S chains of a sequence share x_T ([`NoiseCoupling`]; independent by default).
    pub noise_coupling: NoiseCoupling,
}

impl SamplerConfig {
    /// The sampler named by the settings of the Python `SamplerOptions` and the command line: the one
    /// check of their values. `sampler` is one of [`SamplerKind::NAMES`], `timestep_spacing` one of
    /// [`TimestepSpacing::NAMES`], `noise_coupling` one of [`NoiseCoupling::NAMES`], and `eta` must lie
    /// in [0, 1] whatever the sampler (only DDIM uses it, but a bad value is refused rather than
    /// ignored). `num_inference_steps` is checked against a model's training steps by
    /// [`SamplerConfig::plan`].
    pub fn from_names(
        sampler: &str,
        num_inference_steps: Option<usize>,
        eta: f64,
        timestep_spacing: &str,
        noise_coupling: &str,
    ) -> Result<Self> {
        ddim::check_eta(eta)?;
        let kind = match sampler {
            "ddpm" => SamplerKind::Ddpm,
            "ddim" => SamplerKind::Ddim { eta },
            "dpmpp2m" => SamplerKind::DpmPp2m,
            other => {
                return Err(Error::invalid_input(
                    "sampler",
                    "\"ddpm\", \"ddim\" or \"dpmpp2m\"",
                    format!("{other:?}"),
                ))
            }
        };
        if num_inference_steps == Some(0) {
            return Err(Error::invalid_input(
                "num_inference_steps",
                "at least 1 (or None for every training step)",
                "0",
            ));
        }
        Ok(SamplerConfig {
            kind,
            num_inference_steps,
            timestep_spacing: timestep_spacing.parse()?,
            noise_coupling: noise_coupling.parse()?,
        })
    }

    /// The reference: DDPM over all T steps.
    pub fn ddpm() -> Self {
        SamplerConfig {
            kind: SamplerKind::Ddpm,
            num_inference_steps: None,
            timestep_spacing: TimestepSpacing::Trailing,
            noise_coupling: NoiseCoupling::Independent,
        }
    }

    /// DDIM with `num_inference_steps` trailing-spaced steps.
    pub fn ddim(num_inference_steps: usize, eta: f64) -> Self {
        SamplerConfig {
            kind: SamplerKind::Ddim { eta },
            num_inference_steps: Some(num_inference_steps),
            timestep_spacing: TimestepSpacing::Trailing,
            noise_coupling: NoiseCoupling::Independent,
        }
    }

    /// DPM-Solver++(2M) with `num_inference_steps` trailing-spaced steps.
    pub fn dpmpp2m(num_inference_steps: usize) -> Self {
        SamplerConfig {
            kind: SamplerKind::DpmPp2m,
            num_inference_steps: Some(num_inference_steps),
            timestep_spacing: TimestepSpacing::Trailing,
            noise_coupling: NoiseCoupling::Independent,
        }
    }

    /// The per-step coefficients for a model with this schedule and `variance` (its `variance_type`).
    pub fn plan(&self, schedule: &NoiseSchedule, variance: VarianceType) -> Result<Plan> {
        let t_total = schedule.num_train_timesteps();
        let n = self.num_inference_steps.unwrap_or(t_total);
        let ts = timesteps(t_total, n, self.timestep_spacing)?;
        let steps = match self.kind {
            SamplerKind::Ddpm => step_pairs(&ts)
                .into_iter()
                .map(|(t, prev)| PlanStep {
                    t,
                    prev,
                    update: Update::Ddpm(DdpmStep::new(schedule, t, prev, variance)),
                    to_noise: None,
                })
                .collect(),
            SamplerKind::Ddim { eta } => {
                ddim::check_eta(eta)?;
                step_pairs(&ts)
                    .into_iter()
                    .map(|(t, prev)| PlanStep {
                        t,
                        prev,
                        update: Update::Ddim(DdimStep::new(schedule, t, prev, eta)),
                        to_noise: None,
                    })
                    .collect()
            }
            SamplerKind::DpmPp2m => DpmPp2mStep::plan(schedule, &ts)
                .into_iter()
                .zip(step_pairs(&ts))
                .map(|(st, (t, prev))| PlanStep {
                    t,
                    prev,
                    update: Update::DpmPp2m(st),
                    to_noise: None,
                })
                .collect(),
        };
        Ok(Plan { steps })
    }
}

impl Default for SamplerConfig {
    fn default() -> Self {
        Self::ddpm()
    }
}

/// The update of one step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Update {
    Ddpm(DdpmStep),
    Ddim(DdimStep),
    DpmPp2m(DpmPp2mStep),
}

/// x₀-prediction's output as the noise the updates step with (`training.diffusion.predicted_noise`):
/// `ε̂ = (x_t − a · out) · inv_s` in f32, with `a = √ᾱ_t` and `inv_s = 1/√(1 − ᾱ_t)` computed in f64 and
/// rounded once, the reference's operations in its order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct SampleToNoise {
    /// √ᾱ_t, rounded to f32.
    pub(crate) a: f32,
    /// 1/√(1 − ᾱ_t), rounded to f32.
    pub(crate) inv_s: f32,
}

impl SampleToNoise {
    /// The conversion at training step `t`.
    pub(crate) fn new(schedule: &NoiseSchedule, t: usize) -> Self {
        let alpha_bar = schedule.alpha_bar(Some(t));
        SampleToNoise {
            a: alpha_bar.sqrt() as f32,
            inv_s: (1.0 / (1.0 - alpha_bar).sqrt()) as f32,
        }
    }

    /// `out` (the network's x̂₀ on entry) ← (x − a · out) · inv_s, element-wise.
    pub(crate) fn apply(&self, x: &[f32], out: &mut [f32]) {
        let (a, inv_s) = (self.a, self.inv_s);
        for (ov, &xv) in out.iter_mut().zip(x) {
            *ov = (xv - a * *ov) * inv_s;
        }
    }
}

/// One planned step: network at `t`, then the update towards `prev`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PlanStep {
    pub(crate) t: usize,
    pub(crate) prev: Option<usize>,
    pub(crate) update: Update,
    /// For an x₀-predicting model, how its output becomes the noise before the update
    /// ([`Plan::for_prediction`]); `None`: the output is the noise.
    pub(crate) to_noise: Option<SampleToNoise>,
}

impl PlanStep {
    /// Applies the update to x given ε̂, z (read only by steps that [`use noise`](Self::uses_noise))
    /// and the chain's multistep state `prev_x0` (the previous x̂₀; read and written only by
    /// multistep updates, see [`Plan::is_multistep`]; may be empty otherwise), which the
    /// [`Sampler`] of the chain owns.
    fn apply(&self, x: &mut [f32], eps: &[f32], z: &[f32], prev_x0: &mut [f32]) {
        match &self.update {
            Update::Ddpm(s) => s.apply(x, eps, z),
            Update::Ddim(s) => s.apply(x, eps, z),
            Update::DpmPp2m(s) => s.apply(x, eps, prev_x0),
        }
    }

    /// Whether the step consumes a noise block z (ddpm, ddim; not dpmpp2m).
    pub(crate) fn uses_noise(&self) -> bool {
        !matches!(self.update, Update::DpmPp2m(_))
    }
}

/// The steps of a sampler for one model.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    pub(crate) steps: Vec<PlanStep>,
}

impl Plan {
    /// n.
    pub fn num_steps(&self) -> usize {
        self.steps.len()
    }

    /// Noise blocks per chain: n + 1 (x_T, then one z per step) for ddpm / ddim; 1 (x_T only) for
    /// the deterministic dpmpp2m.
    pub fn num_noise_blocks(&self) -> usize {
        if self.steps.iter().all(PlanStep::uses_noise) {
            self.steps.len() + 1
        } else {
            1
        }
    }

    /// Whether the updates keep the previous x̂₀ (DPM-Solver++(2M)).
    pub fn is_multistep(&self) -> bool {
        self.steps
            .iter()
            .any(|s| matches!(s.update, Update::DpmPp2m(_)))
    }

    /// The visited training steps, descending.
    pub fn timesteps(&self) -> Vec<usize> {
        self.steps.iter().map(|s| s.t).collect()
    }

    /// The plan for a model that predicts `prediction` on `schedule`: with [`PredictionType::Sample`]
    /// every step first turns the output into the noise, `ε̂ = (x_t − √ᾱ_t · out) · (1/√(1 − ᾱ_t))` at
    /// its `t` (`training.diffusion.predicted_noise`; [`Sampler::step`] applies it).
    pub fn for_prediction(mut self, prediction: PredictionType, schedule: &NoiseSchedule) -> Self {
        for step in &mut self.steps {
            step.to_noise = match prediction {
                PredictionType::Epsilon => None,
                PredictionType::Sample => Some(SampleToNoise::new(schedule, step.t)),
            };
        }
        self
    }
}

/// A [`Plan`] run on one chain: the sampler's state between steps, kept here as diffusers' schedulers
/// keep theirs (`DPMSolverMultistepScheduler.model_outputs`): the index of the next step and, for the
/// multistep DPM-Solver++(2M), the previous x̂₀. The caller runs the network at [`Sampler::timestep`]
/// and hands its output (and the step's noise block, for ddpm / ddim) to [`Sampler::step`]; it manages
/// no state of the sampler. One per chain, or [`Sampler::reset`] before the next chain.
#[derive(Clone, Debug)]
pub struct Sampler<'p> {
    plan: &'p Plan,
    /// The values of a chain (K·L).
    len: usize,
    /// The index in `plan.steps` of the next step.
    next: usize,
    /// DPM-Solver++(2M): the previous step's x̂₀ (empty for the one-step updates).
    prev_x0: Vec<f32>,
}

impl<'p> Sampler<'p> {
    /// A chain of `len` values (K·L) run with `plan`, at its first step.
    pub fn new(plan: &'p Plan, len: usize) -> Self {
        Sampler {
            plan,
            len,
            next: 0,
            prev_x0: vec![0.0; if plan.is_multistep() { len } else { 0 }],
        }
    }

    /// Back to the first step, the multistep state cleared: a new chain.
    pub fn reset(&mut self) {
        self.next = 0;
        self.prev_x0.fill(0.0);
    }

    /// The index of the next step in the plan (the steps taken so far); its noise block is block
    /// `index + 1` of the chain (block 0 is x_T).
    pub fn index(&self) -> usize {
        self.next
    }

    /// The training step at which the network runs for the next step; `None` once every step is taken.
    pub fn timestep(&self) -> Option<usize> {
        self.plan.steps.get(self.next).map(|s| s.t)
    }

    /// Takes the next step: `x` (x_t on entry) becomes x at the next training step (x̂₀ after the last).
    /// `output` is the network's output at [`Sampler::timestep`] for `x`; for an x₀-predicting plan
    /// ([`Plan::for_prediction`]) it is turned into the noise in place. `z` is the step's noise block,
    /// read only by the stochastic samplers (ddpm, ddim: [`Plan::num_noise_blocks`] > 1; may be empty
    /// otherwise). Errors past the last step or when a buffer does not have the chain's `len` values.
    pub fn step(&mut self, x: &mut [f32], output: &mut [f32], z: &[f32]) -> Result<()> {
        let num_steps = self.plan.num_steps();
        let Some(step) = self.plan.steps.get(self.next) else {
            return Err(Error::invalid_input(
                "step",
                format!("one of the plan's {num_steps} steps (reset the sampler for a new chain)"),
                format!("step {} of {num_steps}", self.next + 1),
            ));
        };
        let shape = format!("({},) = (K·L,)", self.len);
        check_len("x", x.len(), self.len, &shape)?;
        check_len("output", output.len(), self.len, &shape)?;
        if step.uses_noise() {
            check_len("z", z.len(), self.len, &shape)?;
        }
        if let Some(to_noise) = &step.to_noise {
            to_noise.apply(x, output);
        }
        step.apply(x, output, z, &mut self.prev_x0);
        self.next += 1;
        Ok(())
    }
}

/// One chain's sequence: its conditioning tables, mask and observed values (K·L each).
pub(crate) struct ChainInputs<'a> {
    pub tables: &'a CondTables,
    pub mask: &'a [f32],
    pub observed: &'a [f32],
}

/// Runs one chain and returns the merged result (K·L values); `Err(Cancelled)` as soon as `control`
/// is cancelled (checked before every forward).
pub(crate) fn run_chain(
    denoiser: &Denoiser,
    chain: ChainInputs<'_>,
    plan: &Plan,
    noise: &mut ChainNoise<'_>,
    ws: &mut Workspace,
    control: &Control,
) -> Result<Vec<f32>> {
    let ChainInputs {
        tables,
        mask,
        observed,
    } = chain;
    let n = mask.len();
    let mut x = vec![0.0f32; n];
    let mut eps = vec![0.0f32; n];
    // Buffers a sampler does not use stay empty; nothing is allocated inside the step loop.
    let uses_noise = plan.num_noise_blocks() > 1;
    let mut z = vec![0.0f32; if uses_noise { n } else { 0 }];
    let mut sampler = Sampler::new(plan, n);
    noise.fill(0, &mut x);
    while let Some(t) = sampler.timestep() {
        control.check()?;
        let seq = SequenceInputs {
            tables,
            mask,
            noisy: &x,
            observed,
            step: t,
        };
        denoiser.forward_one(seq, &mut eps, ws);
        control.forward_done();
        if uses_noise {
            noise.fill(sampler.index() + 1, &mut z);
        }
        sampler.step(&mut x, &mut eps, &z)?;
    }
    denoiser.to_poses(&mut x, mask, observed);
    merge_observed(&mut x, observed, mask);
    Ok(x)
}

/// x ← x·(1−m) + observed·m for a binary mask: observed entries are copied bit for bit.
pub fn merge_observed(x: &mut [f32], observed: &[f32], mask: &[f32]) {
    for ((xv, &ov), &mv) in x.iter_mut().zip(observed).zip(mask) {
        if mv == 1.0 {
            *xv = ov;
        }
    }
}

/// Validated inputs of a sampling call.
pub(crate) struct SampleJob<'a> {
    pub observed: Observation<'a>,
    pub num_samples: usize,
    pub plan: Plan,
    pub noise: Noise<'a>,
    pub noise_coupling: NoiseCoupling,
    pub stage: u64,
}

/// Checks what a sampling call adds to its (checked) observation: that it fits the model, and for a model
/// conditioned on the prior that the fill it reads is finite; `num_samples`; the sampler (it builds the
/// plan); the noise (named `noise_argument` in errors).
pub(crate) fn validate_job<'a>(
    denoiser: &Denoiser,
    observed: Observation<'a>,
    num_samples: usize,
    sampler: &SamplerConfig,
    noise: Noise<'a>,
    noise_argument: &str,
    stage: u64,
) -> Result<SampleJob<'a>> {
    let k = denoiser.num_features();
    observed.expect(k, "the model's", None)?;
    let [batch, _, length] = observed.shape();
    check_positive("num_samples", num_samples)?;
    let shape = format!("({batch}, {k}, {length})");
    if denoiser.config().model.cond_fill == CondFill::Prior {
        // The masked entries hold the prior's fill, which the network reads (CondFill::Prior).
        let values = observed.values();
        validate::all_finite("observed", values, values.len(), &shape)?;
    }
    let diffusion = &denoiser.config().diffusion;
    let plan = sampler
        .plan(denoiser.schedule(), diffusion.variance_type)?
        .for_prediction(diffusion.prediction_type, denoiser.schedule());
    match noise {
        Noise::Injected(data) => {
            let blocks = plan.num_noise_blocks();
            let what = if blocks == 1 {
                "1 (x_T only: dpmpp2m draws no per-step noise)"
            } else {
                "num_inference_steps + 1"
            };
            let nshape =
                format!("({num_samples}, {blocks}, {batch}, {k}, {length}) = (num_samples, {what}, B, K, L)");
            check_len(
                noise_argument,
                data.len(),
                num_samples * blocks * batch * k * length,
                &nshape,
            )?;
            validate::all_finite(noise_argument, data, data.len(), &nshape)?;
        }
        Noise::Seeded { sequences, .. } => sequences.check(batch)?,
    }
    Ok(SampleJob {
        observed,
        num_samples,
        plan,
        noise,
        noise_coupling: sampler.noise_coupling,
        stage,
    })
}

impl SampleJob<'_> {
    /// The per-sequence forwards this job runs (for [`Control::expect`]).
    pub(crate) fn forwards(&self) -> usize {
        self.num_samples * self.observed.batch() * self.plan.num_steps()
    }
}

/// Runs every chain of a validated job in parallel; returns (S, B, K, L), or `Err(Cancelled)` when
/// `control` is cancelled while it runs.
pub(crate) fn run_job(
    denoiser: &Denoiser,
    job: &SampleJob<'_>,
    control: &Control,
) -> Result<Vec<f32>> {
    let (values, mask) = (job.observed.values(), job.observed.mask());
    let [batch, _, length] = job.observed.shape();
    let n = denoiser.num_features() * length;
    let tables = denoiser.cond_tables(length);
    let blocks = job.plan.num_noise_blocks();
    let num_chains = job.num_samples * batch;
    let centres = Centres::new(
        job.noise_coupling,
        job.noise,
        job.stage,
        job.num_samples,
        blocks,
        batch,
        n,
    );
    let threads = rayon::current_num_threads().max(1);
    // Whole rounds of one chain per thread first; the chains left over (fewer than the threads)
    // then split their forwards over the idle threads. 5 chains on 2 threads: 2 rounds of 2, then
    // the last chain on both threads, instead of a third round on one thread with the other idle.
    // Results do not depend on the split (a chain's forward is bitwise independent of it).
    let rest = num_chains % threads;
    let whole = num_chains - rest;
    let run = |range: std::ops::Range<usize>, split: usize| -> Result<Vec<Vec<f32>>> {
        range
            .into_par_iter()
            .map_init(
                || Workspace::with_threads(denoiser, length, split),
                |ws, c| {
                    let (s, b) = (c / batch, c % batch);
                    let centre = centres.as_ref().map(|c| c.of(b));
                    let mut noise =
                        ChainNoise::new(job.noise, job.stage, s, b, blocks, batch, centre);
                    let chain = ChainInputs {
                        tables: &tables,
                        mask: &mask[b * n..(b + 1) * n],
                        observed: &values[b * n..(b + 1) * n],
                    };
                    run_chain(denoiser, chain, &job.plan, &mut noise, ws, control)
                },
            )
            .collect()
    };
    let mut chains = run(0..whole, 1)?;
    if let Some(split) = threads.checked_div(rest) {
        chains.extend(run(whole..num_chains, split.max(1))?);
    }
    Ok(chains.concat())
}

/// Draws `num_samples` samples for each sequence of `observed`, whose K must be the model's
/// `num_features` (any L).
///
/// * `noise`: [`Noise::Injected`] with shape (S, blocks, B, K, L) (blocks = n + 1, or 1 for
///   dpmpp2m: [`Plan::num_noise_blocks`]), or [`Noise::Seeded`] (stage [`stage::SHORT`]).
///
/// Returns the merged samples, (S, B, K, L): observed entries are `observed.values()`, bit for bit.
/// `control` counts the forwards and can stop the call ([`Control`]; `&Control::default()` if unused).
pub fn sample(
    denoiser: &Denoiser,
    observed: &Observation<'_>,
    num_samples: usize,
    sampler: &SamplerConfig,
    noise: Noise<'_>,
    control: &Control,
) -> Result<Vec<f32>> {
    let job = validate_job(
        denoiser,
        *observed,
        num_samples,
        sampler,
        noise,
        "noise",
        stage::SHORT,
    )?;
    control.expect(job.forwards());
    run_job(denoiser, &job, control)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spacing_reference_lists() {
        let tr = |n| timesteps(50, n, TimestepSpacing::Trailing).unwrap();
        let le = |n| timesteps(50, n, TimestepSpacing::Leading).unwrap();
        let li = |n| timesteps(50, n, TimestepSpacing::Linspace).unwrap();
        assert_eq!(tr(5), vec![49, 39, 29, 19, 9]);
        assert_eq!(le(5), vec![40, 30, 20, 10, 0]);
        assert_eq!(li(5), vec![49, 37, 24, 12, 0]);
        // numpy: np.round(np.arange(50, 0, -12.5)) - 1 -> [49, 37, 24, 11] (half to even)
        assert_eq!(tr(4), vec![49, 37, 24, 11]);
        assert_eq!(tr(3), vec![49, 32, 16]);
        assert_eq!(tr(1), vec![49]);
        assert_eq!(le(1), vec![0]);
        assert_eq!(li(1), vec![0]);
        let all: Vec<usize> = (0..50).rev().collect();
        for sp in [
            TimestepSpacing::Leading,
            TimestepSpacing::Trailing,
            TimestepSpacing::Linspace,
        ] {
            assert_eq!(timesteps(50, 50, sp).unwrap(), all);
            for n in 1..=50 {
                let ts = timesteps(50, n, sp).unwrap();
                assert_eq!(ts.len(), n);
                assert!(ts.windows(2).all(|w| w[0] > w[1]), "{sp:?} n={n}: {ts:?}");
                assert!(ts[0] < 50);
            }
        }
    }

    #[test]
    fn spacing_errors_name_the_argument() {
        for n in [0, 51] {
            let e = timesteps(50, n, TimestepSpacing::Trailing).unwrap_err();
            assert!(e.to_string().contains("num_inference_steps"), "{e}");
        }
        let e = "middle".parse::<TimestepSpacing>().unwrap_err();
        assert!(e.to_string().contains("timestep_spacing"));
        assert_eq!(
            "linspace".parse::<TimestepSpacing>().unwrap(),
            TimestepSpacing::Linspace
        );
    }

    #[test]
    fn sample_to_noise_recovers_the_noise_of_an_exact_x0() {
        // x_t = sqrt(abar) x0 + sqrt(1 - abar) eps: given the exact x0 the conversion returns eps.
        let s = NoiseSchedule::from_betas(crate::schedule::cosine_betas(50, 0.5));
        for t in [0, 1, 17, 49] {
            let c = SampleToNoise::new(&s, t);
            let ab = s.alpha_bar(Some(t));
            assert_eq!(c.a, ab.sqrt() as f32);
            assert_eq!(c.inv_s, (1.0 / (1.0 - ab).sqrt()) as f32);
            let (x0, eps) = ([0.3f64, -1.2, 2.5], [0.7f64, -0.4, 1.9]);
            let x: Vec<f32> = x0
                .iter()
                .zip(&eps)
                .map(|(a, e)| (ab.sqrt() * a + (1.0 - ab).sqrt() * e) as f32)
                .collect();
            let mut out: Vec<f32> = x0.iter().map(|&v| v as f32).collect();
            c.apply(&x, &mut out);
            for (got, want) in out.iter().zip(&eps) {
                // f32 rounding of x amplified by inv_s (up to 1 / sqrt(1 - abar_0), about 1e2 at t = 0)
                assert!(
                    (*got as f64 - want).abs() < 1e-6 * c.inv_s as f64 * 4.0,
                    "t={t}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn a_sampler_keeps_its_multistep_state_and_resets_for_a_new_chain() {
        // A stand-in network (ε̂ a fixed function of x): a reset sampler repeats a fresh one's chain bit
        // for bit, and the second-order steps do read the state (a sampler whose state is cleared before
        // every step takes another chain).
        let s = NoiseSchedule::from_betas(crate::schedule::cosine_betas(50, 0.5));
        let plan = SamplerConfig::dpmpp2m(6)
            .plan(&s, VarianceType::FixedSmall)
            .unwrap();
        let net = |x: &[f32]| -> Vec<f32> { x.iter().map(|v| 0.5 * v.sin() - 0.1).collect() };
        let run = |sampler: &mut Sampler<'_>, forget: bool| {
            let mut x = vec![0.3f32, -1.1, 2.0, 0.7];
            while sampler.timestep().is_some() {
                let mut eps = net(&x);
                if forget {
                    let next = sampler.index();
                    sampler.reset();
                    sampler.next = next;
                }
                sampler.step(&mut x, &mut eps, &[]).unwrap();
            }
            x
        };
        let mut sampler = Sampler::new(&plan, 4);
        let first = run(&mut sampler, false);
        assert!(sampler.step(&mut [0.0; 4], &mut [0.0; 4], &[]).is_err());
        sampler.reset();
        assert_eq!(sampler.timestep(), Some(plan.steps[0].t));
        assert_eq!(run(&mut sampler, false), first);
        assert_eq!(run(&mut Sampler::new(&plan, 4), false), first);
        assert_ne!(run(&mut Sampler::new(&plan, 4), true), first);
        // a buffer of the wrong size is refused, naming it
        let mut fresh = Sampler::new(&plan, 4);
        let e = fresh.step(&mut [0.0; 3], &mut [0.0; 4], &[]).unwrap_err();
        assert!(e.to_string().contains("`x`"), "{e}");
        assert_eq!(fresh.index(), 0);
    }

    #[test]
    fn an_x0_plan_converts_the_output_at_every_step_and_an_epsilon_plan_at_none() {
        let s = NoiseSchedule::from_betas(crate::schedule::cosine_betas(10, 0.5));
        for sc in [
            SamplerConfig::ddpm(),
            SamplerConfig::ddim(4, 1.0),
            SamplerConfig::dpmpp2m(4),
        ] {
            let plan = sc.plan(&s, VarianceType::FixedSmall).unwrap();
            assert!(plan.steps.iter().all(|st| st.to_noise.is_none()));
            let x0_plan = plan.clone().for_prediction(PredictionType::Sample, &s);
            assert!(x0_plan
                .steps
                .iter()
                .all(|st| st.to_noise == Some(SampleToNoise::new(&s, st.t))));
            assert_eq!(
                plan.clone().for_prediction(PredictionType::Epsilon, &s),
                plan
            );
        }
    }

    #[test]
    fn pairs_end_with_none() {
        assert_eq!(
            step_pairs(&[9, 4, 0]),
            vec![(9, Some(4)), (4, Some(0)), (0, None)]
        );
    }
}
