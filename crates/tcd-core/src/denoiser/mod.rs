//! The CSDI/TCD denoiser ε̂ = net(x_t, x₀, m, t) (TCD_REFERENCE.md section 1): load + forward.
//!
//! # Layouts
//! * Public arrays (`noisy`, `observed`, `mask`, `out`) are **(B, K, L) row-major** f32:
//!   index `b·K·L + k·L + l`, k the coordinate (joint·3 + axis), l the frame.
//! * Inside, one sequence at a time, activations are **token-major**: (N = K·L tokens × C
//!   channels), token `n = k·L + l`, so the time transformer's sequences (fixed k) are contiguous
//!   and the feature transformer works on a transposed copy (L × K × C).
//!
//! # Hoisting
//! The cond projection `W_c · [pe(l) | emb(k) | m] + b` is split into a per-frame table
//! (`W_t · pe(l) + b`, built by [`Denoiser::prepare`] once per length), a per-coordinate table
//! (`W_f · emb(k)`, built at load) and the mask column; the step embedding and every block's
//! diffusion projection are tabulated at load for all T steps. Both only regroup sums.
//!
//! # Files
//! * `mod.rs`: the [`Denoiser`] type and its accessors;
//! * `load.rs`: loading a weight file and hoisting (the step and cond tables), kernel choice;
//! * `workspace.rs`: what forwards reuse: [`CondTables`], [`Prepared`], [`Workspace`];
//! * `forward.rs`: the public forward calls (checks) and the per-sequence dispatch;
//! * `portable.rs`: one sequence on the portable layers of [`crate::nn`];
//! * `packed.rs`: one sequence on the SIMD kernels (weights packed at load);
//! * `input.rs`: the network input (its observed channel filled along time: [`crate::fill`]).

use crate::config::{Role, TcdConfig};
use crate::kernels::Kernel;
use crate::nn::{EncoderLayer, Linear};
use crate::schedule::NoiseSchedule;
use crate::weights::{Network, Source};

mod forward;
mod input;
mod load;
mod packed;
mod portable;
mod workspace;

pub(crate) use forward::SequenceInputs;
pub(crate) use workspace::CondTables;
pub use workspace::{Prepared, Workspace};

use packed::FastModel;

/// One residual block with its cond projection split for hoisting.
#[derive(Clone, Debug)]
struct ResidualLayer {
    time_layer: EncoderLayer,
    feature_layer: EncoderLayer,
    mid_projection: Linear,
    output_projection: Linear,
    /// Time-embedding columns of cond_projection, with its bias: (time_embedding_dim → 2C).
    cond_time: Linear,
    /// `W_f · emb(k)` for every coordinate k: (K × 2C).
    cond_feature: Vec<f32>,
    /// The mask column of cond_projection (2C).
    cond_mask: Vec<f32>,
}

/// The loaded model. Immutable after load; `Send + Sync`, share it between threads freely.
#[derive(Clone, Debug)]
pub struct Denoiser {
    /// The file it was built from and its configuration.
    source: Source<TcdConfig>,
    schedule: NoiseSchedule,
    /// Conv1d 2 → C.
    input_projection: Linear,
    /// (T × D): SiLU(P2 · SiLU(P1 · table[t])).
    step_embedding: Vec<f32>,
    /// (T × N_layers × C): diffusion_projection_i(step_embedding[t]).
    step_bias: Vec<f32>,
    layers: Vec<ResidualLayer>,
    /// Conv1d C → C.
    output_projection1: Linear,
    /// Conv1d C → 1.
    output_projection2: Linear,
    /// The kernel in use (resolved: never `Auto`).
    kernel: Kernel,
    /// Packed weights of the SIMD kernel, if one is in use.
    fast: Option<FastModel>,
}

impl Denoiser {
    /// The kernel this model runs (never `Auto`).
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// The model's role (`short`, `long`, `repair`).
    pub fn role(&self) -> Role {
        self.source.config.role
    }
    /// Predicted frames of the training window.
    pub fn pred_len(&self) -> usize {
        self.source.config.window.pred_len
    }
    /// L of the training window.
    pub fn seq_len(&self) -> usize {
        self.source.config.window.seq_len
    }
    /// T.
    pub fn num_train_timesteps(&self) -> usize {
        self.source.config.diffusion.num_train_timesteps
    }
    /// betas and ᾱ in f64.
    pub fn schedule(&self) -> &NoiseSchedule {
        &self.schedule
    }
    /// The step embedding e_t (D values) after both projections, for inspection.
    pub fn step_embedding(&self, step: usize) -> Option<&[f32]> {
        let d = self.source.config.model.diffusion_embedding_dim;
        self.step_embedding.get(step * d..(step + 1) * d)
    }

    /// A chain's result `x` (K·L values of one sequence, in the model's target space) back in poses: for a
    /// residual target, `fill + x / target_scale` at every entry, the fill taken along time from `observed`
    /// and `mask` as the target was ([`crate::config::Target::residual_fill`]); an absolute target is left
    /// as it is. The observed entries are merged afterwards by the sampler.
    pub(crate) fn to_poses(&self, x: &mut [f32], mask: &[f32], observed: &[f32]) {
        let m = &self.source.config.model;
        if let Some(fill) = m.target.residual_fill() {
            let inv = (1.0 / m.target_scale) as f32;
            let length = x.len() / self.num_features();
            for ((row, mr), or) in x
                .chunks_exact_mut(length)
                .zip(mask.chunks_exact(length))
                .zip(observed.chunks_exact(length))
            {
                fill.fill_row(mr, or, |ll, v| row[ll] = v + row[ll] * inv);
            }
        }
    }
}
