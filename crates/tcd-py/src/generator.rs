//! `tcd._native.Generator`: the MLP sample generator (one `generator.safetensors` file) and its
//! samples. Its arrays are frame-major (B, T, K), as the prior's.

use std::sync::Arc;

use numpy::{PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use tcd_core::{Control, Generator, Network};

use crate::call::{noise_source, seed_args, Streams};
use crate::convert::*;
use crate::error::Result;
use crate::model::model_methods;
use crate::run::interruptible;

/// A loaded sample generator. Immutable; safe to share between threads.
#[pyclass(frozen, module = "tcd._native", name = "Generator")]
pub(crate) struct PyGenerator {
    pub(crate) inner: Arc<Generator>,
}

model_methods! {
    PyGenerator(Generator, "generator weight file") {
        #[getter]
        fn pred_len(&self) -> usize {
            self.inner.pred_len()
        }
        #[getter]
        fn hidden(&self) -> usize {
            self.inner.hidden()
        }
        #[getter]
        fn layers(&self) -> usize {
            self.inner.layers()
        }
        #[getter]
        fn z_dim(&self) -> usize {
            self.inner.z_dim()
        }
        #[getter]
        fn coefs(&self) -> usize {
            self.inner.coefs()
        }

        /// `num_samples` forecasts of each sequence, (S, B, pred_len, K) float32: `obs` (B, T, K) float32 with
        /// T >= obs_len (the last obs_len frames are read), `prior` (B, pred_len, K) the prior forecaster's
        /// forecast of each. Noise: injected `noise` (S, B, z_dim) or the `seed` of `streams` (stream stage
        /// STAGE_GENERATOR).
        #[pyo3(signature = (obs, prior, num_samples, *, noise=None, streams))]
        fn sample<'py>(
            &self,
            py: Python<'py>,
            obs: PyReadonlyArrayDyn<'py, f32>,
            prior: PyReadonlyArrayDyn<'py, f32>,
            num_samples: i64,
            noise: Option<PyReadonlyArrayDyn<'py, f32>>,
            streams: Streams,
        ) -> Result<Bound<'py, PyArrayDyn<f32>>> {
            let model = &self.inner;
            let (k, o, p, z) = (model.num_features(), model.obs_len(), model.pred_len(), model.z_dim());
            let s = positive("num_samples", num_samples)?;
            let obs = Array::from_numpy(&obs);
            let (b, t) = obs.btk("obs", k, o)?;
            let prior = Array::from_numpy(&prior);
            prior.expect_shape("prior", &[b, p, k], "= (B, pred_len, K): the prior's forecast of each sequence")?;
            check_work(s, b, k, p)?;
            let (seed, ids) = seed_args(&streams)?;
            let noise = noise_source("noise", noise.as_ref(), seed, ids, &[s, b, z], "= (num_samples, B, z_dim)")?;
            let threads = threads_arg(streams.threads)?;
            let out = interruptible(py, None, threads, |control: &Control| {
                model.sample(&obs.data, &prior.data, b, t, s, noise.as_noise(), control)
            })?;
            to_numpy(py, &[s, b, p, k], out)
        }

        fn __repr__(&self) -> String {
            format!(
                "Generator(path={:?}, num_features={}, obs_len={}, pred_len={}, hidden={}, layers={}, z_dim={}, coefs={}, kernel={:?})",
                self.path(),
                self.num_features(),
                self.obs_len(),
                self.pred_len(),
                self.hidden(),
                self.layers(),
                self.z_dim(),
                self.coefs(),
                self.kernel()
            )
        }
    }
}
