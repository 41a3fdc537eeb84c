//! One transformer encoder layer (post-norm) on the sequences of a [`SeqLayout`]: packed GEMMs,
//! fused attention (the portable one for other head dimensions) and LayerNorm rows.

use super::attention::attention;
use super::gemm::gemm;
use super::simd::Simd;
use crate::kernels::{Epilogue, FastEncoder, FastScratch, SeqLayout};

/// PyTorch LayerNorm of one row of C floats in place (biased variance, eps inside the root).
#[inline(always)]
unsafe fn layer_norm_row<S: Simd>(x: *mut f32, c: usize, g: &[f32], b: &[f32], eps: f32) {
    // SAFETY (whole body): x is valid for c floats; g and b hold c floats (checked by the
    // dispatcher); vector accesses only when c is a multiple of W.
    unsafe {
        let inv_n = 1.0 / c as f32;
        if !c.is_multiple_of(S::W) {
            let row = std::slice::from_raw_parts_mut(x, c);
            let mean = row.iter().sum::<f32>() * inv_n;
            let var = row.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() * inv_n;
            let rstd = 1.0 / (var + eps).sqrt();
            for ((v, &gv), &bv) in row.iter_mut().zip(g).zip(b) {
                *v = (*v - mean) * rstd * gv + bv;
            }
            return;
        }
        let mut acc = S::zero();
        let mut i = 0;
        while i < c {
            acc = S::add(acc, S::load(x.add(i)));
            i += S::W;
        }
        let mean = S::splat(S::hsum(acc) * inv_n);
        let mut acc = S::zero();
        let mut i = 0;
        while i < c {
            let d = S::sub(S::load(x.add(i)), mean);
            acc = S::fma(d, d, acc);
            i += S::W;
        }
        let var = S::hsum(acc) * inv_n;
        let rstd = S::splat(1.0 / (var + eps).sqrt());
        let mut i = 0;
        while i < c {
            let d = S::mul(S::sub(S::load(x.add(i)), mean), rstd);
            S::store(
                x.add(i),
                S::fma(d, S::load(g.as_ptr().add(i)), S::load(b.as_ptr().add(i))),
            );
            i += S::W;
        }
    }
}

#[inline(always)]
pub(super) unsafe fn encoder<S: Simd>(
    e: &FastEncoder,
    x: *mut f32,
    layout: SeqLayout,
    sc: &mut FastScratch,
) {
    let SeqLayout {
        num_seq,
        seq_len,
        seq_stride,
        tok_stride,
    } = layout;
    let (c, f) = (e.c, e.f);
    let hd = c / e.heads;
    // SAFETY (whole body): the dispatcher checked that every token of every sequence lies inside
    // x and that the scratch holds seq_len rows of each buffer.
    unsafe {
        for s in 0..num_seq {
            let xs = x.add(s * seq_stride);
            gemm::<S>(
                xs,
                tok_stride,
                seq_len,
                &e.qkv,
                sc.qkv.as_mut_ptr(),
                3 * c,
                Epilogue::Store,
            );
            match hd {
                8 => attention::<S, 8>(
                    sc.qkv.as_ptr(),
                    seq_len,
                    c,
                    e.heads,
                    sc.heads.as_mut_ptr(),
                    sc.scores.as_mut_ptr(),
                ),
                4 => attention::<S, 4>(
                    sc.qkv.as_ptr(),
                    seq_len,
                    c,
                    e.heads,
                    sc.heads.as_mut_ptr(),
                    sc.scores.as_mut_ptr(),
                ),
                16 => attention::<S, 16>(
                    sc.qkv.as_ptr(),
                    seq_len,
                    c,
                    e.heads,
                    sc.heads.as_mut_ptr(),
                    sc.scores.as_mut_ptr(),
                ),
                _ => crate::nn::attention::scaled_dot_product_attention(
                    &sc.qkv[..seq_len * 3 * c],
                    seq_len,
                    c,
                    e.heads,
                    &mut sc.heads[..seq_len * c],
                    &mut sc.portable,
                ),
            }
            gemm::<S>(
                sc.heads.as_ptr(),
                c,
                seq_len,
                &e.out,
                xs,
                tok_stride,
                Epilogue::AddTo,
            );
            for t in 0..seq_len {
                layer_norm_row::<S>(xs.add(t * tok_stride), c, &e.ln1.0, &e.ln1.1, e.ln1.2);
            }
            gemm::<S>(
                xs,
                tok_stride,
                seq_len,
                &e.ff1,
                sc.ffn.as_mut_ptr(),
                f,
                Epilogue::Gelu,
            );
            gemm::<S>(
                sc.ffn.as_ptr(),
                f,
                seq_len,
                &e.ff2,
                xs,
                tok_stride,
                Epilogue::AddTo,
            );
            for t in 0..seq_len {
                layer_norm_row::<S>(xs.add(t * tok_stride), c, &e.ln2.0, &e.ln2.1, e.ln2.2);
            }
        }
    }
}
