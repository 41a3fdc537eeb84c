//! The two fixed sinusoidal tables of the model, computed in f32 exactly as the PyTorch side builds
//! them (`training/model.py`), with libm-independent rounding: every transcendental is evaluated in
//! f64 and rounded once to f32 (a correctly rounded result wherever PyTorch's own is, and at most
//! one ulp away elsewhere).

/// Diffusion-step table, (num_steps × dim) row-major: row t = `[sin(t·f_j)]_j ++ [cos(t·f_j)]_j`,
/// f_j = 10^(4·j / (dim/2 − 1)), j = 0..dim/2. As in PyTorch, `t·f_j` is an f32 product of f32s.
pub fn step_embedding_table(num_steps: usize, dim: usize) -> Vec<f32> {
    let half = dim / 2;
    let denom = half.saturating_sub(1).max(1) as f32;
    // torch: 10.0 ** (arange(half) / (half - 1) * 4.0), all f32
    let freqs: Vec<f32> = (0..half)
        .map(|j| {
            let e = j as f32 / denom * 4.0f32;
            10f64.powf(e as f64) as f32
        })
        .collect();
    let mut table = vec![0.0f32; num_steps * dim];
    for (t, row) in table.chunks_exact_mut(dim.max(1)).enumerate() {
        for (j, &f) in freqs.iter().enumerate() {
            let arg = t as f32 * f;
            row[j] = (arg as f64).sin() as f32;
            row[half + j] = (arg as f64).cos() as f32;
        }
    }
    table
}

/// Frame-position embedding, (length × dim) row-major: `pe[pos, 2i] = sin(pos·div_i)`,
/// `pe[pos, 2i+1] = cos(pos·div_i)`, `div_i = exp(2i · (−ln(10000)/dim))` in f32
/// (torch: `exp(arange(0, dim, 2).float() * -(math.log(10000.0) / dim))`).
pub fn frame_embedding(length: usize, dim: usize) -> Vec<f32> {
    let coef = (-(10000f64.ln() / dim as f64)) as f32;
    let div: Vec<f32> = (0..dim / 2)
        .map(|i| (((2 * i) as f32 * coef) as f64).exp() as f32)
        .collect();
    let mut pe = vec![0.0f32; length * dim];
    for (pos, row) in pe.chunks_exact_mut(dim.max(1)).enumerate() {
        for (i, &d) in div.iter().enumerate() {
            let arg = pos as f32 * d;
            row[2 * i] = (arg as f64).sin() as f32;
            row[2 * i + 1] = (arg as f64).cos() as f32;
        }
    }
    pe
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_table_shape_and_values() {
        let t = step_embedding_table(50, 128);
        assert_eq!(t.len(), 50 * 128);
        // row 0: sin(0) = 0, cos(0) = 1
        assert!(t[..64].iter().all(|&v| v == 0.0));
        assert!(t[64..128].iter().all(|&v| v == 1.0));
        // row 1, j = 0: f_0 = 1 -> sin(1), cos(1); j = 63: f = 1e4
        assert_eq!(t[128], 1f64.sin() as f32);
        assert_eq!(t[128 + 64], 1f64.cos() as f32);
        assert_eq!(t[128 + 63], 1e4f64.sin() as f32);
    }

    #[test]
    fn frame_embedding_values() {
        let pe = frame_embedding(3, 8);
        // pos 0: sin 0, cos 1 alternating
        assert_eq!(&pe[..8], &[0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0]);
        // pos 2, i = 1: div = 10000^(-2/8) = 0.1
        let want = (2.0f64 * 0.1).sin();
        assert!((pe[16 + 2] as f64 - want).abs() < 1e-6);
        assert!((pe[16 + 3] as f64 - (0.2f64).cos()).abs() < 1e-6);
    }
}
