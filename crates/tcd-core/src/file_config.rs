//! What every network file's `tcd_config` has alike, the denoiser's ([`crate::TcdConfig`]), the prior's
//! and the generator's ([`ModelFile`]): parsed, then checked ([`FileConfig`]); the roles that tell the
//! kinds apart, the parsing that names a bad field, and the checks alike in all ([`Checks`]).

use std::path::Path;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::config::{DataConfig, FORMAT_VERSION};
use crate::error::{Error, Result};

/// A network file's configuration, the `tcd_config` JSON of its metadata: parsed, then checked
/// ([`crate::Network::config`] does both).
pub trait FileConfig: Sized + Clone + Serialize {
    /// Parses the JSON stored under `tcd_config`; `path` names the file in errors. A file of another
    /// kind is refused by its role before its fields are read.
    fn from_json(json: &str, path: &Path) -> Result<Self>;

    /// Checks it for consistency; `path` names the file in errors.
    fn validate(&self, path: &Path) -> Result<()>;

    /// K: coordinates per frame of the network's inputs and outputs.
    fn num_features(&self) -> usize;

    /// Frames of the observation the network reads.
    fn obs_len(&self) -> usize;

    /// Serialises back to the JSON stored under `tcd_config`.
    fn to_json(&self) -> String {
        // Serialising plain structs of numbers and strings cannot fail; fall back to "{}" anyway.
        serde_json::to_string(self).unwrap_or_else(|_| "{}".to_string())
    }
}

/// The `tcd_config` of a network whose file holds its `model` block and nothing of the denoisers'
/// window or diffusion: the prior's ([`crate::PriorConfig`]) and the generator's
/// ([`crate::GeneratorConfig`]). Other keys (`training`, `source_revision`) are informative: ignored
/// here, kept in the network's `config_json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelFile<M> {
    /// Must be [`FORMAT_VERSION`].
    pub format_version: u32,
    /// Must be [`ModelBlock::ROLE`].
    pub role: String,
    pub model: M,
    #[serde(default)]
    pub data: DataConfig,
}

/// [`ModelBlock::frame`] and [`ModelBlock::obs_len`] of a block that names its frame and window as every
/// model block does (`num_joints`, `coords`, `num_features`, `obs_len`): written once, here, for each.
macro_rules! frame_and_window {
    () => {
        fn frame(&self) -> (usize, usize, usize) {
            (self.num_joints, self.coords, self.num_features)
        }

        fn obs_len(&self) -> usize {
            self.obs_len
        }
    };
}

pub(crate) use frame_and_window;

/// The `model` block of a [`ModelFile`]: its role and its own checks.
pub trait ModelBlock: Clone + Serialize + DeserializeOwned {
    /// The file's `role`.
    const ROLE: &'static str;
    /// What such a file holds, in the error refusing a file of another kind.
    const HOLDS: &'static str;

    /// The block's sizes beyond its frame's that must be at least 1, each with its field's name.
    fn sizes(&self) -> Vec<(&'static str, usize)>;

    /// Its frame: (num_joints, coords, num_features), the last their product.
    fn frame(&self) -> (usize, usize, usize);

    /// Frames of the observation it reads (`model.obs_len`).
    fn obs_len(&self) -> usize;

    /// Checks the rest of the block for consistency (the file's version and role, [`ModelBlock::sizes`]
    /// and [`ModelBlock::frame`] are checked before), by `checks`, which name the file in errors.
    fn validate(&self, checks: &Checks) -> Result<()>;
}

impl<M: ModelBlock> FileConfig for ModelFile<M> {
    fn from_json(json: &str, path: &Path) -> Result<Self> {
        Checks(path).role_is(json, M::ROLE, M::HOLDS)?;
        parse_json(json, path)
    }

    fn validate(&self, path: &Path) -> Result<()> {
        let checks = Checks(path);
        checks.format_version(self.format_version)?;
        checks.role(&self.role, M::ROLE)?;
        let (num_joints, coords, num_features) = self.model.frame();
        checks.at_least_one(&[("model.num_joints", num_joints), ("model.coords", coords)])?;
        checks.at_least_one(&self.model.sizes())?;
        checks.num_features(num_joints, coords, num_features)?;
        self.model.validate(&checks)
    }

    fn num_features(&self) -> usize {
        self.model.frame().2
    }

    fn obs_len(&self) -> usize {
        self.model.obs_len()
    }
}

// What the denoiser's config, the prior's (`crate::prior::PriorConfig`) and the generator's
// (`crate::generator::GeneratorConfig`) share (the same format, metadata key and `data` block): their
// roles, parsing, serialising and the checks alike in all.

/// The `role` of a prior file.
pub(crate) const PRIOR_ROLE: &str = "prior";
/// The `role` of a generator file.
pub(crate) const GENERATOR_ROLE: &str = "generator";

/// What a weight file of `role` holds and what loads it, for the error of a loader given a file of
/// another kind: the prior's, the generator's, and any other role a denoiser's.
pub(crate) fn file_kind(role: &str) -> (&'static str, &'static str) {
    match role {
        PRIOR_ROLE => (
            "the deterministic prior forecaster",
            "`Prior::load` (Python: `tcd.engine.Prior.load`)",
        ),
        GENERATOR_ROLE => (
            "the MLP sample generator",
            "`Generator::load` (Python: `tcd.engine.Generator.load`)",
        ),
        _ => (
            "a denoiser",
            "`Denoiser::load`, in Python `tcd.engine.Denoiser.load` or a model directory with `tcd.load`",
        ),
    }
}

/// The `role` of a `tcd_config` JSON, where it parses and has a string role (to tell a file of the
/// other kind apart before parsing it fully).
pub(crate) fn role_of(json: &str) -> Option<String> {
    #[derive(Deserialize)]
    struct RoleOnly {
        role: Option<String>,
    }
    serde_json::from_str::<RoleOnly>(json).ok()?.role
}

/// Parses the JSON stored under `tcd_config`; `path` names the file in errors.
pub(crate) fn parse_json<T: DeserializeOwned>(json: &str, path: &Path) -> Result<T> {
    let bad = |reason: String| Error::BadMetadata {
        path: path.to_path_buf(),
        reason,
    };
    let mut de = serde_json::Deserializer::from_str(json);
    // serde_path_to_error: the error names the field a bad value is in (`model.anchor: unknown variant
    // ...`), which serde_json alone gives as a line and column of the metadata string only.
    let value =
        serde_path_to_error::deserialize(&mut de).map_err(|e| match e.path().to_string() {
            field if field == "." => bad(e.inner().to_string()),
            field => bad(format!("{field}: {}", e.inner())),
        })?;
    de.end().map_err(|e| bad(e.to_string()))?; // nothing after the object (serde_json::from_str's check)
    Ok(value)
}

/// The checks of a config read from the file at this path.
pub struct Checks<'a>(pub(crate) &'a Path);

impl Checks<'_> {
    /// The error for a bad `field`.
    pub(crate) fn bad(&self, field: &str, reason: String) -> Error {
        Error::InvalidConfig {
            path: self.0.to_path_buf(),
            field: field.to_string(),
            reason,
        }
    }

    /// Nothing where `ok` holds, else the error for a bad `field`, saying `reason()`.
    pub(crate) fn require(
        &self,
        ok: bool,
        field: &str,
        reason: impl FnOnce() -> String,
    ) -> Result<()> {
        if ok {
            Ok(())
        } else {
            Err(self.bad(field, reason()))
        }
    }

    /// Refuses a file whose `role` (read by [`role_of`] before the fields are parsed) is not `role`, the
    /// role of the `this` the loader loads, saying what the file holds and what loads it.
    pub(crate) fn role_is(&self, json: &str, role: &str, this: &str) -> Result<()> {
        match role_of(json).filter(|r| r != role) {
            Some(other) => {
                let (what, loader) = file_kind(&other);
                Err(self.bad(
                    "role",
                    format!("must be \"{role}\" for {this}, but is {other:?} ({what}: it loads with {loader})"),
                ))
            }
            None => Ok(()),
        }
    }

    /// `format_version` is the one this engine reads.
    pub(crate) fn format_version(&self, version: u32) -> Result<()> {
        if version != FORMAT_VERSION {
            return Err(self.bad(
                "format_version",
                format!("must be {FORMAT_VERSION}, but is {version}"),
            ));
        }
        Ok(())
    }

    /// A parsed `role` (a plain string in the prior's and the generator's configs) is `expected`. A
    /// file's other role was refused by [`Checks::role_is`] before parsing; this catches a config made
    /// or edited in code, and keeps `validate` complete on its own.
    pub(crate) fn role(&self, role: &str, expected: &str) -> Result<()> {
        if role != expected {
            return Err(self.bad("role", format!("must be \"{expected}\", but is {role:?}")));
        }
        Ok(())
    }

    /// `model.num_features` is the frame's width `num_joints * coords`, as the prior and the generator
    /// check it: a product that overflows equals no `num_features`. (The denoiser's
    /// [`TcdConfig::validate`] keeps its own check, whose message also gives the product.)
    pub(crate) fn num_features(
        &self,
        num_joints: usize,
        coords: usize,
        num_features: usize,
    ) -> Result<()> {
        if Some(num_features) != num_joints.checked_mul(coords) {
            return Err(self.bad(
                "model.num_features",
                format!(
                    "must equal num_joints * coords = {num_joints} * {coords}, but is {num_features}"
                ),
            ));
        }
        Ok(())
    }

    /// Each of these sizes (field, value) is at least 1.
    pub(crate) fn at_least_one(&self, sizes: &[(&str, usize)]) -> Result<()> {
        match sizes.iter().find(|(_, value)| *value == 0) {
            Some((field, _)) => Err(self.bad(field, "must be at least 1, but is 0".into())),
            None => Ok(()),
        }
    }

    /// `model.layer_norm_eps` is a positive finite number.
    pub(crate) fn layer_norm_eps(&self, eps: f64) -> Result<()> {
        if !(eps.is_finite() && eps > 0.0) {
            return Err(self.bad(
                "model.layer_norm_eps",
                format!("must be a positive finite number, but is {eps}"),
            ));
        }
        Ok(())
    }
}
