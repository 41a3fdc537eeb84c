//! The packed GEMM `y = epilogue(x · W + b)`: a register-tiled micro-kernel of up to [`MR`] rows ×
//! one panel of 1, 2 or 4 vectors, bias, ReLU, GELU and residual-add epilogues fused.

use super::math::gelu;
use super::simd::Simd;
use crate::kernels::{Epilogue, Packed};

/// Rows per GEMM register tile.
const MR: usize = 6;

/// One panel of packed weights as the micro-kernel reads it: `depth` (= in_dim) rows of the
/// panel's pw floats from `weights`, pw biases from `bias`; its first `width` columns are outputs.
#[derive(Clone, Copy)]
struct Panel {
    weights: *const f32,
    bias: *const f32,
    depth: usize,
    width: usize,
}

/// One register tile: M rows (M ≤ MR) × one panel of NV vectors.
#[inline(always)]
unsafe fn tile<S: Simd, const NV: usize, const M: usize>(
    x: *const f32,
    ldx: usize,
    panel: Panel,
    y: *mut f32,
    ldy: usize,
    epi: Epilogue,
) {
    let Panel {
        weights,
        bias,
        depth: k,
        width,
    } = panel;
    // SAFETY (whole body): x is valid for M rows of k floats at stride ldx, weights for k × NV·W
    // floats, bias for NV·W floats, y for M rows of `width` floats at stride ldy (checked by the
    // dispatcher and `gemm`); full-vector stores happen only where `width` covers the vector.
    unsafe {
        let pw = NV * S::W;
        let b: [S::V; NV] = std::array::from_fn(|v| S::load(bias.add(v * S::W)));
        let mut acc = [b; M];
        for i in 0..k {
            let wp = weights.add(i * pw);
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
                    let out = if epi == Epilogue::AddTo {
                        S::add(S::load(yp), val)
                    } else {
                        val
                    };
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
            let c0 = p * pw;
            let panel = Panel {
                weights: w.w.as_ptr().add(p * k * pw),
                bias: w.b.as_ptr().add(p * pw),
                depth: k,
                width: pw.min(w.out_dim - c0),
            };
            let mut r = 0;
            while r + MR <= rows {
                tile::<S, NV, MR>(x.add(r * ldx), ldx, panel, y.add(r * ldy + c0), ldy, epi);
                r += MR;
            }
            let (xr, yr) = (x.add(r * ldx), y.add(r * ldy + c0));
            match rows - r {
                1 => tile::<S, NV, 1>(xr, ldx, panel, yr, ldy, epi),
                2 => tile::<S, NV, 2>(xr, ldx, panel, yr, ldy, epi),
                3 => tile::<S, NV, 3>(xr, ldx, panel, yr, ldy, epi),
                4 => tile::<S, NV, 4>(xr, ldx, panel, yr, ldy, epi),
                5 => tile::<S, NV, 5>(xr, ldx, panel, yr, ldy, epi),
                _ => {}
            }
        }
    }
}

#[inline(always)]
pub(super) unsafe fn gemm<S: Simd>(
    x: *const f32,
    ldx: usize,
    rows: usize,
    w: &Packed,
    y: *mut f32,
    ldy: usize,
    epi: Epilogue,
) {
    // SAFETY: forwarded contract of `gemm_nv`; the panel width selects the instantiation.
    unsafe {
        match w.pw / S::W {
            4 => gemm_nv::<S, 4>(x, ldx, rows, w, y, ldy, epi),
            2 => gemm_nv::<S, 2>(x, ldx, rows, w, y, ldy, epi),
            _ => gemm_nv::<S, 1>(x, ldx, rows, w, y, ldy, epi),
        }
    }
}
