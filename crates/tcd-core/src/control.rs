//! What the caller of a long call sees and decides while it runs: how many denoiser forwards are done
//! out of how many, and a request to stop. The binding polls it from the calling thread (progress bars,
//! Ctrl-C); the chains check it once per diffusion step, so a stop takes effect within one forward.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use crate::error::{Error, Result};

/// Shared by a call's chains and its caller; `Control::default()` is never cancelled.
#[derive(Debug, Default)]
pub struct Control {
    cancelled: AtomicBool,
    done: AtomicUsize,
    total: AtomicUsize,
}

impl Control {
    /// Asks the running call to stop: every chain stops before its next forward and the call returns
    /// [`Error::Cancelled`].
    pub fn cancel(&self) {
        self.cancelled.store(true, Ordering::Relaxed);
    }

    pub fn is_cancelled(&self) -> bool {
        self.cancelled.load(Ordering::Relaxed)
    }

    /// Per-sequence denoiser forwards done so far (one chain's step = one).
    pub fn forwards_done(&self) -> usize {
        self.done.load(Ordering::Relaxed)
    }

    /// Forwards the call will run in all, known once its inputs are checked (0 before).
    pub fn forwards_total(&self) -> usize {
        self.total.load(Ordering::Relaxed)
    }

    pub(crate) fn expect(&self, forwards: usize) {
        self.total.fetch_add(forwards, Ordering::Relaxed);
    }

    pub(crate) fn forward_done(&self) {
        self.done.fetch_add(1, Ordering::Relaxed);
    }

    /// `Err(Error::Cancelled)` once [`Control::cancel`] was called.
    pub(crate) fn check(&self) -> Result<()> {
        if self.is_cancelled() {
            Err(Error::Cancelled)
        } else {
            Ok(())
        }
    }
}
