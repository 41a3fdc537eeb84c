//! A dense layer on whichever kernel a model was loaded with: the portable [`Linear`] (the reference)
//! or its weights packed for the SIMD GEMM. The prior forecaster and the sample generator run their
//! layers on it; the denoiser has its own fused paths (`crate::denoiser`).

use super::activation::{gelu_erf, map_inplace};
use super::Linear;
use crate::error::Result;
use crate::kernels::{self, Epilogue, FastLinear, Isa, Kernel, Matrix, MatrixMut};

/// A dense layer `y = x · Wᵀ + b` on the kernel chosen at load: the portable [`Linear`], or its
/// weights packed for the SIMD GEMM.
///
/// Every row is computed the same way whichever rows share the call (both kernels run each row's
/// sums in one fixed order), so a model that cuts its batch into tiles of rows gets results that do
/// not depend on the thread count or the tile size.
#[derive(Clone, Debug)]
pub(crate) struct Dense {
    linear: Linear,
    fast: Option<(Isa, FastLinear)>,
}

/// Resolves `kernel` (`Auto`: the best this CPU supports; an error if the CPU does not support it) and packs
/// every one of `layers` for it, once: the kernel resolved and its instruction set (`None`: portable).
pub(crate) fn pack_all<'a>(
    kernel: Kernel,
    layers: impl IntoIterator<Item = &'a mut Dense>,
) -> Result<(Kernel, Option<Isa>)> {
    let kernel = kernel.resolve()?;
    let isa = Isa::for_kernel(kernel);
    for d in layers {
        d.pack(isa);
    }
    Ok((kernel, isa))
}

impl Dense {
    pub(crate) fn new(linear: Linear) -> Dense {
        Dense { linear, fast: None }
    }

    /// Packs the weights for `isa` (`None`: the portable kernel).
    pub(crate) fn pack(&mut self, isa: Option<Isa>) {
        self.fast = isa.map(|isa| (isa, FastLinear::new(isa, &self.linear)));
    }

    /// `y = x · Wᵀ + b` for `rows` rows: x (rows × in), y (rows × out), both dense.
    pub(crate) fn forward(&self, x: &[f32], y: &mut [f32], rows: usize) {
        self.run(x, y, rows, Epilogue::Store);
    }

    /// `y = gelu_erf(x · Wᵀ + b)` (PyTorch's exact GELU), fused into the SIMD GEMM.
    pub(crate) fn forward_gelu(&self, x: &[f32], y: &mut [f32], rows: usize) {
        self.run(x, y, rows, Epilogue::Gelu);
    }

    /// `y = epi(x · Wᵀ + b)`, `epi` [`Epilogue::Store`] or [`Epilogue::Gelu`] (the two the portable path
    /// applies after its GEMM).
    fn run(&self, x: &[f32], y: &mut [f32], rows: usize, epi: Epilogue) {
        let (n_in, n_out) = (self.linear.in_dim(), self.linear.out_dim());
        let (x, y) = (&x[..rows * n_in], &mut y[..rows * n_out]);
        match &self.fast {
            Some((isa, packed)) => kernels::gemm(
                *isa,
                Matrix::dense(x, rows, n_in),
                packed,
                MatrixMut::dense(y, rows, n_out),
                epi,
            ),
            None => {
                self.linear.forward(x, y);
                if epi == Epilogue::Gelu {
                    map_inplace(y, gelu_erf);
                }
            }
        }
    }
}
