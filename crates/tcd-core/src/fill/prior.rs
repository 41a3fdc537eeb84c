//! The prior's fill of a window's masked entries (`training.model.prior_fill`, [`prior_fill`]): the
//! natural cubic spline through the observed entries, corrected or continued by a prior network, and a
//! repair fill's gap fill (whole-frame gaps filled from the prior forecaster's forecasts into the gap from
//! both sides, [`fill_gaps`]), with its learned in-betweeners ([`inbetween`]).

use crate::control::Control;
use crate::error::{Error, Result};
use crate::observation::Observation;
use crate::prior::{inbetween_width, Anchor, GapFill, Prior};
use crate::weights::Network;

use super::fill_spline;

/// `observed` with its mask-0 entries replaced by the prior's fill (`training.model.prior_fill`), (B, K, L)
/// like it: over the first O = `prior.obs_len()` frames of every row the natural cubic spline through
/// that row's observed entries among them ([`fill_spline`], the reference's bits), after them the prior's
/// rollout ([`Prior::predict`]) from those O filled frames (frame O + i is its i-th forecast frame).
/// A repair fill (anchor [`Anchor::Window`], L = O) corrects the spline-filled window instead: its
/// output fills every mask-0 entry, and one with `gap_fill` [`GapFill::Forecaster`] then fills the
/// window's whole-frame gaps from `forecaster` ([`fill_gaps`]; required for it, unused otherwise).
/// Mask-1 entries are kept (a long-term window's given frames after O too); mask-0 entries of
/// `observed` are never read. Needs the prior's K and L > O (L = O for a repair fill); `control` can
/// stop the rollout.
pub fn prior_fill(
    prior: &Prior,
    forecaster: Option<&Prior>,
    observed: &Observation<'_>,
    control: &Control,
) -> Result<Vec<f32>> {
    let (k, o) = (prior.num_features(), prior.obs_len());
    observed.expect(k, "the prior's", None)?;
    let [batch, _, length] = observed.shape();
    if prior.config().model.anchor == Anchor::Window && length != o {
        return Err(Error::invalid_input(
            "length",
            format!("the repair fill's window (obs_len = {o} frames)"),
            length.to_string(),
        ));
    }
    if prior.config().model.anchor == Anchor::Last && length <= o {
        return Err(Error::invalid_input(
            "length",
            format!("more frames than the prior reads (obs_len = {o})"),
            length.to_string(),
        ));
    }
    let gaps = gap_forecaster(prior, forecaster)?;
    let mut values = observed.values().to_vec();
    fill_with_prior(
        prior,
        gaps,
        &mut values,
        observed.mask(),
        batch,
        length,
        control,
    )?;
    Ok(values)
}

/// The forecaster a repair fill runs its gap fill with: `None` for a fill without one (`gap_fill`
/// [`GapFill::None`]); for [`GapFill::Forecaster`] `forecaster`, which must be given, be a forecaster
/// (anchor [`Anchor::Last`]) and have the fill's `num_features`.
pub(crate) fn gap_forecaster<'p>(
    fill: &Prior,
    forecaster: Option<&'p Prior>,
) -> Result<Option<&'p Prior>> {
    if fill.config().model.gap_fill == GapFill::None {
        return Ok(None);
    }
    let k = fill.num_features();
    match forecaster {
        None => Err(Error::invalid_input(
            "forecaster",
            "the prior forecaster (prior.safetensors): the repair fill fills whole-frame gaps with it \
             (gap_fill \"forecaster\")",
            "none",
        )),
        Some(f) if f.config().model.anchor != Anchor::Last || f.num_features() != k => {
            Err(Error::invalid_input(
                "forecaster",
                format!("a prior forecaster (anchor \"last\") with the repair fill's num_features = {k}"),
                format!(
                    "anchor {:?}, num_features = {}",
                    f.config().model.anchor,
                    f.num_features()
                ),
            ))
        }
        Some(f) => Ok(Some(f)),
    }
}

/// The maximal runs `[start, end)` of frames `0..length` where `hidden(t)`.
fn hidden_runs(length: usize, hidden: impl Fn(usize) -> bool) -> Vec<(usize, usize)> {
    let mut runs = Vec::new();
    let mut t = 0;
    while t < length {
        if !hidden(t) {
            t += 1;
            continue;
        }
        let start = t;
        while t < length && hidden(t) {
            t += 1;
        }
        runs.push((start, t));
    }
    runs
}

/// The runs of frames `[start, end)` of each sequence of a (B, K, L) `mask` in which every entry is
/// mask 0, as (sequence, start, end), except a run over the whole window (nothing to fill it from).
fn whole_frame_gaps(mask: &[f32], batch: usize, length: usize) -> Vec<(usize, usize, usize)> {
    let k = mask.len() / (batch * length);
    let mut gaps = Vec::new();
    for (b, m) in mask.chunks_exact(k * length).enumerate() {
        let hidden = |t: usize| (0..k).all(|kk| m[kk * length + t] <= 0.5);
        for (start, end) in hidden_runs(length, hidden) {
            if start > 0 || end < length {
                gaps.push((b, start, end));
            }
        }
    }
    gaps
}

/// Fills the whole-frame `gaps` ([`whole_frame_gaps`]) of a filled (B, K, L) window in place
/// (`training.model.fill_gaps`, the same steps). For a gap of n frames [s, e), with weights
/// w_i = (i + 1) / (n + 1):
/// * forward (s > 0): `forecaster` predicts n + 1 frames from the frames before the gap (its last
///   `obs_len`, the first repeated before them where fewer); frame s + i is its i-th frame, plus
///   w_i times the miss of its n-th frame against frame e where the window goes on (so it arrives there);
/// * backward (e < L): the same on the time-reversed frames after the gap (the prior trains with time
///   flips), reversed back, meeting frame s - 1;
/// * the two blended as (1 - w_i) forward + w_i backward (one alone at a window's edge), and that
///   averaged with the fill already there (the repair fill's correction of the spline).
///
/// Every history is read from the fill as it was before any gap is filled, and all of them are
/// predicted in one call. What it gains: docs/repair.md, "Whole-frame gaps".
fn fill_gaps(
    forecaster: &Prior,
    values: &mut [f32],
    gaps: &[(usize, usize, usize)],
    length: usize,
    control: &Control,
) -> Result<()> {
    if gaps.is_empty() {
        return Ok(());
    }
    let (k, o) = (forecaster.num_features(), forecaster.obs_len());
    let at = |b: usize, kk: usize, t: usize| (b * k + kk) * length + t;
    // One history (O, K) frame-major per side of each gap: frame `frame(j)` of the window at step j.
    let mut histories = Vec::new();
    let mut count = 0;
    let mut push = |b: usize, frame: &dyn Fn(usize) -> usize| {
        for j in 0..o {
            let t = frame(j);
            histories.extend((0..k).map(|kk| values[at(b, kk, t)]));
        }
        count += 1;
        count - 1
    };
    let mut sides = Vec::with_capacity(gaps.len());
    for &(b, s, e) in gaps {
        // The last O frames before s (forward), or of the frames after e read backwards, the first
        // repeated before them where there are fewer.
        let fwd = (s > 0).then(|| push(b, &|j| (s + j).saturating_sub(o)));
        let bwd = (e < length).then(|| {
            let after = length - e;
            push(b, &|j| length - 1 - (after + j).saturating_sub(o))
        });
        sides.push((fwd, bwd));
    }
    let horizon = gaps.iter().map(|&(_, s, e)| e - s + 1).max().unwrap_or(1);
    let out = forecaster.predict(&histories, count, o, horizon, control)?; // (count, horizon, K)
    let pred = |row: usize, i: usize, kk: usize| out[(row * horizon + i) * k + kk];
    for (&(b, s, e), &(fwd, bwd)) in gaps.iter().zip(&sides) {
        let n = e - s;
        for kk in 0..k {
            // Each side's miss at the frame it should arrive at (0 at a window's edge).
            let fwd_miss = match fwd {
                Some(r) if e < length => values[at(b, kk, e)] - pred(r, n, kk),
                _ => 0.0,
            };
            let bwd_miss = match bwd {
                Some(r) if s > 0 => values[at(b, kk, s - 1)] - pred(r, n, kk),
                _ => 0.0,
            };
            for i in 0..n {
                let w = (i + 1) as f32 / (n + 1) as f32;
                let forward = fwd.map(|r| pred(r, i, kk) + w * fwd_miss);
                // Backward frame i is its forecast's frame n - 1 - i, whose weight is 1 - w.
                let backward = bwd.map(|r| pred(r, n - 1 - i, kk) + (1.0 - w) * bwd_miss);
                let both = match (forward, backward) {
                    (Some(f), Some(g)) => (1.0 - w) * f + w * g,
                    (Some(f), None) => f,
                    (None, Some(g)) => g,
                    (None, None) => unreachable!("a gap over the whole window is not filled"),
                };
                let v = &mut values[at(b, kk, s + i)];
                *v = 0.5 * (both + *v);
            }
        }
    }
    Ok(())
}

/// [`prior_fill`] in place on `values` with `mask`, (B, K, L) of a checked observation with the prior's K
/// and L > its obs_len (L = obs_len for a repair fill, anchor [`Anchor::Window`]); `gaps`: the repair
/// fill's checked gap forecaster ([`gap_forecaster`]), whose [`fill_gaps`] then runs, `None` otherwise.
pub(crate) fn fill_with_prior(
    prior: &Prior,
    gaps: Option<&Prior>,
    values: &mut [f32],
    mask: &[f32],
    batch: usize,
    length: usize,
    control: &Control,
) -> Result<()> {
    let (k, o) = (prior.num_features(), prior.obs_len());
    let window = prior.config().model.anchor == Anchor::Window;
    // A forecaster rolls out the frames after O; a repair fill corrects the O frames it reads.
    let horizon = if window { o } else { length - o };
    // The filled first O frames, frame-major (B, O, K) as the prior reads them.
    let mut head = vec![0.0f32; batch * o * k];
    let mut row_head = vec![0.0f32; o];
    for (r, (row, m)) in values
        .chunks_exact(length)
        .zip(mask.chunks_exact(length))
        .enumerate()
    {
        row_head.copy_from_slice(&row[..o]);
        fill_spline(&m[..o], &row[..o], |ll, v| row_head[ll] = v);
        let (b, kk) = (r / k, r % k);
        for (t, &v) in row_head.iter().enumerate() {
            head[(b * o + t) * k + kk] = v;
        }
    }
    let out = prior.predict(&head, batch, o, horizon, control)?; // (B, horizon, K): the rollout, or the corrected window
    for (r, (row, m)) in values
        .chunks_exact_mut(length)
        .zip(mask.chunks_exact(length))
        .enumerate()
    {
        let (b, kk) = (r / k, r % k);
        for (ll, (v, &mv)) in row.iter_mut().zip(m).enumerate() {
            if mv > 0.5 {
                continue;
            }
            *v = if window {
                out[(b * o + ll) * k + kk]
            } else if ll < o {
                head[(b * o + ll) * k + kk]
            } else {
                out[(b * horizon + ll - o) * k + kk]
            };
        }
    }
    let m = &prior.config().model;
    if window && (gaps.is_some() || m.inbetween_max_gap > 0 || m.joint_inbetween_max_gap > 0) {
        // the window's whole-frame gaps, which the gap fill fills and the in-betweeners correct
        let frame_gaps = whole_frame_gaps(mask, batch, length);
        if let Some(f) = gaps {
            fill_gaps(f, values, &frame_gaps, length, control)?;
        }
        inbetween(prior, values, mask, &frame_gaps, batch, length);
    }
    Ok(())
}

/// A repair fill's in-betweeners on its gap-filled (B, K, L) window, in place (`training.inbetween`, the same
/// arithmetic in f64; what they gain: docs/repair.md): the whole-frame gaps ([`whole_frame_gaps`]) of a length
/// with a kernel (`inbetween_n`), every coordinate of the gap; then, per coordinate, each run of hidden frames
/// with no frame of a whole-frame gap, not the whole window, of a length with a joint kernel
/// (`joint_inbetween_n`). Every input is read from the window before any correction is added.
fn inbetween(
    prior: &Prior,
    values: &mut [f32],
    mask: &[f32],
    gaps: &[(usize, usize, usize)],
    batch: usize,
    length: usize,
) {
    let m = &prior.config().model;
    if m.inbetween_max_gap == 0 && m.joint_inbetween_max_gap == 0 {
        return;
    }
    let k = prior.num_features();
    let src = values.to_vec();
    for &(b, s, e) in gaps {
        if let Some(w) = prior.inbetween_kernel(e - s) {
            for kk in 0..k {
                let row = (b * k + kk) * length;
                let out = &mut values[row..row + length];
                run_correction(&src[row..row + length], out, (s, e), m.inbetween_context, w);
            }
        }
    }
    if m.joint_inbetween_max_gap == 0 {
        return;
    }
    let mut in_gap = vec![false; batch * length];
    for &(b, s, e) in gaps {
        in_gap[b * length + s..b * length + e].fill(true);
    }
    for (r, m_row) in mask.chunks_exact(length).enumerate() {
        let (b, row) = (r / k, r * length);
        for (s, t) in hidden_runs(length, |t| m_row[t] <= 0.5) {
            let whole = s == 0 && t == length;
            if whole || in_gap[b * length + s..b * length + t].iter().any(|&g| g) {
                continue;
            }
            if let Some(w) = prior.joint_inbetween_kernel(t - s) {
                let out = &mut values[row..row + length];
                run_correction(
                    &src[row..row + length],
                    out,
                    (s, t),
                    m.joint_inbetween_context,
                    w,
                );
            }
        }
    }
}

/// One row's correction over its frames [s, e) (n = e − s) by kernel `w` (n × [`inbetween_width`]) with
/// `c` context frames: the inputs are the row of `src` over frames s − c .. e + c (indices clamped to the
/// row) minus its frame s − 1 (clamped), the fractions of the c context frames inside the row before and
/// after, and that segment times each fraction; `out`[s + i] gets w_i · inputs added (f64 sums).
fn run_correction(src: &[f32], out: &mut [f32], (s, e): (usize, usize), c: usize, w: &[f32]) {
    let (length, n) = (src.len(), e - s);
    let (seg, d) = (2 * c + n, inbetween_width(n, c));
    let at = |t: isize| f64::from(src[t.clamp(0, length as isize - 1) as usize]);
    let before = s.min(c) as f64 / c as f64;
    let after = (length - e).min(c) as f64 / c as f64;
    let base = at(s as isize - 1);
    let mut x = vec![0.0f64; d];
    x[seg] = before;
    x[seg + 1] = after;
    for j in 0..seg {
        let r = at(s as isize - c as isize + j as isize) - base;
        x[j] = r;
        x[seg + 2 + j] = r * before;
        x[2 * seg + 2 + j] = r * after;
    }
    for (i, wi) in w.chunks_exact(d).enumerate() {
        let correction: f64 = wi.iter().zip(&x).map(|(&a, &v)| f64::from(a) * v).sum();
        out[s + i] = (f64::from(out[s + i]) + correction) as f32;
    }
}
