//! The public forward calls (argument checks, workspace reuse) and the per-sequence dispatch to
//! the portable or the packed (SIMD) path.

use super::workspace::{CondTables, Prepared, Workspace};
use super::Denoiser;
use crate::error::{Error, Result};
use crate::observation::Observation;
use crate::validate;
use crate::weights::Network;

/// The inputs of one sequence's forward: its mask, noisy sample x_t and observation x₀ (K × L
/// values each, (k, l) order), the cond tables for its length and the diffusion step.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SequenceInputs<'a> {
    pub tables: &'a CondTables,
    pub mask: &'a [f32],
    pub noisy: &'a [f32],
    pub observed: &'a [f32],
    pub step: usize,
}

impl Denoiser {
    /// The network's output for a batch (ε̂, or x̂₀ for `prediction_type` `sample`): `noisy` and `out`
    /// (B, K, L) like `observed` (whose K must be the model's `num_features`); `step` in 0..T. Entries of
    /// `noisy` where mask = 1 are ignored (may be NaN), and so are those of `observed` where mask = 0,
    /// except that a [`crate::CondFill::Prior`] model reads the prior's fill from them (it must be finite
    /// there).
    pub fn forward(
        &self,
        noisy: &[f32],
        observed: &Observation<'_>,
        step: usize,
        out: &mut [f32],
    ) -> Result<()> {
        let prepared = self.prepare(observed)?;
        self.forward_prepared(&prepared, noisy, step, out)
    }

    /// [`Denoiser::forward`] with the step-independent work done once by [`Denoiser::prepare`].
    pub fn forward_prepared(
        &self,
        prepared: &Prepared,
        noisy: &[f32],
        step: usize,
        out: &mut [f32],
    ) -> Result<()> {
        let mut ws = Workspace::new(self, prepared.length);
        self.forward_with_workspace(prepared, &mut ws, noisy, step, out)
    }

    /// [`Denoiser::forward_prepared`] using caller-owned buffers (no allocation when `workspace`
    /// was made for this length).
    pub fn forward_with_workspace(
        &self,
        prepared: &Prepared,
        workspace: &mut Workspace,
        noisy: &[f32],
        step: usize,
        out: &mut [f32],
    ) -> Result<()> {
        let (b, l, k) = (prepared.batch, prepared.length, self.num_features());
        let n = k * l;
        let shape = format!("({b}, {k}, {l})");
        let c2 = 2 * self.source.config.model.channels;
        let tables = &prepared.tables;
        if prepared.mask.len() != b * n
            || tables.width != c2
            || tables.time.len() != self.layers.len()
            || tables.time.iter().any(|t| t.len() != l * c2)
        {
            return Err(Error::invalid_input(
                "prepared",
                format!(
                    "the result of `prepare` on this model (K = {k}, {} layers, channels = {})",
                    self.layers.len(),
                    self.source.config.model.channels
                ),
                "one prepared by a model of a different shape",
            ));
        }
        validate::finite_where("noisy", noisy, &prepared.mask, 0.0, b * n, &shape)?;
        crate::error::check_len("out", out.len(), b * n, &shape)?;
        self.check_step(step)?;
        if workspace.length != l
            || workspace.dims != (k, self.source.config.model.channels)
            || workspace.fast.is_empty() != self.fast.is_none()
        {
            *workspace = Workspace::with_threads(self, l, workspace.fast.len().max(1));
        }
        for (((nz, ob), m), o) in noisy
            .chunks_exact(n)
            .zip(prepared.observed.chunks_exact(n))
            .zip(prepared.mask.chunks_exact(n))
            .zip(out.chunks_exact_mut(n))
        {
            let seq = SequenceInputs {
                tables: &prepared.tables,
                mask: m,
                noisy: nz,
                observed: ob,
                step,
            };
            self.forward_one(seq, o, workspace);
        }
        Ok(())
    }

    pub(crate) fn check_step(&self, step: usize) -> Result<()> {
        let t = self.num_train_timesteps();
        if step < t {
            Ok(())
        } else {
            Err(Error::invalid_input(
                "step",
                format!("a diffusion step in 0..{t} (num_train_timesteps = {t})"),
                step.to_string(),
            ))
        }
    }

    /// One sequence into `out` (K × L), no validation: sizes, mask, step and the workspace length
    /// were checked by the caller.
    pub(crate) fn forward_one(&self, seq: SequenceInputs<'_>, out: &mut [f32], ws: &mut Workspace) {
        match &self.fast {
            Some(fast) => self.forward_sequence_fast(fast, seq, out, ws),
            None => self.forward_sequence_portable(seq, out, ws),
        }
    }
}
