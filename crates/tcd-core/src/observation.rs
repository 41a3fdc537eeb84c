//! The one observation type of the engine: the observed values of (B, K, L) sequences and their mask,
//! checked once, when made ([`Observation::new`]). Every entry point that takes observations takes
//! this ([`crate::sample`], [`crate::cascade`], [`crate::repair`], [`crate::prior_fill`],
//! [`crate::Denoiser::forward`], [`crate::Denoiser::prepare`]) and then only checks that its shape
//! fits the model.

use crate::error::{check_positive, Error, Result};
use crate::validate;

/// Observed sequences: `values` and `mask`, both **(B, K, L)** row-major f32 (frame fastest, K = joints·3
/// in model units); mask 1 = given, 0 = to generate. `values` may hold anything where the mask is 0 (NaN
/// marks a missing value there): only a model conditioned on the prior forecaster reads those entries,
/// where the caller has put the prior's fill ([`crate::prior_fill`]), and it checks them itself.
///
/// Made by [`Observation::new`], which checks the shape, the mask and the values once; it borrows the
/// two buffers. An error names the argument: `batch`, `num_features` or `length` (a zero dimension),
/// `mask` (its size or a value other than 0 and 1), `observed` (its size, or a non-finite given value).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation<'a> {
    values: &'a [f32],
    mask: &'a [f32],
    shape: [usize; 3],
}

impl<'a> Observation<'a> {
    /// Checks `values` and `mask` as sequences of `shape` = (B, K, L): every dimension at least 1, both
    /// buffers of B·K·L values, the mask of 0.0 and 1.0 only, the values finite wherever the mask is 1.
    pub fn new(values: &'a [f32], mask: &'a [f32], shape: [usize; 3]) -> Result<Self> {
        let [batch, num_features, length] = shape;
        check_positive("batch", batch)?;
        check_positive("num_features", num_features)?;
        check_positive("length", length)?;
        let size = batch
            .checked_mul(num_features)
            .and_then(|v| v.checked_mul(length))
            .ok_or_else(|| {
                Error::invalid_input(
                    "observed",
                    "a shape (B, K, L) whose size fits in memory",
                    format!("shape ({batch}, {num_features}, {length})"),
                )
            })?;
        let described = format!("({batch}, {num_features}, {length})");
        validate::mask("mask", mask, size, &described)?;
        validate::finite_where("observed", values, mask, 1.0, size, &described)?;
        Ok(Observation {
            values,
            mask,
            shape,
        })
    }

    /// An observation the engine built from a checked one (padded, filled, averaged): valid by
    /// construction, so not checked again.
    pub(crate) fn checked_by_construction(
        values: &'a [f32],
        mask: &'a [f32],
        shape: [usize; 3],
    ) -> Self {
        debug_assert_eq!(values.len(), shape.iter().product::<usize>());
        debug_assert_eq!(mask.len(), values.len());
        Observation {
            values,
            mask,
            shape,
        }
    }

    /// The observed values, (B, K, L).
    pub fn values(&self) -> &'a [f32] {
        self.values
    }
    /// The mask, (B, K, L): 1 = given, 0 = to generate.
    pub fn mask(&self) -> &'a [f32] {
        self.mask
    }
    /// (B, K, L).
    pub fn shape(&self) -> [usize; 3] {
        self.shape
    }
    /// B: the sequences.
    pub fn batch(&self) -> usize {
        self.shape[0]
    }
    /// K: the coordinates per frame.
    pub fn num_features(&self) -> usize {
        self.shape[1]
    }
    /// L: the frames of each sequence.
    pub fn length(&self) -> usize {
        self.shape[2]
    }

    /// Checks that the sequences have `num_features` coordinates (`whose`: the model's, for the
    /// message) and, with `frames`, exactly that many frames (`frames_named` says which length it is).
    pub(crate) fn expect(
        &self,
        num_features: usize,
        whose: &str,
        frames: Option<(usize, &str)>,
    ) -> Result<()> {
        let [batch, k, length] = self.shape;
        let fits = k == num_features && frames.is_none_or(|(l, _)| l == length);
        if fits {
            return Ok(());
        }
        let expected = match frames {
            None => format!("sequences (B, K, L) with K = {num_features} ({whose} num_features)"),
            Some((l, named)) => format!(
                "sequences (B, K, L) with K = {num_features} ({whose} num_features) and L = {l} ({whose} {named})"
            ),
        };
        Err(Error::invalid_input(
            "observed",
            expected,
            format!("shape ({batch}, {k}, {length})"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn argument(e: Error) -> String {
        match e {
            Error::InvalidInput { argument, .. } => argument,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn checked_once_with_errors_naming_the_argument() {
        let values = [1.0, f32::NAN, 2.0, 3.0, 4.0, 5.0];
        let mask = [1.0, 0.0, 1.0, 1.0, 1.0, 1.0];
        let o = Observation::new(&values, &mask, [1, 2, 3]).unwrap();
        assert_eq!((o.batch(), o.num_features(), o.length()), (1, 2, 3));
        assert_eq!(o.shape(), [1, 2, 3]);
        assert!(o.expect(2, "the model's", Some((3, "obs_len"))).is_ok());
        let e = o.expect(3, "the model's", None).unwrap_err();
        assert!(
            e.to_string().contains("K = 3 (the model's num_features)"),
            "{e}"
        );
        assert_eq!(
            argument(
                o.expect(2, "the model's", Some((4, "obs_len")))
                    .unwrap_err()
            ),
            "observed"
        );
        let new = |v: &[f32], m: &[f32], s| Observation::new(v, m, s).map(|_| ()).map_err(argument);
        assert_eq!(new(&values, &mask, [0, 2, 3]), Err("batch".into()));
        assert_eq!(new(&values, &mask, [1, 0, 3]), Err("num_features".into()));
        assert_eq!(new(&values, &mask, [1, 2, 0]), Err("length".into()));
        assert_eq!(new(&values, &mask[1..], [1, 2, 3]), Err("mask".into()));
        assert_eq!(new(&values[1..], &mask, [1, 2, 3]), Err("observed".into()));
        assert_eq!(
            new(&values, &mask, [usize::MAX, 2, 3]),
            Err("observed".into())
        );
        let soft = [1.0, 0.5, 1.0, 1.0, 1.0, 1.0];
        assert_eq!(new(&values, &soft, [1, 2, 3]), Err("mask".into()));
        let nan_given = [1.0; 6].map(|v: f32| v * f32::NAN);
        assert_eq!(new(&nan_given, &mask, [1, 2, 3]), Err("observed".into()));
    }
}
