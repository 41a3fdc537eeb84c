//! DDPM ancestral sampling (Ho et al. 2020, Algorithm 2), the TCD reference sampler, generalised
//! to a respaced subsequence of the training steps.
//!
//! For a step from t to t_prev (ᾱ_prev = 1 after the last step):
//! 1. β' = 1 − ᾱ_t / ᾱ_prev (β_t up to rounding when t_prev = t − 1: the reference chain);
//! 2. x ← (1/√(1 − β')) · (x − β'/√(1 − ᾱ_t) · ε̂);
//! 3. if a step follows: x ← x + σ z, σ² = β' (1 − ᾱ_prev)/(1 − ᾱ_t) (`fixed_small`, the posterior
//!    variance β̃) or σ² = β' (`fixed_large`).
//!
//! Coefficients are f64, computed with the same operations in the same order as
//! `training/diffusion.py::sample`, and cast to f32 when applied (as PyTorch multiplies Python
//! floats into float32 tensors): `x = c1 * (x - c2 * eps)`, then `x = x + sigma * z`.

use crate::config::VarianceType;
use crate::schedule::NoiseSchedule;

/// The coefficients of one DDPM step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DdpmStep {
    /// 1/√(1 − β').
    pub c1: f64,
    /// β'/√(1 − ᾱ_t).
    pub c2: f64,
    /// σ (0 at the last step).
    pub sigma: f64,
}

impl DdpmStep {
    /// The step from `t` to `prev` (`None`: the end of the chain).
    pub fn new(
        schedule: &NoiseSchedule,
        t: usize,
        prev: Option<usize>,
        variance: VarianceType,
    ) -> Self {
        let alpha_bar_t = schedule.alpha_bar(Some(t));
        let alpha_bar_prev = schedule.alpha_bar(prev);
        // Step 1: the (generalised) beta of this transition.
        let beta = 1.0 - alpha_bar_t / alpha_bar_prev;
        // Step 2: the mean.
        let c1 = 1.0 / (1.0 - beta).sqrt();
        let c2 = beta / (1.0 - alpha_bar_t).sqrt();
        // Step 3: the noise scale.
        let sigma = match (prev, variance) {
            (None, _) => 0.0,
            (Some(_), VarianceType::FixedSmall) => {
                (beta * (1.0 - alpha_bar_prev) / (1.0 - alpha_bar_t)).sqrt()
            }
            (Some(_), VarianceType::FixedLarge) => beta.sqrt(),
        };
        DdpmStep { c1, c2, sigma }
    }

    /// x ← c1 (x − c2 ε̂) + σ z, element-wise in f32.
    pub fn apply(&self, x: &mut [f32], eps: &[f32], z: &[f32]) {
        let (c1, c2) = (self.c1 as f32, self.c2 as f32);
        for (xv, ev) in x.iter_mut().zip(eps) {
            *xv = c1 * (*xv - c2 * ev);
        }
        super::add_noise(x, z, self.sigma);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::schedule::cosine_betas;

    #[test]
    fn full_chain_uses_the_reference_betas() {
        // Consecutive steps reproduce CSDI's coefficients built from β_t (to f64 rounding), and
        // identical f32 coefficients.
        let s = NoiseSchedule::from_betas(cosine_betas(50, 0.5));
        for t in 1..50 {
            let st = DdpmStep::new(&s, t, Some(t - 1), VarianceType::FixedSmall);
            let b = s.betas()[t];
            let ab = s.alphas_cumprod();
            let (c1, c2, sigma) = (
                1.0 / (1.0 - b).sqrt(),
                b / (1.0 - ab[t]).sqrt(),
                ((1.0 - ab[t - 1]) / (1.0 - ab[t]) * b).sqrt(),
            );
            assert!((st.c1 - c1).abs() < 1e-12 * c1, "t={t}");
            assert!((st.c2 - c2).abs() < 1e-12 * c2, "t={t}");
            assert!((st.sigma - sigma).abs() < 1e-12 * sigma, "t={t}");
        }
        let last = DdpmStep::new(&s, 0, None, VarianceType::FixedSmall);
        assert_eq!(last.sigma, 0.0);
        assert!((last.c1 - 1.0 / (1.0 - s.betas()[0]).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn respaced_beta_is_the_ratio() {
        let s = NoiseSchedule::from_betas(cosine_betas(50, 0.5));
        let st = DdpmStep::new(&s, 49, Some(39), VarianceType::FixedLarge);
        let ab = s.alphas_cumprod();
        let beta = 1.0 - ab[49] / ab[39];
        assert!((st.c1 - 1.0 / (1.0 - beta).sqrt()).abs() < 1e-12);
        assert!((st.sigma - beta.sqrt()).abs() < 1e-12);
    }
}
