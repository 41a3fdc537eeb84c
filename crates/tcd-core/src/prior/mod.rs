//! The deterministic prior forecaster (issue 28): the siMLPe-class network of `training/prior.py`
//! (`PriorNet`), loaded from a `prior.safetensors` file and run on the crate's GEMM kernels.
//!
//! One forward maps the last `obs_len` = L frames of K coordinates to the next `chunk` frames:
//!
//! ```text
//! DCT over time → fc_in (K → K) → blocks × [x + LN_K(temporal FC_L(x))·g + β] → fc_out (K → K)
//!     → inverse DCT (first `chunk` frames) → + the last observed pose
//! ```
//!
//! and [`Prior::predict`] rolls it out to any horizon: each predicted chunk is appended to the
//! history and the last L frames predict the next (as `PriorNet.rollout`).
//!
//! A prior with `anchor` [`Anchor::Window`] (`chunk` = L) adds the output to its input window instead of
//! the last pose: it corrects a window rather than forecasting one, and is the repair fill of
//! [`crate::pipeline::repair`] (its input the spline through a masked window's observed entries).
//!
//! # Layouts
//! * Public arrays are **frame-major (B, T, K)** row-major f32, index `b·T·K + t·K + k` (unlike the
//!   denoiser's (B, K, L)): the poses' own order, and what the Python API takes.
//! * Inside, the state is (B, K, L), frame fastest, so that every temporal FC is one GEMM over all
//!   B·K rows and the layer norm of a frame is a reduction over rows, vectorised along the frames.
//!   The spatial FCs (fc_in, fc_out) are GEMMs over frame-major rows (transposes in between).
//!
//! # Reordering
//! fc_out acts on coordinates and the inverse DCT on frames, so they commute: the inverse DCT runs
//! first, on the state's rows, and fc_out multiplies `chunk` frames instead of L; its bias, carried
//! through the inverse DCT, becomes the table `b_out[k] · Σ_f D[f, t]`. That only regroups sums, and
//! measured against a float64 forward it is as accurate as PyTorch's order. (The same swap of the DCT
//! and fc_in would save a transpose but is not: see `forward.rs`.)
//!
//! # Files
//! * `mod.rs`: the [`Prior`] type, loading, kernel choice, accessors, [`dct_matrix`];
//! * `config.rs`: its `tcd_config` ([`PriorConfig`]) and the tensors it implies;
//! * `forward.rs`: the forward, the rollout and the batch split over threads.

use std::f64::consts::PI;

use crate::error::Result;
use crate::kernels::{Isa, Kernel};
use crate::nn::{pack_all, Dense, Linear};
use crate::weights::{Network, Source, Weights};

pub mod config;
mod forward;

pub use config::{inbetween_width, Anchor, GapFill, PriorConfig, PriorModelConfig};

/// One temporal block: FC over the L frames (DCT coefficients) of each coordinate, layer norm over
/// the K coordinates of each frame with affine `norm_weight`, `norm_bias`.
#[derive(Clone, Debug)]
struct Block {
    fc: Dense,
    norm_weight: Vec<f32>,
    norm_bias: Vec<f32>,
}

/// A loaded prior. Immutable after load; `Send + Sync`, share it between threads freely.
#[derive(Clone, Debug)]
pub struct Prior {
    /// The file it was built from and its configuration.
    source: Source<PriorConfig>,
    /// The kernel in use (resolved: never `Auto`) and its instruction set (`None`: portable).
    kernel: Kernel,
    isa: Option<Isa>,
    /// The orthonormal DCT-II matrix (L × L), row f the f-th cosine.
    dct: Vec<f32>,
    /// fc_in (K → K, on the rows of the DCT coefficients' (L × K) transpose).
    fc_in: Dense,
    /// The DCT as a layer on (B·K) rows of L frames: W = D, no bias.
    dct_layer: Dense,
    blocks: Vec<Block>,
    /// The inverse DCT's first `chunk` frames (L → chunk): W[t, f] = D[f, t], no bias.
    idct_layer: Dense,
    /// fc_out's matrix without its bias (K → K, on frame-major rows).
    fc_out: Dense,
    /// fc_out's bias through the inverse DCT: (chunk × K), `b_out[k] · Σ_f D[f, t]`.
    out_bias: Vec<f32>,
    eps: f32,
    /// The in-betweening kernels of a gap-filling repair fill, gap length n at index n − 1:
    /// (n × [`inbetween_width`]) row-major each; empty for none.
    inbetween: Vec<Vec<f32>>,
    /// The joint in-betweener's kernels (runs of one coordinate), the same layout; empty for none.
    joint_inbetween: Vec<Vec<f32>>,
}

/// The orthonormal DCT-II matrix (n × n, row-major; row k is the k-th cosine, its transpose the
/// inverse) in f32, computed in f64 with the operations of `training.prior_net.dct_matrix` in their
/// order and rounded once, so that it equals PyTorch's `torch.from_numpy(dct_matrix(n)).float()`
/// (checked bit for bit by `tests/test_prior_parity.py`).
pub fn dct_matrix(n: usize) -> Vec<f32> {
    let scale = (2.0 / n as f64).sqrt();
    let mut m = Vec::with_capacity(n * n);
    for k in 0..n {
        for i in 0..n {
            let v = scale * (PI * (2 * i + 1) as f64 * k as f64 / (2 * n) as f64).cos();
            m.push(if k == 0 { v / 2f64.sqrt() } else { v } as f32);
        }
    }
    m
}

/// The prior's file: the `state_dict` of `training.prior_net.PriorNet` (K = num_features, L = obs_len;
/// the DCT matrix is no tensor: the engine computes it, [`dct_matrix`]), and the fill's in-betweening
/// kernels, `inbetween_{n}` and `joint_inbetween_{n}` (n × [`inbetween_width`]) for each gap length n.
impl Network for Prior {
    type Config = PriorConfig;

    fn source(&self) -> &Source<PriorConfig> {
        &self.source
    }

    fn build(w: &mut Weights<'_>, source: Source<PriorConfig>) -> Result<Self> {
        let m = &source.config.model;
        let (k, l, chunk) = (m.num_features, m.obs_len, m.chunk);

        let dct = dct_matrix(l);
        let zeros = |n: usize| vec![0.0f32; n];
        let fc_in = Linear::load(w, "fc_in", k, k)?;
        let dct_layer = Linear::from_torch(l, l, &dct, &zeros(l))?;
        let mut blocks = Vec::with_capacity(m.blocks);
        for i in 0..m.blocks {
            let p = format!("blocks.{i}");
            blocks.push(Block {
                fc: Dense::new(Linear::load(w, &format!("{p}.fc"), l, l)?),
                norm_weight: w.take(&format!("{p}.norm_weight"), &[k])?,
                norm_bias: w.take(&format!("{p}.norm_bias"), &[k])?,
            });
        }
        let idct: Vec<f32> = (0..chunk)
            .flat_map(|t| (0..l).map(move |f| (t, f)))
            .map(|(t, f)| dct[f * l + t])
            .collect();
        let idct_layer = Linear::from_torch(chunk, l, &idct, &zeros(chunk))?;
        let fc_out = Linear::from_torch(k, k, &w.take("fc_out.weight", &[k, k])?, &zeros(k))?;
        let b_out = w.take("fc_out.bias", &[k])?;
        let mut out_bias = Vec::with_capacity(chunk * k);
        for t in 0..chunk {
            let through: f64 = (0..l).map(|f| dct[f * l + t] as f64).sum();
            out_bias.extend(b_out.iter().map(|&b| (b as f64 * through) as f32));
        }
        let eps = m.layer_norm_eps as f32;
        let mut kernels = |prefix: &str, context: usize, max_gap: usize| -> Result<Vec<Vec<f32>>> {
            (1..=max_gap)
                .map(|n| w.take(&format!("{prefix}_{n}"), &[n, inbetween_width(n, context)]))
                .collect()
        };
        let inbetween = kernels("inbetween", m.inbetween_context, m.inbetween_max_gap)?;
        let joint_inbetween = kernels(
            "joint_inbetween",
            m.joint_inbetween_context,
            m.joint_inbetween_max_gap,
        )?;
        let prior = Prior {
            kernel: Kernel::Portable,
            isa: None,
            dct,
            fc_in: Dense::new(fc_in),
            dct_layer: Dense::new(dct_layer),
            blocks,
            idct_layer: Dense::new(idct_layer),
            fc_out: Dense::new(fc_out),
            out_bias,
            eps,
            inbetween,
            joint_inbetween,
            source,
        };
        prior.with_kernel(Kernel::from_env()?)
    }
}

impl Prior {
    /// The same model running `kernel` (`Auto`: the best this CPU supports); an error if the CPU
    /// does not support it. Packs the weights for it once.
    pub fn with_kernel(mut self, kernel: Kernel) -> Result<Self> {
        let layers = [
            &mut self.fc_in,
            &mut self.dct_layer,
            &mut self.idct_layer,
            &mut self.fc_out,
        ];
        let blocks = self.blocks.iter_mut().map(|b| &mut b.fc);
        (self.kernel, self.isa) = pack_all(kernel, layers.into_iter().chain(blocks))?;
        Ok(self)
    }

    /// The kernel this model runs (never `Auto`).
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }
    /// Frames one forward predicts.
    pub fn chunk(&self) -> usize {
        self.source.config.model.chunk
    }
    /// The in-betweening kernel of an n-frame gap ((n × [`inbetween_width`]) row-major, with the
    /// context of `config().model.inbetween_context`), if the fill has one for that length.
    pub fn inbetween_kernel(&self, n: usize) -> Option<&[f32]> {
        n.checked_sub(1)
            .and_then(|i| self.inbetween.get(i))
            .map(Vec::as_slice)
    }
    /// The joint in-betweener's kernel of an n-frame run of one coordinate (context
    /// `config().model.joint_inbetween_context`), if the fill has one for that length.
    pub fn joint_inbetween_kernel(&self, n: usize) -> Option<&[f32]> {
        n.checked_sub(1)
            .and_then(|i| self.joint_inbetween.get(i))
            .map(Vec::as_slice)
    }
    /// The DCT matrix the model uses (obs_len × obs_len, row-major), for inspection.
    pub fn dct(&self) -> &[f32] {
        &self.dct
    }
}
