//! `tcd._native.Denoiser`: one loaded weight file, its description, one forward and one sampled chain.

use std::path::PathBuf;
use std::sync::Arc;

use numpy::{PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use tcd_core::{sample as core_sample, with_threads, Denoiser, Observed};

use crate::convert::*;
use crate::error::{invalid, PyTcdError};
use crate::run::interruptible;

/// A loaded TCD denoiser (one safetensors file). Immutable; safe to share between threads.
#[pyclass(frozen, module = "tcd._native", name = "Denoiser")]
pub(crate) struct PyDenoiser {
    pub(crate) inner: Arc<Denoiser>,
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
                self.inner.config().diffusion.variance_type,
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
                        (b, l),
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
    /// numbered from `first_sequence`, or one stream id per sequence in `sequences`).
    #[pyo3(signature = (observed, mask, num_samples, options, *, noise=None, seed=None, first_sequence=0, sequences=None,
                        threads=None, progress=None))]
    #[expect(
        clippy::too_many_arguments,
        reason = "a Python signature: pyo3 maps each keyword argument to one parameter"
    )]
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
        sequences: Option<Vec<i128>>,
        threads: Option<i64>,
        progress: Option<Bound<'py, PyAny>>,
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
            let (seed, streams) = seed_args(seed, first_sequence, sequences)?;
            let src = noise_source(
                "noise",
                noise.as_ref(),
                seed,
                streams,
                &[s, blocks, b, k, l],
            )?;
            Ok((s, b, l, cfg, src, threads_arg(threads)?))
        })()
        .map_err(PyTcdError)?;
        let (s, b, l, cfg, src, threads) = prepared;
        let model = Arc::clone(&self.inner);
        let out = interruptible(py, progress.as_ref(), move |control| {
            with_threads(threads, || {
                core_sample(
                    &model,
                    Observed::new(&observed.data, &mask.data, b, l),
                    s,
                    &cfg,
                    src.as_noise(),
                    control,
                )
            })?
        })?;
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
