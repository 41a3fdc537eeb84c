//! Checks on user-supplied arrays, shared by the public entry points.

use crate::error::{check_len, Error, Result};

/// `mask` has `expected` elements, each exactly 0.0 or 1.0.
pub(crate) fn mask(argument: &str, mask: &[f32], expected: usize, shape: &str) -> Result<()> {
    check_len(argument, mask.len(), expected, shape)?;
    if let Some((i, v)) = mask
        .iter()
        .enumerate()
        .find(|(_, v)| **v != 0.0 && **v != 1.0)
    {
        return Err(Error::invalid_input(
            argument,
            "a mask of 0.0 (generate) and 1.0 (observed) values",
            format!("{v} at flat index {i}"),
        ));
    }
    Ok(())
}

/// `values` has `expected` elements and is finite wherever `mask == keep` (elsewhere it is ignored,
/// so NaN marks a missing value there).
pub(crate) fn finite_where(
    argument: &str,
    values: &[f32],
    mask: &[f32],
    keep: f32,
    expected: usize,
    shape: &str,
) -> Result<()> {
    check_len(argument, values.len(), expected, shape)?;
    if let Some((i, v)) = values
        .iter()
        .zip(mask)
        .enumerate()
        .find(|(_, (v, m))| **m == keep && !v.is_finite())
        .map(|(i, (v, _))| (i, v))
    {
        let place = if keep == 1.0 {
            "observed (mask 1)"
        } else {
            "generated (mask 0)"
        };
        return Err(Error::invalid_input(
            argument,
            format!("finite at every {place} entry"),
            format!("{v} at flat index {i}"),
        ));
    }
    Ok(())
}

/// Every value finite.
pub(crate) fn all_finite(
    argument: &str,
    values: &[f32],
    expected: usize,
    shape: &str,
) -> Result<()> {
    check_len(argument, values.len(), expected, shape)?;
    if let Some((i, v)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(Error::invalid_input(
            argument,
            "finite everywhere",
            format!("{v} at flat index {i}"),
        ));
    }
    Ok(())
}

/// `values`, sequences of `frames` frames of `k` values (frame-major, (B, frames, K)), is finite in the
/// last `obs_len` frames of every sequence: the frames a model reads; what comes before them is ignored
/// (NaN there is fine). The length is the caller's to check first.
pub(crate) fn finite_last_frames(
    argument: &str,
    values: &[f32],
    frames: usize,
    k: usize,
    obs_len: usize,
) -> Result<()> {
    let skip = (frames - obs_len) * k;
    if let Some(i) = values
        .chunks_exact(frames * k)
        .enumerate()
        .find_map(|(b, seq)| {
            seq[skip..]
                .iter()
                .position(|v| !v.is_finite())
                .map(|j| b * frames * k + skip + j)
        })
    {
        return Err(Error::invalid_input(
            argument,
            format!("finite in the last obs_len = {obs_len} frames of every sequence (the frames the model reads)"),
            format!("{} at flat index {i}", values[i]),
        ));
    }
    Ok(())
}
