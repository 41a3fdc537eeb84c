//! `tcd._native`: the PyO3 binding of `tcd-core`.
//!
//! This crate only converts: numpy arrays in, numpy arrays out, the engine's [`tcd_core::Error`]
//! mapped onto the package's exceptions, which are created here (in [`error`], the one place where errors cross into Python), and
//! the GIL released around every forward / sampling call. The public API, with its argument
//! checking in the caller's terms (poses, units, masks), is the Python package `tcd`; this module
//! is private and works in the engine's layout: (B, K, L) float32 arrays, K = joints·3 with the
//! frame axis last, and injected noise (S, n + 1, B, K, L) ((S, 1, B, K, L) for the deterministic
//! `dpmpp2m`, which only draws x_T).
//!
//! Inputs are copied out of numpy before the GIL is released, so another Python thread mutating
//! an input array cannot race the engine.
//!
//! Files: [`convert`] (arguments and arrays in and out), [`call`] (the arguments `Denoiser.sample`,
//! `cascade` and `repair` share, checked once, and their run), [`run`] (a long call run interruptibly),
//! [`denoiser`] (the `Denoiser` class), [`prior`] (the `Prior` class: the deterministic forecaster,
//! arrays (B, T, K)), [`generator`] (the `Generator` class: the MLP sample generator, arrays (B, T, K)),
//! [`model`] (the loaders and getters the three classes have), [`pipeline`] (the module's functions),
//! [`error`] (the binding's error type: engine errors into Python exceptions).

mod call;
mod convert;
mod denoiser;
mod error;
mod generator;
mod model;
mod pipeline;
mod prior;
mod run;

use pyo3::prelude::*;
use tcd_core::stage;

use crate::denoiser::PyDenoiser;
use crate::generator::PyGenerator;
use crate::pipeline::{
    cascade, check_call_settings, interpolate, repair, seeded_noise, supported_kernels,
};
use crate::prior::PyPrior;

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    error::add_exceptions(m)?;
    m.add("STAGE_SHORT", stage::SHORT)?;
    m.add("STAGE_LONG", stage::LONG)?;
    m.add("STAGE_GENERATOR", stage::GENERATOR)?;
    m.add_class::<PyDenoiser>()?;
    m.add_class::<PyPrior>()?;
    m.add_class::<PyGenerator>()?;
    m.add_class::<convert::Sampler>()?;
    m.add_function(wrap_pyfunction!(cascade, m)?)?;
    m.add_function(wrap_pyfunction!(repair, m)?)?;
    m.add_function(wrap_pyfunction!(seeded_noise, m)?)?;
    m.add_function(wrap_pyfunction!(interpolate, m)?)?;
    m.add_function(wrap_pyfunction!(supported_kernels, m)?)?;
    m.add_function(wrap_pyfunction!(check_call_settings, m)?)?;
    m.add("SAMPLERS", tcd_core::SamplerKind::NAMES.to_vec())?;
    m.add("SPACINGS", tcd_core::TimestepSpacing::NAMES.to_vec())?;
    m.add("COUPLINGS", tcd_core::NoiseCoupling::NAMES.to_vec())?;
    m.add(
        "INTERPOLATIONS",
        tcd_core::CondFill::INTERPOLATIONS.to_vec(),
    )?;
    Ok(())
}
