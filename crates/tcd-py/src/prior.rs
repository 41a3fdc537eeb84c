//! `tcd._native.Prior`: the deterministic prior forecaster (one `prior.safetensors` file) and its
//! rollout. Unlike the denoiser's (B, K, L), its arrays are frame-major (B, T, K), as the engine's.

use std::sync::Arc;

use numpy::{PyArray2, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use tcd_core::{Control, Prior};

use crate::convert::*;
use crate::error::{internal, invalid, Result};
use crate::model::model_methods;
use crate::run::interruptible;

/// A call on one sequence of at most this many chunks (forwards of about 0.2 ms at the bundled size) runs
/// on the calling thread, GIL released: no worker thread to hand it to and back. On a busy machine each
/// hand-off waits for a core (one forecast took 4 ms instead of 0.5 beside a training run); so short a call
/// needs no Ctrl-C of its own (Python raises a pending one as it returns).
const INLINE_CHUNKS: usize = 32;

/// A loaded prior forecaster. Immutable; safe to share between threads.
#[pyclass(frozen, module = "tcd._native", name = "Prior")]
pub(crate) struct PyPrior {
    pub(crate) inner: Arc<Prior>,
}

model_methods! {
    PyPrior(Prior, "prior weight file") {
        #[getter]
        fn chunk(&self) -> usize {
            self.inner.chunk()
        }
        #[getter]
        fn blocks(&self) -> usize {
            self.inner.config().model.blocks
        }
        /// What a forward's output is added to: "last" (a forecaster) or "window" (a repair fill).
        #[getter]
        fn anchor(&self) -> &'static str {
            match self.inner.config().model.anchor {
                tcd_core::Anchor::Last => "last",
                tcd_core::Anchor::Window => "window",
            }
        }
        /// The DCT matrix the engine computed (obs_len, obs_len) float32, row f the f-th cosine.
        #[getter]
        fn dct_matrix<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
            let l = self.inner.obs_len();
            let rows: Vec<Vec<f32>> = self
                .inner
                .dct()
                .chunks_exact(l)
                .map(<[f32]>::to_vec)
                .collect();
            PyArray2::from_vec2(py, &rows)
                .map_err(|e| internal(py, &format!("the DCT matrix has a bad shape ({e})")))
        }

        /// The next `horizon` frames of each sequence of `obs` (B, T, K) float32, T >= obs_len (the last
        /// obs_len frames are read): (B, horizon, K), chunks rolled out.
        #[pyo3(signature = (obs, horizon, *, threads=None))]
        fn predict<'py>(
            &self,
            py: Python<'py>,
            obs: PyReadonlyArrayDyn<'py, f32>,
            horizon: i64,
            threads: Option<i64>,
        ) -> Result<Bound<'py, PyArrayDyn<f32>>> {
            let k = self.inner.num_features();
            let l = self.inner.obs_len();
            let obs = Array::from_numpy(&obs);
            let (b, t) = match obs.shape.as_slice() {
                &[b, t, kk] if kk == k && b >= 1 && t >= l => (b, t),
                _ => {
                    return Err(invalid(
                        "obs",
                        format!("a float32 array of shape (B, T, K) with K = {k}, B >= 1 and T >= obs_len = {l}"),
                        format!("shape {}", Array::shape_str(&obs.shape)),
                    )
                    .into())
                }
            };
            let horizon = positive("horizon", horizon)?;
            // the output's size, refused up front like a sampler's
            if !within_limit(&[b, k, horizon]) {
                return Err(invalid(
                    "horizon",
                    format!("small enough that B x horizon x K = {b} x {horizon} x {k} is at most 2^31 values"),
                    horizon.to_string(),
                )
                .into());
            }
            let threads = threads_arg(threads)?;
            let model = &self.inner;
            let predict = |control: &Control| model.predict(&obs.data, b, t, horizon, control);
            let out = if b == 1 && horizon.div_ceil(model.chunk()) <= INLINE_CHUNKS {
                // one sequence is never split over threads: `threads` changes nothing
                py.detach(|| predict(&Control::default()))?
            } else {
                interruptible(py, None, threads, predict)?
            };
            to_numpy(py, &[b, horizon, k], out)
        }

        fn __repr__(&self) -> String {
            format!(
                "Prior(path={:?}, num_features={}, obs_len={}, chunk={}, blocks={}, anchor={:?}, kernel={:?})",
                self.path(),
                self.num_features(),
                self.obs_len(),
                self.chunk(),
                self.blocks(),
                self.anchor(),
                self.kernel()
            )
        }
    }
}
