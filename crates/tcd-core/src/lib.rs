//! # tcd-core
//!
//! A pure-Rust inference engine for Temporal Cascaded Diffusion (TCD) 3D human pose forecasting:
//! the CSDI denoiser, DDPM / DDIM samplers, and the short-term → long-term cascade; the
//! deterministic prior forecaster ([`Prior`], its arrays frame-major (B, T, K)); and the MLP sample
//! generator ([`Generator`], forecast samples around the prior's forecast, frame-major too). It
//! knows nothing of Python; the binding crate wraps this API.
//!
//! ```no_run
//! use tcd_core::{cascade, CascadeNoise, Control, Denoiser, ForecastOptions, Network, Observation, Sequences};
//! # fn main() -> tcd_core::Result<()> {
//! let short = Denoiser::load("short.safetensors")?;
//! let long = Denoiser::load("long.safetensors")?;
//! let (b, k, o) = (1, short.num_features(), short.obs_len());
//! let values = vec![0.0f32; b * k * o]; // (B, K, O), model units
//! let mask = vec![1.0f32; b * k * o];   // 1 = observed
//! let observed = Observation::new(&values, &mask, [b, k, o])?; // checked here, once
//! let out = cascade(&short, &long, None, &observed, &ForecastOptions::default(),
//!                   CascadeNoise::seeded(0, Sequences::From(0)), &Control::default())?;
//! assert_eq!(out.mean.len(), b * k * out.future_len);
//! # Ok(()) }
//! ```
//!
//! Conventions: every array is a flat row-major f32 buffer; sequences are **(B, K, L)** (frame
//! fastest), samples lead with S. Observations are one type, [`Observation`]: the values and their
//! mask, 1 (observed) / 0 (to generate), with their shape, checked once when made.

#![cfg_attr(test, allow(clippy::unwrap_used, clippy::expect_used, clippy::panic))]

// Every module is private: the public API is the items re-exported below, each under one path,
// `tcd_core::Item`.
mod config;
mod control;
mod denoiser;
mod error;
mod file_config;
mod fill;
mod generator;
mod kernels;
mod nn;
mod observation;
mod pipeline;
mod prior;
mod rng;
mod sampler;
mod schedule;
mod threads;
mod validate;
mod weights;

// Models and their files.
pub use config::{
    CondFill, DataConfig, DiffusionConfig, ModelConfig, PredictionType, Role, Target, TcdConfig,
    VarianceType, WindowConfig, FORMAT_VERSION,
};
pub use denoiser::{Denoiser, Prepared, Workspace};
pub use file_config::{FileConfig, ModelBlock, ModelFile};
pub use generator::{Generator, GeneratorConfig, GeneratorModelConfig};
pub use prior::{
    dct_matrix, inbetween_width, Anchor, GapFill, Prior, PriorConfig, PriorModelConfig,
};
pub use weights::{Network, Source, Weights, CONFIG_KEY};
// Observations and what runs on them.
pub use fill::{fill_linear, fill_rows, fill_spline, prior_fill};
pub use observation::Observation;
pub use pipeline::{cascade, repair, CascadeNoise, CascadeOutput, ForecastOptions, RepairOutput};
// Samplers and their noise.
pub use rng::{seeded_noise, stage, Noise, NoiseCoupling, Sequences};
pub use sampler::{sample, Plan, Sampler, SamplerConfig, SamplerKind, TimestepSpacing};
pub use schedule::{BetaSchedule, NoiseSchedule};
// Kernels, threads, control, errors.
pub use control::Control;
pub use error::{Error, Result};
pub use kernels::{Kernel, KERNEL_ENV};
pub use threads::with_threads;
