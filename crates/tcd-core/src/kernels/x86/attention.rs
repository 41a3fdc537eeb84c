//! Fused softmax attention of one sequence for head dimensions 4, 8 and 16: W queries per vector
//! register, keys streamed, max / exp / sum / P·V in registers.

use super::math::{exp_clamped_n, exp_nonpositive};
use super::simd::Simd;

/// q · k for the W queries of `q` (one vector per head dimension) and the key at `kp` (HD floats),
/// in two partial sums. A function, not a closure: a closure is not reliably compiled with the
/// caller's target features (the HD = 16 one was out of line, in SSE code), an `#[inline(always)]`
/// function is inlined into the `#[target_feature]` entry point.
#[inline(always)]
pub(super) unsafe fn score_key<S: Simd, const HD: usize>(q: &[S::V; HD], kp: *const f32) -> S::V {
    // SAFETY (whole body): kp is valid for HD floats (caller).
    unsafe {
        if HD >= 2 {
            let mut a = S::mul(q[0], S::splat(*kp));
            let mut b = S::mul(q[1], S::splat(*kp.add(1)));
            let mut d = 2;
            while d + 2 <= HD {
                a = S::fma(q[d], S::splat(*kp.add(d)), a);
                b = S::fma(q[d + 1], S::splat(*kp.add(d + 1)), b);
                d += 2;
            }
            if d < HD {
                a = S::fma(q[d], S::splat(*kp.add(d)), a);
            }
            S::add(a, b)
        } else {
            S::mul(q[0], S::splat(*kp))
        }
    }
}

/// Softmax attention of one sequence for head dimension HD: `qkv` (len × 3C, rows [q | k | v]),
/// `out` (len × C, heads concatenated), `scores` (len × W scratch). W queries per vector (the
/// scale folded into them); three passes over the keys, each made of independent work so that
/// the out-of-order core overlaps the long exp chains instead of waiting on them:
/// 1. scores against each key (two partial dot products per key, four keys per iteration) and
///    their running max (two registers);
/// 2. p = e^(s − max) in place and Σp (two partial sums);
/// 3. P·V, two accumulator sets (even / odd keys) summed at the end.
#[inline(always)]
pub(super) unsafe fn attention<S: Simd, const HD: usize>(
    qkv: *const f32,
    len: usize,
    c: usize,
    heads: usize,
    out: *mut f32,
    scores: *mut f32,
) {
    // SAFETY (whole body): qkv is valid for len × 3C floats, out for len × C, scores for
    // len × W; head h reads columns h·HD .. (h+1)·HD (+C, +2C) < 3C since heads·HD = C; the
    // transposition buffer holds HD × W ≤ 16 × 16 floats.
    unsafe {
        let w = S::W;
        let stride = 3 * c;
        let scale = (1.0 / (HD as f64).sqrt()) as f32;
        let mut tmp = [0.0f32; 256];
        let tp = tmp.as_mut_ptr();
        for h in 0..heads {
            let (qo, ko, vo) = (h * HD, c + h * HD, 2 * c + h * HD);
            let mut q0 = 0;
            while q0 < len {
                let nq = w.min(len - q0);
                for d in 0..HD {
                    for lane in 0..w {
                        *tp.add(d * w + lane) = if lane < nq {
                            *qkv.add((q0 + lane) * stride + qo + d) * scale
                        } else {
                            0.0
                        };
                    }
                }
                let q: [S::V; HD] = std::array::from_fn(|d| S::load(tp.add(d * w)));
                // Pass 1: scores (two partial dot products) and their max.
                let kp = qkv.add(ko);
                let mut m0 = S::splat(f32::NEG_INFINITY);
                let mut m1 = m0;
                let mut j = 0;
                // AVX2 has 16 vector registers: HD query vectors plus two keys' partial sums
                // fit, four keys would spill. AVX-512 (32 registers) takes four keys.
                while S::W < 16 && HD <= 8 && j + 2 <= len {
                    let s0 = score_key::<S, HD>(&q, kp.add(j * stride));
                    let s1 = score_key::<S, HD>(&q, kp.add((j + 1) * stride));
                    S::store(scores.add(j * w), s0);
                    S::store(scores.add((j + 1) * w), s1);
                    m0 = S::max(m0, s0);
                    m1 = S::max(m1, s1);
                    j += 2;
                }
                while j + 4 <= len {
                    let s0 = score_key::<S, HD>(&q, kp.add(j * stride));
                    let s1 = score_key::<S, HD>(&q, kp.add((j + 1) * stride));
                    let s2 = score_key::<S, HD>(&q, kp.add((j + 2) * stride));
                    let s3 = score_key::<S, HD>(&q, kp.add((j + 3) * stride));
                    S::store(scores.add(j * w), s0);
                    S::store(scores.add((j + 1) * w), s1);
                    S::store(scores.add((j + 2) * w), s2);
                    S::store(scores.add((j + 3) * w), s3);
                    m0 = S::max(m0, S::max(s0, s2));
                    m1 = S::max(m1, S::max(s1, s3));
                    j += 4;
                }
                while j < len {
                    let s0 = score_key::<S, HD>(&q, kp.add(j * stride));
                    S::store(scores.add(j * w), s0);
                    m0 = S::max(m0, s0);
                    j += 1;
                }
                let m = S::max(m0, m1);
                // Pass 2: p = e^(s − max) ≤ 1 in place, and Σp.
                let (mut sum0, mut sum1) = (S::zero(), S::zero());
                let mut j = 0;
                while j + 4 <= len {
                    let lo = S::splat(-87.0);
                    let mut p = [S::zero(); 4];
                    for (i, pi) in p.iter_mut().enumerate() {
                        *pi = S::max(S::sub(S::load(scores.add((j + i) * w)), m), lo);
                    }
                    exp_clamped_n::<S, 4>(&mut p);
                    for (i, &pi) in p.iter().enumerate() {
                        S::store(scores.add((j + i) * w), pi);
                    }
                    sum0 = S::add(sum0, S::add(p[0], p[2]));
                    sum1 = S::add(sum1, S::add(p[1], p[3]));
                    j += 4;
                }
                while j < len {
                    let p0 = exp_nonpositive::<S>(S::sub(S::load(scores.add(j * w)), m));
                    S::store(scores.add(j * w), p0);
                    sum0 = S::add(sum0, p0);
                    j += 1;
                }
                // Pass 3: P·V, even and odd keys in separate accumulators.
                let mut oa = [S::zero(); HD];
                let mut ob = [S::zero(); HD];
                let mut j = 0;
                // AVX2: one accumulator set (HD ≥ 8 independent FMA chains already cover the
                // FMA latency; a second set would spill). AVX-512: two sets.
                while S::W < 16 && HD >= 8 && j < len {
                    let p0 = S::load(scores.add(j * w));
                    let vp0 = qkv.add(j * stride + vo);
                    for (d, od) in oa.iter_mut().enumerate() {
                        *od = S::fma(p0, S::splat(*vp0.add(d)), *od);
                    }
                    j += 1;
                }
                while j + 2 <= len {
                    let (p0, p1) = (S::load(scores.add(j * w)), S::load(scores.add((j + 1) * w)));
                    let vp0 = qkv.add(j * stride + vo);
                    let vp1 = vp0.add(stride);
                    for d in 0..HD {
                        oa[d] = S::fma(p0, S::splat(*vp0.add(d)), oa[d]);
                        ob[d] = S::fma(p1, S::splat(*vp1.add(d)), ob[d]);
                    }
                    j += 2;
                }
                if j < len {
                    let p0 = S::load(scores.add(j * w));
                    let vp0 = qkv.add(j * stride + vo);
                    for (d, od) in oa.iter_mut().enumerate() {
                        *od = S::fma(p0, S::splat(*vp0.add(d)), *od);
                    }
                }
                let inv = S::div(S::splat(1.0), S::add(sum0, sum1));
                for d in 0..HD {
                    S::store(tp.add(d * w), S::mul(S::add(oa[d], ob[d]), inv));
                }
                for lane in 0..nq {
                    let op = out.add((q0 + lane) * c + qo);
                    for d in 0..HD {
                        *op.add(d) = *tp.add(d * w + lane);
                    }
                }
                q0 += w;
            }
        }
    }
}
