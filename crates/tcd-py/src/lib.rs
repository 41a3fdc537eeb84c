//! `tcd._native`: the PyO3 binding of `tcd-core`.
//!
//! This crate only converts: numpy arrays in, numpy arrays out, the engine's [`tcd_core::Error`]
//! mapped onto `tcd.exceptions` (in [`error`], the one place where errors cross into Python), and
//! the GIL released around every forward / sampling call. The public API, with its argument
//! checking in the caller's terms (poses, units, masks), is the Python package `tcd`; this module
//! is private and works in the engine's layout: (B, K, L) float32 arrays, K = joints·3 with the
//! frame axis last, and injected noise (S, n + 1, B, K, L) ((S, 1, B, K, L) for the deterministic
//! `dpmpp2m`, which only draws x_T).
//!
//! Inputs are copied out of numpy before the GIL is released, so another Python thread mutating
//! an input array cannot race the engine.

mod error;

use std::path::PathBuf;
use std::sync::Arc;

use numpy::ndarray::{ArrayD, IxDyn};
use numpy::{IntoPyArray, PyArrayDyn, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use tcd_core::rng::{seeded_noise as core_seeded_noise, stage};
use tcd_core::{
    cascade as core_cascade, repair as core_repair, sample as core_sample, with_threads,
    CascadeNoise, Denoiser, Error, ForecastOptions, Noise, SamplerConfig, SamplerKind,
    TimestepSpacing,
};

use crate::error::{internal, invalid, PyTcdError};

type CoreResult<T> = Result<T, Error>;

// ------------------------------------------------------------------------------------ arguments

/// An integer argument that must be at least 1 (taken as i64 so that negatives become a typed
/// `InvalidInputError` naming the argument, not an `OverflowError`).
fn positive(argument: &str, value: i64) -> CoreResult<usize> {
    usize::try_from(value)
        .ok()
        .filter(|v| *v >= 1)
        .ok_or_else(|| invalid(argument, "an integer of at least 1", value.to_string()))
}

/// At most this many worker threads (a typo such as `threads=10**6` must not spawn a million).
const MAX_THREADS: i64 = 1024;

fn threads_arg(threads: Option<i64>) -> CoreResult<Option<usize>> {
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
fn u64_arg(argument: &str, value: i128) -> CoreResult<u64> {
    u64::try_from(value)
        .map_err(|_| invalid(argument, "an integer in 0..=2**64 - 1", value.to_string()))
}

/// At most 2^31 values (8 GiB of f32) in the samples of one call: refuse absurd `num_samples`
/// (or batch) up front instead of aborting on a failed allocation.
const MAX_VALUES: usize = 1 << 31;

fn check_work(num_samples: usize, batch: usize, k: usize, length: usize) -> CoreResult<()> {
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
/// one place where the sampler settings cross from Python. The Python type checks its fields when it is
/// made; the values are checked again here, because the binding can be called without it.
#[derive(FromPyObject)]
struct SamplerOptions {
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
    fn config(&self) -> CoreResult<SamplerConfig> {
        let kind = match self.sampler.as_str() {
            "ddpm" => SamplerKind::Ddpm,
            "ddim" => SamplerKind::Ddim { eta: self.eta },
            "dpmpp2m" => SamplerKind::DpmPp2m,
            other => {
                return Err(invalid(
                    "sampler",
                    "\"ddpm\", \"ddim\" or \"dpmpp2m\"",
                    format!("{other:?}"),
                ));
            }
        };
        if !(self.eta.is_finite() && (0.0..=1.0).contains(&self.eta)) {
            return Err(invalid("eta", "a number in [0, 1]", self.eta.to_string()));
        }
        let num_inference_steps = self
            .num_inference_steps
            .map(|n| positive("num_inference_steps", n))
            .transpose()?;
        Ok(SamplerConfig {
            kind,
            num_inference_steps,
            timestep_spacing: self.timestep_spacing.parse::<TimestepSpacing>()?,
        })
    }
}

/// Noise blocks per chain (n + 1; 1 for dpmpp2m) of `sampler` on `model`; validates the sampler.
fn noise_blocks(model: &Denoiser, sampler: &SamplerConfig) -> CoreResult<usize> {
    Ok(sampler
        .plan(model.schedule(), &model.config().diffusion.variance_type)?
        .num_noise_blocks())
}

/// A float32 array copied out of numpy in C order, with its shape.
struct Array {
    shape: Vec<usize>,
    data: Vec<f32>,
}

impl Array {
    fn from_numpy(a: &PyReadonlyArrayDyn<'_, f32>) -> Self {
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

    fn shape_str(shape: &[usize]) -> String {
        let inner: Vec<String> = shape.iter().map(usize::to_string).collect();
        if inner.len() == 1 {
            format!("({},)", inner[0])
        } else {
            format!("({})", inner.join(", "))
        }
    }

    /// Checks rank 3 with `K` features: (B, K, L); returns (B, L).
    fn bkl(&self, argument: &str, k: usize) -> CoreResult<(usize, usize)> {
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
    fn expect_shape(&self, argument: &str, shape: &[usize], what: &str) -> CoreResult<()> {
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

fn to_numpy<'py>(
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

fn seed_args(seed: Option<i128>, first_sequence: i128) -> CoreResult<(Option<u64>, u64)> {
    Ok((
        seed.map(|v| u64_arg("seed", v)).transpose()?,
        u64_arg("first_sequence", first_sequence)?,
    ))
}

/// Where a sampling call's noise comes from: `noise` (injected) xor `seed`.
enum NoiseSource {
    Injected(Vec<f32>),
    Seeded(u64, u64),
}

/// Checks an observation (B, K, O) with O = `obs_len` and its mask of the same shape; returns B.
/// `whose` names the model in the message ("the model's", "the short-term model's").
fn observation_batch(
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

fn noise_source(
    argument: &str,
    noise: Option<&Array>,
    seed: Option<u64>,
    first_sequence: u64,
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
        (None, Some(s)) => Ok(NoiseSource::Seeded(s, first_sequence)),
    }
}

impl NoiseSource {
    fn as_noise(&self) -> Noise<'_> {
        match self {
            NoiseSource::Injected(v) => Noise::Injected(v),
            NoiseSource::Seeded(seed, first_sequence) => Noise::Seeded {
                seed: *seed,
                first_sequence: *first_sequence,
            },
        }
    }
}

// ------------------------------------------------------------------------------------ Denoiser

/// A loaded TCD denoiser (one safetensors file). Immutable; safe to share between threads.
#[pyclass(frozen, module = "tcd._native", name = "Denoiser")]
struct PyDenoiser {
    inner: Arc<Denoiser>,
}

#[pymethods]
impl PyDenoiser {
    /// Loads and validates a weight file.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let d = py
            .detach(move || Denoiser::load(&path))
            .map_err(PyTcdError)?;
        Ok(PyDenoiser { inner: Arc::new(d) })
    }

    /// Loads and validates the bytes of a weight file; `name` names it in error messages.
    #[staticmethod]
    fn from_bytes(py: Python<'_>, data: Vec<u8>, name: PathBuf) -> PyResult<Self> {
        let d = py
            .detach(move || Denoiser::from_bytes(&data, &name))
            .map_err(PyTcdError)?;
        Ok(PyDenoiser { inner: Arc::new(d) })
    }

    #[getter]
    fn path(&self) -> String {
        self.inner.path().display().to_string()
    }
    /// The `tcd_config` JSON exactly as stored in the file.
    #[getter]
    fn config_json(&self) -> String {
        self.inner.config_json().to_string()
    }
    /// The compute kernels this model runs (`portable`, `avx2` or `avx512`; chosen at load from
    /// `TCD_KERNEL`, default the best the CPU supports).
    #[getter]
    fn kernel(&self) -> &'static str {
        self.inner.kernel().name()
    }
    #[getter]
    fn role(&self) -> &'static str {
        self.inner.role().as_str()
    }
    #[getter]
    fn num_features(&self) -> usize {
        self.inner.num_features()
    }
    #[getter]
    fn num_joints(&self) -> usize {
        self.inner.config().model.num_joints
    }
    #[getter]
    fn coords(&self) -> usize {
        self.inner.config().model.coords
    }
    #[getter]
    fn obs_len(&self) -> usize {
        self.inner.obs_len()
    }
    #[getter]
    fn pred_len(&self) -> usize {
        self.inner.pred_len()
    }
    #[getter]
    fn seq_len(&self) -> usize {
        self.inner.seq_len()
    }
    #[getter]
    fn num_train_timesteps(&self) -> usize {
        self.inner.num_train_timesteps()
    }

    /// The descending training steps a sampler visits.
    fn timesteps(&self, options: SamplerOptions) -> PyResult<Vec<usize>> {
        let cfg = options.config().map_err(PyTcdError)?;
        let plan = cfg
            .plan(
                self.inner.schedule(),
                &self.inner.config().diffusion.variance_type,
            )
            .map_err(PyTcdError)?;
        Ok(plan.timesteps())
    }

    /// Noise blocks per chain, the second axis of injected noise: n + 1 (x_T, then one z per
    /// step), or 1 for the deterministic `dpmpp2m`.
    fn num_noise_blocks(&self, options: SamplerOptions) -> PyResult<usize> {
        let cfg = options.config().map_err(PyTcdError)?;
        Ok(noise_blocks(&self.inner, &cfg).map_err(PyTcdError)?)
    }

    /// ε̂ = net(noisy, observed, mask, step); all arrays (B, K, L) float32.
    #[pyo3(signature = (noisy, observed, mask, step, *, threads=None))]
    fn forward<'py>(
        &self,
        py: Python<'py>,
        noisy: PyReadonlyArrayDyn<'py, f32>,
        observed: PyReadonlyArrayDyn<'py, f32>,
        mask: PyReadonlyArrayDyn<'py, f32>,
        step: i64,
        threads: Option<i64>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let threads = threads_arg(threads).map_err(PyTcdError)?;
        let k = self.inner.num_features();
        let (noisy, observed, mask) = (
            Array::from_numpy(&noisy),
            Array::from_numpy(&observed),
            Array::from_numpy(&mask),
        );
        let (b, l) = noisy.bkl("noisy", k).map_err(PyTcdError)?;
        let shape = [b, k, l];
        observed
            .expect_shape("observed", &shape, "(the shape of `noisy`)")
            .map_err(PyTcdError)?;
        mask.expect_shape("mask", &shape, "(the shape of `noisy`)")
            .map_err(PyTcdError)?;
        let t = self.inner.num_train_timesteps();
        let step = usize::try_from(step)
            .ok()
            .filter(|s| *s < t)
            .ok_or_else(|| {
                PyTcdError(invalid(
                    "step",
                    format!("a diffusion step in 0..{t}"),
                    step.to_string(),
                ))
            })?;
        let model = Arc::clone(&self.inner);
        let out = py
            .detach(move || -> CoreResult<Vec<f32>> {
                with_threads(threads, || {
                    let mut out = vec![0.0f32; noisy.data.len()];
                    model.forward(
                        &noisy.data,
                        &observed.data,
                        &mask.data,
                        b,
                        l,
                        step,
                        &mut out,
                    )?;
                    Ok(out)
                })?
            })
            .map_err(PyTcdError)?;
        to_numpy(py, &shape, out)
    }

    /// `num_samples` merged samples per sequence, (S, B, K, L). Noise: injected `noise`
    /// (S, n + 1, B, K, L) ((S, 1, B, K, L) for dpmpp2m) or a `seed` (stream stage 0, sequences
    /// numbered from `first_sequence`).
    #[pyo3(signature = (observed, mask, num_samples, options, *, noise=None, seed=None, first_sequence=0,
                        threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn sample<'py>(
        &self,
        py: Python<'py>,
        observed: PyReadonlyArrayDyn<'py, f32>,
        mask: PyReadonlyArrayDyn<'py, f32>,
        num_samples: i64,
        options: SamplerOptions,
        noise: Option<PyReadonlyArrayDyn<'py, f32>>,
        seed: Option<i128>,
        first_sequence: i128,
        threads: Option<i64>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let k = self.inner.num_features();
        let observed = Array::from_numpy(&observed);
        let mask = Array::from_numpy(&mask);
        let noise = noise.as_ref().map(Array::from_numpy);
        let prepared = (|| -> CoreResult<_> {
            let s = positive("num_samples", num_samples)?;
            let (b, l) = observed.bkl("observed", k)?;
            mask.expect_shape("mask", &[b, k, l], "(the shape of `observed`)")?;
            check_work(s, b, k, l)?;
            let cfg = options.config()?;
            let blocks = noise_blocks(&self.inner, &cfg)?;
            let (seed, first_sequence) = seed_args(seed, first_sequence)?;
            let src = noise_source(
                "noise",
                noise.as_ref(),
                seed,
                first_sequence,
                &[s, blocks, b, k, l],
            )?;
            Ok((s, b, l, cfg, src, threads_arg(threads)?))
        })()
        .map_err(PyTcdError)?;
        let (s, b, l, cfg, src, threads) = prepared;
        let model = Arc::clone(&self.inner);
        let out = py
            .detach(move || {
                with_threads(threads, || {
                    core_sample(
                        &model,
                        &observed.data,
                        &mask.data,
                        b,
                        l,
                        s,
                        &cfg,
                        src.as_noise(),
                    )
                })?
            })
            .map_err(PyTcdError)?;
        to_numpy(py, &[s, b, k, l], out)
    }

    fn __repr__(&self) -> String {
        format!(
            "Denoiser(path={:?}, role={:?}, num_features={}, obs_len={}, seq_len={}, num_train_timesteps={})",
            self.path(),
            self.role(),
            self.num_features(),
            self.obs_len(),
            self.seq_len(),
            self.num_train_timesteps()
        )
    }
}

// ------------------------------------------------------------------------------------ functions

/// The short-term → long-term cascade on an observation (B, K, O), O = the short model's obs_len.
/// Returns a dict: `mean` (B, K, P), `samples` (S, B, K, P), `repaired` (B, K, O), `short_mean`
/// (B, K, L_s). Noise: injected `noise_short` (S, n + 1, B, K, L_s) and `noise_long`
/// (S, n + 1, B, K, L_l) (one block instead of n + 1 for dpmpp2m), or a `seed`.
#[pyfunction]
#[pyo3(signature = (short, long, observed, mask, num_samples, options, *, noise_short=None, noise_long=None,
                    seed=None, first_sequence=0, threads=None))]
#[allow(clippy::too_many_arguments)]
fn cascade<'py>(
    py: Python<'py>,
    short: &Bound<'py, PyDenoiser>,
    long: &Bound<'py, PyDenoiser>,
    observed: PyReadonlyArrayDyn<'py, f32>,
    mask: PyReadonlyArrayDyn<'py, f32>,
    num_samples: i64,
    options: SamplerOptions,
    noise_short: Option<PyReadonlyArrayDyn<'py, f32>>,
    noise_long: Option<PyReadonlyArrayDyn<'py, f32>>,
    seed: Option<i128>,
    first_sequence: i128,
    threads: Option<i64>,
) -> PyResult<Bound<'py, PyDict>> {
    let short = Arc::clone(&short.get().inner);
    let long = Arc::clone(&long.get().inner);
    let k = short.num_features();
    let observed = Array::from_numpy(&observed);
    let mask = Array::from_numpy(&mask);
    let noise_short = noise_short.as_ref().map(Array::from_numpy);
    let noise_long = noise_long.as_ref().map(Array::from_numpy);
    let prepared = (|| -> CoreResult<_> {
        let s = positive("num_samples", num_samples)?;
        let b = observation_batch(
            &observed,
            &mask,
            k,
            short.obs_len(),
            "the short-term model's",
        )?;
        check_work(s, b, k, short.seq_len().max(long.seq_len()))?;
        let cfg = options.config()?;
        let (seed, first_sequence) = seed_args(seed, first_sequence)?;
        let bs = noise_blocks(&short, &cfg)?;
        let bl = noise_blocks(&long, &cfg)?;
        let lk = long.num_features();
        let src_short = noise_source(
            "noise_short",
            noise_short.as_ref(),
            seed,
            first_sequence,
            &[s, bs, b, k, short.seq_len()],
        )?;
        let src_long = noise_source(
            "noise_long",
            noise_long.as_ref(),
            seed,
            first_sequence,
            &[s, bl, b, lk, long.seq_len()],
        )?;
        Ok((s, b, cfg, src_short, src_long, threads_arg(threads)?))
    })()
    .map_err(PyTcdError)?;
    let (s, b, cfg, src_short, src_long, threads) = prepared;
    let out = py
        .detach(move || {
            let noise = match (&src_short, &src_long) {
                (NoiseSource::Injected(a), NoiseSource::Injected(c)) => {
                    CascadeNoise::Injected { short: a, long: c }
                }
                (NoiseSource::Seeded(seed, first_sequence), _)
                | (_, NoiseSource::Seeded(seed, first_sequence)) => CascadeNoise::Seeded {
                    seed: *seed,
                    first_sequence: *first_sequence,
                },
            };
            let options = ForecastOptions {
                num_samples: s,
                sampler: cfg,
            };
            with_threads(threads, || {
                core_cascade(
                    &short,
                    &long,
                    &observed.data,
                    &mask.data,
                    b,
                    &options,
                    noise,
                )
            })?
        })
        .map_err(PyTcdError)?;
    let d = PyDict::new(py);
    let kf = out.num_features;
    d.set_item("mean", to_numpy(py, &[b, kf, out.future_len], out.mean)?)?;
    d.set_item(
        "samples",
        to_numpy(py, &[s, b, kf, out.future_len], out.samples)?,
    )?;
    d.set_item(
        "repaired",
        to_numpy(py, &[b, kf, out.obs_len], out.repaired)?,
    )?;
    d.set_item(
        "short_mean",
        to_numpy(py, &[b, kf, out.short_len], out.short_mean)?,
    )?;
    Ok(d)
}

/// Repairs the mask-0 entries of an observation (B, K, O), O = the model's obs_len. Returns a
/// dict: `mean` (B, K, O; observed entries exact) and `samples` (S, B, K, O).
#[pyfunction]
#[pyo3(signature = (model, observed, mask, num_samples, options, *, noise=None, seed=None, first_sequence=0,
                    threads=None))]
#[allow(clippy::too_many_arguments)]
fn repair<'py>(
    py: Python<'py>,
    model: &Bound<'py, PyDenoiser>,
    observed: PyReadonlyArrayDyn<'py, f32>,
    mask: PyReadonlyArrayDyn<'py, f32>,
    num_samples: i64,
    options: SamplerOptions,
    noise: Option<PyReadonlyArrayDyn<'py, f32>>,
    seed: Option<i128>,
    first_sequence: i128,
    threads: Option<i64>,
) -> PyResult<Bound<'py, PyDict>> {
    let model = Arc::clone(&model.get().inner);
    let k = model.num_features();
    let observed = Array::from_numpy(&observed);
    let mask = Array::from_numpy(&mask);
    let noise = noise.as_ref().map(Array::from_numpy);
    let prepared = (|| -> CoreResult<_> {
        let s = positive("num_samples", num_samples)?;
        let b = observation_batch(&observed, &mask, k, model.obs_len(), "the model's")?;
        let o = model.obs_len();
        check_work(s, b, k, model.seq_len())?;
        let cfg = options.config()?;
        let (seed, first_sequence) = seed_args(seed, first_sequence)?;
        let blocks = noise_blocks(&model, &cfg)?;
        let src = noise_source(
            "noise",
            noise.as_ref(),
            seed,
            first_sequence,
            &[s, blocks, b, k, model.seq_len()],
        )?;
        Ok((s, b, o, cfg, src, threads_arg(threads)?))
    })()
    .map_err(PyTcdError)?;
    let (s, b, o, cfg, src, threads) = prepared;
    let out = py
        .detach(move || {
            let options = ForecastOptions {
                num_samples: s,
                sampler: cfg,
            };
            with_threads(threads, || {
                core_repair(
                    &model,
                    &observed.data,
                    &mask.data,
                    b,
                    &options,
                    src.as_noise(),
                )
            })?
        })
        .map_err(PyTcdError)?;
    let d = PyDict::new(py);
    d.set_item("mean", to_numpy(py, &[b, k, o], out.mean)?)?;
    d.set_item("samples", to_numpy(py, &[s, b, k, o], out.samples)?)?;
    Ok(d)
}

/// The seeded noise streams exactly as the engine consumes them, (S, num_blocks, B, K, L):
/// ChaCha8 keyed by (seed, first_sequence + b, sample, stage), standard normals in block order.
#[pyfunction]
#[pyo3(signature = (seed, stage, num_samples, num_blocks, batch, num_features, length, first_sequence=0))]
#[allow(clippy::too_many_arguments)]
fn seeded_noise<'py>(
    py: Python<'py>,
    seed: i128,
    stage: i128,
    num_samples: i64,
    num_blocks: i64,
    batch: i64,
    num_features: i64,
    length: i64,
    first_sequence: i128,
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let (seed, stage, first_sequence) = (|| -> CoreResult<_> {
        Ok((
            u64_arg("seed", seed)?,
            u64_arg("stage", stage)?,
            u64_arg("first_sequence", first_sequence)?,
        ))
    })()
    .map_err(PyTcdError)?;
    let dims = (|| -> CoreResult<[usize; 5]> {
        let dims = [
            positive("num_samples", num_samples)?,
            positive("num_blocks", num_blocks)?,
            positive("batch", batch)?,
            positive("num_features", num_features)?,
            positive("length", length)?,
        ];
        // Refuse absurd sizes rather than abort on allocation failure (2^31 values = 8 GiB).
        let total = dims.iter().try_fold(1usize, |acc, d| acc.checked_mul(*d));
        match total {
            Some(t) if t <= MAX_VALUES => Ok(dims),
            _ => Err(invalid(
                "num_samples",
                "sizes whose product is at most 2^31 values",
                format!("{dims:?}"),
            )),
        }
    })()
    .map_err(PyTcdError)?;
    let [s, blocks, b, k, l] = dims;
    let data =
        py.detach(move || core_seeded_noise(seed, first_sequence, stage, s, blocks, b, k * l));
    to_numpy(py, &dims, data)
}

/// The native module. Private: use the `tcd` package.
/// The kernel paths this CPU can run, the best last (`TCD_KERNEL` accepts these and `auto`).
#[pyfunction]
fn supported_kernels() -> Vec<&'static str> {
    tcd_core::Kernel::supported().into_iter().map(|k| k.name()).collect()
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("STAGE_SHORT", stage::SHORT)?;
    m.add("STAGE_LONG", stage::LONG)?;
    m.add_class::<PyDenoiser>()?;
    m.add_function(wrap_pyfunction!(cascade, m)?)?;
    m.add_function(wrap_pyfunction!(repair, m)?)?;
    m.add_function(wrap_pyfunction!(seeded_noise, m)?)?;
    m.add_function(wrap_pyfunction!(supported_kernels, m)?)?;
    Ok(())
}
