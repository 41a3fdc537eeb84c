//! The engine's one error type.
//!
//! Every message is a full sentence that names the argument (or file), what was expected and what
//! was received. The Python binding maps the variants exhaustively onto `tcd.exceptions`:
//! [`Error::NotFound`] → `FileNotFoundError`; [`Error::Io`] → `OSError`; the weight-file variants →
//! `WeightsError`; [`Error::InvalidInput`] → `InvalidInputError`; [`Error::ThreadPool`] → `TcdError`.

use std::path::PathBuf;

/// `Result` with the engine's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong in the engine. No panic is reachable from user input: bad input
/// comes back as one of these.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The weight file does not exist.
    #[error("The weights file {} does not exist.", .path.display())]
    NotFound { path: PathBuf },

    /// The weight file exists but could not be read.
    #[error("Could not read the weights file {}: {source}.", .path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// The bytes are not a valid safetensors file (truncated, bad header, overlapping offsets, ...).
    #[error("The weights file {} is not a valid safetensors file (is it truncated or corrupt?): {reason}.", .path.display())]
    Corrupt { path: PathBuf, reason: String },

    /// The safetensors `__metadata__` has no `tcd_config` entry.
    #[error("The weights file {} has no `tcd_config` entry in its safetensors __metadata__; weights must be exported with `python -m training.export`.", .path.display())]
    MissingMetadata { path: PathBuf },

    /// `tcd_config` is not valid JSON or does not have the expected fields and types.
    #[error("The `tcd_config` metadata of the weights file {} could not be parsed: {reason}.", .path.display())]
    BadMetadata { path: PathBuf, reason: String },

    /// `tcd_config` parsed but its values are inconsistent or unsupported.
    #[error("The configuration in the weights file {} is invalid: `{field}` {reason}.", .path.display())]
    InvalidConfig {
        path: PathBuf,
        field: String,
        reason: String,
    },

    /// The stored betas disagree with the schedule they claim to come from.
    #[error("The weights file {} stores betas that disagree with the recomputed `{schedule}` schedule at index {index}: stored {stored:e}, recomputed {recomputed:e} (tolerance 1e-9).", .path.display())]
    BetasMismatch {
        path: PathBuf,
        schedule: String,
        index: usize,
        stored: f64,
        recomputed: f64,
    },

    /// A tensor the configuration requires is absent.
    #[error("The weights file {} lacks the tensor `{name}` (expected F32 with shape {expected:?}).", .path.display())]
    MissingTensor {
        path: PathBuf,
        name: String,
        expected: Vec<usize>,
    },

    /// A tensor the configuration does not know about is present.
    #[error("The weights file {} contains the tensor `{name}`, which this model configuration does not use; expected exactly the state_dict keys of the configured model.", .path.display())]
    UnexpectedTensor { path: PathBuf, name: String },

    /// A tensor has the wrong shape for the configuration.
    #[error("The tensor `{name}` in the weights file {} has shape {received:?}, but the configuration implies {expected:?}.", .path.display())]
    TensorShape {
        path: PathBuf,
        name: String,
        expected: Vec<usize>,
        received: Vec<usize>,
    },

    /// A tensor holds NaN or an infinity: such weights load "fine" and forecast garbage, so they are refused.
    #[error("The tensor `{name}` in the weights file {} holds {value} at flat index {index}: every weight must be finite (the file is corrupt or came from a diverged training run).", .path.display())]
    NonFiniteTensor {
        path: PathBuf,
        name: String,
        index: usize,
        value: f32,
    },

    /// The weights path names a directory, not a file.
    #[error("The weights path {} is a directory, not a .safetensors file (a model directory loads with tcd.load).", .path.display())]
    NotAFile { path: PathBuf },

    /// A tensor is not F32.
    #[error("The tensor `{name}` in the weights file {} has dtype {received}, but F32 is required.", .path.display())]
    TensorDtype {
        path: PathBuf,
        name: String,
        received: String,
    },

    /// A call argument has the wrong size, value or content.
    #[error("Argument `{argument}` must be {expected}, but received {received}.")]
    InvalidInput {
        argument: String,
        expected: String,
        received: String,
    },

    /// The caller asked the call to stop ([`crate::Control::cancel`]); its partial results are dropped.
    #[error("The call was interrupted.")]
    Cancelled,

    /// A rayon thread pool could not be built.
    #[error("Could not build a thread pool with {threads} threads: {reason}.")]
    ThreadPool { threads: usize, reason: String },
}

impl Error {
    /// Shorthand for [`Error::InvalidInput`].
    pub fn invalid_input(
        argument: impl Into<String>,
        expected: impl Into<String>,
        received: impl Into<String>,
    ) -> Self {
        Error::InvalidInput {
            argument: argument.into(),
            expected: expected.into(),
            received: received.into(),
        }
    }

    /// True for the variants that describe a bad weight file (the binding's `WeightsError`).
    pub fn is_weights_error(&self) -> bool {
        matches!(
            self,
            Error::Corrupt { .. }
                | Error::MissingMetadata { .. }
                | Error::BadMetadata { .. }
                | Error::InvalidConfig { .. }
                | Error::BetasMismatch { .. }
                | Error::MissingTensor { .. }
                | Error::UnexpectedTensor { .. }
                | Error::TensorShape { .. }
                | Error::TensorDtype { .. }
                | Error::NonFiniteTensor { .. }
                | Error::NotAFile { .. }
        )
    }
}

/// Checks that a flat buffer has `expected` elements; `shape` names the layout for the message.
pub(crate) fn check_len(
    argument: &str,
    data_len: usize,
    expected: usize,
    shape: &str,
) -> Result<()> {
    if data_len == expected {
        Ok(())
    } else {
        Err(Error::invalid_input(
            argument,
            format!("a flat f32 buffer of {expected} elements (shape {shape})"),
            format!("{data_len} elements"),
        ))
    }
}

/// Checks that a size argument is at least 1.
pub(crate) fn check_positive(argument: &str, value: usize) -> Result<()> {
    if value >= 1 {
        Ok(())
    } else {
        Err(Error::invalid_input(
            argument,
            "at least 1",
            value.to_string(),
        ))
    }
}
