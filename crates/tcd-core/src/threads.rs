//! Running engine calls on a chosen number of threads.
//!
//! Chains are distributed with rayon; by default on rayon's global pool (one thread per core,
//! or `RAYON_NUM_THREADS`). Results never depend on the thread count.

use crate::error::{Error, Result};

/// Runs `f` on a fresh rayon pool of `threads` threads (`None`: the global pool).
pub fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> Result<T> {
    match threads {
        None => Ok(f()),
        Some(n) => {
            if n == 0 {
                return Err(Error::invalid_input("threads", "at least 1 (or None for all cores)", "0"));
            }
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| Error::ThreadPool {
                    threads: n,
                    reason: e.to_string(),
                })?;
            Ok(pool.install(f))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pools() {
        assert_eq!(with_threads(Some(2), rayon::current_num_threads).unwrap(), 2);
        assert_eq!(with_threads(None, || 7).unwrap(), 7);
        assert!(with_threads(Some(0), || ()).is_err());
    }
}
