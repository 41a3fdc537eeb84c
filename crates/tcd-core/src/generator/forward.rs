//! [`Generator::sample`]: its argument checks, each sequence's conditioning (the DCT coefficients of
//! its observation and of the prior's forecast), and the MLP on rows of (sample, sequence), tiles of
//! rows split over the current rayon pool.
//!
//! Row r of a call is sample s = r / B of sequence b = r % B: the rows of the output (S, B, P, K) in
//! order, so a tile is a contiguous run of the output. Every row of every GEMM is computed the same
//! way whichever rows share its tile, and each row's noise is its own (its seeded stream, or its place
//! in the injected array), so results depend neither on the thread count nor on the other sequences
//! of the batch.
//!
//! The first layer is one GEMM over whole rows [past, ahead, z], as PyTorch's. Its (past, ahead) part
//! is the same for the S samples of a sequence and could be multiplied once per sequence: that would
//! save 37% of the multiply-adds at the HumanEva-I sizes (K = 42, O = 15, C = 20, z_dim 64, hidden
//! 768; 50 samples of 188 sequences take about 1.1 s on one AVX2 core as it is), at the price of a
//! second path through the first layer and another order of its sums.

use crate::weights::Network;
use rayon::prelude::*;

use super::Generator;
use crate::control::Control;
use crate::error::{check_len, check_positive, Error, Result};
use crate::rng::{chain_rng, fill_standard_normal, stage, Noise};
use crate::validate;

/// Rows (samples × sequences) per tile: one worker's unit of work. Each GEMM streams every layer's
/// weights (4.6 MiB for the first at the bundled sizes) once per tile, so a tile has enough rows to
/// pay for that; its buffers (3 × 12 KiB per row) stay in L2.
const TILE: usize = 32;

/// One worker's buffers for tiles of up to `tile` rows.
struct Scratch {
    /// The first layer's input rows [past, ahead, z] (tile × input width).
    x: Vec<f32>,
    /// Two hidden activation buffers (tile × hidden).
    a: Vec<f32>,
    b: Vec<f32>,
    /// The head's output, each row the residual's C·K DCT coefficients (tile × C·K).
    y: Vec<f32>,
}

impl Scratch {
    fn new(g: &Generator, tile: usize) -> Scratch {
        let m = &g.config().model;
        Scratch {
            x: vec![0.0; tile * m.input_width().unwrap_or(0)],
            a: vec![0.0; tile * m.hidden],
            b: vec![0.0; tile * m.hidden],
            y: vec![0.0; tile * m.coefs * m.num_features],
        }
    }
}

impl Generator {
    /// The conditioning of each of `batch` sequences, (past, ahead) (O·K + C·K values, each block
    /// coefficient-major), from `obs` (batch × frames × K; its last O frames) and `prior` (batch × P ×
    /// K): the DCTs of the frames minus the last observed pose, their sums in f64, rounded once.
    fn conditioning(&self, obs: &[f32], frames: usize, prior: &[f32], batch: usize) -> Vec<f32> {
        let (k, o, p, c) = (
            self.num_features(),
            self.obs_len(),
            self.pred_len(),
            self.coefs(),
        );
        let width = (o + c) * k;
        let mut cond = vec![0.0f32; batch * width];
        // The DCT (rows × n) of the n frames (frame-major, n × K) of `x`, each minus `last`, into `out`.
        let dct = |d: &[f32], n: usize, x: &[f32], last: &[f32], out: &mut [f32]| {
            let mut acc = vec![0.0f64; k];
            for (row, coefs) in d.chunks_exact(n).zip(out.chunks_exact_mut(k)) {
                acc.fill(0.0);
                for (&w, frame) in row.iter().zip(x.chunks_exact(k)) {
                    for ((a, &v), &l) in acc.iter_mut().zip(frame).zip(last) {
                        *a += w as f64 * (v - l) as f64;
                    }
                }
                for (y, a) in coefs.iter_mut().zip(&acc) {
                    *y = *a as f32;
                }
            }
        };
        cond.par_chunks_mut(width)
            .zip(obs.par_chunks(frames * k))
            .zip(prior.par_chunks(p * k))
            .for_each(|((out, seq), forecast)| {
                let seen = &seq[(frames - o) * k..];
                let last = &seen[(o - 1) * k..];
                let (past, ahead) = out.split_at_mut(o * k);
                dct(&self.dct_obs, o, seen, last, past);
                dct(&self.dct_pred, p, forecast, last, ahead);
            });
        cond
    }

    /// The samples of the rows `first ..` of a call (as many as `out` holds, (rows × P × K)):
    /// `cond` is every sequence's [`Generator::conditioning`], `prior` every sequence's forecast.
    #[expect(
        clippy::too_many_arguments,
        reason = "one tile's view of a call: its rows, the call's inputs, the worker's buffers"
    )]
    fn sample_rows(
        &self,
        first: usize,
        batch: usize,
        cond: &[f32],
        prior: &[f32],
        noise: Noise<'_>,
        out: &mut [f32],
        sc: &mut Scratch,
    ) {
        let m = &self.source.config.model;
        let (k, p, c, z) = (m.num_features, m.pred_len, m.coefs, m.z_dim);
        let cw = (m.obs_len + c) * k;
        let n = out.len() / (p * k);
        for (j, x) in sc.x.chunks_exact_mut(cw + z).take(n).enumerate() {
            let (r, (cx, zx)) = (first + j, x.split_at_mut(cw));
            let (s, b) = (r / batch, r % batch);
            cx.copy_from_slice(&cond[b * cw..(b + 1) * cw]);
            match noise {
                // (S, B, z_dim): row r's noise is the r-th
                Noise::Injected(data) => zx.copy_from_slice(&data[r * z..(r + 1) * z]),
                Noise::Seeded { seed, sequences } => {
                    let mut rng = chain_rng(seed, sequences.id(b), s as u64, stage::GENERATOR);
                    fill_standard_normal(&mut rng, zx);
                }
            }
        }
        // x → a, then a → h and swapped, so that `a` holds the last layer's output
        let (mut a, mut h) = (sc.a.as_mut_slice(), sc.b.as_mut_slice());
        let mut layers = self.layers.iter();
        if let Some(first) = layers.next() {
            first.forward_gelu(&sc.x, a, n);
        }
        for layer in layers {
            layer.forward_gelu(a, h, n);
            std::mem::swap(&mut a, &mut h);
        }
        let y = &mut sc.y;
        self.head.forward(a, y, n);
        // out = prior + IDCT(y): frame t of a row is Σ_c D_P[c, t] · y[c], then the prior's frame t.
        for (j, (o, yr)) in out
            .chunks_exact_mut(p * k)
            .zip(y.chunks_exact(c * k))
            .enumerate()
        {
            let b = (first + j) % batch;
            let forecast = &prior[b * p * k..(b + 1) * p * k];
            for (t, (frame, base)) in o
                .chunks_exact_mut(k)
                .zip(forecast.chunks_exact(k))
                .enumerate()
            {
                frame.fill(0.0);
                for (d, coef) in self.dct_pred.chunks_exact(p).zip(yr.chunks_exact(k)) {
                    let w = d[t];
                    for (v, &yv) in frame.iter_mut().zip(coef) {
                        *v += w * yv;
                    }
                }
                for (v, &q) in frame.iter_mut().zip(base) {
                    *v += q;
                }
            }
        }
    }

    /// Draws `num_samples` forecasts of each of `batch` sequences: `obs` (batch × frames × K,
    /// frame-major; `frames` ≥ `obs_len`, the last `obs_len` frames are read and must be finite) and
    /// `prior` (batch × pred_len × K, finite), the prior forecaster's forecast of each sequence
    /// ([`crate::Prior::predict`] over `pred_len` frames). Returns (num_samples × batch × pred_len × K).
    ///
    /// * `noise`: [`Noise::Injected`] of shape (num_samples, batch, z_dim), finite; or
    ///   [`Noise::Seeded`]: sample s of sequence b draws its z_dim standard normals from the chain
    ///   (`sequences.id(b)`, s) of stage [`stage::GENERATOR`], so
    ///   `seeded_noise(seed, sequences, stage::GENERATOR, S, 1, B, z_dim)` is the noise it reads.
    ///
    /// Tiles of rows run in parallel on the current rayon pool (see [`crate::with_threads`]);
    /// `control` can stop the call between tiles.
    #[expect(
        clippy::too_many_arguments,
        reason = "the arrays with their shape, the sample count, the noise and the control of one call"
    )]
    pub fn sample(
        &self,
        obs: &[f32],
        prior: &[f32],
        batch: usize,
        frames: usize,
        num_samples: usize,
        noise: Noise<'_>,
        control: &Control,
    ) -> Result<Vec<f32>> {
        let (k, o, p, z) = (
            self.num_features(),
            self.obs_len(),
            self.pred_len(),
            self.z_dim(),
        );
        check_positive("batch", batch)?;
        check_positive("num_samples", num_samples)?;
        if frames < o {
            return Err(Error::invalid_input(
                "obs",
                format!("at least obs_len = {o} frames"),
                format!("{frames} frames"),
            ));
        }
        let size = |dims: &[usize]| dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
        let shape = format!("({batch}, {frames}, {k})");
        let total_in = size(&[batch, frames, k]).unwrap_or(usize::MAX);
        check_len("obs", obs.len(), total_in, &shape)?;
        validate::finite_last_frames("obs", obs, frames, k, o)?;
        let shape = format!("({batch}, {p}, {k}) = (B, pred_len, K)");
        let total_prior = size(&[batch, p, k]).unwrap_or(usize::MAX);
        validate::all_finite("prior", prior, total_prior, &shape)?;
        let total_out = size(&[num_samples, batch, p, k])
            .filter(|v| isize::try_from(v.saturating_mul(4)).is_ok())
            .ok_or_else(|| {
                Error::invalid_input(
                    "num_samples",
                    "small enough that num_samples x batch x pred_len x K floats fit in memory",
                    format!("{num_samples} (batch {batch}, pred_len = {p}, K = {k})"),
                )
            })?;
        match noise {
            Noise::Injected(data) => {
                let shape = format!("({num_samples}, {batch}, {z}) = (num_samples, B, z_dim)");
                let total = size(&[num_samples, batch, z]).unwrap_or(usize::MAX);
                validate::all_finite("noise", data, total, &shape)?;
            }
            Noise::Seeded { sequences, .. } => sequences.check(batch)?,
        }
        control.check()?;
        let cond = self.conditioning(obs, frames, prior, batch);
        let mut out = vec![0.0f32; total_out];
        // Enough tiles for every thread, at most TILE rows each.
        let rows = num_samples * batch;
        let tile = TILE.min(rows.div_ceil(rayon::current_num_threads().max(1)));
        if rows <= tile {
            let mut sc = Scratch::new(self, tile);
            self.sample_rows(0, batch, &cond, prior, noise, &mut out, &mut sc);
        } else {
            out.par_chunks_mut(tile * p * k)
                .enumerate()
                .try_for_each_init(
                    || Scratch::new(self, tile),
                    |sc, (i, o)| {
                        control.check()?;
                        self.sample_rows(i * tile, batch, &cond, prior, noise, o, sc);
                        Ok::<(), Error>(())
                    },
                )?;
        }
        Ok(out)
    }
}
