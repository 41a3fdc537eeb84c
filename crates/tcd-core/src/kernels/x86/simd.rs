//! The vector trait [`Simd`] the kernels are written against, and its two implementations:
//! [`Avx512`] (16 lanes) and [`Avx2`] (8 lanes), one intrinsic per method.

use std::arch::x86_64::*;

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
    /// 1/a to about 1 ulp, with the same bits on every CPU that runs the implementor: only
    /// instructions whose results are specified (the rule `tests::no_implementation_defined_estimates`
    /// in kernels/x86/mod.rs guards).
    unsafe fn recip(a: Self::V) -> Self::V;
    /// Whether `recip` is an exact division (no specified estimate to refine): formulas with several
    /// reciprocals then fold them into one division (`math::gated`).
    const RECIP_IS_DIVISION: bool;
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
    const RECIP_IS_DIVISION: bool = false;
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
        // rcp14 (relative error < 2^-14), one Newton step: r + r·(1 − a·r). Unlike AVX2's `rcp_ps`,
        // `rcp14` is specified bit for bit (the SDM gives its reference table), so every AVX-512 CPU
        // returns the same estimate: the golden tables match on Zen 5 and Sapphire Rapids.
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
    const RECIP_IS_DIVISION: bool = true;
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
        // Exact division. AVX2's estimate `rcp_ps` is implementation-defined (Intel and AMD return
        // different bits, so a Newton step on it does too): the avx2 path's outputs depended on the
        // CPU's vendor (issue 27). `vdivps` is IEEE-rounded everywhere.
        _mm256_div_ps(_mm256_set1_ps(1.0), a)
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
