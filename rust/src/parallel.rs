//! Running work on a chosen number of threads. Results never depend on the thread count:
//! work is split into fixed-size chunks and every random number comes from a counter-based
//! generator, so pools only change speed.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use crate::error::{Error, Result};

/// Largest accepted `threads` argument.
pub const MAX_THREADS: usize = 1024;

fn pools() -> &'static Mutex<HashMap<usize, Arc<rayon::ThreadPool>>> {
    static POOLS: OnceLock<Mutex<HashMap<usize, Arc<rayon::ThreadPool>>>> = OnceLock::new();
    POOLS.get_or_init(Default::default)
}

/// Runs `f` on a pool of `threads` workers (`None`: rayon's global pool, one per core).
/// Pools are created once per size and kept.
pub fn with_threads<R: Send>(threads: Option<usize>, f: impl FnOnce() -> R + Send) -> Result<R> {
    let Some(n) = threads else {
        return Ok(f());
    };
    if n == 0 || n > MAX_THREADS {
        return Err(Error::invalid(
            "threads",
            format!("must be between 1 and {MAX_THREADS}, got {n}"),
        ));
    }
    let pool = {
        let mut map = pools().lock().unwrap_or_else(|e| e.into_inner());
        match map.get(&n) {
            Some(p) => p.clone(),
            None => {
                let p = rayon::ThreadPoolBuilder::new()
                    .num_threads(n)
                    .thread_name(|i| format!("viscache-{i}"))
                    .build()
                    .map_err(|e| Error::invalid("threads", e.to_string()))?;
                let p = Arc::new(p);
                map.insert(n, p.clone());
                p
            }
        }
    };
    Ok(pool.install(f))
}
