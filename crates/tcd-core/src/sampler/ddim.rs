//! DDIM (Song et al. 2021, eq. 12) with stochasticity η, on any decreasing subsequence of steps.
//!
//! For a step from t to t_prev (ᾱ_prev = 1 after the last step):
//! 1. x̂₀ = (x − √(1 − ᾱ_t) ε̂) / √ᾱ_t (no clipping);
//! 2. σ = η · √((1 − ᾱ_prev)/(1 − ᾱ_t)) · √(1 − ᾱ_t/ᾱ_prev);
//! 3. x ← √ᾱ_prev · x̂₀ + √(1 − ᾱ_prev − σ²) · ε̂ + σ z (the noise term only when σ > 0).
//!
//! Coefficients are f64 (the operations of `training/diffusion.py::sample`, which follow diffusers'
//! `DDIMScheduler`), cast to f32 when applied.
//! With η = 0 the chain is deterministic given x_T.

use crate::error::{Error, Result};
use crate::schedule::NoiseSchedule;

/// The coefficients of one DDIM step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DdimStep {
    /// √(1 − ᾱ_t).
    pub sqrt_one_minus_alpha_bar: f64,
    /// √ᾱ_t.
    pub sqrt_alpha_bar: f64,
    /// √ᾱ_prev.
    pub sqrt_alpha_bar_prev: f64,
    /// √(1 − ᾱ_prev − σ²) (clamped at 0).
    pub direction: f64,
    /// σ.
    pub sigma: f64,
}

/// Checks η ∈ [0, 1].
pub fn check_eta(eta: f64) -> Result<()> {
    if (0.0..=1.0).contains(&eta) {
        Ok(())
    } else {
        Err(Error::invalid_input(
            "eta",
            "a number in [0, 1]",
            eta.to_string(),
        ))
    }
}

impl DdimStep {
    /// The step from `t` to `prev` (`None`: the end of the chain).
    pub fn new(schedule: &NoiseSchedule, t: usize, prev: Option<usize>, eta: f64) -> Self {
        let alpha_bar_t = schedule.alpha_bar(Some(t));
        let alpha_bar_prev = schedule.alpha_bar(prev);
        let sigma = eta
            * ((1.0 - alpha_bar_prev) / (1.0 - alpha_bar_t)).sqrt()
            * (1.0 - alpha_bar_t / alpha_bar_prev).max(0.0).sqrt();
        DdimStep {
            sqrt_one_minus_alpha_bar: (1.0 - alpha_bar_t).sqrt(),
            sqrt_alpha_bar: alpha_bar_t.sqrt(),
            sqrt_alpha_bar_prev: alpha_bar_prev.sqrt(),
            direction: (1.0 - alpha_bar_prev - sigma * sigma).max(0.0).sqrt(),
            sigma,
        }
    }

    /// x̂₀ = (x − a ε̂)/b; x ← c x̂₀ + d ε̂ (+ σ z), element-wise in f32.
    pub fn apply(&self, x: &mut [f32], eps: &[f32], z: &[f32]) {
        let a = self.sqrt_one_minus_alpha_bar as f32;
        let b = self.sqrt_alpha_bar as f32;
        let c = self.sqrt_alpha_bar_prev as f32;
        let d = self.direction as f32;
        for (xv, ev) in x.iter_mut().zip(eps) {
            let x0 = (*xv - a * ev) / b;
            *xv = c * x0 + d * ev;
        }
        super::add_noise(x, z, self.sigma);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::schedule::cosine_betas;

    #[test]
    fn last_step_returns_x0_hat() {
        let s = NoiseSchedule::from_betas(cosine_betas(50, 0.5));
        let st = DdimStep::new(&s, 9, None, 1.0);
        assert_eq!(st.sigma, 0.0);
        assert_eq!(st.direction, 0.0);
        assert_eq!(st.sqrt_alpha_bar_prev, 1.0);
        let mut x = [0.5f32];
        st.apply(&mut x, &[0.2], &[100.0]);
        let want = (0.5 - st.sqrt_one_minus_alpha_bar as f32 * 0.2) / st.sqrt_alpha_bar as f32;
        assert_eq!(x[0], want);
    }

    #[test]
    fn eta_one_matches_ddpm_posterior_sigma() {
        // With η = 1 and consecutive steps, σ equals DDPM's √β̃.
        let s = NoiseSchedule::from_betas(cosine_betas(50, 0.5));
        let ab = s.alphas_cumprod();
        let st = DdimStep::new(&s, 20, Some(19), 1.0);
        let beta = 1.0 - ab[20] / ab[19];
        let tilde = (1.0 - ab[19]) / (1.0 - ab[20]) * beta;
        assert!((st.sigma - tilde.sqrt()).abs() < 1e-12);
        assert!(check_eta(-0.1).is_err());
        assert!(check_eta(f64::NAN).is_err());
        assert!(check_eta(0.0).is_ok());
    }
}
