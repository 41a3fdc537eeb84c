//! A sampler's configuration: its update rule ([`SamplerKind`]), its step count and how the steps are placed
//! among the training steps ([`TimestepSpacing`], [`timesteps`]), η, and how a sequence's chains share their
//! starting noise.

use std::str::FromStr;

use crate::error::{Error, Result};
use crate::rng::NoiseCoupling;

/// How `num_inference_steps` steps are placed among the T training steps (diffusers semantics).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimestepSpacing {
    /// t = arange(n) · (T // n), reversed (for n = 5, T = 50: 40, 30, 20, 10, 0).
    Leading,
    /// t = round(arange(T, 0, −T/n)) − 1 (for n = 5, T = 50: 49, 39, 29, 19, 9).
    Trailing,
    /// t = round(linspace(0, T − 1, n)), reversed.
    Linspace,
}

impl TimestepSpacing {
    /// Every spacing's name, the default (`trailing`) first.
    pub const NAMES: [&'static str; 3] = ["trailing", "leading", "linspace"];

    /// `leading` | `trailing` | `linspace`.
    pub fn as_str(self) -> &'static str {
        match self {
            TimestepSpacing::Leading => "leading",
            TimestepSpacing::Trailing => "trailing",
            TimestepSpacing::Linspace => "linspace",
        }
    }
}

impl FromStr for TimestepSpacing {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "leading" => Ok(TimestepSpacing::Leading),
            "trailing" => Ok(TimestepSpacing::Trailing),
            "linspace" => Ok(TimestepSpacing::Linspace),
            other => Err(Error::invalid_input(
                "timestep_spacing",
                "\"leading\", \"trailing\" or \"linspace\"",
                format!("{other:?}"),
            )),
        }
    }
}

/// The descending training steps visited by a sampler with `num_inference_steps` steps.
/// Rounding is numpy's (half to even).
pub(crate) fn timesteps(
    num_train_timesteps: usize,
    num_inference_steps: usize,
    spacing: TimestepSpacing,
) -> Result<Vec<usize>> {
    let (t_total, n) = (num_train_timesteps, num_inference_steps);
    if n == 0 || n > t_total {
        return Err(Error::invalid_input(
            "num_inference_steps",
            format!("an integer in 1..{t_total} (num_train_timesteps = {t_total})"),
            n.to_string(),
        ));
    }
    let ts: Vec<usize> = match spacing {
        TimestepSpacing::Leading => {
            let ratio = t_total / n;
            (0..n).rev().map(|i| i * ratio).collect()
        }
        TimestepSpacing::Trailing => {
            let ratio = t_total as f64 / n as f64;
            (0..n)
                .map(|i| {
                    let v = (t_total as f64 - i as f64 * ratio).round_ties_even();
                    (v as usize).saturating_sub(1)
                })
                .collect()
        }
        TimestepSpacing::Linspace => crate::schedule::linspace(0.0, (t_total - 1) as f64, n)
            .into_iter()
            .rev()
            .map(|v| v.round_ties_even() as usize)
            .collect(),
    };
    Ok(ts)
}

/// Which update rule a sampler uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SamplerKind {
    /// Ancestral DDPM; over all T steps it is the TCD reference.
    Ddpm,
    /// DDIM with stochasticity `eta` ∈ [0, 1].
    Ddim { eta: f64 },
    /// DPM-Solver++(2M): deterministic multistep solver (one noise block per chain, x_T).
    DpmPp2m,
}

impl SamplerKind {
    /// Every sampler's name, the default (`ddpm`, the paper's) first.
    pub const NAMES: [&'static str; 3] = ["ddpm", "ddim", "dpmpp2m"];
}

/// A sampler: update rule, number of steps and their spacing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SamplerConfig {
    pub kind: SamplerKind,
    /// `None`: every training step (n = T).
    pub num_inference_steps: Option<usize>,
    pub timestep_spacing: TimestepSpacing,
    /// How the S chains of a sequence share x_T ([`NoiseCoupling`]; independent by default).
    pub noise_coupling: NoiseCoupling,
}

impl SamplerConfig {
    /// The sampler named by the settings of the Python `SamplerOptions` and the command line: the one
    /// check of their values. `sampler` is one of [`SamplerKind::NAMES`], `timestep_spacing` one of
    /// [`TimestepSpacing::NAMES`], `noise_coupling` one of [`NoiseCoupling::NAMES`], and `eta` must lie
    /// in [0, 1] whatever the sampler (only DDIM uses it, but a bad value is refused rather than
    /// ignored). `num_inference_steps` is checked against a model's training steps by
    /// [`SamplerConfig::plan`].
    pub fn from_names(
        sampler: &str,
        num_inference_steps: Option<usize>,
        eta: f64,
        timestep_spacing: &str,
        noise_coupling: &str,
    ) -> Result<Self> {
        super::ddim::check_eta(eta)?;
        let kind = match sampler {
            "ddpm" => SamplerKind::Ddpm,
            "ddim" => SamplerKind::Ddim { eta },
            "dpmpp2m" => SamplerKind::DpmPp2m,
            other => {
                return Err(Error::invalid_input(
                    "sampler",
                    "\"ddpm\", \"ddim\" or \"dpmpp2m\"",
                    format!("{other:?}"),
                ))
            }
        };
        if num_inference_steps == Some(0) {
            return Err(Error::invalid_input(
                "num_inference_steps",
                "at least 1 (or None for every training step)",
                "0",
            ));
        }
        Ok(SamplerConfig {
            kind,
            num_inference_steps,
            timestep_spacing: timestep_spacing.parse()?,
            noise_coupling: noise_coupling.parse()?,
        })
    }

    /// The reference: DDPM over all T steps.
    pub fn ddpm() -> Self {
        SamplerConfig {
            kind: SamplerKind::Ddpm,
            num_inference_steps: None,
            timestep_spacing: TimestepSpacing::Trailing,
            noise_coupling: NoiseCoupling::Independent,
        }
    }

    /// DDIM with `num_inference_steps` trailing-spaced steps.
    pub fn ddim(num_inference_steps: usize, eta: f64) -> Self {
        SamplerConfig {
            kind: SamplerKind::Ddim { eta },
            num_inference_steps: Some(num_inference_steps),
            timestep_spacing: TimestepSpacing::Trailing,
            noise_coupling: NoiseCoupling::Independent,
        }
    }

    /// DPM-Solver++(2M) with `num_inference_steps` trailing-spaced steps.
    pub fn dpmpp2m(num_inference_steps: usize) -> Self {
        SamplerConfig {
            kind: SamplerKind::DpmPp2m,
            num_inference_steps: Some(num_inference_steps),
            timestep_spacing: TimestepSpacing::Trailing,
            noise_coupling: NoiseCoupling::Independent,
        }
    }
}

impl Default for SamplerConfig {
    fn default() -> Self {
        Self::ddpm()
    }
}
