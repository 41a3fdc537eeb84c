//! `y = x · Wᵀ + b` on token-major rows: PyTorch's `nn.Linear`, and `nn.Conv1d` with kernel 1
//! (the same operation once the activations are token-major).

use crate::error::{Error, Result};
use crate::weights::Weights;

/// Output columns per packed panel (register-tile width of the portable kernel).
const NR: usize = 8;
/// Rows per register tile of the portable kernel.
const MR: usize = 4;

/// A dense layer with its weight packed once at load time for `y = x · Wᵀ + b`:
/// Wᵀ (in, out) is cut into panels of NR = 8 output columns, each panel stored contiguously as
/// (in × NR) (the last panel zero-padded), so the kernel streams one panel per register tile.
#[derive(Clone, Debug, PartialEq)]
pub struct Linear {
    in_dim: usize,
    out_dim: usize,
    /// ceil(out/NR) panels of (in × NR).
    packed: Vec<f32>,
    /// The bias, zero-padded to a whole number of panels.
    bias: Vec<f32>,
}

impl Linear {
    /// From a PyTorch weight of shape (out, in) (or (out, in, 1) for a 1×1 conv; same memory) and
    /// a bias of length `out`.
    pub fn from_torch(out_dim: usize, in_dim: usize, weight: &[f32], bias: &[f32]) -> Result<Self> {
        if out_dim == 0 || in_dim == 0 {
            return Err(Error::invalid_input(
                "weight",
                "a non-empty (out, in) matrix",
                format!("shape ({out_dim}, {in_dim})"),
            ));
        }
        if weight.len() != out_dim * in_dim {
            return Err(Error::invalid_input(
                "weight",
                format!("{} values (shape ({out_dim}, {in_dim}))", out_dim * in_dim),
                format!("{} values", weight.len()),
            ));
        }
        if bias.len() != out_dim {
            return Err(Error::invalid_input(
                "bias",
                format!("{out_dim} values"),
                format!("{} values", bias.len()),
            ));
        }
        let panels = out_dim.div_ceil(NR);
        let mut packed = vec![0.0f32; panels * in_dim * NR];
        for (o, row) in weight.chunks_exact(in_dim.max(1)).enumerate() {
            let (p, j) = (o / NR, o % NR);
            for (i, &w) in row.iter().enumerate() {
                packed[(p * in_dim + i) * NR + j] = w;
            }
        }
        let mut padded = vec![0.0f32; panels * NR];
        padded[..out_dim].copy_from_slice(bias);
        Ok(Linear {
            in_dim,
            out_dim,
            packed,
            bias: padded,
        })
    }

    /// `{prefix}.weight` (out, in) and `{prefix}.bias` (out): PyTorch's `nn.Linear`.
    pub fn load(w: &mut Weights<'_>, prefix: &str, out_dim: usize, in_dim: usize) -> Result<Self> {
        Self::load_shaped(w, prefix, &[out_dim, in_dim])
    }

    /// `{prefix}.weight` (out, in, 1) and `{prefix}.bias` (out): PyTorch's `nn.Conv1d` with kernel 1.
    pub fn load_conv(
        w: &mut Weights<'_>,
        prefix: &str,
        out_dim: usize,
        in_dim: usize,
    ) -> Result<Self> {
        Self::load_shaped(w, prefix, &[out_dim, in_dim, 1])
    }

    fn load_shaped(w: &mut Weights<'_>, prefix: &str, shape: &[usize]) -> Result<Self> {
        let weight = w.take(&format!("{prefix}.weight"), shape)?;
        let bias = w.take(&format!("{prefix}.bias"), &shape[..1])?;
        Self::from_torch(shape[0], shape[1], &weight, &bias)
    }

    /// Input width.
    pub fn in_dim(&self) -> usize {
        self.in_dim
    }

    /// Output width.
    pub fn out_dim(&self) -> usize {
        self.out_dim
    }

    /// The bias (out).
    pub fn bias(&self) -> &[f32] {
        &self.bias[..self.out_dim]
    }

    /// W\[o\]\[i\] (PyTorch's indexing), for inspection; 0 outside the shape.
    pub fn weight(&self, o: usize, i: usize) -> f32 {
        if o >= self.out_dim || i >= self.in_dim {
            return 0.0;
        }
        self.packed[((o / NR) * self.in_dim + i) * NR + o % NR]
    }

    /// `y[r] = x[r] · Wᵀ + b` for every row r of `x` (rows × in) into `y` (rows × out).
    /// Processes as many whole rows as both buffers hold. For every output the sum runs over the
    /// inputs in order, starting from the bias.
    pub fn forward(&self, x: &[f32], y: &mut [f32]) {
        let (n_in, n_out) = (self.in_dim, self.out_dim);
        let rows = (x.len() / n_in.max(1)).min(y.len() / n_out);
        let mut r = 0;
        while r + MR <= rows {
            self.tile::<MR>(x, y, r);
            r += MR;
        }
        while r < rows {
            self.tile::<1>(x, y, r);
            r += 1;
        }
    }

    /// M rows starting at `r0`, all panels.
    #[inline]
    fn tile<const M: usize>(&self, x: &[f32], y: &mut [f32], r0: usize) {
        let (n_in, n_out) = (self.in_dim, self.out_dim);
        let xs: [&[f32]; M] = std::array::from_fn(|m| &x[(r0 + m) * n_in..(r0 + m + 1) * n_in]);
        for (p, (panel, bias)) in self
            .packed
            .chunks_exact(n_in * NR)
            .zip(self.bias.chunks_exact(NR))
            .enumerate()
        {
            let mut acc = [[0.0f32; NR]; M];
            for a in acc.iter_mut() {
                a.copy_from_slice(bias);
            }
            for (i, w) in panel.chunks_exact(NR).enumerate() {
                let w: [f32; NR] = std::array::from_fn(|j| w[j]);
                for m in 0..M {
                    let xv = xs[m][i];
                    for j in 0..NR {
                        acc[m][j] += xv * w[j];
                    }
                }
            }
            let c0 = p * NR;
            let width = NR.min(n_out - c0);
            for (m, a) in acc.iter().enumerate() {
                let o = (r0 + m) * n_out + c0;
                y[o..o + width].copy_from_slice(&a[..width]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_naive_xwt_plus_b() {
        // W (out=3, in=2), x (rows=2, in=2)
        let w = [1.0, 2.0, -1.0, 0.5, 3.0, -2.0];
        let b = [0.1, 0.2, 0.3];
        let lin = Linear::from_torch(3, 2, &w, &b).unwrap();
        let x = [1.0, -1.0, 2.0, 4.0];
        let mut y = [0.0; 6];
        lin.forward(&x, &mut y);
        for r in 0..2 {
            for o in 0..3 {
                let want = b[o] + x[r * 2] * w[o * 2] + x[r * 2 + 1] * w[o * 2 + 1];
                assert!((y[r * 3 + o] - want).abs() < 1e-6);
                assert_eq!(lin.weight(o, 1), w[o * 2 + 1]);
            }
        }
        assert_eq!(lin.bias(), &b);
        assert!(Linear::from_torch(3, 2, &w[..5], &b).is_err());
        assert!(Linear::from_torch(3, 2, &w, &b[..2]).is_err());
    }

    #[test]
    fn tiles_and_tails_match_naive() {
        // rows not a multiple of MR, outputs not a multiple of NR
        for (rows, n_in, n_out) in [(7usize, 5usize, 19usize), (4, 3, 8), (1, 1, 1), (9, 16, 24)] {
            let w: Vec<f32> = (0..n_out * n_in)
                .map(|i| ((i * 7 % 13) as f32 - 6.0) * 0.1)
                .collect();
            let b: Vec<f32> = (0..n_out).map(|i| i as f32 * 0.01).collect();
            let x: Vec<f32> = (0..rows * n_in)
                .map(|i| ((i * 5 % 11) as f32 - 5.0) * 0.2)
                .collect();
            let lin = Linear::from_torch(n_out, n_in, &w, &b).unwrap();
            let mut y = vec![f32::NAN; rows * n_out];
            lin.forward(&x, &mut y);
            for r in 0..rows {
                for o in 0..n_out {
                    let mut want = b[o];
                    for i in 0..n_in {
                        want += x[r * n_in + i] * w[o * n_in + i];
                    }
                    assert_eq!(
                        y[r * n_out + o],
                        want,
                        "rows={rows} in={n_in} out={n_out} r={r} o={o}"
                    );
                }
            }
        }
    }
}
