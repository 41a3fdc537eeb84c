//! x86-64 SIMD kernels (AVX-512F + FMA and AVX2 + FMA) written once, generically over a small
//! vector trait [`simd::Simd`], and instantiated inside `#[target_feature]` entry points.
//!
//! Every generic function in these files is `#[inline(always)]`, so that it is compiled into the
//! `#[target_feature]` entry point that calls it and the intrinsics inline into it.
//!
//! Soundness: the entry points (`*_avx2`, `*_avx512`) are safe functions that are only reachable
//! through [`super::Isa`] values, which exist only after runtime detection of the features; the
//! dispatchers in `super` check every size and stride against the slices before calling them, so
//! the raw-pointer arithmetic in these files stays inside the slices.
//!
//! Files: `simd` (the vector trait and its AVX-512 / AVX2 implementations), `math` (exp, erf,
//! GELU, gated activation), `gemm` (packed GEMM micro-kernel), `attention` (fused attention),
//! `encoder` (LayerNorm and the encoder layer), `tail` (residual-block tail), `prior` (the prior's
//! layer norm over the rows of each column, with its own entry points); this file holds the
//! `#[target_feature]` entry points the dispatchers call.
#![allow(unsafe_code)]

use rayon::prelude::*;

use super::{
    Epilogue, FastEncoder, FastScratch, Matrix, MatrixMut, Packed, SeqLayout, TailInputs,
    TailStreams,
};
use encoder::encoder;
use gemm::gemm;
use simd::{Avx2, Avx512};
use tail::tail;

mod attention;
mod encoder;
mod gemm;
mod math;
mod prior;
mod simd;
mod tail;

pub(super) use prior::{column_norm_residual_avx2, column_norm_residual_avx512};

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
        pub(super) fn $encoder_par(
            e: &FastEncoder,
            x: &mut [f32],
            layout: SeqLayout,
            scratch: &mut [FastScratch],
        ) {
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

        /// GEMM entry point (shapes, strides and sizes checked by [`super::gemm`]).
        pub(super) fn $gemm(x: Matrix<'_>, w: &Packed, y: MatrixMut<'_>, epi: Epilogue) {
            #[target_feature(enable = $features)]
            unsafe fn inner(x: Matrix<'_>, w: &Packed, y: MatrixMut<'_>, epi: Epilogue) {
                // SAFETY: shapes, strides and sizes checked by the dispatcher.
                unsafe {
                    gemm::<$simd>(
                        x.data.as_ptr(),
                        x.ld,
                        x.rows,
                        w,
                        y.data.as_mut_ptr(),
                        y.ld,
                        epi,
                    )
                }
            }
            // SAFETY: reachable only through an `Isa` built after detecting these features.
            unsafe { inner(x, w, y, epi) }
        }

        /// Encoder-layer entry point (sizes checked by [`super::fast::encoder`]).
        pub(super) fn $encoder(
            e: &FastEncoder,
            x: &mut [f32],
            layout: SeqLayout,
            sc: &mut FastScratch,
        ) {
            #[target_feature(enable = $features)]
            unsafe fn inner(
                e: &FastEncoder,
                x: &mut [f32],
                layout: SeqLayout,
                sc: &mut FastScratch,
            ) {
                // SAFETY: sizes and strides checked by the dispatcher.
                unsafe { encoder::<$simd>(e, x.as_mut_ptr(), layout, sc) }
            }
            // SAFETY: reachable only through an `Isa` built after detecting these features.
            unsafe { inner(e, x, layout, sc) }
        }

        /// Residual-block tail entry point (sizes checked by [`super::block_tail`]).
        pub(super) fn $tail(
            inp: &TailInputs<'_>,
            k0: usize,
            streams: TailStreams<'_>,
            sc: &mut FastScratch,
        ) {
            #[target_feature(enable = $features)]
            unsafe fn inner(
                inp: &TailInputs<'_>,
                k0: usize,
                streams: TailStreams<'_>,
                sc: &mut FastScratch,
            ) {
                // SAFETY: sizes checked by the dispatcher.
                unsafe { tail::<$simd>(inp, k0, streams, sc) }
            }
            // SAFETY: reachable only through an `Isa` built after detecting these features.
            unsafe { inner(inp, k0, streams, sc) }
        }
    };
}

entries!(
    Avx512,
    "avx512f,fma",
    gemm_avx512,
    encoder_avx512,
    encoder_par_avx512,
    tail_avx512
);
entries!(
    Avx2,
    "avx2,fma",
    gemm_avx2,
    encoder_avx2,
    encoder_par_avx2,
    tail_avx2
);

#[cfg(test)]
mod tests {
    use std::path::Path;

    /// x86 estimate instructions whose results the architecture leaves to the implementation: Intel and
    /// AMD return different bits for them (issue 27: the avx2 golden table differed on a Xeon). AVX-512's
    /// `rcp14`/`rsqrt14` are specified exactly and are not on the list. Built from parts so that this
    /// file holds none of the names and is scanned like the others.
    fn implementation_defined() -> Vec<String> {
        let mut names = Vec::new();
        for width in ["_mm_", "_mm256_"] {
            for op in ["rcp_ps", "rcp_ss", "rsqrt_ps", "rsqrt_ss"] {
                names.push(format!("{width}{op}"));
            }
        }
        names
    }

    fn rust_sources(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                rust_sources(&path, out);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
            }
        }
    }

    /// Same kernel path, same bits on every CPU that runs it: no kernel source (the whole crate, so that
    /// a new kernel file is covered too) calls an implementation-defined estimate.
    #[test]
    fn no_implementation_defined_estimates() {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        let mut files = Vec::new();
        rust_sources(&src, &mut files);
        assert!(
            files.iter().any(|f| f.ends_with("kernels/x86/simd.rs")),
            "the scan missed simd.rs"
        );
        let names = implementation_defined();
        let mut found = Vec::new();
        for f in &files {
            let text = std::fs::read_to_string(f).unwrap();
            for name in &names {
                // a whole identifier, not the start of a longer one
                let hit = text.match_indices(name).any(|(i, _)| {
                    let next = text[i + name.len()..].chars().next();
                    !next.is_some_and(|c| c.is_alphanumeric() || c == '_')
                });
                if hit {
                    found.push(format!("{}: {name}", f.display()));
                }
            }
        }
        assert!(
            found.is_empty(),
            "implementation-defined estimates in the kernels: {found:?}"
        );
    }
}
