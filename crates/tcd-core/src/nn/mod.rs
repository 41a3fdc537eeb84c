//! Layers of the denoiser, one per file, as portable f32 code; and [`Dense`], a dense layer on
//! either kernel, which the prior forecaster and the sample generator share.
//!
//! Data layout everywhere: **token-major, contiguous, row-major** buffers of shape
//! (tokens, channels); a token is one coordinate of one frame. Weights are stored once, at load
//! time, transposed to (in, out) so that `y = x · Wᵀ + b` streams contiguous rows (the shape a
//! packed-GEMM micro-kernel will take later). Every layer has `load(weights, prefix, cfg)` and a
//! `forward`; weight names are the PyTorch state_dict keys.

pub mod activation;
pub mod attention;
pub mod dense;
pub mod embedding;
pub mod layer_norm;
pub mod linear;
pub mod transformer;

pub(crate) use dense::{pack_all, Dense};
pub use linear::Linear;
pub use transformer::{EncoderLayer, EncoderScratch};
