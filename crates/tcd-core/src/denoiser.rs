//! The CSDI/TCD denoiser ε̂ = net(x_t, x₀, m, t) (TCD_REFERENCE.md section 1): load + forward.
//!
//! # Layouts
//! * Public arrays (`noisy`, `observed`, `mask`, `out`) are **(B, K, L) row-major** f32:
//!   index `b·K·L + k·L + l`, k the coordinate (joint·3 + axis), l the frame.
//! * Inside, one sequence at a time, activations are **token-major**: (N = K·L tokens × C
//!   channels), token `n = k·L + l`, so the time transformer's sequences (fixed k) are contiguous
//!   and the feature transformer works on a transposed copy (L × K × C).
//!
//! # Hoisting
//! The cond projection `W_c · [pe(l) | emb(k) | m] + b` is split into a per-frame table
//! (`W_t · pe(l) + b`, built by [`Denoiser::prepare`] once per length), a per-coordinate table
//! (`W_f · emb(k)`, built at load) and the mask column; the step embedding and every block's
//! diffusion projection are tabulated at load for all T steps. Both only regroup sums.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::config::{CondFill, Role, TcdConfig};
use crate::error::{check_positive, Error, Result};
use crate::kernels::{self, Epilogue, FastEncoder, FastLinear, FastScratch, Isa, Kernel, SeqLayout, TailInputs};
use crate::nn::activation::{map_inplace, relu, sigmoid, silu};
use crate::nn::embedding::{frame_embedding, step_embedding_table};
use crate::nn::{EncoderLayer, EncoderScratch, Linear};
use crate::schedule::NoiseSchedule;
use crate::validate;
use crate::weights::WeightFile;

/// One residual block with its cond projection split for hoisting.
#[derive(Clone, Debug)]
struct ResidualLayer {
    time_layer: EncoderLayer,
    feature_layer: EncoderLayer,
    mid_projection: Linear,
    output_projection: Linear,
    /// Time-embedding columns of cond_projection, with its bias: (time_embedding_dim → 2C).
    cond_time: Linear,
    /// `W_f · emb(k)` for every coordinate k: (K × 2C).
    cond_feature: Vec<f32>,
    /// The mask column of cond_projection (2C).
    cond_mask: Vec<f32>,
}

/// A residual block with weights packed for the SIMD kernels.
#[derive(Clone, Debug)]
struct FastBlock {
    time: FastEncoder,
    feature: FastEncoder,
    mid: FastLinear,
    out: FastLinear,
}

/// The weights packed for the SIMD kernels of one instruction set.
#[derive(Clone, Debug)]
struct FastModel {
    isa: Isa,
    input: FastLinear,
    out1: FastLinear,
    blocks: Vec<FastBlock>,
}

impl FastModel {
    fn new(isa: Isa, d: &Denoiser) -> FastModel {
        FastModel {
            isa,
            input: FastLinear::new(isa, &d.input_projection),
            out1: FastLinear::new(isa, &d.output_projection1),
            blocks: d
                .layers
                .iter()
                .map(|l| FastBlock {
                    time: FastEncoder::new(isa, &l.time_layer),
                    feature: FastEncoder::new(isa, &l.feature_layer),
                    mid: FastLinear::new(isa, &l.mid_projection),
                    out: FastLinear::new(isa, &l.output_projection),
                })
                .collect(),
        }
    }
}

/// The loaded model. Immutable after load; `Send + Sync`, share it between threads freely.
#[derive(Clone, Debug)]
pub struct Denoiser {
    path: PathBuf,
    config: TcdConfig,
    config_json: String,
    schedule: NoiseSchedule,
    /// Conv1d 2 → C.
    input_projection: Linear,
    /// (T × D): SiLU(P2 · SiLU(P1 · table[t])).
    step_embedding: Vec<f32>,
    /// (T × N_layers × C): diffusion_projection_i(step_embedding[t]).
    step_bias: Vec<f32>,
    layers: Vec<ResidualLayer>,
    /// Conv1d C → C.
    output_projection1: Linear,
    /// Conv1d C → 1.
    output_projection2: Linear,
    /// The kernel in use (resolved: never `Auto`).
    kernel: Kernel,
    /// Packed weights of the SIMD kernel, if one is in use.
    fast: Option<FastModel>,
}

/// The length-dependent cond tables: for every block, `W_t · pe(l) + b` (L × 2C).
#[derive(Clone, Debug)]
pub struct CondTables {
    length: usize,
    /// 2C of the model that built the tables.
    width: usize,
    time: Vec<Vec<f32>>,
}

impl CondTables {
    /// The frame count L the tables were built for.
    pub fn length(&self) -> usize {
        self.length
    }
}

/// Everything about a batch of sequences that does not change across diffusion steps and samples:
/// the mask (B, K, L) and the cond tables. Built by [`Denoiser::prepare`].
#[derive(Clone, Debug)]
pub struct Prepared {
    batch: usize,
    length: usize,
    mask: Vec<f32>,
    tables: CondTables,
}

impl Prepared {
    /// B.
    pub fn batch(&self) -> usize {
        self.batch
    }
    /// L.
    pub fn length(&self) -> usize {
        self.length
    }
    /// The mask, (B, K, L).
    pub fn mask(&self) -> &[f32] {
        &self.mask
    }
}

/// Activation buffers of one forward (one sequence of length L), reused across steps so that the
/// step loop does not allocate. Create one per thread / chain.
#[derive(Clone, Debug)]
pub struct Workspace {
    length: usize,
    /// (K, C) of the model it was made for.
    dims: (usize, usize),
    /// Residual stream h (N × C).
    h: Vec<f32>,
    /// Block input / transformer stream y (N × C).
    y: Vec<f32>,
    /// Transposed copy for the feature transformer (L × K × C).
    yt: Vec<f32>,
    /// mid + cond, then output projection (N × 2C).
    z: Vec<f32>,
    /// Gated activation (N × C).
    g: Vec<f32>,
    /// Σ skip (N × C).
    skip: Vec<f32>,
    scratch: EncoderScratch,
    /// Scratch of the SIMD kernels (empty for the portable kernel).
    fast: Vec<FastScratch>,
}

impl Workspace {
    /// Buffers for sequences of `length` frames of `denoiser`. With a SIMD kernel, one forward
    /// is split over up to the current rayon pool's thread count (see [`Workspace::with_threads`]).
    pub fn new(denoiser: &Denoiser, length: usize) -> Self {
        Self::with_threads(denoiser, length, rayon::current_num_threads())
    }

    /// Buffers for sequences of `length` frames of `denoiser`; with a SIMD kernel, one forward
    /// (one chain) is split over `threads` rayon workers (coordinates for the time transformer
    /// and the block tail, frames for the feature transformer). Use 1 when independent chains
    /// already occupy the threads. Results do not depend on `threads`.
    pub fn with_threads(denoiser: &Denoiser, length: usize, threads: usize) -> Self {
        let m = &denoiser.config.model;
        let n = m.num_features * length;
        let c = m.channels;
        Workspace {
            length,
            dims: (m.num_features, c),
            h: vec![0.0; n * c],
            y: vec![0.0; n * c],
            yt: vec![0.0; n * c],
            z: vec![0.0; n * 2 * c],
            g: vec![0.0; n * c],
            skip: vec![0.0; n * c],
            scratch: EncoderScratch::new(m, length.max(m.num_features)),
            fast: if denoiser.fast.is_some() {
                let parts = threads.clamp(1, m.num_features.max(1));
                vec![FastScratch::new(c, m.ffn_dim, length.max(m.num_features), length); parts]
            } else {
                Vec::new()
            },
        }
    }

    /// The length L this workspace serves.
    pub fn length(&self) -> usize {
        self.length
    }
}

impl Denoiser {
    /// Loads and validates a weight file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        Self::from_weights(WeightFile::load(path)?)
    }

    /// From the bytes of a weight file; `name` names it in errors.
    pub fn from_bytes(bytes: &[u8], name: impl AsRef<Path>) -> Result<Self> {
        Self::from_weights(WeightFile::from_bytes(bytes, name)?)
    }

    /// From a validated [`WeightFile`].
    pub fn from_weights(mut w: WeightFile) -> Result<Self> {
        let config = w.config().clone();
        let config_json = w.config_json().to_string();
        let path = w.path().to_path_buf();
        let m = &config.model;
        let (k, c, d, e, te) = (
            m.num_features,
            m.channels,
            m.diffusion_embedding_dim,
            m.feature_embedding_dim,
            m.time_embedding_dim,
        );
        let num_steps = config.diffusion.num_train_timesteps;

        let feature_embedding = w.take("embed_layer.weight")?.data; // (K, E)
        let input_projection = Linear::load(&mut w, "diffmodel.input_projection", c, 2)?;
        let projection1 = Linear::load(&mut w, "diffmodel.diffusion_embedding.projection1", d, d)?;
        let projection2 = Linear::load(&mut w, "diffmodel.diffusion_embedding.projection2", d, d)?;
        let output_projection1 = Linear::load(&mut w, "diffmodel.output_projection1", c, c)?;
        let output_projection2 = Linear::load(&mut w, "diffmodel.output_projection2", 1, c)?;

        // Step embedding e_t = SiLU(P2 · SiLU(P1 · table[t])) for every t.
        let table = step_embedding_table(num_steps, d);
        let mut hidden = vec![0.0f32; num_steps * d];
        projection1.forward(&table, &mut hidden);
        map_inplace(&mut hidden, silu);
        let mut step_embedding = vec![0.0f32; num_steps * d];
        projection2.forward(&hidden, &mut step_embedding);
        map_inplace(&mut step_embedding, silu);

        let num_layers = m.num_layers;
        let mut step_bias = vec![0.0f32; num_steps * num_layers * c];
        let mut layers = Vec::with_capacity(num_layers);
        for i in 0..num_layers {
            let p = format!("diffmodel.residual_layers.{i}");
            let diffusion_projection = Linear::load(&mut w, &format!("{p}.diffusion_projection"), c, d)?;
            for t in 0..num_steps {
                let off = (t * num_layers + i) * c;
                diffusion_projection.forward(&step_embedding[t * d..(t + 1) * d], &mut step_bias[off..off + c]);
            }
            // cond_projection (2C, S, 1): columns [time (te) | feature (E) | mask (1)].
            let cw = w.take(&format!("{p}.cond_projection.weight"))?.data;
            let cb = w.take(&format!("{p}.cond_projection.bias"))?.data;
            let s = m.side_dim;
            let time_cols: Vec<f32> = cw.chunks_exact(s).flat_map(|row| row[..te].iter().copied()).collect();
            let cond_time = Linear::from_torch(2 * c, te, &time_cols, &cb)?;
            let cond_mask: Vec<f32> = cw.chunks_exact(s).map(|row| row[te + e]).collect();
            let mut cond_feature = vec![0.0f32; k * 2 * c];
            for (kk, emb) in feature_embedding.chunks_exact(e).enumerate() {
                for (o, row) in cw.chunks_exact(s).enumerate() {
                    let wf = &row[te..te + e];
                    cond_feature[kk * 2 * c + o] = wf.iter().zip(emb).map(|(a, b)| a * b).sum();
                }
            }
            layers.push(ResidualLayer {
                time_layer: EncoderLayer::load(&mut w, &format!("{p}.time_layer.layers.0"), m)?,
                feature_layer: EncoderLayer::load(&mut w, &format!("{p}.feature_layer.layers.0"), m)?,
                mid_projection: Linear::load(&mut w, &format!("{p}.mid_projection"), 2 * c, c)?,
                output_projection: Linear::load(&mut w, &format!("{p}.output_projection"), 2 * c, c)?,
                cond_time,
                cond_feature,
                cond_mask,
            });
        }
        let schedule = config.schedule();
        let kernel = Kernel::from_env()?;
        Denoiser {
            path,
            config,
            config_json,
            schedule,
            input_projection,
            step_embedding,
            step_bias,
            layers,
            output_projection1,
            output_projection2,
            kernel: Kernel::Portable,
            fast: None,
        }
        .with_kernel(kernel)
    }

    /// The same model running `kernel` (`Auto`: the best this CPU supports). Errors if the CPU
    /// does not support the kernel. Packs the weights for it once.
    pub fn with_kernel(mut self, kernel: Kernel) -> Result<Self> {
        let kernel = kernel.resolve()?;
        self.fast = Isa::for_kernel(kernel).map(|isa| FastModel::new(isa, &self));
        self.kernel = kernel;
        Ok(self)
    }

    /// The kernel this model runs (never `Auto`).
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    // ----------------------------------------------------------------------------- accessors

    /// The file the model came from (or the name given to [`Denoiser::from_bytes`]).
    pub fn path(&self) -> &Path {
        &self.path
    }
    /// The parsed `tcd_config`.
    pub fn config(&self) -> &TcdConfig {
        &self.config
    }
    /// The `tcd_config` JSON exactly as stored.
    pub fn config_json(&self) -> &str {
        &self.config_json
    }
    /// The model's role (`short`, `long`, `repair`).
    pub fn role(&self) -> Role {
        self.config.role
    }
    /// K: coordinates per frame.
    pub fn num_features(&self) -> usize {
        self.config.model.num_features
    }
    /// Observed frames of the training window.
    pub fn obs_len(&self) -> usize {
        self.config.window.obs_len
    }
    /// Predicted frames of the training window.
    pub fn pred_len(&self) -> usize {
        self.config.window.pred_len
    }
    /// L of the training window.
    pub fn seq_len(&self) -> usize {
        self.config.window.seq_len
    }
    /// T.
    pub fn num_train_timesteps(&self) -> usize {
        self.config.diffusion.num_train_timesteps
    }
    /// betas and ᾱ in f64.
    pub fn schedule(&self) -> &NoiseSchedule {
        &self.schedule
    }
    /// The step embedding e_t (D values) after both projections, for inspection.
    pub fn step_embedding(&self, step: usize) -> Option<&[f32]> {
        let d = self.config.model.diffusion_embedding_dim;
        self.step_embedding.get(step * d..(step + 1) * d)
    }

    // ----------------------------------------------------------------------------- forward

    /// The cond tables for sequences of `length` frames (independent of mask and step).
    pub fn cond_tables(&self, length: usize) -> CondTables {
        let te = self.config.model.time_embedding_dim;
        let c2 = 2 * self.config.model.channels;
        let pe = frame_embedding(length, te);
        let time = self
            .layers
            .iter()
            .map(|layer| {
                let mut t = vec![0.0f32; length * c2];
                layer.cond_time.forward(&pe, &mut t);
                t
            })
            .collect();
        CondTables {
            length,
            width: c2,
            time,
        }
    }

    /// Validates `mask` (B, K, L) and builds what every step of every sample of these sequences
    /// shares.
    pub fn prepare(&self, mask: &[f32], batch: usize, length: usize) -> Result<Prepared> {
        check_positive("batch", batch)?;
        check_positive("length", length)?;
        let k = self.num_features();
        validate::mask("mask", mask, batch * k * length, &format!("({batch}, {k}, {length})"))?;
        Ok(Prepared {
            batch,
            length,
            mask: mask.to_vec(),
            tables: self.cond_tables(length),
        })
    }

    /// ε̂ for a batch: `noisy`, `observed`, `mask`, `out` all (B, K, L); `step` in 0..T.
    /// Entries of `observed` where mask = 0 and of `noisy` where mask = 1 are ignored (may be NaN).
    #[allow(clippy::too_many_arguments)]
    pub fn forward(
        &self,
        noisy: &[f32],
        observed: &[f32],
        mask: &[f32],
        batch: usize,
        length: usize,
        step: usize,
        out: &mut [f32],
    ) -> Result<()> {
        let prepared = self.prepare(mask, batch, length)?;
        self.forward_prepared(&prepared, noisy, observed, step, out)
    }

    /// [`Denoiser::forward`] with the step-independent work done once by [`Denoiser::prepare`].
    pub fn forward_prepared(
        &self,
        prepared: &Prepared,
        noisy: &[f32],
        observed: &[f32],
        step: usize,
        out: &mut [f32],
    ) -> Result<()> {
        let mut ws = Workspace::new(self, prepared.length);
        self.forward_with_workspace(prepared, &mut ws, noisy, observed, step, out)
    }

    /// [`Denoiser::forward_prepared`] using caller-owned buffers (no allocation when `workspace`
    /// was made for this length).
    pub fn forward_with_workspace(
        &self,
        prepared: &Prepared,
        workspace: &mut Workspace,
        noisy: &[f32],
        observed: &[f32],
        step: usize,
        out: &mut [f32],
    ) -> Result<()> {
        let (b, l, k) = (prepared.batch, prepared.length, self.num_features());
        let n = k * l;
        let shape = format!("({b}, {k}, {l})");
        let c2 = 2 * self.config.model.channels;
        let tables = &prepared.tables;
        if prepared.mask.len() != b * n
            || tables.width != c2
            || tables.time.len() != self.layers.len()
            || tables.time.iter().any(|t| t.len() != l * c2)
        {
            return Err(Error::invalid_input(
                "prepared",
                format!(
                    "the result of `prepare` on this model (K = {k}, {} layers, channels = {})",
                    self.layers.len(),
                    self.config.model.channels
                ),
                "one prepared by a model of a different shape",
            ));
        }
        validate::finite_where("noisy", noisy, &prepared.mask, 0.0, b * n, &shape)?;
        validate::finite_where("observed", observed, &prepared.mask, 1.0, b * n, &shape)?;
        crate::error::check_len("out", out.len(), b * n, &shape)?;
        self.check_step(step)?;
        if workspace.length != l
            || workspace.dims != (k, self.config.model.channels)
            || workspace.fast.is_empty() != self.fast.is_none()
        {
            *workspace = Workspace::with_threads(self, l, workspace.fast.len().max(1));
        }
        for (((nz, ob), m), o) in noisy
            .chunks_exact(n)
            .zip(observed.chunks_exact(n))
            .zip(prepared.mask.chunks_exact(n))
            .zip(out.chunks_exact_mut(n))
        {
            self.forward_sequence(&prepared.tables, m, nz, ob, step, o, workspace);
        }
        Ok(())
    }

    pub(crate) fn check_step(&self, step: usize) -> Result<()> {
        let t = self.num_train_timesteps();
        if step < t {
            Ok(())
        } else {
            Err(Error::invalid_input(
                "step",
                format!("a diffusion step in 0..{t} (num_train_timesteps = {t})"),
                step.to_string(),
            ))
        }
    }

    /// One sequence (K × L values each), no validation: sizes, mask, step and the workspace length
    /// were checked by the caller.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn forward_sequence(
        &self,
        tables: &CondTables,
        mask: &[f32],
        noisy: &[f32],
        observed: &[f32],
        step: usize,
        out: &mut [f32],
        ws: &mut Workspace,
    ) {
        if let Some(fast) = &self.fast {
            return self.forward_sequence_fast(fast, tables, mask, noisy, observed, step, out, ws);
        }
        let m = &self.config.model;
        let (k, l, c) = (m.num_features, tables.length, m.channels);
        let n = k * l;
        let c2 = 2 * c;
        let num_layers = self.layers.len();
        let Workspace {
            h,
            y,
            yt,
            z,
            g,
            skip,
            scratch,
            ..
        } = ws;

        // Input: channel 0 = the observed channel, channel 1 = (1−m)·x_t; h = ReLU(input_projection) (N × C).
        let inp = &mut z[..2 * n];
        build_input(m.cond_fill, l, mask, observed, noisy, inp);
        self.input_projection.forward(inp, h);
        map_inplace(h, relu);
        skip.fill(0.0);

        let sqrt2 = std::f64::consts::SQRT_2 as f32;
        for (i, layer) in self.layers.iter().enumerate() {
            // y = h + diffusion_projection(e_t), broadcast over the N tokens.
            let off = (step * num_layers + i) * c;
            let dp = &self.step_bias[off..off + c];
            for (yr, hr) in y.chunks_exact_mut(c).zip(h.chunks_exact(c)) {
                for ((yv, hv), dv) in yr.iter_mut().zip(hr).zip(dp) {
                    *yv = hv + dv;
                }
            }
            // Temporal transformer: K sequences of L tokens (contiguous in token-major layout).
            if l > 1 {
                layer.time_layer.forward(y, l, scratch);
            }
            // Feature transformer: L sequences of K tokens, on a (L × K × C) transposed copy.
            if k > 1 {
                transpose_tokens(y, yt, k, l, c);
                layer.feature_layer.forward(yt, k, scratch);
                transpose_tokens(yt, y, l, k, c);
            }
            // z = mid_projection(y) + cond_projection(side)  (N × 2C)
            layer.mid_projection.forward(y, z);
            let time_tab = &tables.time[i];
            for (kk, zk) in z.chunks_exact_mut(l * c2).enumerate() {
                let ft = &layer.cond_feature[kk * c2..(kk + 1) * c2];
                for (ll, zr) in zk.chunks_exact_mut(c2).enumerate() {
                    let tt = &time_tab[ll * c2..(ll + 1) * c2];
                    let mv = mask[kk * l + ll];
                    for (((zv, tv), fv), wv) in zr.iter_mut().zip(tt).zip(ft).zip(&layer.cond_mask) {
                        *zv += tv + fv + mv * wv;
                    }
                }
            }
            // g = sigmoid(gate) · tanh(filter), gate = first C channels.
            for (gr, zr) in g.chunks_exact_mut(c).zip(z.chunks_exact(c2)) {
                let (gate, filter) = zr.split_at(c);
                for ((gv, a), f) in gr.iter_mut().zip(gate).zip(filter) {
                    *gv = sigmoid(*a) * f.tanh();
                }
            }
            // [residual | skip] = output_projection(g); h = (h + residual)/√2; Σskip += skip.
            layer.output_projection.forward(g, z);
            for ((hr, sr), zr) in h.chunks_exact_mut(c).zip(skip.chunks_exact_mut(c)).zip(z.chunks_exact(c2)) {
                let (res, sk) = zr.split_at(c);
                for (hv, rv) in hr.iter_mut().zip(res) {
                    *hv = (*hv + rv) / sqrt2;
                }
                for (sv, kv) in sr.iter_mut().zip(sk) {
                    *sv += kv;
                }
            }
        }
        // out = output_projection2(ReLU(output_projection1(Σskip / √N_layers)))  → (K, L)
        let sqrt_layers = (num_layers as f64).sqrt() as f32;
        map_inplace(skip, |v| v / sqrt_layers);
        self.output_projection1.forward(skip, y);
        map_inplace(y, relu);
        self.output_projection2.forward(y, &mut out[..n]);
    }
}

impl Denoiser {
    /// [`Denoiser::forward_sequence`] on the SIMD kernels.
    #[allow(clippy::too_many_arguments)]
    fn forward_sequence_fast(
        &self,
        fast: &FastModel,
        tables: &CondTables,
        mask: &[f32],
        noisy: &[f32],
        observed: &[f32],
        step: usize,
        out: &mut [f32],
        ws: &mut Workspace,
    ) {
        let m = &self.config.model;
        let (k, l, c) = (m.num_features, tables.length, m.channels);
        let n = k * l;
        let num_layers = self.layers.len();
        let isa = fast.isa;
        let Workspace {
            h,
            y,
            z,
            skip,
            fast: scratch,
            ..
        } = ws;
        let parts = scratch.len();

        let inp = &mut z[..2 * n];
        build_input(m.cond_fill, l, mask, observed, noisy, inp);
        kernels::gemm(isa, inp, 2, n, &fast.input, h, c, Epilogue::Relu);
        skip.fill(0.0);
        let bias = |i: usize| {
            let off = (step * num_layers + i) * c;
            &self.step_bias[off..off + c]
        };
        if num_layers > 0 {
            let dp = bias(0);
            for (yr, hr) in y.chunks_exact_mut(c).zip(h.chunks_exact(c)) {
                for ((yv, hv), dv) in yr.iter_mut().zip(hr).zip(dp) {
                    *yv = hv + dv;
                }
            }
        }
        for (i, (layer, block)) in self.layers.iter().zip(&fast.blocks).enumerate() {
            if l > 1 {
                let layout = SeqLayout {
                    num_seq: k,
                    seq_len: l,
                    seq_stride: l * c,
                    tok_stride: c,
                };
                kernels::encoder_par(isa, &block.time, y, layout, scratch);
            }
            if k > 1 {
                let layout = SeqLayout {
                    num_seq: l,
                    seq_len: k,
                    seq_stride: c,
                    tok_stride: l * c,
                };
                kernels::encoder_par(isa, &block.feature, y, layout, scratch);
            }
            let inputs = TailInputs {
                mid: &block.mid,
                out: &block.out,
                mask,
                time_tab: &tables.time[i],
                cond_feature: &layer.cond_feature,
                cond_mask: &layer.cond_mask,
                next_bias: (i + 1 < num_layers).then(|| bias(i + 1)),
            };
            if parts <= 1 {
                kernels::block_tail(isa, &inputs, 0, l, c, y, h, skip, &mut scratch[0]);
            } else {
                // Contiguous coordinate ranges per worker.
                let per = k.div_ceil(parts) * l * c;
                y.par_chunks_mut(per)
                    .zip(h.par_chunks_mut(per))
                    .zip(skip.par_chunks_mut(per))
                    .zip(scratch.par_iter_mut())
                    .enumerate()
                    .for_each(|(p, (((yc, hc), sk), sc))| {
                        kernels::block_tail(isa, &inputs, p * (per / (l * c)), l, c, yc, hc, sk, sc);
                    });
            }
        }
        let sqrt_layers = (num_layers as f64).sqrt() as f32;
        map_inplace(skip, |v| v / sqrt_layers);
        if parts <= 1 {
            kernels::gemm(isa, skip, c, n, &fast.out1, y, c, Epilogue::Relu);
        } else {
            let per = k.div_ceil(parts) * l * c;
            skip.par_chunks(per).zip(y.par_chunks_mut(per)).for_each(|(s, yc)| {
                kernels::gemm(isa, s, c, s.len() / c, &fast.out1, yc, c, Epilogue::Relu);
            });
        }
        self.output_projection2.forward(y, &mut out[..n]);
    }
}

/// (A × B × C) → (B × A × C): moves token rows, C values each.
fn transpose_tokens(src: &[f32], dst: &mut [f32], a: usize, b: usize, c: usize) {
    for (ia, block) in src.chunks_exact(b * c).take(a).enumerate() {
        for (ib, row) in block.chunks_exact(c).enumerate() {
            let o = (ib * a + ia) * c;
            dst[o..o + c].copy_from_slice(row);
        }
    }
}

/// The network input of one sequence, interleaved (N × 2) with N = K·L in (k, l) order: channel 0 is
/// the observed channel (`m · x₀`, or with [`CondFill::Linear`] / [`CondFill::Spline`] the masked entries
/// filled along time from the observed ones, [`CondFill::fill_row`]), channel 1 is `(1 − m) · x_t`.
fn build_input(fill: CondFill, length: usize, mask: &[f32], observed: &[f32], noisy: &[f32], inp: &mut [f32]) {
    for (((pair, &mv), &ov), &nv) in inp.chunks_exact_mut(2).zip(mask).zip(observed).zip(noisy) {
        pair[0] = if mv == 0.0 { 0.0 } else { mv * ov };
        pair[1] = if mv == 1.0 { 0.0 } else { (1.0 - mv) * nv };
    }
    if fill != CondFill::Zero {
        for ((row, m), o) in inp
            .chunks_exact_mut(2 * length)
            .zip(mask.chunks_exact(length))
            .zip(observed.chunks_exact(length))
        {
            fill.fill_row(m, o, |ll, v| row[2 * ll] = v);
        }
    }
}

impl CondFill {
    /// Calls `set(l, v)` with this fill's value `v` for every masked entry `l` of one coordinate's row
    /// ([`fill_linear`] or [`fill_spline`]); `Zero` calls nothing (its masked entries stay 0).
    pub fn fill_row(self, mask: &[f32], observed: &[f32], set: impl FnMut(usize, f32)) {
        match self {
            CondFill::Zero => {}
            CondFill::Linear => fill_linear(mask, observed, set),
            CondFill::Spline => fill_spline(mask, observed, set),
        }
    }
}

/// Natural cubic spline through one coordinate's observed entries (mask > 0.5; knots at their indices),
/// evaluated at every masked entry between the first and the last observed one; other masked entries get
/// the rule of [`fill_linear`] (the nearest observed entry held, 0 on a row with none). In f64, rounded to
/// f32, with the operation order of the PyTorch reference `training.model.spline_fill` (Thomas algorithm
/// for the second derivatives `M`, then `M0·a³/(6h) + M1·b³/(6h) + (y0/h − M0·h/6)·a + (y1/h − M1·h/6)·b`
/// on a segment of length h, a and b the distances to its right and left knots), so both give identical
/// bits. `set(l, v)` is called once for every masked entry; observed entries are not touched.
pub fn fill_spline(mask: &[f32], observed: &[f32], mut set: impl FnMut(usize, f32)) {
    let knots: Vec<usize> = (0..mask.len()).filter(|&i| mask[i] > 0.5).collect();
    let n = knots.len();
    if n < 2 {
        return fill_linear(mask, observed, set);
    }
    let y = |j: usize| observed[knots[j]] as f64;
    let h = |j: usize| (knots[j + 1] - knots[j]) as f64;
    let mut cp = vec![0.0f64; n];
    let mut dp = vec![0.0f64; n];
    for i in 1..n - 1 {
        let (a, c) = (h(i - 1), h(i));
        let b = 2.0 * (a + c);
        let d = 6.0 * ((y(i + 1) - y(i)) / c - (y(i) - y(i - 1)) / a);
        let w = b - a * cp[i - 1];
        cp[i] = c / w;
        dp[i] = (d - a * dp[i - 1]) / w;
    }
    let mut m = vec![0.0f64; n];
    for i in (1..n - 1).rev() {
        m[i] = dp[i] - cp[i] * m[i + 1];
    }
    let (first, last) = (knots[0], knots[n - 1]);
    let mut j = 0;
    for (ll, &mv) in mask.iter().enumerate() {
        if mv > 0.5 {
            continue;
        }
        if ll < first {
            set(ll, observed[first]);
            continue;
        }
        if ll > last {
            set(ll, observed[last]);
            continue;
        }
        while knots[j + 1] < ll {
            j += 1;
        }
        let (x0, x1) = (knots[j] as f64, knots[j + 1] as f64);
        let t = ll as f64;
        let hh = x1 - x0;
        let (a, b) = (x1 - t, t - x0);
        let (m0, m1) = (m[j], m[j + 1]);
        let v = m0 * a * a * a / (6.0 * hh) + m1 * b * b * b / (6.0 * hh) + (y(j) / hh - m0 * hh / 6.0) * a
            + (y(j + 1) / hh - m1 * hh / 6.0) * b;
        set(ll, v as f32);
    }
}

/// Linear interpolation of one coordinate's row over its masked entries (mask < 0.5): between the
/// nearest observed entries `p < l < n` the value is `a + (b − a) · ((l − p) / (n − p))` in f32 (the
/// operation order of the PyTorch reference `training.model.linear_fill`); before the first and after
/// the last observed entry the nearest one is held; a row with none observed gets 0. `set(l, v)` is
/// called for every masked entry; observed entries are not touched.
pub fn fill_linear(mask: &[f32], observed: &[f32], mut set: impl FnMut(usize, f32)) {
    let seen = |i: usize| mask[i] > 0.5;
    let mut prev: Option<usize> = None;
    let mut next = (0..mask.len()).find(|&i| seen(i));
    for ll in 0..mask.len() {
        if seen(ll) {
            prev = Some(ll);
            continue;
        }
        if next.is_some_and(|nx| nx < ll) {
            next = (ll..mask.len()).find(|&i| seen(i));
        }
        let v = match (prev, next) {
            (Some(p), Some(nx)) => {
                let (a, b) = (observed[p], observed[nx]);
                let w = (ll - p) as f32 / (nx - p) as f32;
                a + (b - a) * w
            }
            (Some(p), None) => observed[p],
            (None, Some(nx)) => observed[nx],
            (None, None) => 0.0,
        };
        set(ll, v);
    }
}

#[cfg(test)]
mod tests {
    use super::{fill_spline, transpose_tokens};

    #[test]
    fn spline_fill_natural_three_knots() {
        // knots (1, 0), (3, 1), (5, 0): natural spline, M at the middle knot = -6 / 8 = -0.75, so at
        // distance 1 from a knot the value is -0.75 / 12 + 0.5 + 0.25 = 0.6875; held outside the knots.
        let mask = [0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0];
        let obs = [f32::NAN, 0.0, f32::NAN, 1.0, f32::NAN, 0.0, f32::NAN, f32::NAN];
        let mut out = [f32::NAN; 8];
        let mut calls = 0;
        fill_spline(&mask, &obs, |l, v| {
            out[l] = v;
            calls += 1;
        });
        assert_eq!(calls, 5);
        assert_eq!(out[0], 0.0);
        assert_eq!(out[2], 0.6875);
        assert_eq!(out[4], 0.6875);
        assert_eq!(out[6], 0.0);
        assert_eq!(out[7], 0.0);
        assert!(out[1].is_nan() && out[3].is_nan() && out[5].is_nan()); // observed entries untouched
        // two knots: the straight line; none: zero
        let mut two = [f32::NAN; 5];
        fill_spline(&[1.0, 0.0, 0.0, 0.0, 1.0], &[0.0, 9.0, 9.0, 9.0, 2.0], |l, v| two[l] = v);
        assert_eq!(&two[1..4], &[0.5, 1.0, 1.5]);
        let mut none = [f32::NAN; 3];
        fill_spline(&[0.0; 3], &[f32::NAN; 3], |l, v| none[l] = v);
        assert_eq!(none, [0.0; 3]);
    }

    #[test]
    fn transpose_round_trip() {
        let (a, b, c) = (3, 4, 2);
        let src: Vec<f32> = (0..a * b * c).map(|v| v as f32).collect();
        let mut t = vec![0.0; a * b * c];
        let mut back = vec![0.0; a * b * c];
        transpose_tokens(&src, &mut t, a, b, c);
        // element (ia=1, ib=2, ch=1) goes to (ib=2, ia=1, ch=1)
        assert_eq!(t[(2 * a + 1) * c + 1], src[(b + 2) * c + 1]);
        transpose_tokens(&t, &mut back, b, a, c);
        assert_eq!(src, back);
    }
}
