//! The network input of one sequence: the observed channel (filled along time by the model's
//! [`CondFill`], [`crate::fill`]) and the noisy channel, interleaved.

use crate::config::CondFill;

/// The network input of one sequence, interleaved (N × 2) with N = K·L in (k, l) order: channel 0 is
/// the observed channel (`m · x₀`, or with [`CondFill::Linear`] / [`CondFill::Spline`] the masked entries
/// filled along time from the observed ones, with [`CondFill::Prior`] the values `observed` holds there:
/// [`CondFill::fill_row`]), channel 1 is `(1 − m) · x_t`.
pub(super) fn build_input(
    fill: CondFill,
    length: usize,
    mask: &[f32],
    observed: &[f32],
    noisy: &[f32],
    inp: &mut [f32],
) {
    for (((pair, &mv), &ov), &nv) in inp.chunks_exact_mut(2).zip(mask).zip(observed).zip(noisy) {
        pair[0] = if mv == 0.0 { 0.0 } else { mv * ov };
        pair[1] = if mv == 1.0 { 0.0 } else { (1.0 - mv) * nv };
    }
    if fill != CondFill::Zero {
        for ((row, m), o) in inp
            .chunks_exact_mut(2 * length)
            .zip(mask.chunks_exact(length))
            .zip(observed.chunks_exact(length))
        {
            fill.fill_row(m, o, |ll, v| row[2 * ll] = v);
        }
    }
}
