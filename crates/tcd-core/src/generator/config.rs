//! The generator's `tcd_config` (role `"generator"`): its own model fields, no window or diffusion
//! block. Same format version, metadata key and `data` block as the denoisers' ([`crate::config`]);
//! `docs/tcd_config.schema.json` defines all three kinds.

use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::file_config::{frame_and_window, Checks, ModelBlock, ModelFile, GENERATOR_ROLE as ROLE};

/// Sizes of the generator's MLP (`training/generator.py`, `Generator`).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct GeneratorModelConfig {
    /// Joints in the model layout (HumanEva-I: 14).
    pub num_joints: usize,
    /// Coordinates per joint (3).
    pub coords: usize,
    /// K = num_joints * coords: the width of one frame.
    pub num_features: usize,
    /// O: observed frames it reads (the last `obs_len` of the input; the observation's DCT length).
    pub obs_len: usize,
    /// P: frames it forecasts (the prior's forecast it is given, and each sample; their DCT length).
    pub pred_len: usize,
    /// Width of every hidden layer.
    pub hidden: usize,
    /// Hidden layers (`layers.{i}`, each a Linear and an exact GELU).
    pub layers: usize,
    /// Noise values one sample reads.
    pub z_dim: usize,
    /// C ≤ P: the DCT coefficients of the forecast it reads and of the residual it writes.
    pub coefs: usize,
}

impl GeneratorModelConfig {
    /// The first layer's input: the observation's O·K and the prior's C·K DCT coefficients, then z
    /// (`None` if that overflows, which [`GeneratorConfig::validate`] refuses).
    pub fn input_width(&self) -> Option<usize> {
        let k = self.num_features;
        self.obs_len
            .checked_add(self.coefs)?
            .checked_mul(k)?
            .checked_add(self.z_dim)
    }
}

/// The whole `tcd_config` object of a generator file.
pub type GeneratorConfig = ModelFile<GeneratorModelConfig>;

impl ModelBlock for GeneratorModelConfig {
    const ROLE: &'static str = ROLE;
    const HOLDS: &'static str = "the MLP sample generator";

    fn sizes(&self) -> Vec<(&'static str, usize)> {
        vec![
            ("model.obs_len", self.obs_len),
            ("model.pred_len", self.pred_len),
            ("model.hidden", self.hidden),
            ("model.layers", self.layers),
            ("model.z_dim", self.z_dim),
            ("model.coefs", self.coefs),
        ]
    }

    frame_and_window!();

    fn validate(&self, checks: &Checks) -> Result<()> {
        let m = self;
        checks.require(m.coefs <= m.pred_len, "model.coefs", || {
            format!(
                "must not exceed pred_len = {} (the forecast's DCT coefficients), but is {}",
                m.pred_len, m.coefs
            )
        })?;
        checks.require(m.input_width().is_some(), "model.z_dim", || {
            format!(
                "and (obs_len + coefs) * num_features must add up to a first-layer width that fits in memory, \
                 but are {} and ({} + {}) * {}",
                m.z_dim, m.obs_len, m.coefs, m.num_features
            )
        })
    }
}
