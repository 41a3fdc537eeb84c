//! One PyTorch `nn.TransformerEncoderLayer` in eval mode (post-norm, dropout off, GELU erf):
//!
//! ```text
//! x = norm1(x + SelfAttn(x))
//! x = norm2(x + linear2(gelu(linear1(x))))
//! ```

use crate::config::ModelConfig;
use crate::error::Result;
use crate::nn::activation::{gelu_erf, map_inplace};
use crate::nn::attention::{AttentionScratch, MultiHeadAttention};
use crate::nn::layer_norm::LayerNorm;
use crate::nn::linear::Linear;
use crate::weights::Weights;

/// A transformer encoder layer over sequences of C-vectors.
#[derive(Clone, Debug, PartialEq)]
pub struct EncoderLayer {
    self_attn: MultiHeadAttention,
    linear1: Linear,
    linear2: Linear,
    norm1: LayerNorm,
    norm2: LayerNorm,
}

/// Per-sequence scratch buffers of an [`EncoderLayer`], reused across calls.
#[derive(Clone, Debug, Default)]
pub struct EncoderScratch {
    attention: AttentionScratch,
    attn: Vec<f32>,
    ffn: Vec<f32>,
}

impl EncoderScratch {
    /// Scratch for sequences of up to `max_len` tokens.
    pub fn new(cfg: &ModelConfig, max_len: usize) -> Self {
        let mut s = EncoderScratch::default();
        s.ensure(cfg.channels, cfg.ffn_dim, max_len);
        s
    }

    fn ensure(&mut self, c: usize, f: usize, len: usize) {
        let grow = |v: &mut Vec<f32>, n: usize| {
            if v.len() < n {
                v.resize(n, 0.0);
            }
        };
        self.attention.ensure(c, len);
        grow(&mut self.attn, len * c);
        grow(&mut self.ffn, len * f);
    }
}

impl EncoderLayer {
    /// Loads `{prefix}.self_attn.*`, `{prefix}.linear{1,2}.*`, `{prefix}.norm{1,2}.*`
    /// (prefix e.g. `diffmodel.residual_layers.0.time_layer.layers.0`).
    pub fn load(w: &mut Weights<'_>, prefix: &str, cfg: &ModelConfig) -> Result<Self> {
        let (c, f) = (cfg.channels, cfg.ffn_dim);
        Ok(EncoderLayer {
            self_attn: MultiHeadAttention::load(w, &format!("{prefix}.self_attn"), cfg)?,
            linear1: Linear::load(w, &format!("{prefix}.linear1"), f, c)?,
            linear2: Linear::load(w, &format!("{prefix}.linear2"), c, f)?,
            norm1: LayerNorm::load(w, &format!("{prefix}.norm1"), c, cfg.layer_norm_eps)?,
            norm2: LayerNorm::load(w, &format!("{prefix}.norm2"), c, cfg.layer_norm_eps)?,
        })
    }

    /// Channels C.
    pub fn channels(&self) -> usize {
        self.self_attn.channels()
    }

    /// The self-attention block.
    pub fn self_attn(&self) -> &MultiHeadAttention {
        &self.self_attn
    }

    /// linear1 (C → F) and linear2 (F → C).
    pub fn feed_forward(&self) -> (&Linear, &Linear) {
        (&self.linear1, &self.linear2)
    }

    /// norm1 and norm2.
    pub fn norms(&self) -> (&LayerNorm, &LayerNorm) {
        (&self.norm1, &self.norm2)
    }

    /// Runs the layer in place on `x`, a contiguous batch of sequences (num_seq × seq_len × C),
    /// one sequence at a time.
    pub fn forward(&self, x: &mut [f32], seq_len: usize, scratch: &mut EncoderScratch) {
        let c = self.channels();
        let f = self.linear1.out_dim();
        if seq_len == 0 || c == 0 {
            return;
        }
        scratch.ensure(c, f, seq_len);
        let n = seq_len * c;
        for seq in x.chunks_exact_mut(n) {
            // x = norm1(x + SelfAttn(x))
            self.self_attn
                .forward(seq, seq_len, &mut scratch.attention, &mut scratch.attn);
            for (v, a) in seq.iter_mut().zip(&scratch.attn[..n]) {
                *v += a;
            }
            self.norm1.forward_inplace(seq);
            // x = norm2(x + linear2(gelu(linear1(x))))
            let ffn = &mut scratch.ffn[..seq_len * f];
            self.linear1.forward(seq, ffn);
            map_inplace(ffn, gelu_erf);
            self.linear2.forward(ffn, &mut scratch.attn[..n]);
            for (v, a) in seq.iter_mut().zip(&scratch.attn[..n]) {
                *v += a;
            }
            self.norm2.forward_inplace(seq);
        }
    }
}
