//! The prior's `tcd_config` (role `"prior"`): its own model fields, no window or diffusion block.
//! Same format version, metadata key and `data` block as the denoisers' ([`crate::config`]);
//! `docs/tcd_config.schema.json` defines both.

use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::file_config::{frame_and_window, Checks, ModelBlock, ModelFile, PRIOR_ROLE as ROLE};

/// Sizes of the prior network (`training/prior.py`, `PriorNet`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PriorModelConfig {
    /// Joints in the model layout (Human3.6M: 22).
    pub num_joints: usize,
    /// Coordinates per joint (3).
    pub coords: usize,
    /// K = num_joints * coords: the width of one frame.
    pub num_features: usize,
    /// Observed frames one forward reads (the DCT length).
    pub obs_len: usize,
    /// Frames one forward predicts; longer horizons are rolled out chunk by chunk.
    pub chunk: usize,
    /// Temporal FC + layer norm blocks.
    pub blocks: usize,
    /// Epsilon of the layer norm over the K coordinates of a frame.
    pub layer_norm_eps: f64,
    /// What a forward's output is added to (`training/prior.py`, `PriorConfig.anchor`); absent in a
    /// forecaster's file (written as before it existed), so only a repair fill's file names it.
    #[serde(default, skip_serializing_if = "Anchor::is_last")]
    pub anchor: Anchor,
    /// What a repair fill (anchor [`Anchor::Window`]) does over its window's whole-frame gaps; absent
    /// ([`GapFill::None`]) in every other file.
    #[serde(default, skip_serializing_if = "GapFill::is_none")]
    pub gap_fill: GapFill,
    /// The in-betweener of a gap-filling repair fill (`training/inbetween.py`): its context frames each
    /// side of a gap; 0 (absent) for none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub inbetween_context: usize,
    /// The longest whole-frame gap with an in-betweening kernel (`inbetween_{n}`, n = 1 ..= this); 0
    /// (absent) for none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub inbetween_max_gap: usize,
    /// The joint in-betweener of a repair fill (`training/inbetween.py`, `fit_joint_runs`): its context
    /// frames each side of a run of one coordinate hidden in frames where others are seen; 0 for none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub joint_inbetween_context: usize,
    /// The longest such run with a kernel (`joint_inbetween_{n}`, n = 1 ..= this); 0 for none.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub joint_inbetween_max_gap: usize,
}

fn is_zero(v: &usize) -> bool {
    *v == 0
}

/// The inputs of the in-betweening kernel of an n-frame gap with `context` frames each side:
/// the segment (2 C + n), the two context fractions, the segment times each (`training.inbetween`).
pub fn inbetween_width(n: usize, context: usize) -> usize {
    3 * (2 * context + n) + 2
}

/// How a repair fill fills a window's whole-frame gaps: runs of frames with every entry hidden, where
/// its network has no joint of the frame to correct the spline from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GapFill {
    /// Like every other hidden entry: the network's correction of the spline.
    #[default]
    None,
    /// With the prior forecaster (`prior.safetensors`) run forward into the gap and backward into it
    /// (`crate::fill`'s gap fill), averaged with the correction of the spline.
    Forecaster,
}

impl GapFill {
    /// Whether this is the default, [`GapFill::None`] (not written to a file's config).
    pub fn is_none(&self) -> bool {
        *self == GapFill::None
    }
}

/// What a prior's forward adds its network's output to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Anchor {
    /// The last observed pose: the output is the next `chunk` frames (the forecaster, rolled out).
    #[default]
    Last,
    /// The input window itself (`chunk` = `obs_len`): the output is that window corrected. A repair
    /// fill: its input is the natural cubic spline through a masked window's observed entries
    /// ([`crate::pipeline::repair`]).
    Window,
}

impl Anchor {
    /// Whether this is the default, [`Anchor::Last`] (not written to a file's config).
    pub fn is_last(&self) -> bool {
        *self == Anchor::Last
    }
}

/// The whole `tcd_config` object of a prior file.
pub type PriorConfig = ModelFile<PriorModelConfig>;

impl ModelBlock for PriorModelConfig {
    const ROLE: &'static str = ROLE;
    const HOLDS: &'static str = "the prior forecaster";

    fn sizes(&self) -> Vec<(&'static str, usize)> {
        vec![
            ("model.obs_len", self.obs_len),
            ("model.chunk", self.chunk),
            ("model.blocks", self.blocks),
        ]
    }

    frame_and_window!();

    fn validate(&self, checks: &Checks) -> Result<()> {
        let m = self;
        checks.require(m.chunk <= m.obs_len, "model.chunk", || {
            format!(
                "must not exceed obs_len = {}, but is {}",
                m.obs_len, m.chunk
            )
        })?;
        checks.require(m.anchor != Anchor::Window || m.chunk == m.obs_len, "model.chunk", || {
            format!(
                "must equal obs_len = {} for anchor \"window\" (the output corrects the whole input), but is {}",
                m.obs_len, m.chunk
            )
        })?;
        checks.require(
            m.gap_fill == GapFill::None || m.anchor == Anchor::Window,
            "model.gap_fill",
            || "is for a repair fill (anchor \"window\"); a forecaster fills no gaps".to_string(),
        )?;
        // The two in-betweeners (training/inbetween.py): each a context and a longest gap, both 0 or both at
        // least 1, the gap shorter than the window, on the fills they are for.
        for (name, context, max_gap, fits, what) in [
            (
                "inbetween",
                m.inbetween_context,
                m.inbetween_max_gap,
                m.gap_fill == GapFill::Forecaster,
                format!(
                    "a repair fill with gap_fill \"forecaster\" (gap_fill {:?})",
                    m.gap_fill
                ),
            ),
            (
                "joint_inbetween",
                m.joint_inbetween_context,
                m.joint_inbetween_max_gap,
                m.anchor == Anchor::Window,
                format!("a repair fill (anchor \"window\"; anchor {:?})", m.anchor),
            ),
        ] {
            let field = format!("model.{name}_max_gap");
            checks.require((context > 0) == (max_gap > 0), &field, || {
                format!("and {name}_context are both 0 or both at least 1, but are {max_gap} and {context}")
            })?;
            checks.require(max_gap == 0 || (fits && max_gap < m.obs_len), &field, || {
                format!(
                    "is for {what}, with runs shorter than its window (obs_len = {}), but is {max_gap}",
                    m.obs_len
                )
            })?;
        }
        checks.layer_norm_eps(m.layer_norm_eps)?;
        Ok(())
    }
}
