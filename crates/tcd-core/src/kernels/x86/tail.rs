//! The residual-block tail, one coordinate (L tokens) at a time so that no N × 2C tensor is
//! materialised: mid projection, cond add, gated activation, output projection, residual / skip
//! update and the next block's step bias.

use super::gemm::gemm;
use super::math::gated;
use super::simd::Simd;
use crate::kernels::{Epilogue, FastScratch, TailInputs, TailStreams};
use crate::nn::activation::sigmoid;

/// z + (time table + feature table + m · mask column) at column `i` (a function, not a closure:
/// see [`super::attention::score_key`]).
#[inline(always)]
unsafe fn zc<S: Simd>(
    z: *const f32,
    tt: *const f32,
    ft: *const f32,
    cm: *const f32,
    mv: S::V,
    i: usize,
) -> S::V {
    // SAFETY: each pointer is valid for i + W floats (caller).
    unsafe {
        S::add(
            S::load(z.add(i)),
            S::fma(
                mv,
                S::load(cm.add(i)),
                S::add(S::load(tt.add(i)), S::load(ft.add(i))),
            ),
        )
    }
}

/// [`crate::kernels::block_tail`] on the coordinates `k0..` whose streams are given.
#[inline(always)]
pub(super) unsafe fn tail<S: Simd>(
    inp: &TailInputs<'_>,
    k0: usize,
    streams: TailStreams<'_>,
    sc: &mut FastScratch,
) {
    let (frames, c) = (inp.frames, inp.channels);
    let nk = streams.h.len() / (frames * c);
    let (y, h, skip) = (
        streams.y.as_mut_ptr(),
        streams.h.as_mut_ptr(),
        streams.skip.as_mut_ptr(),
    );
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
                    let (a0, f0) = (
                        zc::<S>(z, tt, ft, cm, mv, i),
                        zc::<S>(z, tt, ft, cm, mv, c + i),
                    );
                    let (a1, f1) = (
                        zc::<S>(z, tt, ft, cm, mv, i + w),
                        zc::<S>(z, tt, ft, cm, mv, c + i + w),
                    );
                    let (g0, g1) = (gated::<S>(a0, f0), gated::<S>(a1, f1));
                    S::store(g.add(i), g0);
                    S::store(g.add(i + w), g1);
                    i += 2 * w;
                }
                while i + w <= c {
                    S::store(
                        g.add(i),
                        gated::<S>(
                            zc::<S>(z, tt, ft, cm, mv, i),
                            zc::<S>(z, tt, ft, cm, mv, c + i),
                        ),
                    );
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
