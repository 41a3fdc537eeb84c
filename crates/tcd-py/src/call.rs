//! A sampling call: the arguments `Denoiser.sample`, `cascade` and `repair` share ([`SamplingArgs`],
//! their seeded streams and threads one [`Streams`]),
//! checked in one order by [`SamplingArgs::prepare`], and the checked [`Call`], run off the GIL by
//! [`Call::run`]; and the noise arguments (`noise` xor `seed`, `first_sequence` xor `sequences`:
//! [`seed_args`], [`noise_source`]), which `Generator.sample` takes too.
//!
//! The order of the checks, which decides the error raised when several arguments are wrong:
//! `num_samples`, the observation's shape (`observed`, then `mask`), the size of the samples, the sampler
//! options, `seed` / `first_sequence` / `sequences`, the sampler on each model (its number of noise blocks),
//! each model's injected noise (or the seed), `threads`. The engine then checks the values (the mask's 0/1
//! entries, finite observations and noise).

use numpy::PyReadonlyArrayDyn;
use pyo3::prelude::*;
use tcd_core::{Control, Denoiser, ForecastOptions, Network, Noise, Observation, Sequences};

use crate::convert::*;
use crate::error::{internal, invalid, Result};
use crate::run::interruptible;

/// The arguments of a sampling call other than its models and their injected noise: the `call` dict of
/// `Denoiser.sample`, `cascade` and `repair` (`tcd.engine._chains` builds it; `_native._Call` in the stubs).
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
pub(crate) struct SamplingArgs<'py> {
    pub(crate) observed: PyReadonlyArrayDyn<'py, f32>,
    pub(crate) mask: PyReadonlyArrayDyn<'py, f32>,
    pub(crate) num_samples: i64,
    pub(crate) options: SamplerOptions,
    pub(crate) streams: Streams,
    pub(crate) progress: Option<Bound<'py, PyAny>>,
}

/// How a seeded call numbers its noise streams and how many threads it runs: the `streams` dict of
/// every sampling function (`tcd._checks.streams` builds it from the Python keywords of the same names).
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
pub(crate) struct Streams {
    pub(crate) seed: Option<i128>,
    pub(crate) first_sequence: i128,
    pub(crate) sequences: Option<Vec<i128>>,
    pub(crate) threads: Option<i64>,
}

/// One model of a call with its injected noise: (model, the noise argument's name, its value).
pub(crate) type Stage<'a, 'py> = (&'a Denoiser, &'a str, Option<PyReadonlyArrayDyn<'py, f32>>);

/// The frames of a call's observation.
pub(crate) enum Window<'a> {
    /// Any number L >= 1: the chains run on the observation itself (`Denoiser.sample`).
    Any,
    /// The first model's obs_len, each model's chains on its seq_len frames (the observation padded);
    /// the string names the first model in the message ("the model's").
    ObsLen(&'a str),
}

/// How many samples a call may ask for.
pub(crate) enum SampleCount {
    /// Sampling and forecasting: at least 1.
    AtLeastOne,
    /// A repair: 0 is its fill alone (the engine checks that the model has one).
    ZeroIsFillAlone,
}

/// A checked call's inputs, as the engine takes them: `Send`, for the worker thread.
pub(crate) struct Job<const N: usize> {
    /// B, the sequences of the observation.
    pub(crate) batch: usize,
    /// The frames of the observation (L, or the model's obs_len).
    pub(crate) frames: usize,
    pub(crate) options: ForecastOptions,
    /// (B, K, frames).
    pub(crate) observed: Vec<f32>,
    /// (B, K, frames).
    pub(crate) mask: Vec<f32>,
    /// The noise of each stage, in the order of the stages.
    pub(crate) noise: [NoiseSource; N],
}

impl<const N: usize> Job<N> {
    /// The shape of the samples of a model with `k` features: (S, B, K, frames).
    pub(crate) fn samples_shape(&self, k: usize) -> [usize; 4] {
        [self.options.num_samples, self.batch, k, self.frames]
    }

    /// The observation as the engine takes it, (B, K, frames) with K = `k` (the first model's); the
    /// engine checks its values here.
    pub(crate) fn observation(&self, k: usize) -> CoreResult<Observation<'_>> {
        Observation::new(&self.observed, &self.mask, [self.batch, k, self.frames])
    }
}

/// A checked sampling call of `N` stages (models).
pub(crate) struct Call<'py, const N: usize> {
    pub(crate) job: Job<N>,
    threads: Option<usize>,
    progress: Option<Bound<'py, PyAny>>,
}

impl<'py> SamplingArgs<'py> {
    /// Checks every argument (see the module's documentation) and copies the arrays out of numpy.
    pub(crate) fn prepare<const N: usize>(
        self,
        window: Window<'_>,
        count: SampleCount,
        stages: [Stage<'_, 'py>; N],
    ) -> Result<Call<'py, N>> {
        let py = self.observed.py();
        let observed = Array::from_numpy(&self.observed);
        let mask = Array::from_numpy(&self.mask);
        let first = stages
            .first()
            .map(|(model, _, _)| *model)
            .ok_or_else(|| internal(py, "a sampling call without a model"))?;
        let k = first.num_features();
        let s = match count {
            SampleCount::AtLeastOne => positive("num_samples", self.num_samples)?,
            SampleCount::ZeroIsFillAlone => non_negative("num_samples", self.num_samples)?,
        };
        let (b, frames) = observed.bkl("observed", k)?;
        if let Window::ObsLen(whose) = window {
            let obs_len = first.obs_len();
            if frames != obs_len {
                return Err(invalid(
                    "observed",
                    format!("{obs_len} frames ({whose} obs_len)"),
                    format!("{frames} frames"),
                )
                .into());
            }
        }
        mask.expect_shape("mask", &[b, k, frames], "(the shape of `observed`)")?;
        // the frames each model's chains run on
        let length = |model: &Denoiser| match window {
            Window::Any => frames,
            Window::ObsLen(_) => model.seq_len(),
        };
        let longest = stages
            .iter()
            .map(|(model, _, _)| length(model))
            .max()
            .unwrap_or(frames);
        check_work(s, b, k, longest)?;
        let sampler = self.options.config();
        let (seed, streams) = seed_args(&self.streams)?;
        let blocks = stages
            .iter()
            .map(|(model, _, _)| noise_blocks(model, &sampler))
            .collect::<CoreResult<Vec<usize>>>()?;
        let sources = stages
            .iter()
            .zip(blocks)
            .map(|((model, argument, noise), blocks)| {
                let shape = [s, blocks, b, model.num_features(), length(model)];
                let what = "= (num_samples, num_noise_blocks, B, K, L); num_noise_blocks = num_inference_steps + 1 (1 for dpmpp2m)";
                noise_source(argument, noise.as_ref(), seed, streams.clone(), &shape, what)
            })
            .collect::<CoreResult<Vec<NoiseSource>>>()?;
        let noise = sources
            .try_into()
            .map_err(|_| internal(py, "a sampling call lost the noise of a stage"))?;
        Ok(Call {
            job: Job {
                batch: b,
                frames,
                options: ForecastOptions {
                    num_samples: s,
                    sampler,
                },
                observed: observed.data,
                mask: mask.data,
                noise,
            },
            threads: threads_arg(self.streams.threads)?,
            progress: self.progress,
        })
    }
}

impl<const N: usize> Call<'_, N> {
    /// Runs `work` on the job off the GIL, interruptibly ([`interruptible`]), on the call's threads.
    pub(crate) fn run<T: Send>(
        &self,
        py: Python<'_>,
        work: impl FnOnce(&Job<N>, &Control) -> CoreResult<T> + Send,
    ) -> Result<T> {
        let job = &self.job;
        interruptible(py, self.progress.as_ref(), self.threads, move |control| {
            work(job, control)
        })
    }
}

/// The stream numbering of a seeded call, owned: sequence b draws stream `first_sequence + b`, or
/// `sequences[b]` when the caller numbers every sequence (the engine checks one id per sequence).
#[derive(Clone)]
pub(crate) enum StreamIds {
    From(u64),
    Ids(Vec<u64>),
}

impl StreamIds {
    pub(crate) fn as_sequences(&self) -> Sequences<'_> {
        match self {
            StreamIds::From(first) => Sequences::From(*first),
            StreamIds::Ids(ids) => Sequences::Ids(ids),
        }
    }
}

/// `seed`, and `first_sequence` xor `sequences`, as the engine takes them (also `Generator.sample`'s).
pub(crate) fn seed_args(streams: &Streams) -> CoreResult<(Option<u64>, StreamIds)> {
    let seed = streams.seed.map(|v| u64_arg("seed", v)).transpose()?;
    let first = u64_arg("first_sequence", streams.first_sequence)?;
    let ids = match &streams.sequences {
        None => StreamIds::From(first),
        Some(_) if seed.is_none() => {
            return Err(invalid(
                "sequences",
                "None unless a `seed` is given",
                "a list of stream ids",
            ))
        }
        Some(_) if first != 0 => {
            return Err(invalid(
                "sequences",
                "None when `first_sequence` is given (number the streams one way)",
                "a list of stream ids",
            ))
        }
        Some(v) => StreamIds::Ids(
            v.iter()
                .map(|&id| u64_arg("sequences", id))
                .collect::<CoreResult<_>>()?,
        ),
    };
    Ok((seed, ids))
}

/// Where a sampling call's noise comes from: `noise` (injected) xor `seed`.
pub(crate) enum NoiseSource {
    Injected(Vec<f32>),
    Seeded(u64, StreamIds),
}

/// The noise of one model of a call: `noise`, the injected array of the argument so named (copied out
/// of numpy here, once it is known to be used), checked against `expected_shape` (`what` explains it in
/// the message), or the seeded streams.
pub(crate) fn noise_source(
    argument: &str,
    noise: Option<&PyReadonlyArrayDyn<'_, f32>>,
    seed: Option<u64>,
    streams: StreamIds,
    expected_shape: &[usize],
    what: &str,
) -> CoreResult<NoiseSource> {
    match (noise, seed) {
        (Some(_), Some(_)) => Err(invalid(
            argument,
            format!("None when `seed` is given (pass either injected `{argument}` or a `seed`)"),
            "both",
        )),
        (None, None) => Err(invalid(
            "seed",
            format!("an integer seed when no injected `{argument}` is given"),
            "None",
        )),
        (Some(n), None) => {
            let n = Array::from_numpy(n);
            n.expect_shape(argument, expected_shape, what)?;
            Ok(NoiseSource::Injected(n.data))
        }
        (None, Some(s)) => Ok(NoiseSource::Seeded(s, streams)),
    }
}

impl NoiseSource {
    pub(crate) fn as_noise(&self) -> Noise<'_> {
        match self {
            NoiseSource::Injected(v) => Noise::Injected(v),
            NoiseSource::Seeded(seed, streams) => Noise::Seeded {
                seed: *seed,
                sequences: streams.as_sequences(),
            },
        }
    }
}
