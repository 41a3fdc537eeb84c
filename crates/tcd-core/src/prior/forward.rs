//! The prior's forward on a tile of sequences, the rollout to a horizon, and [`Prior::predict`],
//! which splits the batch into tiles over the current rayon pool.
//!
//! Every row of every GEMM and every sequence's layer norm is computed the same way whichever rows
//! share its tile, so results do not depend on the thread count or the tile size.

use rayon::prelude::*;

use super::config::Anchor;
use super::Prior;
use crate::control::Control;
use crate::error::{check_len, check_positive, Error, Result};
use crate::kernels::{self, ColumnNorm};
use crate::validate;
use crate::weights::Network;

/// Sequences per tile: one worker's unit of work. Its buffers (2 × 13 KiB per sequence at
/// K = 66, L = 50) and the packed weights stay in L2; more rows per GEMM gain nothing.
const TILE: usize = 4;

/// One worker's buffers for tiles of up to `tile` sequences.
struct Scratch {
    /// The last L frames of every sequence, frame-major (n × L × K).
    hist: Vec<f32>,
    /// Two activation buffers of n × L × K values (either layout).
    x: Vec<f32>,
    y: Vec<f32>,
    /// One predicted chunk, frame-major (n × chunk × K).
    pred: Vec<f32>,
    /// Layer-norm statistics of one sequence: mean and 1/std per frame (2 × L).
    stats: Vec<f32>,
}

impl Scratch {
    fn new(p: &Prior, tile: usize) -> Scratch {
        let (k, l, c) = (p.num_features(), p.obs_len(), p.chunk());
        Scratch {
            hist: vec![0.0; tile * l * k],
            x: vec![0.0; tile * l * k],
            y: vec![0.0; tile * l * k],
            pred: vec![0.0; tile * c * k],
            stats: vec![0.0; 2 * l],
        }
    }
}

/// Transposes each of the `n` (rows × cols) matrices of `src` into `dst` (cols × rows).
fn transpose(src: &[f32], dst: &mut [f32], n: usize, rows: usize, cols: usize) {
    let size = rows * cols;
    for (s, d) in src
        .chunks_exact(size)
        .zip(dst.chunks_exact_mut(size))
        .take(n)
    {
        for (r, row) in s.chunks_exact(cols).enumerate() {
            for (c, &v) in row.iter().enumerate() {
                d[c * rows + r] = v;
            }
        }
    }
}

impl Prior {
    /// `state += LN(y)·g + β` for the `n` sequences of (K × L) values: the layer norm of each frame
    /// f normalises y[·, f] over the K coordinates (biased variance, as PyTorch), in the order of
    /// `TemporalBlock.forward`: `x + ((y − mean)·rstd)·g + β`. The SIMD kernels
    /// ([`kernels::column_norm_residual`]) do the same with the frames in vector lanes.
    fn norm_residual(
        &self,
        block: &super::Block,
        state: &mut [f32],
        y: &[f32],
        n: usize,
        stats: &mut [f32],
    ) {
        let (k, l) = (self.num_features(), self.obs_len());
        if let Some(isa) = self.isa {
            let p = ColumnNorm {
                k,
                l,
                weight: &block.norm_weight,
                bias: &block.norm_bias,
                eps: self.eps,
            };
            kernels::column_norm_residual(isa, &p, &mut state[..n * k * l], &y[..n * k * l], stats);
            return;
        }
        let kf = k as f32;
        let (mean, rstd) = stats.split_at_mut(l);
        for (s, y) in state
            .chunks_exact_mut(k * l)
            .zip(y.chunks_exact(k * l))
            .take(n)
        {
            mean.fill(0.0);
            for row in y.chunks_exact(l) {
                for (m, v) in mean.iter_mut().zip(row) {
                    *m += v;
                }
            }
            for m in mean.iter_mut() {
                *m /= kf;
            }
            rstd.fill(0.0);
            for row in y.chunks_exact(l) {
                for ((r, v), m) in rstd.iter_mut().zip(row).zip(mean.iter()) {
                    *r += (v - m) * (v - m);
                }
            }
            for r in rstd.iter_mut() {
                *r = 1.0 / (*r / kf + self.eps).sqrt();
            }
            for ((srow, yrow), (&g, &b)) in s
                .chunks_exact_mut(l)
                .zip(y.chunks_exact(l))
                .zip(block.norm_weight.iter().zip(&block.norm_bias))
            {
                for (((sv, yv), m), r) in
                    srow.iter_mut().zip(yrow).zip(mean.iter()).zip(rstd.iter())
                {
                    *sv = *sv + (yv - m) * r * g + b;
                }
            }
        }
    }

    /// One forward of `n` sequences: `sc.hist` (n × L × K) → `sc.pred` (n × chunk × K).
    fn forward_tile(&self, n: usize, sc: &mut Scratch) {
        let (k, l, c) = (self.num_features(), self.obs_len(), self.chunk());
        let Scratch {
            hist,
            x,
            y,
            pred,
            stats,
        } = sc;
        // The DCT on each coordinate's frames, then fc_in on each frame's coordinates: PyTorch's order
        // (fc_in's matrix first would save a transpose, but on trained weights it loses a factor of 6 in
        // accuracy: the DC coefficient of the poses is exact only when the DCT sees them first).
        transpose(hist, x, n, l, k);
        self.dct_layer.forward(x, y, n * k);
        transpose(y, x, n, k, l);
        self.fc_in.forward(x, y, n * l);
        transpose(y, x, n, l, k);
        // The state is x (n × K × L); y takes each block's temporal FC.
        for block in &self.blocks {
            block.fc.forward(x, y, n * k);
            self.norm_residual(block, x, y, n, stats);
        }
        // The inverse DCT's first `chunk` frames, then fc_out on them (they commute).
        self.idct_layer.forward(x, y, n * k);
        transpose(y, x, n, k, c);
        self.fc_out.forward(x, pred, n * c);
        let window = self.source.config.model.anchor == Anchor::Window;
        for (p, h) in pred
            .chunks_exact_mut(c * k)
            .zip(hist.chunks_exact(l * k))
            .take(n)
        {
            let last = &h[(l - 1) * k..];
            for (t, (frame, bias)) in p
                .chunks_exact_mut(k)
                .zip(self.out_bias.chunks_exact(k))
                .enumerate()
            {
                // The anchor: the last observed pose, or (a window's correction, c = l) frame t itself.
                let base = if window { &h[t * k..(t + 1) * k] } else { last };
                for ((v, b), z) in frame.iter_mut().zip(bias).zip(base) {
                    *v += b + z;
                }
            }
        }
    }

    /// The rollout of `n` sequences: `obs` (n × frames × K) → `out` (n × horizon × K).
    fn rollout_tile(
        &self,
        obs: &[f32],
        frames: usize,
        out: &mut [f32],
        horizon: usize,
        sc: &mut Scratch,
    ) {
        let (k, l, c) = (self.num_features(), self.obs_len(), self.chunk());
        let n = out.len() / (horizon * k);
        for (h, o) in sc
            .hist
            .chunks_exact_mut(l * k)
            .zip(obs.chunks_exact(frames * k))
            .take(n)
        {
            h.copy_from_slice(&o[(frames - l) * k..]);
        }
        let mut done = 0;
        while done < horizon {
            self.forward_tile(n, sc);
            let take = c.min(horizon - done);
            for (o, p) in out
                .chunks_exact_mut(horizon * k)
                .zip(sc.pred.chunks_exact(c * k))
            {
                o[done * k..(done + take) * k].copy_from_slice(&p[..take * k]);
            }
            done += take;
            if done < horizon {
                // The history's last L frames: drop the oldest `chunk`, append the prediction.
                for (h, p) in sc
                    .hist
                    .chunks_exact_mut(l * k)
                    .zip(sc.pred.chunks_exact(c * k))
                    .take(n)
                {
                    h.copy_within(c * k.., 0);
                    h[(l - c) * k..].copy_from_slice(p);
                }
            }
        }
    }

    /// Forecasts `horizon` frames of each of `batch` sequences from `obs` (batch × frames × K,
    /// frame-major; `frames` ≥ `obs_len`, the last `obs_len` frames are read and must be finite):
    /// returns (batch × horizon × K). Tiles of sequences run in parallel on the current rayon pool
    /// (see [`crate::with_threads`]); `control` can stop the call between tiles.
    pub fn predict(
        &self,
        obs: &[f32],
        batch: usize,
        frames: usize,
        horizon: usize,
        control: &Control,
    ) -> Result<Vec<f32>> {
        let (k, l) = (self.num_features(), self.obs_len());
        check_positive("batch", batch)?;
        check_positive("horizon", horizon)?;
        if self.source.config.model.anchor == Anchor::Window && horizon != l {
            return Err(Error::invalid_input(
                "horizon",
                format!("obs_len = {l}: a prior with anchor \"window\" (a repair fill) corrects its window, it does not forecast"),
                horizon.to_string(),
            ));
        }
        if frames < l {
            return Err(Error::invalid_input(
                "obs",
                format!("at least obs_len = {l} frames"),
                format!("{frames} frames"),
            ));
        }
        let shape = format!("({batch}, {frames}, {k})");
        let total_in = batch.checked_mul(frames).and_then(|v| v.checked_mul(k));
        check_len("obs", obs.len(), total_in.unwrap_or(usize::MAX), &shape)?;
        validate::finite_last_frames("obs", obs, frames, k, l)?;
        let total_out = batch
            .checked_mul(horizon)
            .and_then(|v| v.checked_mul(k))
            .filter(|v| isize::try_from(v.saturating_mul(4)).is_ok())
            .ok_or_else(|| {
                Error::invalid_input(
                    "horizon",
                    "small enough that batch x horizon x K floats fit in memory",
                    format!("{horizon} (batch {batch}, K = {k})"),
                )
            })?;
        let mut out = vec![0.0f32; total_out];
        control.check()?;
        // Enough tiles for every thread, at most TILE sequences each.
        let tile = TILE.min(batch.div_ceil(rayon::current_num_threads().max(1)));
        let (in_tile, out_tile) = (tile * frames * k, tile * horizon * k);
        if batch <= tile {
            self.rollout_tile(
                obs,
                frames,
                &mut out,
                horizon,
                &mut Scratch::new(self, tile),
            );
        } else {
            out.par_chunks_mut(out_tile)
                .zip(obs.par_chunks(in_tile))
                .try_for_each_init(
                    || Scratch::new(self, tile),
                    |sc, (o, x)| {
                        control.check()?;
                        self.rollout_tile(x, frames, o, horizon, sc);
                        Ok::<(), Error>(())
                    },
                )?;
        }
        Ok(out)
    }

    /// One forward: `obs` (batch × obs_len × K) → the next `chunk` frames (batch × chunk × K).
    pub fn forward(&self, obs: &[f32], batch: usize) -> Result<Vec<f32>> {
        self.predict(
            obs,
            batch,
            self.obs_len(),
            self.chunk(),
            &Control::default(),
        )
    }
}
