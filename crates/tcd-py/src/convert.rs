//! Python values into the engine's: argument checks that name the argument, the sampler options, numpy
//! arrays copied out (so the GIL can be released), and numpy arrays out.

use numpy::ndarray::{ArrayD, IxDyn};
use numpy::{IntoPyArray, PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use tcd_core::{Denoiser, Error, Network, SamplerConfig};

use crate::error::{internal, invalid, Result};

pub(crate) type CoreResult<T> = std::result::Result<T, Error>;

/// An integer argument that must be at least 1 (taken as i64 so that negatives become a typed
/// `InvalidInputError` naming the argument, not an `OverflowError`).
pub(crate) fn positive(argument: &str, value: i64) -> CoreResult<usize> {
    usize::try_from(value)
        .ok()
        .filter(|v| *v >= 1)
        .ok_or_else(|| invalid(argument, "an integer of at least 1", value.to_string()))
}

/// As [`positive`], with 0 allowed.
pub(crate) fn non_negative(argument: &str, value: i64) -> CoreResult<usize> {
    usize::try_from(value)
        .map_err(|_| invalid(argument, "an integer of at least 0", value.to_string()))
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

/// Whether an array of shape `dims` holds at most [`MAX_VALUES`] values.
pub(crate) fn within_limit(dims: &[usize]) -> bool {
    dims.iter()
        .try_fold(1usize, |acc, d| acc.checked_mul(*d))
        .is_some_and(|total| total <= MAX_VALUES)
}

pub(crate) fn check_work(
    num_samples: usize,
    batch: usize,
    k: usize,
    length: usize,
) -> CoreResult<()> {
    if within_limit(&[num_samples, batch, k, length]) {
        Ok(())
    } else {
        Err(invalid(
            "num_samples",
            format!("small enough that num_samples x B x K x L = {num_samples} x {batch} x {k} x {length} is at most 2^31 values"),
            num_samples.to_string(),
        ))
    }
}

/// The engine's sampler, made once per `tcd.SamplerOptions` (its `_engine`, when the Python object is
/// made): the one check of the settings' values ([`SamplerConfig::from_names`]) and the one place where
/// they cross from Python. Every call reads the checked sampler back from there ([`SamplerOptions`]).
#[pyclass(frozen, name = "Sampler", module = "tcd._native")]
pub(crate) struct Sampler(SamplerConfig);

#[pymethods]
impl Sampler {
    #[new]
    #[pyo3(signature = (sampler, num_inference_steps, eta, timestep_spacing, noise_coupling))]
    fn new(
        sampler: &str,
        num_inference_steps: Option<i64>,
        eta: f64,
        timestep_spacing: &str,
        noise_coupling: &str,
    ) -> Result<Self> {
        let num_inference_steps = num_inference_steps
            .map(|n| positive("num_inference_steps", n))
            .transpose()?;
        Ok(Sampler(SamplerConfig::from_names(
            sampler,
            num_inference_steps,
            eta,
            timestep_spacing,
            noise_coupling,
        )?))
    }
}

/// A call's `tcd.SamplerOptions`: the engine's sampler it made when it was made, not checked again.
#[derive(FromPyObject)]
pub(crate) struct SamplerOptions {
    #[pyo3(attribute("_engine"))]
    engine: Py<Sampler>,
}

impl SamplerOptions {
    pub(crate) fn config(&self) -> SamplerConfig {
        self.engine.get().0
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

    /// Checks a frame-major observation, as the prior and the generator read it: rank 3 (B, T, K) with
    /// `K` features, B >= 1 and at least `obs_len` frames (the model reads the last obs_len); returns
    /// (B, T).
    pub(crate) fn btk(
        &self,
        argument: &str,
        k: usize,
        obs_len: usize,
    ) -> CoreResult<(usize, usize)> {
        match self.shape.as_slice() {
            &[b, t, kk] if kk == k && b >= 1 && t >= obs_len => Ok((b, t)),
            _ => Err(invalid(
                argument,
                format!("a float32 array of shape (B, T, K) with K = {k}, B >= 1 and T >= obs_len = {obs_len}"),
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

/// `data` as a numpy array of `shape` (the engine's output, moved, not copied).
pub(crate) fn to_numpy<'py>(
    py: Python<'py>,
    shape: &[usize],
    data: Vec<f32>,
) -> Result<Bound<'py, PyArrayDyn<f32>>> {
    let arr = ArrayD::from_shape_vec(IxDyn(shape), data).map_err(|e| {
        internal(
            py,
            &format!("an engine output has an unexpected size ({e})"),
        )
    })?;
    Ok(arr.into_pyarray(py))
}

/// A dict of numpy arrays, `(key, shape, data)` in order (a call's outputs).
pub(crate) fn arrays<'py, const N: usize>(
    py: Python<'py>,
    entries: [(&str, &[usize], Vec<f32>); N],
) -> Result<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    for (key, shape, data) in entries {
        dict.set_item(key, to_numpy(py, shape, data)?)?;
    }
    Ok(dict)
}
