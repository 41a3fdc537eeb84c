//! `tcd._native.Denoiser`: one loaded weight file, its description, one forward and one sampled chain.

use std::sync::Arc;

use numpy::{PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use tcd_core::{sample as core_sample, with_threads, Denoiser, Network, Observation};

use crate::call::{SampleCount, SamplingArgs, Window};
use crate::convert::*;
use crate::error::{invalid, Result};
use crate::model::model_methods;

/// A loaded TCD denoiser (one safetensors file). Immutable; safe to share between threads.
#[pyclass(frozen, module = "tcd._native", name = "Denoiser")]
pub(crate) struct PyDenoiser {
    pub(crate) inner: Arc<Denoiser>,
}

model_methods! {
    PyDenoiser(Denoiser, "weight file") {
        #[getter]
        fn role(&self) -> &'static str {
            self.inner.role().as_str()
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
        fn timesteps(&self, options: SamplerOptions) -> Result<Vec<usize>> {
            let variance = self.inner.config().diffusion.variance_type;
            let plan = options.config().plan(self.inner.schedule(), variance)?;
            Ok(plan.timesteps())
        }

        /// Noise blocks per chain, the second axis of injected noise: n + 1 (x_T, then one z per
        /// step), or 1 for the deterministic `dpmpp2m`.
        fn num_noise_blocks(&self, options: SamplerOptions) -> Result<usize> {
            Ok(noise_blocks(&self.inner, &options.config())?)
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
        ) -> Result<Bound<'py, PyArrayDyn<f32>>> {
            let threads = threads_arg(threads)?;
            let k = self.inner.num_features();
            let (noisy, observed, mask) = (
                Array::from_numpy(&noisy),
                Array::from_numpy(&observed),
                Array::from_numpy(&mask),
            );
            let (b, l) = noisy.bkl("noisy", k)?;
            let shape = [b, k, l];
            observed.expect_shape("observed", &shape, "(the shape of `noisy`)")?;
            mask.expect_shape("mask", &shape, "(the shape of `noisy`)")?;
            let t = self.inner.num_train_timesteps();
            let Some(step) = usize::try_from(step).ok().filter(|s| *s < t) else {
                let expected = format!("a diffusion step in 0..{t}");
                return Err(invalid("step", expected, step.to_string()).into());
            };
            let model = &self.inner;
            let out = py.detach(|| -> CoreResult<Vec<f32>> {
                with_threads(threads, || {
                    let observed = Observation::new(&observed.data, &mask.data, shape)?;
                    let mut out = vec![0.0f32; noisy.data.len()];
                    model.forward(&noisy.data, &observed, step, &mut out)?;
                    Ok(out)
                })?
            })?;
            to_numpy(py, &shape, out)
        }

        /// `num_samples` merged samples per sequence, (S, B, K, L), of the `call` dict (observed, mask,
        /// num_samples, options, streams, progress). Noise: injected `noise` (S, n + 1, B, K, L)
        /// ((S, 1, B, K, L) for dpmpp2m) or the `seed` of the call's `streams` (stream stage 0).
        #[pyo3(signature = (call, *, noise=None))]
        fn sample<'py>(
            &self,
            py: Python<'py>,
            call: SamplingArgs<'py>,
            noise: Option<PyReadonlyArrayDyn<'py, f32>>,
        ) -> Result<Bound<'py, PyArrayDyn<f32>>> {
            let model = &self.inner;
            let call = call.prepare(Window::Any, SampleCount::AtLeastOne, [(model, "noise", noise)])?;
            let out = call.run(py, |job, control| {
                let [noise] = &job.noise;
                core_sample(
                    model,
                    &job.observation(model.num_features())?,
                    job.options.num_samples,
                    &job.options.sampler,
                    noise.as_noise(),
                    control,
                )
            })?;
            to_numpy(py, &call.job.samples_shape(model.num_features()), out)
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
}
