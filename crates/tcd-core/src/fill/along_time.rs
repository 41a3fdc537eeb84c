//! The fills along time of one coordinate's row ([`CondFill`]: none, linear, natural cubic spline, the
//! prior's fill found in `observed`): a denoiser's observed channel and `tcd.interpolate`, with the
//! operation order of the PyTorch reference so that both give identical bits.

use crate::config::CondFill;
use crate::error::{Error, Result};

impl CondFill {
    /// Calls `set(l, v)` with this fill's value `v` for every masked entry `l` of one coordinate's row
    /// ([`fill_linear`] or [`fill_spline`]; [`CondFill::Prior`]: the value `observed` holds there, where
    /// the caller has put the prior's fill); `Zero` calls nothing (its masked entries stay 0).
    pub fn fill_row(self, mask: &[f32], observed: &[f32], mut set: impl FnMut(usize, f32)) {
        match self {
            CondFill::Zero => {}
            CondFill::Linear => fill_linear(mask, observed, set),
            CondFill::Spline => fill_spline(mask, observed, set),
            CondFill::Prior => {
                for (ll, (&mv, &ov)) in mask.iter().zip(observed).enumerate() {
                    if mv <= 0.5 {
                        set(ll, ov);
                    }
                }
            }
        }
    }
}

impl CondFill {
    /// The fills that interpolate ([`fill_rows`]'s `method`), the default first.
    pub const INTERPOLATIONS: [&'static str; 2] = ["linear", "spline"];

    /// The interpolating fill named `method` (one of [`CondFill::INTERPOLATIONS`]).
    pub fn interpolation(method: &str) -> Result<Self> {
        match method {
            "linear" => Ok(CondFill::Linear),
            "spline" => Ok(CondFill::Spline),
            other => Err(Error::invalid_input(
                "method",
                "\"linear\" or \"spline\"",
                format!("{other:?}"),
            )),
        }
    }
}

/// Every row of `observed` (rows × `length`, row-major) with its masked entries (mask < 0.5) filled
/// along the row by `fill`, its observed entries copied: exactly what a model with this conditioning fill
/// sees in its observed channel (`tcd.interpolate`). Masked entries of `observed` are never read; a row
/// with nothing observed is all 0 ([`fill_linear`]'s rule).
pub fn fill_rows(
    fill: CondFill,
    length: usize,
    mask: &[f32],
    observed: &[f32],
) -> Result<Vec<f32>> {
    if length == 0 || !observed.len().is_multiple_of(length) {
        return Err(Error::invalid_input(
            "observed",
            "rows of length L >= 1 (an array whose last axis is time)",
            format!("{} values in rows of length {length}", observed.len()),
        ));
    }
    if mask.len() != observed.len() {
        return Err(Error::invalid_input(
            "mask",
            format!("one value per value of `observed` ({})", observed.len()),
            format!("{} values", mask.len()),
        ));
    }
    let mut out: Vec<f32> = observed
        .iter()
        .zip(mask)
        .map(|(&o, &m)| if m > 0.5 { o } else { 0.0 })
        .collect();
    for ((row, m), o) in out
        .chunks_exact_mut(length)
        .zip(mask.chunks_exact(length))
        .zip(observed.chunks_exact(length))
    {
        fill.fill_row(m, o, |ll, v| row[ll] = v);
    }
    Ok(out)
}

/// Natural cubic spline through one coordinate's observed entries (mask > 0.5; knots at their indices),
/// evaluated at every masked entry between the first and the last observed one; other masked entries get
/// the rule of [`fill_linear`] (the nearest observed entry held, 0 on a row with none). In f64, rounded to
/// f32, with the operation order of the PyTorch reference `training.model.spline_fill` (Thomas algorithm
/// for the second derivatives `M`, then `M0·a³/(6h) + M1·b³/(6h) + (y0/h − M0·h/6)·a + (y1/h − M1·h/6)·b`
/// on a segment of length h, a and b the distances to its right and left knots), so both give identical
/// bits. `set(l, v)` is called once for every masked entry; observed entries are not touched.
pub fn fill_spline(mask: &[f32], observed: &[f32], mut set: impl FnMut(usize, f32)) {
    let knots: Vec<usize> = (0..mask.len()).filter(|&i| mask[i] > 0.5).collect();
    let n = knots.len();
    if n < 2 {
        return fill_linear(mask, observed, set);
    }
    let y = |j: usize| observed[knots[j]] as f64;
    let h = |j: usize| (knots[j + 1] - knots[j]) as f64;
    let mut cp = vec![0.0f64; n];
    let mut dp = vec![0.0f64; n];
    for i in 1..n - 1 {
        let (a, c) = (h(i - 1), h(i));
        let b = 2.0 * (a + c);
        let d = 6.0 * ((y(i + 1) - y(i)) / c - (y(i) - y(i - 1)) / a);
        let w = b - a * cp[i - 1];
        cp[i] = c / w;
        dp[i] = (d - a * dp[i - 1]) / w;
    }
    let mut m = vec![0.0f64; n];
    for i in (1..n - 1).rev() {
        m[i] = dp[i] - cp[i] * m[i + 1];
    }
    let (first, last) = (knots[0], knots[n - 1]);
    let mut j = 0;
    for (ll, &mv) in mask.iter().enumerate() {
        if mv > 0.5 {
            continue;
        }
        if ll < first {
            set(ll, observed[first]);
            continue;
        }
        if ll > last {
            set(ll, observed[last]);
            continue;
        }
        while knots[j + 1] < ll {
            j += 1;
        }
        let (x0, x1) = (knots[j] as f64, knots[j + 1] as f64);
        let t = ll as f64;
        let hh = x1 - x0;
        let (a, b) = (x1 - t, t - x0);
        let (m0, m1) = (m[j], m[j + 1]);
        let v = m0 * a * a * a / (6.0 * hh)
            + m1 * b * b * b / (6.0 * hh)
            + (y(j) / hh - m0 * hh / 6.0) * a
            + (y(j + 1) / hh - m1 * hh / 6.0) * b;
        set(ll, v as f32);
    }
}

/// Linear interpolation of one coordinate's row over its masked entries (mask < 0.5): between the
/// nearest observed entries `p < l < n` the value is `a + (b − a) · ((l − p) / (n − p))` in f32 (the
/// operation order of the PyTorch reference `training.model.linear_fill`); before the first and after
/// the last observed entry the nearest one is held; a row with none observed gets 0. `set(l, v)` is
/// called for every masked entry; observed entries are not touched.
pub fn fill_linear(mask: &[f32], observed: &[f32], mut set: impl FnMut(usize, f32)) {
    let seen = |i: usize| mask[i] > 0.5;
    let mut prev: Option<usize> = None;
    let mut next = (0..mask.len()).find(|&i| seen(i));
    for ll in 0..mask.len() {
        if seen(ll) {
            prev = Some(ll);
            continue;
        }
        if next.is_some_and(|nx| nx < ll) {
            next = (ll..mask.len()).find(|&i| seen(i));
        }
        let v = match (prev, next) {
            (Some(p), Some(nx)) => {
                let (a, b) = (observed[p], observed[nx]);
                let w = (ll - p) as f32 / (nx - p) as f32;
                a + (b - a) * w
            }
            (Some(p), None) => observed[p],
            (None, Some(nx)) => observed[nx],
            (None, None) => 0.0,
        };
        set(ll, v);
    }
}

#[cfg(test)]
mod tests {
    use super::fill_spline;

    #[test]
    fn spline_fill_natural_three_knots() {
        // knots (1, 0), (3, 1), (5, 0): natural spline, M at the middle knot = -6 / 8 = -0.75, so at
        // distance 1 from a knot the value is -0.75 / 12 + 0.5 + 0.25 = 0.6875; held outside the knots.
        let mask = [0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0];
        let obs = [
            f32::NAN,
            0.0,
            f32::NAN,
            1.0,
            f32::NAN,
            0.0,
            f32::NAN,
            f32::NAN,
        ];
        let mut out = [f32::NAN; 8];
        let mut calls = 0;
        fill_spline(&mask, &obs, |l, v| {
            out[l] = v;
            calls += 1;
        });
        assert_eq!(calls, 5);
        assert_eq!(out[0], 0.0);
        assert_eq!(out[2], 0.6875);
        assert_eq!(out[4], 0.6875);
        assert_eq!(out[6], 0.0);
        assert_eq!(out[7], 0.0);
        assert!(out[1].is_nan() && out[3].is_nan() && out[5].is_nan()); // observed entries untouched
                                                                        // two knots: the straight line; none: zero
        let mut two = [f32::NAN; 5];
        fill_spline(
            &[1.0, 0.0, 0.0, 0.0, 1.0],
            &[0.0, 9.0, 9.0, 9.0, 2.0],
            |l, v| two[l] = v,
        );
        assert_eq!(&two[1..4], &[0.5, 1.0, 1.5]);
        let mut none = [f32::NAN; 3];
        fill_spline(&[0.0; 3], &[f32::NAN; 3], |l, v| none[l] = v);
        assert_eq!(none, [0.0; 3]);
    }

    #[test]
    fn fill_rows_fills_every_row_and_checks_sizes() {
        use super::{fill_rows, CondFill};
        let mask = [1.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        let obs = [2.0, f32::NAN, 4.0, f32::NAN, f32::NAN, f32::NAN];
        let out = fill_rows(CondFill::Linear, 3, &mask, &obs).unwrap();
        assert_eq!(out, [2.0, 3.0, 4.0, 0.0, 0.0, 0.0]); // a row with nothing observed is 0
        assert_eq!(fill_rows(CondFill::Spline, 3, &mask, &obs).unwrap(), out); // two knots: the line
        assert!(fill_rows(CondFill::Linear, 4, &mask, &obs).is_err());
        assert!(fill_rows(CondFill::Linear, 0, &mask, &obs).is_err());
        assert!(fill_rows(CondFill::Linear, 3, &mask[..3], &obs).is_err());
        assert_eq!(CondFill::interpolation("spline").unwrap(), CondFill::Spline);
        assert!(CondFill::interpolation("zero").is_err());
    }
}
