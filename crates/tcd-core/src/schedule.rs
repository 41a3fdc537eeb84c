//! Noise schedules, all in f64 (TCD_REFERENCE.md 1.6).
//!
//! Notation: β_t (`betas`), ᾱ_t = Π_{s≤t} (1 − β_s) (`alphas_cumprod`), t = 0..T−1; by convention
//! ᾱ_{−1} = 1 (the clean end of the chain).

/// The named schedules whose betas can be recomputed (and are checked against the stored ones).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BetaSchedule {
    /// Nichol & Dhariwal: ᾱ(s) = cos²(((s + 0.008)/1.008)·π/2), β_i = min(1 − ᾱ((i+1)/T)/ᾱ(i/T), max_beta).
    Cosine,
    /// linspace(beta_start, beta_end, T).
    Linear,
    /// linspace(√beta_start, √beta_end, T)² (CSDI's default).
    Quad,
}

impl BetaSchedule {
    /// `cosine` | `linear` | `quad`; `None` for any other (custom) name.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "cosine" => Some(BetaSchedule::Cosine),
            "linear" => Some(BetaSchedule::Linear),
            "quad" => Some(BetaSchedule::Quad),
            _ => None,
        }
    }

    /// The T betas of this schedule (`max_beta` is used by `Cosine` only; `beta_*` by the others).
    pub fn betas(
        self,
        num_train_timesteps: usize,
        beta_start: f64,
        beta_end: f64,
        max_beta: f64,
    ) -> Vec<f64> {
        match self {
            BetaSchedule::Cosine => cosine_betas(num_train_timesteps, max_beta),
            BetaSchedule::Linear => linspace(beta_start, beta_end, num_train_timesteps),
            BetaSchedule::Quad => linspace(beta_start.sqrt(), beta_end.sqrt(), num_train_timesteps)
                .into_iter()
                .map(|b| b * b)
                .collect(),
        }
    }
}

/// ᾱ(s) of the cosine schedule, s ∈ [0, 1].
fn cosine_alpha_bar(s: f64) -> f64 {
    let c = ((s + 0.008) / 1.008 * std::f64::consts::FRAC_PI_2).cos();
    c * c
}

/// Cosine betas: β_i = min(1 − ᾱ((i+1)/T)/ᾱ(i/T), max_beta), i = 0..T−1.
pub fn cosine_betas(num_train_timesteps: usize, max_beta: f64) -> Vec<f64> {
    let t_total = num_train_timesteps as f64;
    (0..num_train_timesteps)
        .map(|i| {
            let t1 = i as f64 / t_total;
            let t2 = (i + 1) as f64 / t_total;
            (1.0 - cosine_alpha_bar(t2) / cosine_alpha_bar(t1)).min(max_beta)
        })
        .collect()
}

/// numpy.linspace(start, stop, n) with endpoint: y_i = start + i·step, the last value exactly `stop`.
pub fn linspace(start: f64, stop: f64, n: usize) -> Vec<f64> {
    match n {
        0 => Vec::new(),
        1 => vec![start],
        _ => {
            let step = (stop - start) / (n - 1) as f64;
            let mut y: Vec<f64> = (0..n).map(|i| i as f64 * step + start).collect();
            if let Some(last) = y.last_mut() {
                *last = stop;
            }
            y
        }
    }
}

/// betas and their cumulative products, in f64.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseSchedule {
    betas: Vec<f64>,
    alphas_cumprod: Vec<f64>,
}

impl NoiseSchedule {
    /// From the authoritative betas; ᾱ_t = cumprod(1 − β) computed sequentially (as numpy/torch do).
    pub fn from_betas(betas: Vec<f64>) -> Self {
        let mut acc = 1.0f64;
        let alphas_cumprod = betas
            .iter()
            .map(|b| {
                acc *= 1.0 - b;
                acc
            })
            .collect();
        NoiseSchedule {
            betas,
            alphas_cumprod,
        }
    }

    /// T.
    pub fn num_train_timesteps(&self) -> usize {
        self.betas.len()
    }

    /// β_t, t = 0..T−1.
    pub fn betas(&self) -> &[f64] {
        &self.betas
    }

    /// ᾱ_t, t = 0..T−1.
    pub fn alphas_cumprod(&self) -> &[f64] {
        &self.alphas_cumprod
    }

    /// ᾱ_t, with ᾱ = 1 for `None` (before the first step: the clean sample).
    pub fn alpha_bar(&self, t: Option<usize>) -> f64 {
        match t {
            None => 1.0,
            Some(t) => self.alphas_cumprod.get(t).copied().unwrap_or(1.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn cosine_t50_reference_values() {
        // TCD_REFERENCE.md 1.6: β_0 = 1.75e-3, β_1 = 3.69e-3, last three clipped to 0.5,
        // ᾱ_0 = 0.99825, ᾱ_49 = 1.09e-3.
        let betas = cosine_betas(50, 0.5);
        assert_eq!(betas.len(), 50);
        assert!(close(betas[0], 1.75e-3, 5e-6), "beta_0 = {}", betas[0]);
        assert!(close(betas[1], 3.69e-3, 5e-6), "beta_1 = {}", betas[1]);
        assert_eq!(&betas[47..], &[0.5, 0.5, 0.5]);
        assert!(betas[46] < 0.5);
        let s = NoiseSchedule::from_betas(betas.clone());
        assert!(
            close(s.alphas_cumprod()[0], 0.99825, 5e-6),
            "{}",
            s.alphas_cumprod()[0]
        );
        assert!(
            close(s.alphas_cumprod()[49], 1.09e-3, 5e-6),
            "{}",
            s.alphas_cumprod()[49]
        );
        // increasing betas, decreasing alpha bars
        assert!(betas.windows(2).all(|w| w[0] <= w[1]));
        assert!(s.alphas_cumprod().windows(2).all(|w| w[0] > w[1]));
        assert_eq!(s.alpha_bar(None), 1.0);
        assert_eq!(s.alpha_bar(Some(0)), 1.0 - betas[0]);
    }

    #[test]
    fn linear_and_quad() {
        let lin = BetaSchedule::Linear.betas(5, 0.1, 0.5, 0.0);
        let want = [0.1, 0.2, 0.3, 0.4, 0.5];
        for (a, b) in lin.iter().zip(want) {
            assert!(close(*a, b, 1e-15));
        }
        let quad = BetaSchedule::Quad.betas(3, 1e-4, 0.25, 0.0);
        let want = [1e-4, ((0.01f64 + 0.5) / 2.0).powi(2), 0.25];
        for (a, b) in quad.iter().zip(want) {
            assert!(close(*a, b, 1e-15), "{a} vs {b}");
        }
        assert_eq!(linspace(0.3, 0.7, 1), vec![0.3]);
        assert!(linspace(0.0, 1.0, 0).is_empty());
    }

    #[test]
    fn schedule_names() {
        assert_eq!(
            BetaSchedule::from_name("cosine"),
            Some(BetaSchedule::Cosine)
        );
        assert_eq!(BetaSchedule::from_name("quad"), Some(BetaSchedule::Quad));
        assert_eq!(
            BetaSchedule::from_name("linear"),
            Some(BetaSchedule::Linear)
        );
        assert_eq!(BetaSchedule::from_name("custom"), None);
    }
}
