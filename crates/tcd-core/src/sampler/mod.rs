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

mod config;
mod ddim;
mod ddpm;
mod dpmpp;

use crate::weights::Network;
use rayon::prelude::*;

use crate::config::{CondFill, PredictionType, VarianceType};
use crate::control::Control;
use crate::denoiser::{CondTables, Denoiser, SequenceInputs, Workspace};
use crate::error::{check_len, check_positive, Error, Result};
use crate::observation::Observation;
use crate::rng::{stage, Centres, ChainNoise, Noise, NoiseCoupling};
use crate::schedule::NoiseSchedule;
use crate::validate;

pub(crate) use config::timesteps;
pub use config::{SamplerConfig, SamplerKind, TimestepSpacing};
use ddim::DdimStep;
use ddpm::DdpmStep;
use dpmpp::DpmPp2mStep;

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

impl SamplerConfig {
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
mod tests;
