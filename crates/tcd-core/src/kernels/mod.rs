//! Compute-kernel selection and the fast (SIMD) forward path.
//!
//! The portable Rust code in [`crate::nn`] is the reference implementation and runs everywhere.
//! On x86-64, hand-written kernels with `std::arch` intrinsics (AVX-512F + FMA, or AVX2 + FMA)
//! are selected once, when a model is loaded, by runtime CPU-feature detection:
//!
//! * weights are packed at load into column panels of 64 (AVX-512) or 16 (AVX2) outputs, the
//!   width of the register-tiled GEMM micro-kernel (6 rows × panel), with bias, ReLU, exact-erf
//!   GELU and residual-add epilogues fused;
//! * attention for head dimensions 4, 8 and 16 is one fused kernel: 16 (or 8) queries per vector
//!   register, keys streamed, max / exp / sum / P·V in registers;
//! * the residual-block tail (mid projection, cond add, gated activation, output projection,
//!   residual / skip update, next block's step bias) runs one coordinate (L tokens) at a time so
//!   that no N × 2C tensor is materialised.
//!
//! Which kernel runs is chosen by [`Kernel`]: `Auto` (the best the CPU supports) unless the
//! environment variable **`TCD_KERNEL`** (`portable`, `avx2`, `avx512` or `auto`) says otherwise
//! when the model is loaded, or the caller asks for one with
//! [`crate::Denoiser::with_kernel`]. The fast paths agree with the portable one to ~1e-6 (FMA
//! rounding, polynomial exp / erf accurate to ~1e-7); see `tests/kernels.rs`.
//!
//! Files: this one chooses the kernel ([`Kernel`], CPU-feature detection); `fast.rs` holds the
//! packed weights, scratch, layouts and the checked dispatchers; `x86/` the SIMD kernels.

use std::fmt;
use std::str::FromStr;

use crate::error::{Error, Result};

mod fast;
#[cfg(target_arch = "x86_64")]
mod x86;

pub(crate) use fast::{
    block_tail, column_norm_residual, encoder_par, gemm, ColumnNorm, Epilogue, FastEncoder,
    FastLinear, FastScratch, Matrix, MatrixMut, Packed, SeqLayout, TailInputs, TailStreams,
};

/// The environment variable read at load time to choose the kernel.
pub const KERNEL_ENV: &str = "TCD_KERNEL";

/// Which compute kernels a [`crate::Denoiser`] runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Kernel {
    /// The best kernel this CPU supports (AVX-512 → AVX2 → portable).
    #[default]
    Auto,
    /// The portable Rust reference implementation (any target).
    Portable,
    /// x86-64 AVX2 + FMA intrinsics.
    Avx2,
    /// x86-64 AVX-512F + FMA intrinsics.
    Avx512,
}

impl Kernel {
    /// Every concrete kernel (not `Auto`), slowest first.
    pub const ALL: [Kernel; 3] = [Kernel::Portable, Kernel::Avx2, Kernel::Avx512];

    /// The name used by `TCD_KERNEL` and [`FromStr`].
    pub fn name(self) -> &'static str {
        match self {
            Kernel::Auto => "auto",
            Kernel::Portable => "portable",
            Kernel::Avx2 => "avx2",
            Kernel::Avx512 => "avx512",
        }
    }

    /// Whether this CPU can run the kernel (`Auto` and `Portable` always can).
    pub fn is_supported(self) -> bool {
        match self {
            Kernel::Auto | Kernel::Portable => true,
            Kernel::Avx2 => Isa::avx2().is_some(),
            Kernel::Avx512 => Isa::avx512().is_some(),
        }
    }

    /// The concrete kernels this CPU supports, slowest first (always starts with `Portable`).
    pub fn supported() -> Vec<Kernel> {
        Self::ALL.into_iter().filter(|k| k.is_supported()).collect()
    }

    /// `Auto` → the best supported kernel; a concrete kernel → itself if supported, else an error.
    pub fn resolve(self) -> Result<Kernel> {
        match self {
            Kernel::Auto => Ok(*Self::supported().last().unwrap_or(&Kernel::Portable)),
            k if k.is_supported() => Ok(k),
            k => Err(Error::invalid_input(
                "kernel",
                format!(
                    "a kernel this CPU supports ({})",
                    Self::supported()
                        .iter()
                        .map(|k| k.name())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
                format!("{:?}", k.name()),
            )),
        }
    }

    /// The kernel requested by `TCD_KERNEL` (`Auto` when unset or empty); an unknown value is an
    /// error naming the variable.
    pub fn from_env() -> Result<Kernel> {
        match std::env::var(KERNEL_ENV) {
            Ok(v) if !v.trim().is_empty() => v.parse().map_err(|_| {
                Error::invalid_input(
                    KERNEL_ENV,
                    "one of \"auto\", \"portable\", \"avx2\", \"avx512\"",
                    format!("{v:?}"),
                )
            }),
            _ => Ok(Kernel::Auto),
        }
    }
}

impl fmt::Display for Kernel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Kernel {
    type Err = Error;
    fn from_str(s: &str) -> Result<Kernel> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(Kernel::Auto),
            "portable" => Ok(Kernel::Portable),
            "avx2" => Ok(Kernel::Avx2),
            "avx512" | "avx-512" => Ok(Kernel::Avx512),
            _ => Err(Error::invalid_input(
                "kernel",
                "one of \"auto\", \"portable\", \"avx2\", \"avx512\"",
                format!("{s:?}"),
            )),
        }
    }
}

/// A detected SIMD instruction set. Values exist only after the CPU was checked to support them
/// (the constructors detect), which is what makes calling the `#[target_feature]` kernels sound.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Isa(IsaKind);

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum IsaKind {
    #[cfg(target_arch = "x86_64")]
    Avx2,
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl Isa {
    fn avx2() -> Option<Isa> {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                return Some(Isa(IsaKind::Avx2));
            }
        }
        None
    }

    fn avx512() -> Option<Isa> {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("fma")
            {
                return Some(Isa(IsaKind::Avx512));
            }
        }
        None
    }

    /// The instruction set of a resolved kernel (`None` for portable).
    pub(crate) fn for_kernel(kernel: Kernel) -> Option<Isa> {
        match kernel {
            Kernel::Auto => Self::avx512().or_else(Self::avx2),
            Kernel::Portable => None,
            Kernel::Avx2 => Self::avx2(),
            Kernel::Avx512 => Self::avx512(),
        }
    }

    /// f32 lanes per vector register.
    pub(crate) fn lanes(self) -> usize {
        match self.0 {
            #[cfg(target_arch = "x86_64")]
            IsaKind::Avx2 => 8,
            #[cfg(target_arch = "x86_64")]
            IsaKind::Avx512 => 16,
        }
    }

    /// Vectors per GEMM panel for an output width: the widest panel ≤ 4 vectors (AVX-512) or
    /// 2 (AVX2) that the output fills at least half of.
    fn panel_vectors(self, out_dim: usize) -> usize {
        let w = self.lanes();
        let max = if w == 16 { 4 } else { 2 };
        let mut nv = 1;
        while nv < max && out_dim > nv * w {
            nv *= 2;
        }
        nv
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip() {
        for k in [Kernel::Auto, Kernel::Portable, Kernel::Avx2, Kernel::Avx512] {
            assert_eq!(k.name().parse::<Kernel>().unwrap(), k);
            assert_eq!(k.to_string(), k.name());
        }
        assert!("sse".parse::<Kernel>().is_err());
        assert_eq!(" AVX512 ".parse::<Kernel>().unwrap(), Kernel::Avx512);
    }

    #[test]
    fn resolve_and_support() {
        let s = Kernel::supported();
        assert_eq!(s[0], Kernel::Portable);
        let best = Kernel::Auto.resolve().unwrap();
        assert_eq!(best, *s.last().unwrap());
        assert_eq!(Kernel::Portable.resolve().unwrap(), Kernel::Portable);
        for k in [Kernel::Avx2, Kernel::Avx512] {
            assert_eq!(k.resolve().is_ok(), k.is_supported());
        }
        assert_eq!(Isa::for_kernel(Kernel::Portable), None);
    }

    #[test]
    fn panel_widths() {
        if let Some(isa) = Isa::avx512() {
            assert_eq!(isa.panel_vectors(192), 4);
            assert_eq!(isa.panel_vectors(64), 4);
            assert_eq!(isa.panel_vectors(32), 2);
            assert_eq!(isa.panel_vectors(16), 1);
            assert_eq!(isa.panel_vectors(33), 4);
        }
        if let Some(isa) = Isa::avx2() {
            assert_eq!(isa.panel_vectors(64), 2);
            assert_eq!(isa.panel_vectors(8), 1);
        }
    }
}
