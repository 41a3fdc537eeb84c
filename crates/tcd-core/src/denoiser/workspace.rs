//! What forwards reuse across steps and samples: the length-dependent [`CondTables`], the
//! [`Prepared`] batch (mask + tables) and the activation buffers of a [`Workspace`].

use super::Denoiser;
use crate::error::Result;
use crate::kernels::FastScratch;
use crate::nn::embedding::frame_embedding;
use crate::nn::EncoderScratch;
use crate::observation::Observation;
use crate::validate;
use crate::weights::Network;

/// The length-dependent cond tables: for every block, `W_t · pe(l) + b` (L × 2C).
#[derive(Clone, Debug)]
pub(crate) struct CondTables {
    /// The frame count L the tables were built for.
    pub(super) length: usize,
    /// 2C of the model that built the tables.
    pub(super) width: usize,
    pub(super) time: Vec<Vec<f32>>,
}

/// Everything about a batch of sequences that does not change across diffusion steps and samples:
/// the observation (its values and mask, (B, K, L), copied) and the cond tables. Built by
/// [`Denoiser::prepare`].
#[derive(Clone, Debug)]
pub struct Prepared {
    pub(super) batch: usize,
    pub(super) length: usize,
    pub(super) observed: Vec<f32>,
    pub(super) mask: Vec<f32>,
    pub(super) tables: CondTables,
}

impl Prepared {
    /// B.
    pub fn batch(&self) -> usize {
        self.batch
    }
    /// L.
    pub fn length(&self) -> usize {
        self.length
    }
    /// The observed values, (B, K, L).
    pub fn observed(&self) -> &[f32] {
        &self.observed
    }
    /// The mask, (B, K, L).
    pub fn mask(&self) -> &[f32] {
        &self.mask
    }
}

/// Activation buffers of one forward (one sequence of length L), reused across steps so that the
/// step loop does not allocate. Create one per thread / chain.
#[derive(Clone, Debug)]
pub struct Workspace {
    pub(super) length: usize,
    /// (K, C) of the model it was made for.
    pub(super) dims: (usize, usize),
    /// Residual stream h (N × C).
    pub(super) h: Vec<f32>,
    /// Block input / transformer stream y (N × C).
    pub(super) y: Vec<f32>,
    /// Transposed copy for the feature transformer (L × K × C).
    pub(super) yt: Vec<f32>,
    /// mid + cond, then output projection (N × 2C).
    pub(super) z: Vec<f32>,
    /// Gated activation (N × C).
    pub(super) g: Vec<f32>,
    /// Σ skip (N × C).
    pub(super) skip: Vec<f32>,
    pub(super) scratch: EncoderScratch,
    /// Scratch of the SIMD kernels (empty for the portable kernel).
    pub(super) fast: Vec<FastScratch>,
}

impl Workspace {
    /// Buffers for sequences of `length` frames of `denoiser`. With a SIMD kernel, one forward
    /// is split over up to the current rayon pool's thread count (see [`Workspace::with_threads`]).
    pub fn new(denoiser: &Denoiser, length: usize) -> Self {
        Self::with_threads(denoiser, length, rayon::current_num_threads())
    }

    /// Buffers for sequences of `length` frames of `denoiser`; with a SIMD kernel, one forward
    /// (one chain) is split over `threads` rayon workers (coordinates for the time transformer
    /// and the block tail, frames for the feature transformer). Use 1 when independent chains
    /// already occupy the threads. Results do not depend on `threads`.
    pub fn with_threads(denoiser: &Denoiser, length: usize, threads: usize) -> Self {
        let m = &denoiser.source.config.model;
        let n = m.num_features * length;
        let c = m.channels;
        Workspace {
            length,
            dims: (m.num_features, c),
            h: vec![0.0; n * c],
            y: vec![0.0; n * c],
            yt: vec![0.0; n * c],
            z: vec![0.0; n * 2 * c],
            g: vec![0.0; n * c],
            skip: vec![0.0; n * c],
            scratch: EncoderScratch::new(m, length.max(m.num_features)),
            fast: if denoiser.fast.is_some() {
                let parts = threads.clamp(1, m.num_features.max(1));
                vec![FastScratch::new(c, m.ffn_dim, length.max(m.num_features), length); parts]
            } else {
                Vec::new()
            },
        }
    }

    /// The length L this workspace serves.
    pub fn length(&self) -> usize {
        self.length
    }
}

impl Denoiser {
    /// The cond tables for sequences of `length` frames (independent of mask and step).
    pub(crate) fn cond_tables(&self, length: usize) -> CondTables {
        let te = self.source.config.model.time_embedding_dim;
        let c2 = 2 * self.source.config.model.channels;
        let pe = frame_embedding(length, te);
        let time = self
            .layers
            .iter()
            .map(|layer| {
                let mut t = vec![0.0f32; length * c2];
                layer.cond_time.forward(&pe, &mut t);
                t
            })
            .collect();
        CondTables {
            length,
            width: c2,
            time,
        }
    }

    /// What every step of every sample of the sequences of `observed` shares (its K must be the model's
    /// `num_features`). A [`crate::CondFill::Prior`] model reads the prior's fill from the mask-0 entries
    /// of `observed`: they must be finite.
    pub fn prepare(&self, observed: &Observation<'_>) -> Result<Prepared> {
        let k = self.num_features();
        observed.expect(k, "the model's", None)?;
        let [batch, _, length] = observed.shape();
        let values = observed.values();
        if self.source.config.model.cond_fill == crate::config::CondFill::Prior {
            // The masked entries hold the prior's fill, which the network reads (CondFill::Prior).
            let shape = format!("({batch}, {k}, {length})");
            validate::all_finite("observed", values, values.len(), &shape)?;
        }
        Ok(Prepared {
            batch,
            length,
            observed: values.to_vec(),
            mask: observed.mask().to_vec(),
            tables: self.cond_tables(length),
        })
    }
}
