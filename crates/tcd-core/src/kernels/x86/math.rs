//! Vector math on [`Simd`] registers: e^x (Cody-Waite + degree-5 polynomial, one or N chains in
//! lock-step), erf, exact-erf GELU and the gated activation σ(a)·tanh(f); with accuracy tests
//! against f64 references.

use super::simd::Simd;

/// e^x, x clamped to [−87, 88] (relative error < 3e-7).
#[inline(always)]
pub(super) unsafe fn exp<S: Simd>(x: S::V) -> S::V {
    // SAFETY: vector arithmetic on registers, valid under the caller's ISA.
    unsafe { exp_clamped::<S>(S::min(S::max(x, S::splat(-87.0)), S::splat(88.0))) }
}

/// e^x for x ≤ 0 (softmax arguments after the max is subtracted): only the lower clamp.
#[inline(always)]
pub(super) unsafe fn exp_nonpositive<S: Simd>(x: S::V) -> S::V {
    // SAFETY: vector arithmetic on registers, valid under the caller's ISA.
    unsafe { exp_clamped::<S>(S::max(x, S::splat(-87.0))) }
}

/// e^x for x in [−87, 88]: Cody-Waite reduction and the degree-5 polynomial of
/// [`crate::nn::activation::exp_nonpositive`], evaluated by Estrin's scheme (a shorter dependency
/// chain than Horner's).
#[inline(always)]
pub(super) unsafe fn exp_clamped<S: Simd>(x: S::V) -> S::V {
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
pub(super) unsafe fn exp_clamped_n<S: Simd, const N: usize>(x: &mut [S::V; N]) {
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
pub(super) unsafe fn erf<S: Simd>(z: S::V) -> S::V {
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
pub(super) unsafe fn gelu<S: Simd>(x: S::V) -> S::V {
    // SAFETY: vector arithmetic on registers, valid under the caller's ISA.
    unsafe {
        let e = erf::<S>(S::mul(x, S::splat(std::f32::consts::FRAC_1_SQRT_2)));
        S::mul(S::mul(x, S::splat(0.5)), S::add(S::splat(1.0), e))
    }
}

/// σ(a)·tanh(f), σ(a) = 1/(1 + e^(−a)), tanh(f) = 1 − 2/(1 + e^(2f)).
///
/// Where `recip` is a specified estimate refined by Newton (AVX-512's `rcp14`), as two reciprocals.
/// Where it is an exact division (AVX2: its estimate `rcp_ps` differs between Intel and AMD, issue
/// 27), as one division, (e^(2f) − 1) / ((1 + e^(−a))·(1 + e^(2f))), which costs half of two: the
/// clamps keep that denominator finite (tanh(±9) rounds to ±1 in f32; below a = −60, σ(a) < 1e−26).
/// The AVX-512 form stays as it was so that its golden outputs, recorded on AVX-512 CPUs, still hold.
#[inline(always)]
pub(super) unsafe fn gated<S: Simd>(a: S::V, f: S::V) -> S::V {
    // SAFETY: vector arithmetic on registers, valid under the caller's ISA.
    unsafe {
        let one = S::splat(1.0);
        if S::RECIP_IS_DIVISION {
            let a = S::max(a, S::splat(-60.0));
            let f = S::min(S::max(f, S::splat(-9.0)), S::splat(9.0));
            let e2f = exp::<S>(S::add(f, f));
            let den = S::mul(
                S::add(one, exp::<S>(S::sub(S::zero(), a))),
                S::add(one, e2f),
            );
            S::div(S::sub(e2f, one), den)
        } else {
            let sig = S::recip(S::add(one, exp::<S>(S::sub(S::zero(), a))));
            let th = S::fma(
                S::splat(-2.0),
                S::recip(S::add(one, exp::<S>(S::add(f, f)))),
                one,
            );
            S::mul(sig, th)
        }
    }
}

#[cfg(test)]
mod tests {
    use std::arch::x86_64::*;

    use super::super::simd::{Avx2, Avx512, Simd};
    use super::{erf, exp, gated, gelu};
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
        (0..n)
            .map(|i| lo + (hi - lo) * i as f32 / (n - 1) as f32)
            .collect()
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
        for got in [map_avx512(xs, f512), map_avx2(xs, f256)]
            .into_iter()
            .flatten()
        {
            let mut worst = 0.0f64;
            for (&x, &g) in xs.iter().zip(&got) {
                let want = reference(x as f64);
                let err = (g as f64 - want).abs();
                assert!(
                    err <= tol(want),
                    "{name}({x}) = {g}, want {want}, err {err:e}"
                );
                worst = worst.max(err);
            }
            eprintln!("{name}: worst abs err {worst:e}");
        }
    }

    #[test]
    fn vector_exp_is_accurate() {
        let xs = grid(-87.0, 88.0, 160_000);
        check(
            &xs,
            exp::<Avx512>,
            exp::<Avx2>,
            f64::exp,
            |w| 3e-7 * w,
            "exp",
        );
    }

    #[test]
    fn vector_erf_and_gelu_are_accurate() {
        let xs = grid(-9.0, 9.0, 160_000);
        let erf_ref = |x: f64| libm::erf(x);
        check(&xs, erf::<Avx512>, erf::<Avx2>, erf_ref, |_| 2e-7, "erf");
        let gelu_ref = |x: f64| x * 0.5 * (1.0 + libm::erf(x / std::f64::consts::SQRT_2));
        check(
            &xs,
            gelu::<Avx512>,
            gelu::<Avx2>,
            gelu_ref,
            |w| 2e-7 * w.abs().max(1.0),
            "gelu",
        );
        // and against the portable f32 GELU
        if let Some(got) = map_avx512(&xs, gelu::<Avx512>) {
            for (&x, &g) in xs.iter().zip(&got) {
                assert!(
                    (g - gelu_erf(x)).abs() <= 4e-7 * x.abs().max(1.0),
                    "gelu({x})"
                );
            }
        }
    }

    #[test]
    fn vector_gated_activation_is_accurate() {
        // σ(a)·tanh(a/2 − 1) over a grid (both arguments varying).
        fn g512(a: __m512) -> __m512 {
            // SAFETY: only called under the avx512 target feature by `map_avx512`.
            unsafe {
                gated::<Avx512>(
                    a,
                    Avx512::sub(Avx512::mul(a, Avx512::splat(0.5)), Avx512::splat(1.0)),
                )
            }
        }
        fn g256(a: __m256) -> __m256 {
            // SAFETY: only called under the avx2 target feature by `map_avx2`.
            unsafe {
                gated::<Avx2>(
                    a,
                    Avx2::sub(Avx2::mul(a, Avx2::splat(0.5)), Avx2::splat(1.0)),
                )
            }
        }
        let xs = grid(-100.0, 100.0, 80_000);
        let reference = |a: f64| (1.0 / (1.0 + (-a).exp())) * (a / 2.0 - 1.0).tanh();
        check(&xs, g512, g256, reference, |_| 3e-7, "gated");
    }
}
