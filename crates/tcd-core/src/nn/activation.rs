//! Element-wise activations, matching PyTorch's definitions.

use std::f32::consts::FRAC_1_SQRT_2;

/// Exact GELU (PyTorch's default, `approximate="none"`): x · ½ · (1 + erf(x / √2)).
#[inline]
pub fn gelu_erf(x: f32) -> f32 {
    x * 0.5 * (1.0 + libm::erff(x * FRAC_1_SQRT_2))
}

/// Logistic sigmoid 1 / (1 + e^(−x)).
#[inline]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// SiLU x · sigmoid(x) (computed as x / (1 + e^(−x)) like PyTorch).
#[inline]
pub fn silu(x: f32) -> f32 {
    x / (1.0 + (-x).exp())
}

/// max(x, 0).
#[inline]
pub fn relu(x: f32) -> f32 {
    x.max(0.0)
}

/// e^x for x ≤ 0 (softmax after max subtraction), branch-free so that loops over it vectorise
/// on any target: Cody-Waite reduction x = n·ln2 + r with round-to-nearest by the 1.5·2²³
/// trick, the Cephes degree-5 polynomial, and 2ⁿ built from the exponent bits. Relative error
/// below 3e-7 on [−87, 0]; inputs below −87 are clamped there (e^−87 ≈ 1.6e−38, where PyTorch
/// gives a denormal or 0: no difference once summed with the max term, which is 1).
#[inline]
pub fn exp_nonpositive(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    const SHIFTER: f32 = 12_582_912.0; // 1.5 · 2^23
    let x = x.clamp(-87.0, 0.0);
    let t = x * LOG2E + SHIFTER;
    let n = t - SHIFTER; // round(x · log2 e)
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = 1.987_569_1e-4;
    let p = p * r + 1.398_199_9e-3;
    let p = p * r + 8.333_452e-3;
    let p = p * r + 4.166_579_6e-2;
    let p = p * r + 1.666_666_5e-1;
    let p = p * r + 0.5;
    let y = p * (r * r) + r + 1.0;
    // n ∈ [−126, 0]: the low bits of t hold n + 0x400000 (bias of the shifter's mantissa).
    let ni = (t.to_bits() as i32).wrapping_sub(0x4B40_0000);
    let scale = f32::from_bits(((ni + 127) as u32) << 23);
    y * scale
}

/// Applies `f` to every element in place.
#[inline]
pub fn map_inplace(x: &mut [f32], f: impl Fn(f32) -> f32) {
    for v in x.iter_mut() {
        *v = f(*v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gelu_reference_values() {
        // torch.nn.functional.gelu(torch.tensor([...])) in float64
        let cases = [
            (0.0f32, 0.0f64),
            (1.0, 0.841_344_746_068_543),
            (-1.0, -0.158_655_253_931_457_05),
            (2.0, 1.954_499_736_103_641_6),
            (-3.0, -0.004_049_694_094_890_31),
            (0.5, 0.345_731_230_637_006_56),
        ];
        for (x, want) in cases {
            let got = gelu_erf(x) as f64;
            assert!((got - want).abs() < 2e-7, "gelu({x}) = {got}, want {want}");
        }
    }

    #[test]
    fn exp_nonpositive_is_accurate() {
        let mut worst = 0.0f64;
        let mut x = 0.0f32;
        while x > -87.0 {
            let want = (x as f64).exp();
            let got = exp_nonpositive(x) as f64;
            worst = worst.max(((got - want) / want).abs());
            x -= 0.001_37;
        }
        assert!(worst < 3e-7, "worst relative error {worst}");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert_eq!(exp_nonpositive(-1000.0), exp_nonpositive(-87.0));
        assert!(exp_nonpositive(f32::NEG_INFINITY) < 1e-37);
    }

    #[test]
    fn sigmoid_silu_relu() {
        assert!((sigmoid(0.0) - 0.5).abs() < 1e-7);
        assert!((sigmoid(2.0) as f64 - 0.880_797_077_977_882_3).abs() < 1e-7);
        assert!((silu(-1.0) as f64 - (-0.268_941_421_369_995_1)).abs() < 1e-7);
        assert_eq!(relu(-2.0), 0.0);
        assert_eq!(relu(3.0), 3.0);
        let mut v = [1.0f32, -1.0];
        map_inplace(&mut v, relu);
        assert_eq!(v, [1.0, 0.0]);
    }
}
