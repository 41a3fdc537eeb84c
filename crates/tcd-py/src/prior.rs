//! `tcd._native.Prior`: the deterministic prior forecaster (one `prior.safetensors` file) and its
//! rollout. Unlike the denoiser's (B, K, L), its arrays are frame-major (B, T, K), as the engine's.

use std::sync::Arc;

use numpy::{PyArray2, PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use tcd_core::{prior_fill, Control, Network, Observation, Prior};

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
        /// How a repair fill fills whole-frame gaps: "none" (like every other hidden entry) or
        /// "forecaster" (with the prior forecaster, which `repair` then needs).
        #[getter]
        fn gap_fill(&self) -> &'static str {
            match self.inner.config().model.gap_fill {
                tcd_core::GapFill::None => "none",
                tcd_core::GapFill::Forecaster => "forecaster",
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
            let (b, t) = obs.btk("obs", k, l)?;
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

        /// What a model conditioned on this prior sees (`tcd_core::prior_fill`): `observed` (B, T, K) with
        /// its `mask`-0 entries filled, (B, T, K) float32; `mask` of the same shape, 1 = given. A forecaster
        /// fills the first obs_len frames with the spline and rolls out after them (T > obs_len); a repair
        /// fill (T = obs_len) corrects the spline, and one with gap_fill "forecaster" fills whole-frame gaps
        /// from `forecaster`.
        #[pyo3(signature = (observed, mask, *, forecaster=None, threads=None))]
        fn fill<'py>(
            &self,
            py: Python<'py>,
            observed: PyReadonlyArrayDyn<'py, f32>,
            mask: PyReadonlyArrayDyn<'py, f32>,
            forecaster: Option<&Bound<'py, PyPrior>>,
            threads: Option<i64>,
        ) -> Result<Bound<'py, PyArrayDyn<f32>>> {
            let k = self.inner.num_features();
            let observed = Array::from_numpy(&observed);
            let mask = Array::from_numpy(&mask);
            let (b, t) = match observed.shape.as_slice() {
                &[b, t, kk] if kk == k => (b, t),
                _ => {
                    return Err(invalid(
                        "observed",
                        format!("a float32 array of shape (B, T, K) with K = {k}"),
                        format!("shape {}", Array::shape_str(&observed.shape)),
                    )
                    .into())
                }
            };
            mask.expect_shape("mask", &observed.shape, "(the shape of `observed`)")?;
            // the engine's layout, (B, K, T)
            let to_bkt = |a: &[f32]| -> Vec<f32> {
                let mut out = vec![0.0f32; a.len()];
                for (i, v) in a.iter().enumerate() {
                    let (bb, tt, kk) = (i / (t * k), i / k % t, i % k);
                    out[(bb * k + kk) * t + tt] = *v;
                }
                out
            };
            let (values, m) = (to_bkt(&observed.data), to_bkt(&mask.data));
            let threads = threads_arg(threads)?;
            let (model, forecaster) = (&self.inner, forecaster.map(|p| Arc::clone(&p.get().inner)));
            let out = interruptible(py, None, threads, |control: &Control| {
                let obs = Observation::new(&values, &m, [b, k, t])?;
                prior_fill(model, forecaster.as_deref(), &obs, control)
            })?;
            let mut frames = vec![0.0f32; out.len()];
            for (i, v) in out.iter().enumerate() {
                let (bb, kk, tt) = (i / (k * t), i / t % k, i % t);
                frames[(bb * t + tt) * k + kk] = *v;
            }
            to_numpy(py, &[b, t, k], frames)
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
