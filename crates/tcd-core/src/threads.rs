//! Running engine calls on a chosen number of threads.
//!
//! Chains are distributed with rayon; by default on rayon's global pool (one thread per core,
//! or `RAYON_NUM_THREADS`). Results never depend on the thread count.

use std::collections::HashMap;
use std::sync::{Mutex, MutexGuard, OnceLock, PoisonError};

use rayon::ThreadPool;

use crate::error::{Error, Result};

/// Runs `f` on a rayon pool of `threads` threads (`None`: the global pool).
///
/// Pools are built once and reused: a call takes an idle pool of its thread count (building one
/// only if none is idle) and gives it back when `f` returns, so that repeated calls (one per
/// forecast, one per Python call) do not spawn and join threads each time. Calls that overlap
/// (several Python threads, or a call inside `f`) each get a pool of their own, as when every
/// call built one: they never queue behind each other on a shared pool. Pools are kept for the
/// life of the process, as many per thread count as calls ever overlapped.
pub fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> Result<T> {
    match threads {
        None => Ok(f()),
        Some(n) => {
            let lease = Lease::take(n)?;
            Ok(lease.pool().install(f))
        }
    }
}

/// The idle pools, by thread count.
fn idle() -> MutexGuard<'static, HashMap<usize, Vec<ThreadPool>>> {
    static IDLE: OnceLock<Mutex<HashMap<usize, Vec<ThreadPool>>>> = OnceLock::new();
    // The map is consistent whenever the lock is released (one push or pop at most happens under
    // it), so a lock poisoned by a panic elsewhere is still usable.
    IDLE.get_or_init(Default::default)
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
}

/// A pool of `threads` threads taken from the idle ones, given back when dropped (also when `f`
/// panics: rayon passes the panic on and the pool stays usable). The lock is held only to take
/// or give back, never while work runs.
struct Lease {
    threads: usize,
    pool: Option<ThreadPool>,
}

impl Lease {
    fn take(threads: usize) -> Result<Lease> {
        if threads == 0 {
            return Err(Error::invalid_input(
                "threads",
                "at least 1 (or None for all cores)",
                "0",
            ));
        }
        let reused = idle().get_mut(&threads).and_then(Vec::pop);
        let pool = match reused {
            Some(p) => p,
            None => rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .map_err(|e| Error::ThreadPool {
                    threads,
                    reason: e.to_string(),
                })?,
        };
        Ok(Lease {
            threads,
            pool: Some(pool),
        })
    }

    fn pool(&self) -> &ThreadPool {
        // `pool` is only taken out in `drop`.
        self.pool
            .as_ref()
            .unwrap_or_else(|| unreachable!("a lease holds its pool until dropped"))
    }
}

impl Drop for Lease {
    fn drop(&mut self) {
        if let Some(p) = self.pool.take() {
            idle().entry(self.threads).or_default().push(p);
        }
    }
}

#[cfg(test)]
mod tests {
    use std::thread::{self, ThreadId};

    use super::*;

    #[test]
    fn pools() {
        assert_eq!(
            with_threads(Some(2), rayon::current_num_threads).unwrap(),
            2
        );
        assert_eq!(with_threads(None, || 7).unwrap(), 7);
        assert!(with_threads(Some(0), || ()).is_err());
    }

    /// The worker of a one-thread pool that runs `f` (thread ids are never reused in a process,
    /// so the same id means the same pool).
    fn worker() -> ThreadId {
        thread::current().id()
    }

    #[test]
    fn repeated_calls_reuse_one_pool() {
        // Thread count 1 is used only by this test, so no other test takes its pool meanwhile.
        let first = with_threads(Some(1), worker).unwrap();
        assert_ne!(first, thread::current().id());
        for _ in 0..3 {
            assert_eq!(with_threads(Some(1), worker).unwrap(), first);
        }
        // A call inside a call gets another pool (not queued on the busy one); afterwards both
        // are idle and reused.
        let (outer, inner) = with_threads(Some(1), || {
            (worker(), with_threads(Some(1), worker).unwrap())
        })
        .unwrap();
        assert_eq!(outer, first);
        assert_ne!(inner, first);
        assert_eq!(with_threads(Some(1), worker).unwrap(), first);
        assert_eq!(
            with_threads(Some(3), rayon::current_num_threads).unwrap(),
            3
        );
    }
}
