//! Every fill of missing values the engine runs: along time, row by row ([`fill_linear`],
//! [`fill_spline`], [`fill_rows`]: the denoisers' observed channel and `tcd.interpolate`), and the prior's
//! fill of a window with its gap fill and in-betweeners ([`prior_fill`]: what a model conditioned on the
//! prior forecaster, or a repair model conditioned on its repair fill, sees at its masked entries).

mod along_time;
mod prior;

pub use along_time::{fill_linear, fill_rows, fill_spline};
pub use prior::prior_fill;
pub(crate) use prior::{fill_with_prior, gap_forecaster};
