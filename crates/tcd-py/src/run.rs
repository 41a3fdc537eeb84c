//! Running a long engine call from Python: the work runs on a scoped thread while the calling thread,
//! without the GIL, waits for it in slices of [`POLL`]. Between slices it takes the GIL to run Python's
//! signal handlers (Ctrl-C raises `KeyboardInterrupt` there) and to report progress; when either raises,
//! the call is cancelled (every chain stops before its next forward), the thread is joined, and that
//! exception is returned: nothing keeps computing in the background.
//!
//! A signal can arrive before the first slice: between the caller's last Python bytecode (where Python
//! itself would have raised it) and this function, while Rust code holds the GIL (converting the
//! arguments, preparing the noise). Such a signal is only pending, so the signals are checked once more
//! before the worker starts: a call interrupted before it started does no work. (Unchecked, it was seen
//! after the first slice, or only once the result was back when the work took less than one slice.)
//!
//! Only the main thread runs Python's signal handlers (`check_signals` does nothing elsewhere): a call made
//! from another thread is stopped by an exception raised in its `progress` callback, not by Ctrl-C. And a
//! process that ignores SIGINT (`SIG_IGN`, e.g. inherited from a non-interactive shell's `cmd &`) never
//! sees it: the disposition is the application's, which this binding does not change.

use std::sync::mpsc::{channel, RecvTimeoutError};
use std::time::Duration;

use pyo3::prelude::*;
use tcd_core::{with_threads, Control};

use crate::convert::CoreResult;
use crate::error::{internal, Result};

/// How often the waiting thread looks at signals and progress: the bound on how late Ctrl-C is seen.
const POLL: Duration = Duration::from_millis(100);

/// Runs `work` interruptibly on `threads` threads (`None`: all cores); `progress`, a Python callable,
/// gets `(forwards_done, forwards_total)` at every poll and once at the end.
pub(crate) fn interruptible<T, F>(
    py: Python<'_>,
    progress: Option<&Bound<'_, PyAny>>,
    threads: Option<usize>,
    work: F,
) -> Result<T>
where
    T: Send,
    F: FnOnce(&Control) -> CoreResult<T> + Send,
{
    py.check_signals()?; // one that arrived before the call: see the module's documentation
    let control = Control::default();
    let report = |control: &Control| -> PyResult<()> {
        match progress {
            Some(callback) => callback
                .call1((control.forwards_done(), control.forwards_total()))
                .map(drop),
            None => Ok(()),
        }
    };
    std::thread::scope(|scope| {
        let (tx, rx) = channel();
        let ctl = &control;
        scope.spawn(move || {
            // the receiver outlives the thread unless the caller is already gone: nothing to report then
            let _ = tx.send(with_threads(threads, || work(ctl)).and_then(|out| out));
        });
        let mut rx = rx;
        loop {
            // the receiver is not Sync: it travels into the GIL-free closure and back
            let (got, back) = py.detach(move || (rx.recv_timeout(POLL), rx));
            rx = back;
            match got {
                Ok(result) => {
                    let out = result?;
                    report(ctl)?;
                    return Ok(out);
                }
                Err(RecvTimeoutError::Timeout) => {
                    if let Err(e) = py.check_signals().and_then(|()| report(ctl)) {
                        ctl.cancel();
                        let _ = py.detach(move || rx.recv());
                        return Err(e.into());
                    }
                }
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(
                        internal(py, "the engine's worker thread ended without a result").into(),
                    );
                }
            }
        }
    })
}
