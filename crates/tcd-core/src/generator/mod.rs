//! The MLP sample generator (issue 31): the network of `training/generator.py` (`Generator`), loaded
//! from a `generator.safetensors` file and run on the crate's GEMM kernels. It draws forecast samples
//! around the prior forecaster's forecast, one MLP forward each:
//!
//! ```text
//! past  = DCT_O(obs − last)          (O × K): the last O observed frames, relative to the last pose
//! ahead = DCT_P(prior − last)[:C]    (C × K): the first C coefficients of the prior's P-frame forecast
//! y     = head(GELU(W_n ⋯ GELU(W_1 [past, ahead, z])))    z: z_dim standard normals per sample
//! out   = prior + IDCT_P(y)          y (C × K): the first C DCT coefficients of a residual
//! ```
//!
//! (GELU the exact, erf one; DCTs the orthonormal DCT-II of [`crate::dct_matrix`], over time, one
//! coordinate at a time; flattened, coefficient-major.) The caller runs the prior
//! ([`crate::Prior::predict`]) and passes its forecast: the generator is a model of its own, with no
//! prior inside.
//!
//! # Layouts
//! Arrays are **frame-major (B, T, K)**, as the prior's: the observation (B, T, K) with T ≥ O (the
//! last O frames are read), the prior's forecast (B, P, K), the samples (S, B, P, K). Injected noise
//! is (S, B, z_dim); seeded noise is stage [`crate::stage::GENERATOR`] of [`crate::Noise`]'s streams.
//!
//! # Files
//! * `mod.rs`: the [`Generator`] type, loading, kernel choice, accessors;
//! * `config.rs`: its `tcd_config` ([`GeneratorConfig`]) and the tensors it implies;
//! * `forward.rs`: [`Generator::sample`], its argument checks and the rows split over threads.

use crate::error::Result;
use crate::kernels::Kernel;
use crate::nn::{pack_all, Dense, Linear};
use crate::prior::dct_matrix;
use crate::weights::{Network, Source, Weights};

pub mod config;
mod forward;

pub use config::{GeneratorConfig, GeneratorModelConfig};

/// A loaded sample generator. Immutable after load; `Send + Sync`, share it between threads freely.
#[derive(Clone, Debug)]
pub struct Generator {
    /// The file it was built from and its configuration.
    source: Source<GeneratorConfig>,
    /// The kernel in use (resolved: never `Auto`).
    kernel: Kernel,
    /// The observation's DCT: the orthonormal DCT-II matrix (O × O), row f the f-th cosine.
    dct_obs: Vec<f32>,
    /// The forecast's: the first C rows of the (P × P) one, (C × P).
    dct_pred: Vec<f32>,
    /// The hidden layers, each followed by the exact GELU: `layers.{i}`.
    layers: Vec<Dense>,
    /// `head`: hidden → the C·K coefficients of the residual.
    head: Dense,
}

/// The generator's file: PyTorch's (out, in) layers `layers.{i}` (the first reads
/// [`GeneratorModelConfig::input_width`] values, the others `hidden`) and `head` (C·K out); the DCT
/// matrices are no tensors: the engine computes them, [`crate::dct_matrix`].
impl Network for Generator {
    type Config = GeneratorConfig;

    fn source(&self) -> &Source<GeneratorConfig> {
        &self.source
    }

    fn build(w: &mut Weights<'_>, source: Source<GeneratorConfig>) -> Result<Self> {
        let m = &source.config.model;
        let mut dense = |name: &str, out: usize, input: usize| -> Result<Dense> {
            Ok(Dense::new(Linear::load(w, name, out, input)?))
        };
        let width = m.input_width().unwrap_or(0); // validated
        let layers = (0..m.layers)
            .map(|i| {
                dense(
                    &format!("layers.{i}"),
                    m.hidden,
                    if i == 0 { width } else { m.hidden },
                )
            })
            .collect::<Result<Vec<Dense>>>()?;
        let head = dense("head", m.coefs * m.num_features, m.hidden)?;
        let mut dct_pred = dct_matrix(m.pred_len);
        dct_pred.truncate(m.coefs * m.pred_len);
        let generator = Generator {
            kernel: Kernel::Portable,
            dct_obs: dct_matrix(m.obs_len),
            dct_pred,
            layers,
            head,
            source,
        };
        generator.with_kernel(Kernel::from_env()?)
    }
}

impl Generator {
    /// The same model running `kernel` (`Auto`: the best this CPU supports); an error if the CPU
    /// does not support it. Packs the weights for it once.
    pub fn with_kernel(mut self, kernel: Kernel) -> Result<Self> {
        (self.kernel, _) = pack_all(kernel, self.layers.iter_mut().chain([&mut self.head]))?;
        Ok(self)
    }

    /// The kernel this model runs (never `Auto`).
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }
    /// P: frames of the prior's forecast it takes and of each sample.
    pub fn pred_len(&self) -> usize {
        self.source.config.model.pred_len
    }
    /// Noise values one sample reads.
    pub fn z_dim(&self) -> usize {
        self.source.config.model.z_dim
    }
    /// C: DCT coefficients of the forecast it reads and of the residual it writes.
    pub fn coefs(&self) -> usize {
        self.source.config.model.coefs
    }
    /// Width of the hidden layers.
    pub fn hidden(&self) -> usize {
        self.source.config.model.hidden
    }
    /// Hidden layers.
    pub fn layers(&self) -> usize {
        self.source.config.model.layers
    }
}
