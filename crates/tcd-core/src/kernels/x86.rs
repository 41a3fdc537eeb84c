//! x86-64 SIMD kernels (AVX-512F + FMA and AVX2 + FMA) written once, generically over a small
//! vector trait [`Simd`], and instantiated inside `#[target_feature]` entry points.
//!
//! Every generic function here is `#[inline(always)]`, so that it is compiled into the
//! `#[target_feature]` entry point that calls it and the intrinsics inline into it.
//!
//! Soundness: the entry points (`*_avx2`, `*_avx512`) are safe functions that are only reachable
//! through [`super::Isa`] values, which exist only after runtime detection of the features; the
//! dispatchers in `super` check every size and stride against the slices before calling them, so
//! the raw-pointer arithmetic below stays inside the slices.
#![allow(unsafe_code)]

use std::arch::x86_64::*;

use rayon::prelude::*;

use super::{Epilogue, FastEncoder, FastScratch, Packed, SeqLayout, TailInputs};
use crate::nn::activation::sigmoid;

/// Rows per GEMM register tile.
const MR: usize = 6;

// ------------------------------------------------------------------------------ vector trait

/// The vector operations the kernels need. All methods are `unsafe`: they must be called only
/// from code compiled with (and running on a CPU with) the instruction set of the implementor,
/// and the pointer ones with pointers valid for `W` floats.
pub(crate) trait Simd: Copy {
    /// Lanes.
    const W: usize;
    type V: Copy;
    unsafe fn splat(x: f32) -> Self::V;
    unsafe fn zero() -> Self::V;
    unsafe fn load(p: *const f32) -> Self::V;
    unsafe fn store(p: *mut f32, v: Self::V);
    unsafe fn add(a: Self::V, b: Self::V) -> Self::V;
    unsafe fn sub(a: Self::V, b: Self::V) -> Self::V;
    unsafe fn mul(a: Self::V, b: Self::V) -> Self::V;
    unsafe fn div(a: Self::V, b: Self::V) -> Self::V;
    /// 1/a to about 1 ulp: the hardware estimate refined by one Newton step (cheaper than `div`).
    unsafe fn recip(a: Self::V) -> Self::V;
    unsafe fn max(a: Self::V, b: Self::V) -> Self::V;
    unsafe fn min(a: Self::V, b: Self::V) -> Self::V;
    /// a·b + c, one rounding.
    unsafe fn fma(a: Self::V, b: Self::V, c: Self::V) -> Self::V;
    unsafe fn abs(a: Self::V) -> Self::V;
    /// The sign bit of `s` on the magnitude of `a` (a ≥ 0).
    unsafe fn with_sign_of(a: Self::V, s: Self::V) -> Self::V;
    /// Lane-wise `a < b ? x : y`.
    unsafe fn select_lt(a: Self::V, b: Self::V, x: Self::V, y: Self::V) -> Self::V;
    /// 2ⁿ from `t = n + 1.5·2²³` (n integral, −126 ≤ n ≤ 127), by exponent-bit arithmetic.
    unsafe fn pow2_from_shifted(t: Self::V) -> Self::V;
    /// Sum of the lanes.
    unsafe fn hsum(a: Self::V) -> f32;
}

#[derive(Clone, Copy)]
pub(crate) struct Avx512;

impl Simd for Avx512 {
    const W: usize = 16;
    type V = __m512;
    #[inline(always)]
    unsafe fn splat(x: f32) -> __m512 {
        _mm512_set1_ps(x)
    }
    #[inline(always)]
    unsafe fn zero() -> __m512 {
        _mm512_setzero_ps()
    }
    #[inline(always)]
    unsafe fn load(p: *const f32) -> __m512 {
        // SAFETY: the caller guarantees p is valid for 16 floats; unaligned load.
        unsafe { _mm512_loadu_ps(p) }
    }
    #[inline(always)]
    unsafe fn store(p: *mut f32, v: __m512) {
        // SAFETY: the caller guarantees p is valid for 16 floats; unaligned store.
        unsafe { _mm512_storeu_ps(p, v) }
    }
    #[inline(always)]
    unsafe fn add(a: __m512, b: __m512) -> __m512 {
        _mm512_add_ps(a, b)
    }
    #[inline(always)]
    unsafe fn sub(a: __m512, b: __m512) -> __m512 {
        _mm512_sub_ps(a, b)
    }
    #[inline(always)]
    unsafe fn mul(a: __m512, b: __m512) -> __m512 {
        _mm512_mul_ps(a, b)
    }
    #[inline(always)]
    unsafe fn div(a: __m512, b: __m512) -> __m512 {
        _mm512_div_ps(a, b)
    }
    #[inline(always)]
    unsafe fn recip(a: __m512) -> __m512 {
        // rcp14 (relative error < 2^-14), one Newton step: r + r·(1 − a·r).
        let r = _mm512_rcp14_ps(a);
        _mm512_fmadd_ps(r, _mm512_fnmadd_ps(a, r, _mm512_set1_ps(1.0)), r)
    }
    #[inline(always)]
    unsafe fn max(a: __m512, b: __m512) -> __m512 {
        _mm512_max_ps(a, b)
    }
    #[inline(always)]
    unsafe fn min(a: __m512, b: __m512) -> __m512 {
        _mm512_min_ps(a, b)
    }
    #[inline(always)]
    unsafe fn fma(a: __m512, b: __m512, c: __m512) -> __m512 {
        _mm512_fmadd_ps(a, b, c)
    }
    #[inline(always)]
    unsafe fn abs(a: __m512) -> __m512 {
        _mm512_abs_ps(a)
    }
    #[inline(always)]
    unsafe fn with_sign_of(a: __m512, s: __m512) -> __m512 {
        let sign = _mm512_and_si512(_mm512_castps_si512(s), _mm512_set1_epi32(i32::MIN));
        _mm512_castsi512_ps(_mm512_or_si512(_mm512_castps_si512(a), sign))
    }
    #[inline(always)]
    unsafe fn select_lt(a: __m512, b: __m512, x: __m512, y: __m512) -> __m512 {
        let m = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(a, b);
        _mm512_mask_blend_ps(m, y, x)
    }
    #[inline(always)]
    unsafe fn pow2_from_shifted(t: __m512) -> __m512 {
        let n = _mm512_sub_epi32(_mm512_castps_si512(t), _mm512_set1_epi32(0x4B40_0000 - 127));
        _mm512_castsi512_ps(_mm512_slli_epi32::<23>(n))
    }
    #[inline(always)]
    unsafe fn hsum(a: __m512) -> f32 {
        _mm512_reduce_add_ps(a)
    }
}

#[derive(Clone, Copy)]
pub(crate) struct Avx2;

impl Simd for Avx2 {
    const W: usize = 8;
    type V = __m256;
    #[inline(always)]
    unsafe fn splat(x: f32) -> __m256 {
        _mm256_set1_ps(x)
    }
    #[inline(always)]
    unsafe fn zero() -> __m256 {
        _mm256_setzero_ps()
    }
    #[inline(always)]
    unsafe fn load(p: *const f32) -> __m256 {
        // SAFETY: the caller guarantees p is valid for 8 floats; unaligned load.
        unsafe { _mm256_loadu_ps(p) }
    }
    #[inline(always)]
    unsafe fn store(p: *mut f32, v: __m256) {
        // SAFETY: the caller guarantees p is valid for 8 floats; unaligned store.
        unsafe { _mm256_storeu_ps(p, v) }
    }
    #[inline(always)]
    unsafe fn add(a: __m256, b: __m256) -> __m256 {
        _mm256_add_ps(a, b)
    }
    #[inline(always)]
    unsafe fn sub(a: __m256, b: __m256) -> __m256 {
        _mm256_sub_ps(a, b)
    }
    #[inline(always)]
    unsafe fn mul(a: __m256, b: __m256) -> __m256 {
        _mm256_mul_ps(a, b)
    }
    #[inline(always)]
    unsafe fn div(a: __m256, b: __m256) -> __m256 {
        _mm256_div_ps(a, b)
    }
    #[inline(always)]
    unsafe fn recip(a: __m256) -> __m256 {
        // rcp (relative error < 1.5·2^-12), one Newton step: r + r·(1 − a·r).
        let r = _mm256_rcp_ps(a);
        _mm256_fmadd_ps(r, _mm256_fnmadd_ps(a, r, _mm256_set1_ps(1.0)), r)
    }
    #[inline(always)]
    unsafe fn max(a: __m256, b: __m256) -> __m256 {
        _mm256_max_ps(a, b)
    }
    #[inline(always)]
    unsafe fn min(a: __m256, b: __m256) -> __m256 {
        _mm256_min_ps(a, b)
    }
    #[inline(always)]
    unsafe fn fma(a: __m256, b: __m256, c: __m256) -> __m256 {
        _mm256_fmadd_ps(a, b, c)
    }
    #[inline(always)]
    unsafe fn abs(a: __m256) -> __m256 {
        _mm256_andnot_ps(_mm256_set1_ps(-0.0), a)
    }
    #[inline(always)]
    unsafe fn with_sign_of(a: __m256, s: __m256) -> __m256 {
        _mm256_or_ps(a, _mm256_and_ps(s, _mm256_set1_ps(-0.0)))
    }
    #[inline(always)]
    unsafe fn select_lt(a: __m256, b: __m256, x: __m256, y: __m256) -> __m256 {
        let m = _mm256_cmp_ps::<_CMP_LT_OQ>(a, b);
        _mm256_blendv_ps(y, x, m)
    }
    #[inline(always)]
    unsafe fn pow2_from_shifted(t: __m256) -> __m256 {
        let n = _mm256_sub_epi32(_mm256_castps_si256(t), _mm256_set1_epi32(0x4B40_0000 - 127));
        _mm256_castsi256_ps(_mm256_slli_epi32::<23>(n))
    }
    #[inline(always)]
    unsafe fn hsum(a: __m256) -> f32 {
        let s = _mm_add_ps(_mm256_castps256_ps128(a), _mm256_extractf128_ps::<1>(a));
        let s = _mm_add_ps(s, _mm_movehl_ps(s, s));
        let s = _mm_add_ss(s, _mm_shuffle_ps::<0b01>(s, s));
        _mm_cvtss_f32(s)
    }
}

// ------------------------------------------------------------------------ vector math

/// e^x, x clamped to [−87, 88] (relative error < 3e-7).
#[inline(always)]
unsafe fn exp<S: Simd>(x: S::V) -> S::V {
    // SAFETY: vector arithmetic on registers, valid under the caller's ISA.
    unsafe { exp_clamped::<S>(S::min(S::max(x, S::splat(-87.0)), S::splat(88.0))) }
}

/// e^x for x ≤ 0 (softmax arguments after the max is subtracted): only the lower clamp.
#[inline(always)]
unsafe fn exp_nonpositive<S: Simd>(x: S::V) -> S::V {
    // SAFETY: vector arithmetic on registers, valid under the caller's ISA.
    unsafe { exp_clamped::<S>(S::max(x, S::splat(-87.0))) }
}

/// e^x for x in [−87, 88]: Cody-Waite reduction and the degree-5 polynomial of
/// [`crate::nn::activation::exp_nonpositive`], evaluated by Estrin's scheme (a shorter dependency
/// chain than Horner's).
#[inline(always)]
unsafe fn exp_clamped<S: Simd>(x: S::V) -> S::V {
    let mut v = [x];
    // SAFETY: vector arithmetic on registers, valid under the caller's ISA.
    unsafe { exp_clamped_n::<S, 1>(&mut v) };
    v[0]
}

/// [`exp_clamped`] of N independent vectors (the one implementation; N = 1 is `exp_clamped`), step
/// by step in lock-step: the N dependency chains are interleaved in the instruction stream, so that
/// the core overlaps them instead of waiting on one chain's latency (the scheduler's window is too
/// small to find that on its own).
#[inline(always)]
unsafe fn exp_clamped_n<S: Simd, const N: usize>(x: &mut [S::V; N]) {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    const SHIFTER: f32 = 12_582_912.0;
    // SAFETY (whole body): vector arithmetic on registers, valid under the caller's ISA.
    unsafe {
        let mut t = [S::zero(); N];
        let mut r = [S::zero(); N];
        let mut r2 = [S::zero(); N];
        let mut p = [S::zero(); N];
        let mut q = [S::zero(); N];
        for i in 0..N {
            t[i] = S::fma(x[i], S::splat(LOG2E), S::splat(SHIFTER));
        }
        for i in 0..N {
            let n = S::sub(t[i], S::splat(SHIFTER));
            r[i] = S::fma(n, S::splat(-LN2_LO), S::fma(n, S::splat(-LN2_HI), x[i]));
        }
        // p(r) = c0 + c1 r + ... + c5 r^5 = (c0 + c1 r) + r²((c2 + c3 r) + r²(c4 + c5 r)).
        for i in 0..N {
            r2[i] = S::mul(r[i], r[i]);
            p[i] = S::fma(S::splat(1.987_569_1e-4), r[i], S::splat(1.398_199_9e-3));
            q[i] = S::fma(S::splat(8.333_452e-3), r[i], S::splat(4.166_579_6e-2));
        }
        for i in 0..N {
            p[i] = S::fma(p[i], r2[i], q[i]);
            q[i] = S::fma(S::splat(1.666_666_5e-1), r[i], S::splat(0.5));
        }
        for i in 0..N {
            p[i] = S::fma(p[i], r2[i], q[i]);
        }
        for i in 0..N {
            let y = S::add(S::fma(p[i], r2[i], r[i]), S::splat(1.0));
            x[i] = S::mul(y, S::pow2_from_shifted(t[i]));
        }
    }
}

/// erf(z) to ~1.3e-7 absolute: |z| < 1: z·Q(z²) (degree 5); 1 ≤ |z|: 1 − e^(−z²)·P(1/(1 + z/2))
/// (degree 5), |z| clamped at 4 (erf(4) rounds to 1 in f32). Least-squares fits made for this
/// engine.
#[inline(always)]
#[allow(clippy::approx_constant)] // the leading coefficient is fitted, close to 2/√π on purpose
unsafe fn erf<S: Simd>(z: S::V) -> S::V {
    // SAFETY (whole body): vector arithmetic on registers, valid under the caller's ISA.
    unsafe {
        let a = S::min(S::abs(z), S::splat(4.0));
        let a2 = S::mul(a, a);
        let mut q = S::splat(-5.555_575_5e-4);
        q = S::fma(q, a2, S::splat(4.894_259_4e-3));
        q = S::fma(q, a2, S::splat(-2.668_538_3e-2));
        q = S::fma(q, a2, S::splat(0.112_789_184));
        q = S::fma(q, a2, S::splat(-0.376_120_75));
        q = S::fma(q, a2, S::splat(1.128_379));
        let small = S::mul(a, q);
        let t = S::recip(S::fma(a, S::splat(0.5), S::splat(1.0)));
        let mut p = S::splat(-0.231_343_9);
        p = S::fma(p, t, S::splat(0.638_257_3));
        p = S::fma(p, t, S::splat(-0.066_290_52));
        p = S::fma(p, t, S::splat(0.397_860_26));
        p = S::fma(p, t, S::splat(0.259_395_63));
        p = S::fma(p, t, S::splat(0.001_857_526_8));
        let e = exp::<S>(S::sub(S::zero(), a2));
        let large = S::sub(S::splat(1.0), S::mul(e, p));
        let r = S::select_lt(a, S::splat(1.0), small, large);
        S::with_sign_of(r, z)
    }
}

/// Exact-erf GELU x·½·(1 + erf(x/√2)).
#[inline(always)]
unsafe fn gelu<S: Simd>(x: S::V) -> S::V {
    // SAFETY: vector arithmetic on registers, valid under the caller's ISA.
    unsafe {
        let e = erf::<S>(S::mul(x, S::splat(std::f32::consts::FRAC_1_SQRT_2)));
        S::mul(S::mul(x, S::splat(0.5)), S::add(S::splat(1.0), e))
    }
}

/// σ(a)·tanh(f) with σ(a) = 1/(1 + e^(−a)) and tanh(f) = 1 − 2/(1 + e^(2f)).
#[inline(always)]
unsafe fn gated<S: Simd>(a: S::V, f: S::V) -> S::V {
    // SAFETY: vector arithmetic on registers, valid under the caller's ISA.
    unsafe {
        let one = S::splat(1.0);
        let sig = S::recip(S::add(one, exp::<S>(S::sub(S::zero(), a))));
        let th = S::fma(S::splat(-2.0), S::recip(S::add(one, exp::<S>(S::add(f, f)))), one);
        S::mul(sig, th)
    }
}

// ------------------------------------------------------------------------------- GEMM

/// One register tile: M rows (M ≤ MR) × one panel of NV vectors.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn tile<S: Simd, const NV: usize, const M: usize>(
    x: *const f32,
    ldx: usize,
    k: usize,
    panel: *const f32,
    bias: *const f32,
    y: *mut f32,
    ldy: usize,
    width: usize,
    epi: Epilogue,
) {
    // SAFETY (whole body): x is valid for M rows of k floats at stride ldx, panel for k × NV·W
    // floats, bias for NV·W floats, y for M rows of `width` floats at stride ldy (checked by the
    // dispatcher and `gemm`); full-vector stores happen only where `width` covers the vector.
    unsafe {
        let pw = NV * S::W;
        let b: [S::V; NV] = std::array::from_fn(|v| S::load(bias.add(v * S::W)));
        let mut acc = [b; M];
        for i in 0..k {
            let wp = panel.add(i * pw);
            let wv: [S::V; NV] = std::array::from_fn(|v| S::load(wp.add(v * S::W)));
            for (m, accm) in acc.iter_mut().enumerate() {
                let xb = S::splat(*x.add(m * ldx + i));
                for v in 0..NV {
                    accm[v] = S::fma(xb, wv[v], accm[v]);
                }
            }
        }
        for (m, accm) in acc.iter().enumerate() {
            for (v, &a) in accm.iter().enumerate() {
                let col = v * S::W;
                if col >= width {
                    break;
                }
                let val = match epi {
                    Epilogue::Relu => S::max(a, S::zero()),
                    Epilogue::Gelu => gelu::<S>(a),
                    Epilogue::Store | Epilogue::AddTo => a,
                };
                let yp = y.add(m * ldy + col);
                if col + S::W <= width {
                    let out = if epi == Epilogue::AddTo { S::add(S::load(yp), val) } else { val };
                    S::store(yp, out);
                } else {
                    let mut tmp = [0.0f32; 16];
                    S::store(tmp.as_mut_ptr(), val);
                    for (lane, &t) in tmp.iter().enumerate().take(width - col) {
                        let o = yp.add(lane);
                        *o = if epi == Epilogue::AddTo { *o + t } else { t };
                    }
                }
            }
        }
    }
}

#[inline(always)]
unsafe fn gemm_nv<S: Simd, const NV: usize>(
    x: *const f32,
    ldx: usize,
    rows: usize,
    w: &Packed,
    y: *mut f32,
    ldy: usize,
    epi: Epilogue,
) {
    // SAFETY (whole body): the dispatcher checked x (rows × ldx, in_dim wide) and y (rows × ldy,
    // out_dim wide); panel p covers columns p·pw .. p·pw + width ≤ out_dim; the packed weights
    // hold panels × in_dim × pw floats and the bias panels × pw.
    unsafe {
        let (k, pw) = (w.in_dim, w.pw);
        debug_assert_eq!(pw, NV * S::W);
        for p in 0..w.panels {
            let panel = w.w.as_ptr().add(p * k * pw);
            let bias = w.b.as_ptr().add(p * pw);
            let c0 = p * pw;
            let width = pw.min(w.out_dim - c0);
            let mut r = 0;
            while r + MR <= rows {
                tile::<S, NV, MR>(x.add(r * ldx), ldx, k, panel, bias, y.add(r * ldy + c0), ldy, width, epi);
                r += MR;
            }
            let (xr, yr) = (x.add(r * ldx), y.add(r * ldy + c0));
            match rows - r {
                1 => tile::<S, NV, 1>(xr, ldx, k, panel, bias, yr, ldy, width, epi),
                2 => tile::<S, NV, 2>(xr, ldx, k, panel, bias, yr, ldy, width, epi),
                3 => tile::<S, NV, 3>(xr, ldx, k, panel, bias, yr, ldy, width, epi),
                4 => tile::<S, NV, 4>(xr, ldx, k, panel, bias, yr, ldy, width, epi),
                5 => tile::<S, NV, 5>(xr, ldx, k, panel, bias, yr, ldy, width, epi),
                _ => {}
            }
        }
    }
}

#[inline(always)]
unsafe fn gemm<S: Simd>(x: *const f32, ldx: usize, rows: usize, w: &Packed, y: *mut f32, ldy: usize, epi: Epilogue) {
    // SAFETY: forwarded contract of `gemm_nv`; the panel width selects the instantiation.
    unsafe {
        match w.pw / S::W {
            4 => gemm_nv::<S, 4>(x, ldx, rows, w, y, ldy, epi),
            2 => gemm_nv::<S, 2>(x, ldx, rows, w, y, ldy, epi),
            _ => gemm_nv::<S, 1>(x, ldx, rows, w, y, ldy, epi),
        }
    }
}

// -------------------------------------------------------------------------- attention

/// q · k for the W queries of `q` (one vector per head dimension) and the key at `kp` (HD floats),
/// in two partial sums. A function, not a closure: a closure is not reliably compiled with the
/// caller's target features (the HD = 16 one was out of line, in SSE code), an `#[inline(always)]`
/// function is inlined into the `#[target_feature]` entry point.
#[inline(always)]
unsafe fn score_key<S: Simd, const HD: usize>(q: &[S::V; HD], kp: *const f32) -> S::V {
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
unsafe fn attention<S: Simd, const HD: usize>(
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
                        *tp.add(d * w + lane) =
                            if lane < nq { *qkv.add((q0 + lane) * stride + qo + d) * scale } else { 0.0 };
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

// -------------------------------------------------------------------------- LayerNorm

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
            S::store(x.add(i), S::fma(d, S::load(g.as_ptr().add(i)), S::load(b.as_ptr().add(i))));
            i += S::W;
        }
    }
}

// ---------------------------------------------------------------------------- encoder

#[inline(always)]
unsafe fn encoder<S: Simd>(e: &FastEncoder, x: *mut f32, layout: SeqLayout, sc: &mut FastScratch) {
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
            gemm::<S>(xs, tok_stride, seq_len, &e.qkv, sc.qkv.as_mut_ptr(), 3 * c, Epilogue::Store);
            match hd {
                8 => attention::<S, 8>(sc.qkv.as_ptr(), seq_len, c, e.heads, sc.heads.as_mut_ptr(), sc.scores.as_mut_ptr()),
                4 => attention::<S, 4>(sc.qkv.as_ptr(), seq_len, c, e.heads, sc.heads.as_mut_ptr(), sc.scores.as_mut_ptr()),
                16 => attention::<S, 16>(sc.qkv.as_ptr(), seq_len, c, e.heads, sc.heads.as_mut_ptr(), sc.scores.as_mut_ptr()),
                _ => crate::nn::attention::scaled_dot_product_attention(
                    &sc.qkv[..seq_len * 3 * c],
                    seq_len,
                    c,
                    e.heads,
                    &mut sc.heads[..seq_len * c],
                    &mut sc.p_scores,
                    &mut sc.p_kt,
                    &mut sc.p_v,
                ),
            }
            gemm::<S>(sc.heads.as_ptr(), c, seq_len, &e.out, xs, tok_stride, Epilogue::AddTo);
            for t in 0..seq_len {
                layer_norm_row::<S>(xs.add(t * tok_stride), c, &e.ln1.0, &e.ln1.1, e.ln1.2);
            }
            gemm::<S>(xs, tok_stride, seq_len, &e.ff1, sc.ffn.as_mut_ptr(), f, Epilogue::Gelu);
            gemm::<S>(sc.ffn.as_ptr(), f, seq_len, &e.ff2, xs, tok_stride, Epilogue::AddTo);
            for t in 0..seq_len {
                layer_norm_row::<S>(xs.add(t * tok_stride), c, &e.ln2.0, &e.ln2.1, e.ln2.2);
            }
        }
    }
}

// ------------------------------------------------------------------------ block tail

/// z + (time table + feature table + m · mask column) at column `i` (a function, not a closure:
/// see [`score_key`]).
#[inline(always)]
unsafe fn zc<S: Simd>(z: *const f32, tt: *const f32, ft: *const f32, cm: *const f32, mv: S::V, i: usize) -> S::V {
    // SAFETY: each pointer is valid for i + W floats (caller).
    unsafe { S::add(S::load(z.add(i)), S::fma(mv, S::load(cm.add(i)), S::add(S::load(tt.add(i)), S::load(ft.add(i))))) }
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
unsafe fn tail<S: Simd>(
    inp: &TailInputs<'_>,
    k0: usize,
    frames: usize,
    c: usize,
    y: *mut f32,
    h: *mut f32,
    skip: *mut f32,
    nk: usize,
    sc: &mut FastScratch,
) {
    let c2 = 2 * c;
    let w = S::W;
    let inv_sqrt2 = S::splat(std::f32::consts::FRAC_1_SQRT_2); // ≤ 1 ulp from PyTorch's division by √2
    // SAFETY (whole body): y, h, skip hold nk × frames × c floats; the tables, mask and
    // scratch sizes were checked by the dispatcher; vector accesses stay below c (resp. 2c)
    // per row, the scalar loops finish the rows.
    unsafe {
        let zt = sc.zt.as_mut_ptr();
        let gt = sc.gt.as_mut_ptr();
        for kl in 0..nk {
            let kk = k0 + kl;
            let base = kl * frames * c;
            gemm::<S>(y.add(base), c, frames, &inp.mid.0, zt, c2, Epilogue::Store);
            let ft = inp.cond_feature.as_ptr().add(kk * c2);
            let cm = inp.cond_mask.as_ptr();
            for ll in 0..frames {
                let z = zt.add(ll * c2);
                let tt = inp.time_tab.as_ptr().add(ll * c2);
                let mvs = inp.mask[kk * frames + ll];
                let mv = S::splat(mvs);
                let g = gt.add(ll * c);
                let mut i = 0;
                // Two vectors per iteration: independent exp chains for the core to overlap.
                while i + 2 * w <= c {
                    let (a0, f0) = (zc::<S>(z, tt, ft, cm, mv, i), zc::<S>(z, tt, ft, cm, mv, c + i));
                    let (a1, f1) = (zc::<S>(z, tt, ft, cm, mv, i + w), zc::<S>(z, tt, ft, cm, mv, c + i + w));
                    let (g0, g1) = (gated::<S>(a0, f0), gated::<S>(a1, f1));
                    S::store(g.add(i), g0);
                    S::store(g.add(i + w), g1);
                    i += 2 * w;
                }
                while i + w <= c {
                    S::store(g.add(i), gated::<S>(zc::<S>(z, tt, ft, cm, mv, i), zc::<S>(z, tt, ft, cm, mv, c + i)));
                    i += w;
                }
                while i < c {
                    let j = c + i;
                    let a = *z.add(i) + (*tt.add(i) + *ft.add(i) + mvs * *cm.add(i));
                    let fl = *z.add(j) + (*tt.add(j) + *ft.add(j) + mvs * *cm.add(j));
                    *g.add(i) = sigmoid(a) * fl.tanh();
                    i += 1;
                }
            }
            gemm::<S>(gt, c, frames, &inp.out.0, zt, c2, Epilogue::Store);
            for ll in 0..frames {
                let z = zt.add(ll * c2);
                let o = base + ll * c;
                let (hp, sp, yp) = (h.add(o), skip.add(o), y.add(o));
                let mut i = 0;
                while i + w <= c {
                    let hv = S::mul(S::add(S::load(hp.add(i)), S::load(z.add(i))), inv_sqrt2);
                    S::store(hp.add(i), hv);
                    S::store(sp.add(i), S::add(S::load(sp.add(i)), S::load(z.add(c + i))));
                    if let Some(nb) = inp.next_bias {
                        S::store(yp.add(i), S::add(hv, S::load(nb.as_ptr().add(i))));
                    }
                    i += w;
                }
                while i < c {
                    let hv = (*hp.add(i) + *z.add(i)) / (std::f64::consts::SQRT_2 as f32);
                    *hp.add(i) = hv;
                    *sp.add(i) += *z.add(c + i);
                    if let Some(nb) = inp.next_bias {
                        *yp.add(i) = hv + nb[i];
                    }
                    i += 1;
                }
            }
        }
    }
}

// ---------------------------------------------------------------------- entry points

/// A base pointer shared by the workers of [`encoder_par_avx512`] / [`encoder_par_avx2`], each of
/// which writes only the tokens of its own sequences.
struct SharedBase(*mut f32);

// SAFETY: the pointer is only dereferenced by the encoder kernels on disjoint token sets (the
// dispatcher checked that the layout maps distinct (sequence, token) pairs to disjoint rows).
unsafe impl Send for SharedBase {}
// SAFETY: as above.
unsafe impl Sync for SharedBase {}

impl SharedBase {
    fn get(&self) -> *mut f32 {
        self.0
    }
}

macro_rules! entries {
    ($simd:ty, $features:literal, $gemm:ident, $encoder:ident, $encoder_par:ident, $tail:ident) => {
        /// Encoder-layer entry point splitting the sequences over `scratch.len()` rayon workers
        /// (layout checked injective and in bounds by [`super::encoder_par`]).
        pub(super) fn $encoder_par(e: &FastEncoder, x: &mut [f32], layout: SeqLayout, scratch: &mut [FastScratch]) {
            #[target_feature(enable = $features)]
            unsafe fn inner(e: &FastEncoder, x: *mut f32, layout: SeqLayout, sc: &mut FastScratch) {
                // SAFETY: forwarded from the caller.
                unsafe { encoder::<$simd>(e, x, layout, sc) }
            }
            let parts = scratch.len();
            let base = SharedBase(x.as_mut_ptr());
            let base = &base;
            scratch.par_iter_mut().enumerate().for_each(|(p, sc)| {
                let (s0, s1) = (layout.num_seq * p / parts, layout.num_seq * (p + 1) / parts);
                if s1 > s0 {
                    let sub = SeqLayout {
                        num_seq: s1 - s0,
                        ..layout
                    };
                    // SAFETY: features detected (reachable only through an `Isa`); sequences
                    // s0..s1 lie inside x (checked by the dispatcher) and no other worker touches
                    // their tokens (the layout is injective, sequence ranges are disjoint); `x`
                    // stays mutably borrowed until every worker has finished.
                    unsafe { inner(e, base.get().add(s0 * layout.seq_stride), sub, sc) }
                }
            });
        }

        /// GEMM entry point (sizes checked by [`super::gemm`]).
        #[allow(clippy::too_many_arguments)]
        pub(super) fn $gemm(x: &[f32], ldx: usize, rows: usize, w: &Packed, y: &mut [f32], ldy: usize, epi: Epilogue) {
            #[target_feature(enable = $features)]
            #[allow(clippy::too_many_arguments)]
            unsafe fn inner(x: &[f32], ldx: usize, rows: usize, w: &Packed, y: &mut [f32], ldy: usize, epi: Epilogue) {
                // SAFETY: sizes and strides checked by the dispatcher.
                unsafe { gemm::<$simd>(x.as_ptr(), ldx, rows, w, y.as_mut_ptr(), ldy, epi) }
            }
            // SAFETY: reachable only through an `Isa` built after detecting these features.
            unsafe { inner(x, ldx, rows, w, y, ldy, epi) }
        }

        /// Encoder-layer entry point (sizes checked by [`super::encoder`]).
        pub(super) fn $encoder(e: &FastEncoder, x: &mut [f32], layout: SeqLayout, sc: &mut FastScratch) {
            #[target_feature(enable = $features)]
            unsafe fn inner(e: &FastEncoder, x: &mut [f32], layout: SeqLayout, sc: &mut FastScratch) {
                // SAFETY: sizes and strides checked by the dispatcher.
                unsafe { encoder::<$simd>(e, x.as_mut_ptr(), layout, sc) }
            }
            // SAFETY: reachable only through an `Isa` built after detecting these features.
            unsafe { inner(e, x, layout, sc) }
        }

        /// Residual-block tail entry point (sizes checked by [`super::block_tail`]).
        #[allow(clippy::too_many_arguments)]
        pub(super) fn $tail(
            inp: &TailInputs<'_>,
            k0: usize,
            frames: usize,
            c: usize,
            y: &mut [f32],
            h: &mut [f32],
            skip: &mut [f32],
            sc: &mut FastScratch,
        ) {
            #[target_feature(enable = $features)]
            #[allow(clippy::too_many_arguments)]
            unsafe fn inner(
                inp: &TailInputs<'_>,
                k0: usize,
                frames: usize,
                c: usize,
                y: &mut [f32],
                h: &mut [f32],
                skip: &mut [f32],
                sc: &mut FastScratch,
            ) {
                let nk = h.len() / (frames * c);
                // SAFETY: sizes checked by the dispatcher.
                unsafe { tail::<$simd>(inp, k0, frames, c, y.as_mut_ptr(), h.as_mut_ptr(), skip.as_mut_ptr(), nk, sc) }
            }
            // SAFETY: reachable only through an `Isa` built after detecting these features.
            unsafe { inner(inp, k0, frames, c, y, h, skip, sc) }
        }
    };
}

entries!(Avx512, "avx512f,fma", gemm_avx512, encoder_avx512, encoder_par_avx512, tail_avx512);
entries!(Avx2, "avx2,fma", gemm_avx2, encoder_avx2, encoder_par_avx2, tail_avx2);

// ---------------------------------------------------------------------------- tests

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::activation::gelu_erf;

    /// Applies a vector function to `xs` with the given ISA (when supported) and returns results.
    fn map_avx512(xs: &[f32], f: unsafe fn(__m512) -> __m512) -> Option<Vec<f32>> {
        if !(is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("fma")) {
            return None;
        }
        #[target_feature(enable = "avx512f,fma")]
        unsafe fn run(xs: &[f32], f: unsafe fn(__m512) -> __m512) -> Vec<f32> {
            let mut out = vec![0.0f32; xs.len()];
            for (o, x) in out.chunks_exact_mut(16).zip(xs.chunks_exact(16)) {
                // SAFETY: 16-float chunks; features detected by the caller.
                unsafe { Avx512::store(o.as_mut_ptr(), f(Avx512::load(x.as_ptr()))) }
            }
            out
        }
        // SAFETY: features detected above.
        Some(unsafe { run(xs, f) })
    }

    fn map_avx2(xs: &[f32], f: unsafe fn(__m256) -> __m256) -> Option<Vec<f32>> {
        if !(is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")) {
            return None;
        }
        #[target_feature(enable = "avx2,fma")]
        unsafe fn run(xs: &[f32], f: unsafe fn(__m256) -> __m256) -> Vec<f32> {
            let mut out = vec![0.0f32; xs.len()];
            for (o, x) in out.chunks_exact_mut(8).zip(xs.chunks_exact(8)) {
                // SAFETY: 8-float chunks; features detected by the caller.
                unsafe { Avx2::store(o.as_mut_ptr(), f(Avx2::load(x.as_ptr()))) }
            }
            out
        }
        // SAFETY: features detected above.
        Some(unsafe { run(xs, f) })
    }

    fn grid(lo: f32, hi: f32, n: usize) -> Vec<f32> {
        (0..n).map(|i| lo + (hi - lo) * i as f32 / (n - 1) as f32).collect()
    }

    /// Every function on both ISAs: (name, avx512 fn, avx2 fn, f64 reference, tolerance kind).
    fn check(
        xs: &[f32],
        f512: unsafe fn(__m512) -> __m512,
        f256: unsafe fn(__m256) -> __m256,
        reference: impl Fn(f64) -> f64,
        tol: impl Fn(f64) -> f64,
        name: &str,
    ) {
        for got in [map_avx512(xs, f512), map_avx2(xs, f256)].into_iter().flatten() {
            let mut worst = 0.0f64;
            for (&x, &g) in xs.iter().zip(&got) {
                let want = reference(x as f64);
                let err = (g as f64 - want).abs();
                assert!(err <= tol(want), "{name}({x}) = {g}, want {want}, err {err:e}");
                worst = worst.max(err);
            }
            eprintln!("{name}: worst abs err {worst:e}");
        }
    }

    #[test]
    fn vector_exp_is_accurate() {
        let xs = grid(-87.0, 88.0, 160_000);
        check(&xs, exp::<Avx512>, exp::<Avx2>, f64::exp, |w| 3e-7 * w, "exp");
    }

    #[test]
    fn vector_erf_and_gelu_are_accurate() {
        let xs = grid(-9.0, 9.0, 160_000);
        let erf_ref = |x: f64| libm::erf(x);
        check(&xs, erf::<Avx512>, erf::<Avx2>, erf_ref, |_| 2e-7, "erf");
        let gelu_ref = |x: f64| x * 0.5 * (1.0 + libm::erf(x / std::f64::consts::SQRT_2));
        check(&xs, gelu::<Avx512>, gelu::<Avx2>, gelu_ref, |w| 2e-7 * w.abs().max(1.0), "gelu");
        // and against the portable f32 GELU
        if let Some(got) = map_avx512(&xs, gelu::<Avx512>) {
            for (&x, &g) in xs.iter().zip(&got) {
                assert!((g - gelu_erf(x)).abs() <= 4e-7 * x.abs().max(1.0), "gelu({x})");
            }
        }
    }

    #[test]
    fn vector_gated_activation_is_accurate() {
        // σ(a)·tanh(a/2 − 1) over a grid (both arguments varying).
        fn g512(a: __m512) -> __m512 {
            // SAFETY: only called under the avx512 target feature by `map_avx512`.
            unsafe { gated::<Avx512>(a, Avx512::sub(Avx512::mul(a, Avx512::splat(0.5)), Avx512::splat(1.0))) }
        }
        fn g256(a: __m256) -> __m256 {
            // SAFETY: only called under the avx2 target feature by `map_avx2`.
            unsafe { gated::<Avx2>(a, Avx2::sub(Avx2::mul(a, Avx2::splat(0.5)), Avx2::splat(1.0))) }
        }
        let xs = grid(-100.0, 100.0, 80_000);
        let reference = |a: f64| (1.0 / (1.0 + (-a).exp())) * (a / 2.0 - 1.0).tanh();
        check(&xs, g512, g256, reference, |_| 3e-7, "gated");
    }
}
