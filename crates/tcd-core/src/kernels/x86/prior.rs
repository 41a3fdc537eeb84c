//! The prior's block update after its temporal FC: `state += LN(y)·g + β`, the layer norm of
//! every frame taken over the K coordinates. The sequences are (K × L), frame fastest, so one
//! frame's values are a column: the kernel reduces rows, with the frames in vector lanes (the
//! last `L mod W` frames as scalars), and the entry points for both instruction sets.

use super::simd::{Avx2, Avx512, Simd};
use crate::kernels::ColumnNorm;

/// One row's term of [`column_sum`]: the W values at `p`, or their squared distances from `centre`.
#[inline(always)]
unsafe fn term<S: Simd, const SQUARES: bool>(p: *const f32, centre: S::V) -> S::V {
    // SAFETY: p is valid for W floats (the caller's contract).
    unsafe {
        let v = S::load(p);
        if SQUARES {
            let d = S::sub(v, centre);
            S::mul(d, d)
        } else {
            v
        }
    }
}

/// Σ over the `k` rows (stride `l`) of the W frames at `y` of [`term`]. Four independent
/// accumulators (rows kk mod 4), so that the additions do not wait on each other. Plain functions,
/// no closures: a closure would be compiled without the entry point's CPU features.
#[inline(always)]
unsafe fn column_sum<S: Simd, const SQUARES: bool>(
    y: *const f32,
    k: usize,
    l: usize,
    centre: S::V,
) -> S::V {
    // SAFETY (whole body): y is valid for W floats at every row kk < k (the caller's frames j..j + W).
    unsafe {
        let mut acc = [S::zero(); 4];
        let mut kk = 0;
        while kk + 4 <= k {
            for (r, a) in acc.iter_mut().enumerate() {
                *a = S::add(*a, term::<S, SQUARES>(y.add((kk + r) * l), centre));
            }
            kk += 4;
        }
        for (r, a) in acc.iter_mut().enumerate().take(k - kk) {
            *a = S::add(*a, term::<S, SQUARES>(y.add((kk + r) * l), centre));
        }
        S::add(S::add(acc[0], acc[1]), S::add(acc[2], acc[3]))
    }
}

/// One sequence: `state`, `y` valid for K·L floats, `stats` for 2·L (means, then 1/std).
#[inline(always)]
unsafe fn sequence<S: Simd>(p: &ColumnNorm<'_>, state: *mut f32, y: *const f32, stats: *mut f32) {
    // SAFETY (whole body): the pointers are valid for the sizes above (checked by the dispatcher
    // `kernels::column_norm_residual`); vector accesses cover frames j..j + W ≤ L of a row only.
    unsafe {
        let (k, l) = (p.k, p.l);
        let vec_end = l - l % S::W;
        let (mean, rstd) = (stats, stats.add(l));
        let kf = k as f32;
        // Pass 1: means (frames in vector lanes; the last L mod W frames as scalars).
        let mut j = 0;
        while j < vec_end {
            let sum = column_sum::<S, false>(y.add(j), k, l, S::zero());
            S::store(mean.add(j), S::div(sum, S::splat(kf)));
            j += S::W;
        }
        for f in vec_end..l {
            *mean.add(f) = (0..k).map(|kk| *y.add(kk * l + f)).sum::<f32>() / kf;
        }
        // Pass 2: biased variance about the means → 1/std (one square root per frame).
        let mut j = 0;
        while j < vec_end {
            let sq = column_sum::<S, true>(y.add(j), k, l, S::load(mean.add(j)));
            S::store(rstd.add(j), sq);
            j += S::W;
        }
        for f in vec_end..l {
            let m = *mean.add(f);
            *rstd.add(f) = (0..k)
                .map(|kk| (*y.add(kk * l + f) - m) * (*y.add(kk * l + f) - m))
                .sum::<f32>();
        }
        for f in 0..l {
            *rstd.add(f) = 1.0 / (*rstd.add(f) / kf + p.eps).sqrt();
        }
        // Pass 3: state + ((y − mean)·rstd)·g + β, PyTorch's order.
        for kk in 0..k {
            let (row, out) = (y.add(kk * l), state.add(kk * l));
            let (g, b) = (p.weight[kk], p.bias[kk]);
            let (gv, bv) = (S::splat(g), S::splat(b));
            let mut j = 0;
            while j < vec_end {
                let t = S::mul(
                    S::sub(S::load(row.add(j)), S::load(mean.add(j))),
                    S::load(rstd.add(j)),
                );
                S::store(out.add(j), S::add(S::fma(t, gv, S::load(out.add(j))), bv));
                j += S::W;
            }
            for f in vec_end..l {
                let t = (*row.add(f) - *mean.add(f)) * *rstd.add(f);
                *out.add(f) = *out.add(f) + t * g + b;
            }
        }
    }
}

macro_rules! entry {
    ($simd:ty, $features:literal, $name:ident) => {
        /// Entry point: every sequence of `state` / `y` (sizes checked by
        /// [`crate::kernels::column_norm_residual`]).
        pub(in crate::kernels) fn $name(
            p: &ColumnNorm<'_>,
            state: &mut [f32],
            y: &[f32],
            stats: &mut [f32],
        ) {
            #[target_feature(enable = $features)]
            unsafe fn inner(p: &ColumnNorm<'_>, state: &mut [f32], y: &[f32], stats: &mut [f32]) {
                let size = p.k * p.l;
                for (s, yv) in state.chunks_exact_mut(size).zip(y.chunks_exact(size)) {
                    // SAFETY: each chunk holds K·L floats, stats 2·L (checked by the dispatcher).
                    unsafe { sequence::<$simd>(p, s.as_mut_ptr(), yv.as_ptr(), stats.as_mut_ptr()) }
                }
            }
            // SAFETY: reachable only through an `Isa` built after detecting these features.
            unsafe { inner(p, state, y, stats) }
        }
    };
}

entry!(Avx512, "avx512f,fma", column_norm_residual_avx512);
entry!(Avx2, "avx2,fma", column_norm_residual_avx2);
