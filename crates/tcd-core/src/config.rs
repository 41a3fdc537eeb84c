//! The model configuration carried in the safetensors `__metadata__` under the key `tcd_config`.
//!
//! The names are the diffusers / training-config names (`num_train_timesteps`, `beta_schedule`,
//! `prediction_type`, `variance_type`, ...), so one vocabulary runs through Rust, Python and the
//! weight files. Unknown keys are ignored; `data` keeps whatever it holds.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::file_config::{
    file_kind, parse_json, role_of, Checks, FileConfig, GENERATOR_ROLE, PRIOR_ROLE,
};
use crate::schedule::{BetaSchedule, NoiseSchedule};

/// The weight-file format version this engine reads.
pub const FORMAT_VERSION: u32 = 1;

/// What a model was trained for (informative; the cascade checks window lengths, not roles).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Short-term model: `obs_len` observed frames, a few predicted frames (TCD: 50 + 5).
    Short,
    /// Long-term model: the short-term output as observation, the rest predicted (TCD: 55 + 20).
    Long,
    /// A model trained to repair (impute) corrupted observations.
    Repair,
}

impl Role {
    /// The name used in `tcd_config`.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Short => "short",
            Role::Long => "long",
            Role::Repair => "repair",
        }
    }
}

/// What the observed input channel holds at masked (mask = 0) entries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CondFill {
    /// Zero, as in CSDI / TCD (`mask · observed`).
    #[default]
    Zero,
    /// Linear interpolation along time between the nearest observed frames of the same coordinate,
    /// held constant before the first and after the last (PriSTI-style interpolated conditioning).
    Linear,
    /// The natural cubic spline through the observed frames of the same coordinate, with the rule of
    /// `Linear` before the first and after the last observed frame ([`crate::fill_spline`]).
    Spline,
    /// The prior forecaster's fill (`training.model.prior_fill`): the spline over the prior's
    /// `obs_len` observed frames, the prior's rollout from them after. It depends on the observation
    /// only, so the caller computes it once per call and puts it into the masked entries of `observed`
    /// ([`crate::cascade`] does, given the [`crate::Prior`]); the denoiser then takes the value it finds
    /// there. Goes with [`Target::PriorResidual`].
    Prior,
}

impl CondFill {
    /// The name used in `tcd_config`.
    pub fn as_str(self) -> &'static str {
        match self {
            CondFill::Zero => "zero",
            CondFill::Linear => "linear",
            CondFill::Spline => "spline",
            CondFill::Prior => "prior",
        }
    }
}

/// The variable the diffusion generates.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Target {
    /// The poses themselves (TCD).
    #[default]
    Absolute,
    /// `target_scale · (poses − fill_linear(observed, mask))`: the residual over the linear
    /// interpolation of the observation; a chain's result is mapped back as
    /// `fill + x · (1 / target_scale)` before the observation is merged.
    LinearResidual,
    /// `target_scale · (poses − fill_spline(observed, mask))`: the same over the natural cubic spline.
    SplineResidual,
    /// `target_scale · (poses − prior fill)`: the same over the prior forecaster's fill
    /// ([`CondFill::Prior`], which it requires).
    PriorResidual,
}

impl Target {
    /// The fill a residual target is taken over (`None` for [`Target::Absolute`]).
    pub fn residual_fill(self) -> Option<CondFill> {
        match self {
            Target::Absolute => None,
            Target::LinearResidual => Some(CondFill::Linear),
            Target::SplineResidual => Some(CondFill::Spline),
            Target::PriorResidual => Some(CondFill::Prior),
        }
    }

    /// The name used in `tcd_config`.
    pub fn as_str(self) -> &'static str {
        match self {
            Target::Absolute => "absolute",
            Target::LinearResidual => "linear_residual",
            Target::SplineResidual => "spline_residual",
            Target::PriorResidual => "prior_residual",
        }
    }
}

fn default_target_scale() -> f64 {
    1.0
}

/// Sizes of the CSDI denoiser (TCD_REFERENCE.md 1.5).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelConfig {
    /// Joints in the model layout (Human3.6M: 22).
    pub num_joints: usize,
    /// Coordinates per joint (3).
    pub coords: usize,
    /// K = num_joints * coords: one token per coordinate.
    pub num_features: usize,
    /// Residual channels C.
    pub channels: usize,
    /// Residual blocks N.
    pub num_layers: usize,
    /// Attention heads of both transformers (C must be divisible by it).
    pub num_heads: usize,
    /// Feed-forward width F of the transformer layers.
    pub ffn_dim: usize,
    /// D: width of the diffusion-step table and its projections.
    pub diffusion_embedding_dim: usize,
    /// Sinusoidal frame-position channels of the side information.
    pub time_embedding_dim: usize,
    /// E: learned per-coordinate embedding channels of the side information.
    pub feature_embedding_dim: usize,
    /// S = time_embedding_dim + feature_embedding_dim + 1 (the mask channel).
    pub side_dim: usize,
    /// LayerNorm epsilon of the transformer layers.
    pub layer_norm_eps: f64,
    /// The observed channel at masked entries (absent in older files: `zero`).
    #[serde(default)]
    pub cond_fill: CondFill,
    /// What the diffusion generates (absent in older files: `absolute`).
    #[serde(default)]
    pub target: Target,
    /// Multiplier of a residual target (absent: 1).
    #[serde(default = "default_target_scale")]
    pub target_scale: f64,
}

impl ModelConfig {
    /// C / num_heads.
    pub fn head_dim(&self) -> usize {
        self.channels / self.num_heads.max(1)
    }
}

/// Window lengths, in frames, of the sequences the model was trained on.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct WindowConfig {
    /// Observed (conditioned) frames at the start of the window.
    pub obs_len: usize,
    /// Predicted frames after them.
    pub pred_len: usize,
    /// obs_len + pred_len: the L the model runs at.
    pub seq_len: usize,
}

/// The diffusion process the model was trained with.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DiffusionConfig {
    /// T: number of training diffusion steps.
    pub num_train_timesteps: usize,
    /// `cosine`, `linear` or `quad` (checked against `betas`); any other name means custom betas, so
    /// this one stays a string (an open set, unlike the enums of this file).
    pub beta_schedule: String,
    /// First beta of `linear`/`quad`.
    pub beta_start: f64,
    /// Last beta of `linear`/`quad`.
    pub beta_end: f64,
    /// Clip of the `cosine` schedule (TCD: 0.5).
    pub max_beta: f64,
    /// The T betas: authoritative.
    pub betas: Vec<f64>,
    /// What the network predicts.
    pub prediction_type: PredictionType,
    /// `fixed_small` (posterior variance, the reference) or `fixed_large` (beta).
    pub variance_type: VarianceType,
}

/// Description of the training data (informative; the engine does not use it).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DataConfig {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dataset: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fps: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub units: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub root_relative: Option<bool>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_names: Option<Vec<String>>,
    /// Every other key, kept as it was.
    #[serde(flatten)]
    pub extra: BTreeMap<String, serde_json::Value>,
}

/// The whole `tcd_config` object.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TcdConfig {
    /// Must be [`FORMAT_VERSION`].
    pub format_version: u32,
    pub role: Role,
    pub model: ModelConfig,
    pub window: WindowConfig,
    pub diffusion: DiffusionConfig,
    #[serde(default)]
    pub data: DataConfig,
}

/// What the network predicts (`prediction_type`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PredictionType {
    /// ε, the noise added (TCD, CSDI).
    Epsilon,
    /// x₀, the clean diffusion variable (the residual, for a residual target): every sampler first turns
    /// it into the noise, `ε̂ = (x_t − √ᾱ_t · out) · (1/√(1 − ᾱ_t))` ([`crate::Plan::for_prediction`]).
    Sample,
}

/// How the DDPM sampler chooses σ (`variance_type`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VarianceType {
    /// σ² = β̃ = β'(1 − ᾱ_prev)/(1 − ᾱ_t): the reference.
    FixedSmall,
    /// σ² = β'.
    FixedLarge,
}

impl FileConfig for TcdConfig {
    fn num_features(&self) -> usize {
        self.model.num_features
    }

    fn obs_len(&self) -> usize {
        self.window.obs_len
    }

    /// Parses the JSON string stored under `tcd_config`; `path` names the file in errors.
    fn from_json(json: &str, path: &Path) -> Result<Self> {
        // A prior's or generator's file given to the denoiser's loader: say what it holds, not that its
        // role is unknown.
        if let Some(role) = role_of(json).filter(|r| r == PRIOR_ROLE || r == GENERATOR_ROLE) {
            let (what, loader) = file_kind(&role);
            return Err(Checks(path).bad(
                "role",
                format!("is {role:?}: the file holds {what}, which loads with {loader}, not as a denoiser"),
            ));
        }
        parse_json(json, path)
    }

    /// Checks sizes, window and schedule for consistency; `path` names the file in errors.
    fn validate(&self, path: &Path) -> Result<()> {
        let checks = Checks(path);
        let bad = |field: &str, reason: String| checks.bad(field, reason);
        checks.format_version(self.format_version)?;
        let m = &self.model;
        checks.at_least_one(&[
            ("model.num_joints", m.num_joints),
            ("model.coords", m.coords),
            ("model.channels", m.channels),
            ("model.num_layers", m.num_layers),
            ("model.num_heads", m.num_heads),
            ("model.ffn_dim", m.ffn_dim),
            ("model.feature_embedding_dim", m.feature_embedding_dim),
        ])?;
        // Not `Checks::num_features` (the prior's and the generator's): this message, older than theirs,
        // also gives the product, and error texts stay as they are.
        if m.num_features != m.num_joints * m.coords {
            return Err(bad(
                "model.num_features",
                format!(
                    "must equal num_joints * coords = {} * {} = {}, but is {}",
                    m.num_joints,
                    m.coords,
                    m.num_joints * m.coords,
                    m.num_features
                ),
            ));
        }
        // The prior's fill is both the conditioning and the residual's base: one without the other is a
        // model the reference cannot build (training.model.ModelConfig refuses it too).
        if (m.target == Target::PriorResidual) != (m.cond_fill == CondFill::Prior) {
            let (field, reason) = if m.target == Target::PriorResidual {
                ("model.target", format!(
                    "is \"prior_residual\", which needs cond_fill \"prior\" (the two go together), but cond_fill is {:?}",
                    m.cond_fill.as_str()
                ))
            } else {
                ("model.cond_fill", format!(
                    "is \"prior\", which needs target \"prior_residual\" (the two go together), but target is {:?}",
                    m.target.as_str()
                ))
            };
            return Err(bad(field, reason));
        }
        if !(m.target_scale.is_finite() && m.target_scale > 0.0) {
            return Err(bad(
                "model.target_scale",
                format!("must be a finite number > 0, but is {}", m.target_scale),
            ));
        }
        if !m.channels.is_multiple_of(m.num_heads) {
            return Err(bad(
                "model.channels",
                format!(
                    "must be divisible by num_heads = {}, but is {}",
                    m.num_heads, m.channels
                ),
            ));
        }
        // the sizes of the two sinusoidal embeddings
        for (field, dim, min) in [
            (
                "model.diffusion_embedding_dim",
                m.diffusion_embedding_dim,
                4,
            ),
            ("model.time_embedding_dim", m.time_embedding_dim, 2),
        ] {
            if dim < min || !dim.is_multiple_of(2) {
                return Err(bad(
                    field,
                    format!("must be even and at least {min}, but is {dim}"),
                ));
            }
        }
        let side = m.time_embedding_dim + m.feature_embedding_dim + 1;
        if m.side_dim != side {
            return Err(bad(
                "model.side_dim",
                format!(
                    "must equal time_embedding_dim + feature_embedding_dim + 1 = {side}, but is {}",
                    m.side_dim
                ),
            ));
        }
        checks.layer_norm_eps(m.layer_norm_eps)?;
        let w = &self.window;
        if w.seq_len == 0 || w.seq_len != w.obs_len + w.pred_len {
            return Err(bad(
                "window.seq_len",
                format!(
                    "must equal obs_len + pred_len = {} and be at least 1, but is {}",
                    w.obs_len + w.pred_len,
                    w.seq_len
                ),
            ));
        }
        let d = &self.diffusion;
        if d.num_train_timesteps == 0 {
            return Err(bad(
                "diffusion.num_train_timesteps",
                "must be at least 1, but is 0".into(),
            ));
        }
        if d.betas.len() != d.num_train_timesteps {
            return Err(bad(
                "diffusion.betas",
                format!(
                    "must have num_train_timesteps = {} values, but has {}",
                    d.num_train_timesteps,
                    d.betas.len()
                ),
            ));
        }
        if let Some((i, b)) = d
            .betas
            .iter()
            .enumerate()
            .find(|(_, b)| !(b.is_finite() && **b > 0.0 && **b < 1.0))
        {
            return Err(bad(
                "diffusion.betas",
                format!("must lie in the open interval (0, 1), but value {i} is {b}"),
            ));
        }
        if let Some(schedule) = BetaSchedule::from_name(&d.beta_schedule) {
            if schedule == BetaSchedule::Cosine && !(d.max_beta > 0.0 && d.max_beta <= 1.0) {
                return Err(bad(
                    "diffusion.max_beta",
                    format!("must lie in (0, 1], but is {}", d.max_beta),
                ));
            }
            let recomputed =
                schedule.betas(d.num_train_timesteps, d.beta_start, d.beta_end, d.max_beta);
            for (index, (&stored, &rec)) in d.betas.iter().zip(&recomputed).enumerate() {
                let diff = (stored - rec).abs();
                // A NaN recomputation (absurd beta_start) is a mismatch too.
                if diff.is_nan() || diff > 1e-9 {
                    return Err(Error::BetasMismatch {
                        path: path.to_path_buf(),
                        schedule: d.beta_schedule.clone(),
                        index,
                        stored,
                        recomputed: rec,
                    });
                }
            }
        }
        Ok(())
    }
}

impl TcdConfig {
    /// The noise schedule built from the stored (authoritative) betas.
    pub fn schedule(&self) -> NoiseSchedule {
        NoiseSchedule::from_betas(self.diffusion.betas.clone())
    }
}
