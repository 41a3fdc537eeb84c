//! Multi-head self-attention (PyTorch `nn.MultiheadAttention` with packed `in_proj`, no masks, no
//! dropout): q, k, v = x · W_inᵀ + b_in (row blocks q | k | v); per head
//! softmax(q kᵀ / √head_dim) v with max subtraction; heads concatenated; `out_proj`.

use crate::config::ModelConfig;
use crate::error::{Error, Result};
use crate::nn::activation::exp_nonpositive;
use crate::nn::linear::Linear;
use crate::weights::Weights;

/// Self-attention over one sequence of C-vectors at a time.
#[derive(Clone, Debug, PartialEq)]
pub struct MultiHeadAttention {
    in_proj: Linear,
    out_proj: Linear,
    num_heads: usize,
}

impl MultiHeadAttention {
    /// From a packed input projection (C → 3C) and an output projection (C → C).
    pub fn new(in_proj: Linear, out_proj: Linear, num_heads: usize) -> Result<Self> {
        let c = out_proj.out_dim();
        if num_heads == 0 || !c.is_multiple_of(num_heads) {
            return Err(Error::invalid_input(
                "num_heads",
                format!("a positive divisor of the channel count {c}"),
                num_heads.to_string(),
            ));
        }
        if in_proj.in_dim() != c || in_proj.out_dim() != 3 * c || out_proj.in_dim() != c {
            return Err(Error::invalid_input(
                "in_proj",
                format!(
                    "a ({c} -> {}) projection matching out_proj ({c} -> {c})",
                    3 * c
                ),
                format!(
                    "in_proj ({} -> {}), out_proj ({} -> {c})",
                    in_proj.in_dim(),
                    in_proj.out_dim(),
                    out_proj.in_dim()
                ),
            ));
        }
        Ok(MultiHeadAttention {
            in_proj,
            out_proj,
            num_heads,
        })
    }

    /// Loads `{prefix}.in_proj_weight`, `{prefix}.in_proj_bias`, `{prefix}.out_proj.{weight,bias}`.
    pub fn load(w: &mut Weights<'_>, prefix: &str, cfg: &ModelConfig) -> Result<Self> {
        let c = cfg.channels;
        let wi = w.take(&format!("{prefix}.in_proj_weight"), &[3 * c, c])?;
        let bi = w.take(&format!("{prefix}.in_proj_bias"), &[3 * c])?;
        let in_proj = Linear::from_torch(3 * c, c, &wi, &bi)?;
        let out_proj = Linear::load(w, &format!("{prefix}.out_proj"), c, c)?;
        Self::new(in_proj, out_proj, cfg.num_heads)
    }

    /// Channels C.
    pub fn channels(&self) -> usize {
        self.out_proj.out_dim()
    }

    /// Number of heads.
    pub fn num_heads(&self) -> usize {
        self.num_heads
    }

    /// The packed input projection (C → 3C).
    pub fn in_proj(&self) -> &Linear {
        &self.in_proj
    }

    /// The output projection (C → C).
    pub fn out_proj(&self) -> &Linear {
        &self.out_proj
    }

    /// Attention of one sequence `x` (len × C) into `y` (len × C).
    /// Processes at most as many tokens as `x` and `y` hold.
    pub fn forward(&self, x: &[f32], len: usize, scratch: &mut AttentionScratch, y: &mut [f32]) {
        let c = self.channels();
        let len = len.min(x.len() / c).min(y.len() / c);
        scratch.ensure(c, len);
        self.in_proj
            .forward(&x[..len * c], &mut scratch.qkv[..len * 3 * c]);
        let AttentionScratch { qkv, heads, head } = scratch;
        scaled_dot_product_attention(qkv, len, c, self.num_heads, heads, head);
        self.out_proj.forward(&heads[..len * c], &mut y[..len * c]);
    }
}

/// Scratch buffers of [`MultiHeadAttention::forward`], grown on demand.
#[derive(Clone, Debug, Default)]
pub struct AttentionScratch {
    /// Packed projections (len × 3C).
    qkv: Vec<f32>,
    /// Concatenated head outputs (len × C).
    heads: Vec<f32>,
    /// Buffers of one head.
    head: HeadScratch,
}

impl AttentionScratch {
    /// Grows the buffers for sequences of `len` tokens of `channels`.
    pub fn ensure(&mut self, channels: usize, len: usize) {
        let grow = |b: &mut Vec<f32>, n: usize| {
            if b.len() < n {
                b.resize(n, 0.0);
            }
        };
        grow(&mut self.qkv, len * 3 * channels);
        grow(&mut self.heads, len * channels);
        self.head.ensure(channels, len);
    }
}

/// The buffers [`scaled_dot_product_attention`] works in, one head at a time: a query's scores
/// (len), the head's keys transposed (head_dim × len) and its values (len × head_dim), sized for
/// head_dim up to C.
#[derive(Clone, Debug, Default)]
pub(crate) struct HeadScratch {
    pub(crate) scores: Vec<f32>,
    pub(crate) kt: Vec<f32>,
    pub(crate) v: Vec<f32>,
}

impl HeadScratch {
    /// Buffers for sequences of up to `len` tokens of `channels`.
    pub(crate) fn new(channels: usize, len: usize) -> Self {
        let mut s = HeadScratch::default();
        s.ensure(channels, len);
        s
    }

    /// Grows the buffers for sequences of `len` tokens of `channels`.
    fn ensure(&mut self, channels: usize, len: usize) {
        let grow = |b: &mut Vec<f32>, n: usize| {
            if b.len() < n {
                b.resize(n, 0.0);
            }
        };
        grow(&mut self.scores, len);
        grow(&mut self.kt, len * channels);
        grow(&mut self.v, len * channels);
    }

    /// Whether the buffers hold sequences of `len` tokens of `channels`.
    pub(crate) fn fits(&self, channels: usize, len: usize) -> bool {
        self.scores.len() >= len
            && self.kt.len() >= len * channels
            && self.v.len() >= len * channels
    }
}

/// One head's place in the packed projections of a sequence: `len` rows of `[q | k | v]` (3C
/// wide, C = `channels`), its `dim` columns at `offset` in each part, and its softmax scale.
#[derive(Clone, Copy, Debug)]
struct Head {
    len: usize,
    channels: usize,
    dim: usize,
    offset: usize,
    scale: f32,
}

/// Softmax attention on packed projections: `qkv` is (len × 3C), each row `[q | k | v]`; writes the
/// concatenated head outputs to `out` (len × C), working in `scratch`. Scale 1/√head_dim (computed in f64, as PyTorch does, then cast);
/// max-subtracted softmax, normalised before multiplying V. Each head's keys are transposed
/// first so that the scores of a query vectorise over the keys.
pub(crate) fn scaled_dot_product_attention(
    qkv: &[f32],
    len: usize,
    channels: usize,
    num_heads: usize,
    out: &mut [f32],
    scratch: &mut HeadScratch,
) {
    if num_heads == 0 || len == 0 {
        return;
    }
    let hd = channels / num_heads;
    let stride = 3 * channels;
    let scale = (1.0 / (hd as f64).sqrt()) as f32;
    let HeadScratch { scores, kt, v } = scratch;
    let scores = &mut scores[..len];
    let kt = &mut kt[..hd * len];
    let v = &mut v[..len * hd];
    for h in 0..num_heads {
        let (qo, ko, vo) = (h * hd, channels + h * hd, 2 * channels + h * hd);
        for (j, row) in qkv.chunks_exact(stride).take(len).enumerate() {
            for d in 0..hd {
                kt[d * len + j] = row[ko + d];
            }
            v[j * hd..(j + 1) * hd].copy_from_slice(&row[vo..vo + hd]);
        }
        let head = Head {
            len,
            channels,
            dim: hd,
            offset: qo,
            scale,
        };
        match hd {
            4 => attend_fixed::<4>(qkv, head, out, scores, kt, v),
            8 => attend_fixed::<8>(qkv, head, out, scores, kt, v),
            16 => attend_fixed::<16>(qkv, head, out, scores, kt, v),
            _ => attend_dynamic(qkv, head, out, scores, kt, v),
        }
    }
}

/// Scores of query `q` against every key: s_j = (Σ_d q_d k_jd) · scale (d in order); then the
/// max-subtracted exponentials in place; returns 1 / Σ_j e_j.
#[inline]
fn softmax_scores(q: &[f32], kt: &[f32], len: usize, scale: f32, scores: &mut [f32]) -> f32 {
    scores.fill(0.0);
    for (qd, ktd) in q.iter().zip(kt.chunks_exact(len)) {
        for (s, kv) in scores.iter_mut().zip(ktd) {
            *s += qd * kv;
        }
    }
    // Separate passes, so that the element-wise ones vectorise (the reductions stay in order).
    for s in scores.iter_mut() {
        *s *= scale;
    }
    let max = scores.iter().fold(f32::NEG_INFINITY, |m, &s| m.max(s));
    for s in scores.iter_mut() {
        *s = exp_nonpositive(*s - max);
    }
    1.0 / scores.iter().sum::<f32>()
}

/// One head with a compile-time head dimension (the output accumulator lives in registers).
#[inline]
fn attend_fixed<const HD: usize>(
    qkv: &[f32],
    head: Head,
    out: &mut [f32],
    scores: &mut [f32],
    kt: &[f32],
    v: &[f32],
) {
    debug_assert_eq!(head.dim, HD);
    let Head {
        len,
        channels,
        offset: qo,
        scale,
        ..
    } = head;
    let stride = 3 * channels;
    for (i, row) in qkv.chunks_exact(stride).take(len).enumerate() {
        let inv = softmax_scores(&row[qo..qo + HD], kt, len, scale, scores);
        let mut o = [0.0f32; HD];
        for (s, vj) in scores.iter().zip(v.chunks_exact(HD)) {
            let p = s * inv;
            let vj: [f32; HD] = std::array::from_fn(|d| vj[d]);
            for d in 0..HD {
                o[d] += p * vj[d];
            }
        }
        out[i * channels + qo..i * channels + qo + HD].copy_from_slice(&o);
    }
}

/// One head, any head dimension.
fn attend_dynamic(
    qkv: &[f32],
    head: Head,
    out: &mut [f32],
    scores: &mut [f32],
    kt: &[f32],
    v: &[f32],
) {
    let Head {
        len,
        channels,
        dim: hd,
        offset: qo,
        scale,
    } = head;
    let stride = 3 * channels;
    for (i, row) in qkv.chunks_exact(stride).take(len).enumerate() {
        let inv = softmax_scores(&row[qo..qo + hd], kt, len, scale, scores);
        let o = &mut out[i * channels + qo..i * channels + qo + hd];
        o.fill(0.0);
        for (s, vj) in scores.iter().zip(v.chunks_exact(hd)) {
            let p = s * inv;
            for (ov, vv) in o.iter_mut().zip(vj) {
                *ov += p * vv;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Naive f64 softmax attention with one head.
    fn naive_one_head(
        x: &[f64],
        len: usize,
        c: usize,
        wq: &[f64],
        wk: &[f64],
        wv: &[f64],
    ) -> Vec<f64> {
        let proj = |w: &[f64], i: usize| -> Vec<f64> {
            (0..c)
                .map(|o| (0..c).map(|j| w[o * c + j] * x[i * c + j]).sum())
                .collect()
        };
        let q: Vec<Vec<f64>> = (0..len).map(|i| proj(wq, i)).collect();
        let k: Vec<Vec<f64>> = (0..len).map(|i| proj(wk, i)).collect();
        let v: Vec<Vec<f64>> = (0..len).map(|i| proj(wv, i)).collect();
        let mut out = vec![0.0; len * c];
        for i in 0..len {
            let s: Vec<f64> = (0..len)
                .map(|j| {
                    q[i].iter().zip(&k[j]).map(|(a, b)| a * b).sum::<f64>() / (c as f64).sqrt()
                })
                .collect();
            let m = s.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
            let e: Vec<f64> = s.iter().map(|v| (v - m).exp()).collect();
            let z: f64 = e.iter().sum();
            for j in 0..len {
                for d in 0..c {
                    out[i * c + d] += e[j] / z * v[j][d];
                }
            }
        }
        out
    }

    #[test]
    fn one_head_matches_naive() {
        let (len, c) = (5usize, 4usize);
        let val = |i: usize, s: f64| (i as f64 * 0.37 + s).sin() * 0.8;
        let x: Vec<f64> = (0..len * c).map(|i| val(i, 0.1) * 2.0).collect();
        let wq: Vec<f64> = (0..c * c).map(|i| val(i, 1.0)).collect();
        let wk: Vec<f64> = (0..c * c).map(|i| val(i, 2.0)).collect();
        let wv: Vec<f64> = (0..c * c).map(|i| val(i, 3.0)).collect();
        let eye: Vec<f32> = (0..c * c)
            .map(|i| if i / c == i % c { 1.0 } else { 0.0 })
            .collect();
        let w_in: Vec<f32> = wq.iter().chain(&wk).chain(&wv).map(|&v| v as f32).collect();
        let mha = MultiHeadAttention::new(
            Linear::from_torch(3 * c, c, &w_in, &vec![0.0; 3 * c]).unwrap(),
            Linear::from_torch(c, c, &eye, &vec![0.0; c]).unwrap(),
            1,
        )
        .unwrap();
        let xf: Vec<f32> = x.iter().map(|&v| v as f32).collect();
        let mut scratch = AttentionScratch::default();
        let mut y = vec![0.0; len * c];
        mha.forward(&xf, len, &mut scratch, &mut y);
        let want = naive_one_head(&x, len, c, &wq, &wk, &wv);
        for (a, b) in y.iter().zip(&want) {
            assert!((*a as f64 - b).abs() < 1e-5, "{a} vs {b}");
        }
    }

    #[test]
    fn heads_are_independent_blocks() {
        // With 2 heads, head h only sees its own channel block: compare with two 1-head runs.
        let (len, c) = (3usize, 4usize);
        let qkv: Vec<f32> = (0..len * 3 * c)
            .map(|i| ((i as f32) * 0.77).cos())
            .collect();
        let mut out = vec![0.0; len * c];
        let mut scratch = HeadScratch::new(c, len);
        scaled_dot_product_attention(&qkv, len, c, 2, &mut out, &mut scratch);
        for h in 0..2 {
            // Build a 1-head packed qkv of width 2 for head h.
            let mut sub = Vec::new();
            for i in 0..len {
                for part in 0..3 {
                    let base = i * 3 * c + part * c + h * 2;
                    sub.extend_from_slice(&qkv[base..base + 2]);
                }
            }
            let mut o1 = vec![0.0; len * 2];
            scaled_dot_product_attention(&sub, len, 2, 1, &mut o1, &mut scratch);
            for i in 0..len {
                for d in 0..2 {
                    assert_eq!(o1[i * 2 + d], out[i * c + h * 2 + d]);
                }
            }
        }
    }
}
