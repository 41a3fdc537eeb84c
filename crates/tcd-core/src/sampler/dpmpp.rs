//! DPM-Solver++(2M) (Lu et al. 2022, "DPM-Solver++", multistep, second order, data prediction),
//! on any decreasing subsequence of steps; deterministic given x_T.
//!
//! With α = √ᾱ, σ = √(1 − ᾱ), λ = log(α/σ), a step from s = t_i to t' = t_{i+1},
//! h_i = λ_t' − λ_s:
//! 1. x̂₀ⁱ = (x − σ_s ε̂)/α_s (no clipping);
//! 2. D = x̂₀ⁱ at the first step (first order), otherwise
//!    D = (1 + 1/(2r)) x̂₀ⁱ − 1/(2r) x̂₀ⁱ⁻¹ with r = h_{i−1}/h_i;
//! 3. x ← (σ_t'/σ_s) x − α_t' (e^{−h} − 1) D.
//!
//! The last step goes to ᾱ = 1 (σ = 0, λ = +∞): it is taken first order, whose limit is
//! x ← x̂₀ⁱ (diffusers' `DPMSolverMultistepScheduler` with `final_sigmas_type="zero"`,
//! `lower_order_final=True`; k-diffusion's `sample_dpmpp_2m` does the same).
//!
//! The multistep update needs the previous x̂₀: [`DpmPp2mStep::apply`] reads it from and writes the
//! current one to a per-chain buffer, which the chain's [`super::Sampler`] owns. Coefficients are f64 (the operations of
//! `training/diffusion.py::dpmpp2m_coefficients`), cast to f32 when applied.
//! The sampler draws no per-step noise: a chain consumes one noise block, x_T.

use crate::schedule::NoiseSchedule;

/// The coefficients of one DPM-Solver++(2M) step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DpmPp2mStep {
    /// σ_s = √(1 − ᾱ_t).
    pub sqrt_one_minus_alpha_bar: f64,
    /// α_s = √ᾱ_t.
    pub sqrt_alpha_bar: f64,
    /// The last step: x ← x̂₀.
    pub last: bool,
    /// σ_t'/σ_s (0 at the last step).
    pub ratio: f64,
    /// −α_t' (e^{−h} − 1), from `exp_m1` (0 at the last step).
    pub c0: f64,
    /// Weight of the current x̂₀ in D (1 at first order).
    pub w_cur: f64,
    /// Weight of the previous x̂₀ in D (0 at first order).
    pub w_prev: f64,
}

/// λ_t = log(α_t/σ_t) = ½ log ᾱ − ½ log(1 − ᾱ).
fn lambda(alpha_bar: f64) -> f64 {
    0.5 * alpha_bar.ln() - 0.5 * (1.0 - alpha_bar).ln()
}

impl DpmPp2mStep {
    /// The steps over descending `timesteps` (the last one goes to ᾱ = 1).
    pub fn plan(schedule: &NoiseSchedule, timesteps: &[usize]) -> Vec<Self> {
        let mut h_prev: Option<f64> = None;
        let mut out = Vec::with_capacity(timesteps.len());
        for (i, &t) in timesteps.iter().enumerate() {
            let alpha_bar_t = schedule.alpha_bar(Some(t));
            let mut step = DpmPp2mStep {
                sqrt_one_minus_alpha_bar: (1.0 - alpha_bar_t).sqrt(),
                sqrt_alpha_bar: alpha_bar_t.sqrt(),
                last: true,
                ratio: 0.0,
                c0: 0.0,
                w_cur: 1.0,
                w_prev: 0.0,
            };
            if let Some(&next) = timesteps.get(i + 1) {
                let alpha_bar_n = schedule.alpha_bar(Some(next));
                let h = lambda(alpha_bar_n) - lambda(alpha_bar_t);
                step.last = false;
                step.ratio = (1.0 - alpha_bar_n).sqrt() / (1.0 - alpha_bar_t).sqrt();
                step.c0 = -alpha_bar_n.sqrt() * (-h).exp_m1();
                if let Some(hp) = h_prev {
                    let r = hp / h;
                    step.w_cur = 1.0 + 0.5 / r;
                    step.w_prev = -0.5 / r;
                }
                h_prev = Some(h);
            }
            out.push(step);
        }
        out
    }

    /// Element-wise in f32: x̂₀ = (x − a ε̂)/b; D = x̂₀ (first order) or w_cur x̂₀ + w_prev p;
    /// x ← ratio·x + c0·D (x ← x̂₀ at the last step); p ← x̂₀. `prev_x0` (p) holds the previous
    /// step's x̂₀ on entry (unread at the first step) and this step's on return.
    pub(super) fn apply(&self, x: &mut [f32], eps: &[f32], prev_x0: &mut [f32]) {
        let a = self.sqrt_one_minus_alpha_bar as f32;
        let b = self.sqrt_alpha_bar as f32;
        let (ratio, c0) = (self.ratio as f32, self.c0 as f32);
        let (wc, wp) = (self.w_cur as f32, self.w_prev as f32);
        let second_order = self.w_prev != 0.0;
        for ((xv, ev), pv) in x.iter_mut().zip(eps).zip(prev_x0.iter_mut()) {
            let x0 = (*xv - a * ev) / b;
            if self.last {
                *xv = x0;
            } else {
                let d = if second_order { wc * x0 + wp * *pv } else { x0 };
                *xv = ratio * *xv + c0 * d;
            }
            *pv = x0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::{timesteps, TimestepSpacing};
    use crate::schedule::cosine_betas;

    fn schedule() -> NoiseSchedule {
        NoiseSchedule::from_betas(cosine_betas(50, 0.5))
    }

    #[test]
    fn first_and_last_steps_are_first_order() {
        let s = schedule();
        let ts = timesteps(50, 5, TimestepSpacing::Trailing).unwrap();
        let plan = DpmPp2mStep::plan(&s, &ts);
        assert_eq!(plan.len(), 5);
        assert_eq!((plan[0].w_cur, plan[0].w_prev), (1.0, 0.0));
        assert!(plan[4].last && !plan[3].last);
        for st in &plan[1..4] {
            assert!(st.w_prev < 0.0);
            assert!((st.w_cur + st.w_prev - 1.0).abs() < 1e-15);
        }
        // The last step returns x̂₀ whatever the previous x̂₀.
        let mut x = [0.5f32];
        let mut p = [123.0f32];
        plan[4].apply(&mut x, &[0.2], &mut p);
        let want =
            (0.5 - plan[4].sqrt_one_minus_alpha_bar as f32 * 0.2) / plan[4].sqrt_alpha_bar as f32;
        assert_eq!(x[0], want);
        assert_eq!(p[0], want);
    }

    #[test]
    fn first_order_step_is_ddim_eta0() {
        // DPM-Solver++(1) is DDIM (η = 0): σ_t'/σ_s x − α_t'(e^{−h} − 1) x̂₀ = α_t' x̂₀ + σ_t' ε̂.
        let s = schedule();
        let ab = s.alphas_cumprod();
        let st = DpmPp2mStep::plan(&s, &[49, 39])[0];
        let (x, eps) = (0.7f64, -1.1f64);
        let x0 = (x - (1.0 - ab[49]).sqrt() * eps) / ab[49].sqrt();
        let got = st.ratio * x + st.c0 * x0;
        let want = ab[39].sqrt() * x0 + (1.0 - ab[39]).sqrt() * eps;
        assert!((got - want).abs() < 1e-12 * want.abs(), "{got} vs {want}");
    }

    #[test]
    fn coefficients_match_the_written_formula() {
        // The second-order weights from λ written out with α, σ (diffusers' midpoint form:
        // D0 + ½ D1, D1 = (m0 − m1)/r0).
        let s = schedule();
        let ab = s.alphas_cumprod();
        let ts = timesteps(50, 10, TimestepSpacing::Trailing).unwrap();
        let plan = DpmPp2mStep::plan(&s, &ts);
        let lam = |t: usize| (ab[t].sqrt() / (1.0 - ab[t]).sqrt()).ln();
        for i in 1..ts.len() - 1 {
            let (tp, t, tn) = (ts[i - 1], ts[i], ts[i + 1]);
            let h = lam(tn) - lam(t);
            let r0 = (lam(t) - lam(tp)) / h;
            let st = plan[i];
            assert!((st.w_cur - (1.0 + 0.5 / r0)).abs() < 1e-12, "i={i}");
            assert!((st.w_prev + 0.5 / r0).abs() < 1e-12, "i={i}");
            assert!((st.ratio - ((1.0 - ab[tn]) / (1.0 - ab[t])).sqrt()).abs() < 1e-12);
            assert!((st.c0 - ab[tn].sqrt() * (1.0 - (-h).exp())).abs() < 1e-12);
        }
    }

    #[test]
    fn oracle_eps_recovers_x0() {
        // With ε̂ the exact noise of a fixed x₀, every x̂₀ is x₀ and the chain ends there.
        let s = schedule();
        let ab = s.alphas_cumprod();
        let x0 = [0.3f64, -1.2, 2.5];
        for n in [1, 2, 3, 5, 10, 20, 50] {
            let ts = timesteps(50, n, TimestepSpacing::Trailing).unwrap();
            let plan = DpmPp2mStep::plan(&s, &ts);
            let mut x = [0.4f32, -0.9, 1.7];
            let mut p = [0.0f32; 3];
            for (st, &t) in plan.iter().zip(&ts) {
                let eps: Vec<f32> = x
                    .iter()
                    .zip(&x0)
                    .map(|(&xv, &v)| ((xv as f64 - ab[t].sqrt() * v) / (1.0 - ab[t]).sqrt()) as f32)
                    .collect();
                st.apply(&mut x, &eps, &mut p);
            }
            for (got, want) in x.iter().zip(&x0) {
                assert!((*got as f64 - want).abs() < 1e-4, "n={n}: {got} vs {want}");
            }
        }
    }
}
