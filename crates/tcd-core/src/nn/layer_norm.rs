//! LayerNorm over the channel dimension (PyTorch `nn.LayerNorm`: biased variance, eps inside the
//! square root).

use crate::error::{Error, Result};
use crate::weights::Weights;

/// LayerNorm with an affine weight and bias of width `dim`.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerNorm {
    weight: Vec<f32>,
    bias: Vec<f32>,
    eps: f32,
}

impl LayerNorm {
    /// From weight and bias of equal length.
    pub fn new(weight: Vec<f32>, bias: Vec<f32>, eps: f64) -> Result<Self> {
        if weight.len() != bias.len() {
            return Err(Error::invalid_input(
                "bias",
                format!("{} values (the weight's length)", weight.len()),
                format!("{} values", bias.len()),
            ));
        }
        Ok(LayerNorm {
            weight,
            bias,
            eps: eps as f32,
        })
    }

    /// Loads `{prefix}.weight` / `{prefix}.bias`, each (dim).
    pub fn load(w: &mut Weights<'_>, prefix: &str, dim: usize, eps: f64) -> Result<Self> {
        let weight = w.take(&format!("{prefix}.weight"), &[dim])?;
        let bias = w.take(&format!("{prefix}.bias"), &[dim])?;
        Self::new(weight, bias, eps)
    }

    /// The affine weight (dim).
    pub fn weight(&self) -> &[f32] {
        &self.weight
    }

    /// The affine bias (dim).
    pub fn bias(&self) -> &[f32] {
        &self.bias
    }

    /// Epsilon (as f32, the precision it is applied in).
    pub fn eps(&self) -> f32 {
        self.eps
    }

    /// Normalises every row of `x` (rows × dim) in place:
    /// `y = (x − mean) / sqrt(var + eps) · weight + bias`, var biased (divided by dim).
    pub fn forward_inplace(&self, x: &mut [f32]) {
        let dim = self.weight.len();
        if dim == 0 {
            return;
        }
        let inv_n = 1.0 / dim as f32;
        for row in x.chunks_exact_mut(dim) {
            let mean = row.iter().sum::<f32>() * inv_n;
            let var = row.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() * inv_n;
            let rstd = 1.0 / (var + self.eps).sqrt();
            for ((v, &g), &b) in row.iter_mut().zip(&self.weight).zip(&self.bias) {
                *v = (*v - mean) * rstd * g + b;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_checked_values() {
        // x = [1, 2, 3, 4]: mean 2.5, biased var 1.25.
        let ln = LayerNorm::new(vec![1.0, 2.0, 1.0, 1.0], vec![0.0, 0.0, 0.5, 0.0], 1e-5).unwrap();
        let mut x = [1.0f32, 2.0, 3.0, 4.0, 5.0, 5.0, 5.0, 5.0];
        ln.forward_inplace(&mut x);
        let rstd = 1.0 / (1.25f64 + 1e-5).sqrt();
        let want = [-1.5 * rstd, 2.0 * -0.5 * rstd, 0.5 * rstd + 0.5, 1.5 * rstd];
        for (a, b) in x[..4].iter().zip(want) {
            assert!((*a as f64 - b).abs() < 1e-6, "{a} vs {b}");
        }
        // a constant row normalises to the bias
        assert_eq!(&x[4..], &[0.0, 0.0, 0.5, 0.0]);
        assert!(LayerNorm::new(vec![1.0], vec![], 1e-5).is_err());
    }
}
