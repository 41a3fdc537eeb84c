//! The module's functions: the cascade and repair over several denoisers and chains, the seeded noise
//! streams materialised, the kernel paths of this CPU.

use numpy::{PyArrayDyn, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use tcd_core::seeded_noise as core_seeded_noise;
use tcd_core::Network;
use tcd_core::{
    cascade as core_cascade, fill_rows, repair as core_repair, CascadeNoise, CondFill, Sequences,
};

use crate::call::{NoiseSource, SampleCount, SamplingArgs, Window};
use crate::convert::*;
use crate::denoiser::PyDenoiser;
use crate::error::{invalid, Result};
use crate::prior::PyPrior;

/// The short-term → long-term cascade on the `call` dict's observation (B, K, O), O = the short model's obs_len.
/// Returns a dict: `mean` (B, K, P), `samples` (S, B, K, P), `repaired` (B, K, O), `short_mean`
/// (B, K, L_s). Noise: injected `noise_short` (S, n + 1, B, K, L_s) and `noise_long`
/// (S, n + 1, B, K, L_l) (one block instead of n + 1 for dpmpp2m), or the `seed` of `streams`. `prior`: the prior
/// forecaster, required where a model is conditioned on it (`cond_fill` "prior"), unused otherwise.
#[pyfunction]
#[pyo3(signature = (short, long, call, *, noise_short=None, noise_long=None, prior=None))]
pub(crate) fn cascade<'py>(
    py: Python<'py>,
    short: &Bound<'py, PyDenoiser>,
    long: &Bound<'py, PyDenoiser>,
    call: SamplingArgs<'py>,
    noise_short: Option<PyReadonlyArrayDyn<'py, f32>>,
    noise_long: Option<PyReadonlyArrayDyn<'py, f32>>,
    prior: Option<&Bound<'py, PyPrior>>,
) -> Result<Bound<'py, PyDict>> {
    let (short, long) = (&*short.get().inner, &*long.get().inner);
    let prior = prior.map(|p| &*p.get().inner);
    let stages = [
        (short, "noise_short", noise_short),
        (long, "noise_long", noise_long),
    ];
    let window = Window::ObsLen("the short-term model's");
    let call = call.prepare(window, SampleCount::AtLeastOne, stages)?;
    let out = call.run(py, |job, control| {
        let noise = match &job.noise {
            [NoiseSource::Injected(a), NoiseSource::Injected(c)] => CascadeNoise::injected(a, c),
            [NoiseSource::Seeded(seed, streams), _] | [_, NoiseSource::Seeded(seed, streams)] => {
                CascadeNoise::seeded(*seed, streams.as_sequences())
            }
        };
        core_cascade(
            short,
            long,
            prior,
            &job.observation(short.num_features())?,
            &job.options,
            noise,
            control,
        )
    })?;
    let job = &call.job;
    let (s, b, kf) = (job.options.num_samples, job.batch, out.num_features);
    arrays(
        py,
        [
            ("mean", &[b, kf, out.future_len], out.mean),
            ("samples", &[s, b, kf, out.future_len], out.samples),
            ("repaired", &[b, kf, out.obs_len], out.repaired),
            ("short_mean", &[b, kf, out.short_len], out.short_mean),
        ],
    )
}

/// Repairs the mask-0 entries of the `call` dict's observation (B, K, O), O = the model's obs_len. Returns a
/// dict: `mean` (B, K, O; observed entries exact) and `samples` (S, B, K, O). `fill`: the repair fill
/// (a `Prior` with anchor "window"), required where the model is conditioned on it (`cond_fill`
/// "prior"), unused otherwise. `forecaster`: the prior forecaster, required where that fill fills
/// whole-frame gaps with it (`gap_fill` "forecaster"), unused otherwise.
#[pyfunction]
#[pyo3(signature = (model, call, *, noise=None, fill=None, forecaster=None))]
pub(crate) fn repair<'py>(
    py: Python<'py>,
    model: &Bound<'py, PyDenoiser>,
    call: SamplingArgs<'py>,
    noise: Option<PyReadonlyArrayDyn<'py, f32>>,
    fill: Option<&Bound<'py, PyPrior>>,
    forecaster: Option<&Bound<'py, PyPrior>>,
) -> Result<Bound<'py, PyDict>> {
    let model = &model.get().inner;
    let fill = fill.map(|p| &*p.get().inner);
    let forecaster = forecaster.map(|p| &*p.get().inner);
    let window = Window::ObsLen("the model's");
    let call = call.prepare(
        window,
        SampleCount::ZeroIsFillAlone,
        [(model, "noise", noise)],
    )?;
    let out = call.run(py, |job, control| {
        let [noise] = &job.noise;
        core_repair(
            model,
            fill,
            forecaster,
            &job.observation(model.num_features())?,
            &job.options,
            noise.as_noise(),
            control,
        )
    })?;
    let job = &call.job;
    let k = model.num_features();
    arrays(
        py,
        [
            ("mean", &[job.batch, k, job.frames], out.mean),
            ("samples", &job.samples_shape(k), out.samples),
        ],
    )
}

/// `observed` (..., L) with its mask-0 entries filled along the last axis by the interpolating fill
/// `method` (`CondFill::INTERPOLATIONS`): what a model with that conditioning fill sees. `mask` has the
/// shape of `observed`; a row with nothing observed comes back all 0.
#[pyfunction]
pub(crate) fn interpolate<'py>(
    py: Python<'py>,
    observed: PyReadonlyArrayDyn<'py, f32>,
    mask: PyReadonlyArrayDyn<'py, f32>,
    method: &str,
) -> Result<Bound<'py, PyArrayDyn<f32>>> {
    let observed = Array::from_numpy(&observed);
    let mask = Array::from_numpy(&mask);
    let fill = CondFill::interpolation(method)?;
    mask.expect_shape("mask", &observed.shape, "(the shape of `observed`)")?;
    let length = observed.shape.last().copied().unwrap_or(0);
    let out = py.detach(|| fill_rows(fill, length, &mask.data, &observed.data))?;
    to_numpy(py, &observed.shape, out)
}

/// The names of the seeded noise's dimensions, in `seeded_noise`'s errors (`tcd.engine.seeded_noise`'s arguments).
const NOISE_DIMS: [&str; 5] = [
    "num_samples",
    "num_blocks",
    "batch",
    "num_features",
    "length",
];

/// The seeded noise streams exactly as the engine consumes them, `shape` = (S, num_blocks, B, K, L):
/// ChaCha8 keyed by (seed, first_sequence + b, sample, stage), standard normals in block order.
#[pyfunction]
#[pyo3(signature = (seed, stage, shape, first_sequence=0))]
pub(crate) fn seeded_noise<'py>(
    py: Python<'py>,
    seed: i128,
    stage: i128,
    shape: [i64; 5],
    first_sequence: i128,
) -> Result<Bound<'py, PyArrayDyn<f32>>> {
    let seed = u64_arg("seed", seed)?;
    let stage = u64_arg("stage", stage)?;
    let first_sequence = u64_arg("first_sequence", first_sequence)?;
    let mut dims = [0; 5];
    for ((d, name), value) in dims.iter_mut().zip(NOISE_DIMS).zip(shape) {
        *d = positive(name, value)?;
    }
    // Refuse absurd sizes rather than abort on allocation failure (2^31 values = 8 GiB).
    if !within_limit(&dims) {
        return Err(invalid(
            "num_samples",
            "sizes whose product is at most 2^31 values",
            format!("{dims:?}"),
        )
        .into());
    }
    let [s, blocks, b, k, l] = dims;
    let data = py.detach(move || {
        core_seeded_noise(
            seed,
            Sequences::From(first_sequence),
            stage,
            s,
            blocks,
            b,
            k * l,
        )
    });
    to_numpy(py, &dims, data)
}

/// Checks settings a caller keeps for later calls (`tcd.load(threads=...)`, `tcd repair`'s options) with
/// the very conversions every call applies to them, so that their ranges have one home (raises
/// `InvalidInputError` naming the setting).
/// With `window = (K, L)`, `num_samples` is also checked against the work of one sequence of that size.
#[pyfunction]
#[pyo3(signature = (*, num_samples=None, seed=None, threads=None, window=None))]
pub(crate) fn check_call_settings(
    num_samples: Option<i64>,
    seed: Option<i128>,
    threads: Option<i64>,
    window: Option<(usize, usize)>,
) -> Result<()> {
    if let Some(n) = num_samples {
        let s = positive("num_samples", n)?;
        if let Some((k, l)) = window {
            check_work(s, 1, k, l)?;
        }
    }
    seed.map(|s| u64_arg("seed", s)).transpose()?;
    threads_arg(threads)?;
    Ok(())
}

/// The kernel paths this CPU can run, the best last (`TCD_KERNEL` accepts these and `auto`).
#[pyfunction]
pub(crate) fn supported_kernels() -> Vec<&'static str> {
    tcd_core::Kernel::supported()
        .into_iter()
        .map(|k| k.name())
        .collect()
}
