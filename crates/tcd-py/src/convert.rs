//! Python values into the engine's: argument checks that name the argument, the sampler options, numpy
//! arrays copied out (so the GIL can be released), numpy arrays out, and the noise source of a call.

use numpy::ndarray::{ArrayD, IxDyn};
use numpy::{IntoPyArray, PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use tcd_core::{Denoiser, Error, Noise, SamplerConfig, Sequences};

use crate::error::{internal, invalid};

pub(crate) type CoreResult<T> = Result<T, Error>;

/// An integer argument that must be at least 1 (taken as i64 so that negatives become a typed
/// `InvalidInputError` naming the argument, not an `OverflowError`).
pub(crate) fn positive(argument: &str, value: i64) -> CoreResult<usize> {
    usize::try_from(value)
        .ok()
        .filter(|v| *v >= 1)
        .ok_or_else(|| invalid(argument, "an integer of at least 1", value.to_string()))
}

/// At most this many worker threads (a typo such as `threads=10**6` must not spawn a million).
pub(crate) const MAX_THREADS: i64 = 1024;

pub(crate) fn threads_arg(threads: Option<i64>) -> CoreResult<Option<usize>> {
    threads
        .map(|t| {
            if t > MAX_THREADS {
                Err(invalid(
                    "threads",
                    format!("an integer in 1..={MAX_THREADS}"),
                    t.to_string(),
                ))
            } else {
                positive("threads", t)
            }
        })
        .transpose()
}

/// A seed-like integer: taken as i128 so that a negative or too large value is a typed
/// `InvalidInputError` naming the argument, not an `OverflowError`.
pub(crate) fn u64_arg(argument: &str, value: i128) -> CoreResult<u64> {
    u64::try_from(value)
        .map_err(|_| invalid(argument, "an integer in 0..=2**64 - 1", value.to_string()))
}

/// At most 2^31 values (8 GiB of f32) in the samples of one call: refuse absurd `num_samples`
/// (or batch) up front instead of aborting on a failed allocation.
pub(crate) const MAX_VALUES: usize = 1 << 31;

pub(crate) fn check_work(
    num_samples: usize,
    batch: usize,
    k: usize,
    length: usize,
) -> CoreResult<()> {
    let total = [batch, k, length]
        .iter()
        .try_fold(num_samples, |acc, d| acc.checked_mul(*d));
    match total {
        Some(t) if t <= MAX_VALUES => Ok(()),
        _ => Err(invalid(
            "num_samples",
            format!("small enough that num_samples x B x K x L = {num_samples} x {batch} x {k} x {length} is at most 2^31 values"),
            num_samples.to_string(),
        )),
    }
}

/// `tcd.SamplerOptions` (any object with its four attributes) → the engine's [`SamplerConfig`]: the
/// one place where the sampler settings cross from Python. Their values are checked by the engine
/// ([`SamplerConfig::from_names`]), also when the Python type is made (`check_sampler_options`).
#[derive(FromPyObject)]
pub(crate) struct SamplerOptions {
    #[pyo3(attribute)]
    sampler: String,
    #[pyo3(attribute)]
    num_inference_steps: Option<i64>,
    #[pyo3(attribute)]
    eta: f64,
    #[pyo3(attribute)]
    timestep_spacing: String,
}

impl SamplerOptions {
    pub(crate) fn config(&self) -> CoreResult<SamplerConfig> {
        let num_inference_steps = self
            .num_inference_steps
            .map(|n| positive("num_inference_steps", n))
            .transpose()?;
        SamplerConfig::from_names(
            &self.sampler,
            num_inference_steps,
            self.eta,
            &self.timestep_spacing,
        )
    }
}

/// Noise blocks per chain (n + 1; 1 for dpmpp2m) of `sampler` on `model`; validates the sampler.
pub(crate) fn noise_blocks(model: &Denoiser, sampler: &SamplerConfig) -> CoreResult<usize> {
    Ok(sampler
        .plan(model.schedule(), model.config().diffusion.variance_type)?
        .num_noise_blocks())
}

/// A float32 array copied out of numpy in C order, with its shape.
pub(crate) struct Array {
    pub(crate) shape: Vec<usize>,
    pub(crate) data: Vec<f32>,
}

impl Array {
    pub(crate) fn from_numpy(a: &PyReadonlyArrayDyn<'_, f32>) -> Self {
        let view = a.as_array();
        let data = match view.as_slice() {
            Some(s) => s.to_vec(),
            None => view.iter().copied().collect(),
        };
        Array {
            shape: a.shape().to_vec(),
            data,
        }
    }

    pub(crate) fn shape_str(shape: &[usize]) -> String {
        let inner: Vec<String> = shape.iter().map(usize::to_string).collect();
        if inner.len() == 1 {
            format!("({},)", inner[0])
        } else {
            format!("({})", inner.join(", "))
        }
    }

    /// Checks rank 3 with `K` features: (B, K, L); returns (B, L).
    pub(crate) fn bkl(&self, argument: &str, k: usize) -> CoreResult<(usize, usize)> {
        match self.shape.as_slice() {
            &[b, kk, l] if kk == k && b >= 1 && l >= 1 => Ok((b, l)),
            _ => Err(invalid(
                argument,
                format!("a float32 array of shape (B, K, L) with K = {k} and B, L >= 1"),
                format!("shape {}", Self::shape_str(&self.shape)),
            )),
        }
    }

    /// Checks this array has exactly `shape`; `what` describes it for the message.
    pub(crate) fn expect_shape(
        &self,
        argument: &str,
        shape: &[usize],
        what: &str,
    ) -> CoreResult<()> {
        if self.shape == shape {
            Ok(())
        } else {
            Err(invalid(
                argument,
                format!("a float32 array of shape {} {what}", Self::shape_str(shape)),
                format!("shape {}", Self::shape_str(&self.shape)),
            ))
        }
    }
}

pub(crate) fn to_numpy<'py>(
    py: Python<'py>,
    shape: &[usize],
    data: Vec<f32>,
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let arr = ArrayD::from_shape_vec(IxDyn(shape), data).map_err(|e| {
        internal(
            py,
            &format!("an engine output has an unexpected size ({e})"),
        )
    })?;
    Ok(arr.into_pyarray(py))
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

/// `seed`, and `first_sequence` xor `sequences`, as the engine takes them.
pub(crate) fn seed_args(
    seed: Option<i128>,
    first_sequence: i128,
    sequences: Option<Vec<i128>>,
) -> CoreResult<(Option<u64>, StreamIds)> {
    let seed = seed.map(|v| u64_arg("seed", v)).transpose()?;
    let first = u64_arg("first_sequence", first_sequence)?;
    let ids = match sequences {
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
            v.into_iter()
                .map(|id| u64_arg("sequences", id))
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

/// Checks an observation (B, K, O) with O = `obs_len` and its mask of the same shape; returns B.
/// `whose` names the model in the message ("the model's", "the short-term model's").
pub(crate) fn observation_batch(
    observed: &Array,
    mask: &Array,
    k: usize,
    obs_len: usize,
    whose: &str,
) -> CoreResult<usize> {
    let (b, o) = observed.bkl("observed", k)?;
    if o != obs_len {
        return Err(invalid(
            "observed",
            format!("{obs_len} frames ({whose} obs_len)"),
            format!("{o} frames"),
        ));
    }
    mask.expect_shape("mask", &[b, k, o], "(the shape of `observed`)")?;
    Ok(b)
}

pub(crate) fn noise_source(
    argument: &str,
    noise: Option<&Array>,
    seed: Option<u64>,
    streams: StreamIds,
    expected_shape: &[usize],
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
            n.expect_shape(
                argument,
                expected_shape,
                "= (num_samples, num_noise_blocks, B, K, L); num_noise_blocks = num_inference_steps + 1 (1 for dpmpp2m)",
            )?;
            Ok(NoiseSource::Injected(n.data.clone()))
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
