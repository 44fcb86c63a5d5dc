//! Running work on a chosen number of threads. Results never depend on the thread count:
//! work is split into fixed-size chunks and every random number comes from a counter-based
//! generator, so pools only change speed.

use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::Arc;

use crate::error::{Error, Result};
use crate::stop::Stop;

/// Largest accepted `threads` argument.
pub const MAX_THREADS: usize = 1024;

/// Rows per rayon task at least in the batch-of-rows functions
/// ([`crate::bsdf::rows`], [`crate::lights::envmap::rows`]): below this a batch is not
/// worth splitting further.
pub const MIN_ROWS_PER_TASK: usize = 4096;

/// Fails with [`Error::InvalidArgument`] naming `name` unless it has the `want` rows of
/// `like` (what the message compares it with).
pub fn check_rows(name: &str, got: usize, want: usize, like: &str) -> Result<()> {
    if got == want {
        Ok(())
    } else {
        Err(Error::invalid(
            name,
            format!("expected {want} rows like {like}, got {got}"),
        ))
    }
}

thread_local! {
    /// This calling thread's pools, by size. Each caller has its own, so that callers on
    /// different threads (Python threads with `threads=1`, say) run side by side instead of
    /// queueing for one shared pool's workers; a thread's pools end with it.
    static POOLS: RefCell<HashMap<usize, Arc<rayon::ThreadPool>>> = RefCell::default();
}

/// Runs `f` on a pool of `threads` workers (`None`: rayon's global pool, one per core).
/// Pools are created once per calling thread and size, and kept. A call made from a
/// worker of a pool of that size (a nested call) runs on that pool. The calling thread's
/// current [`Stop`] is `f`'s current stop too.
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
    if rayon::current_thread_index().is_some() && rayon::current_num_threads() == n {
        return Ok(f());
    }
    let pool = POOLS.with(|pools| -> Result<_> {
        let mut pools = pools.borrow_mut();
        if let Some(p) = pools.get(&n) {
            return Ok(p.clone());
        }
        let p = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .thread_name(|i| format!("viscache-{i}"))
            .build()
            .map_err(|e| Error::invalid("threads", e.to_string()))?;
        Ok(pools.entry(n).or_insert(Arc::new(p)).clone())
    })?;
    let stop = Stop::installed();
    Ok(pool.install(|| Stop::scope_opt(stop, f)))
}

/// `f` of every item, in the items' order, computed on every worker of the current pool,
/// each taking the next item not yet taken. At any moment the workers are on neighbouring
/// items, where rayon's splitting would hand each a far part of the slice: shadow rays of
/// record bundles in the Morton order of their points then share the tree's nodes in the
/// cache the cores share (strands' bundles 1.06-1.12x, garden 1.06-1.09x, blob 1.03-1.04x
/// on 2 threads). Each result depends only on its item, so results never depend on the
/// thread count.
///
/// No item is taken once the calling thread's current [`Stop`] is set: the call then
/// returns [`Error::Interrupted`] when the items under way are done (an item that runs
/// long polls the stop itself, as ray runs do).
pub fn map_in_order<T: Sync, R: Send + Sync>(
    items: &[T],
    f: impl Fn(&T) -> R + Sync,
) -> Result<Vec<R>> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let next = AtomicUsize::new(0);
    let stop = Stop::current();
    let slots: Vec<std::sync::OnceLock<R>> = items.iter().map(|_| Default::default()).collect();
    rayon::broadcast(|_| loop {
        if stop.is_set() {
            break;
        }
        let i = next.fetch_add(1, Ordering::Relaxed);
        let Some(item) = items.get(i) else { break };
        // Each index is taken once, so each slot is set once.
        let _ = slots[i].set(f(item));
    });
    stop.check("work in order")?;
    Ok(slots
        .into_iter()
        .map(|s| s.into_inner().expect("every item is taken"))
        .collect())
}

/// Runs `work` on a scoped thread while the calling thread calls `poll` every `interval`
/// until the work returns; its result is returned (a panic in it is resumed here). For
/// callers that must stay responsive while the work runs: progress reports, signal checks.
/// The calling thread's current [`Stop`] is the work's current stop too.
pub fn run_polling<R: Send>(
    work: impl FnOnce() -> R + Send,
    interval: std::time::Duration,
    poll: &mut dyn FnMut(),
) -> R {
    std::thread::scope(|scope| {
        let (finished, wait) = std::sync::mpsc::channel::<()>();
        let stop = Stop::installed();
        let handle = scope.spawn(move || {
            let out = Stop::scope_opt(stop, work);
            let _ = finished.send(());
            out
        });
        while let Err(std::sync::mpsc::RecvTimeoutError::Timeout) = wait.recv_timeout(interval) {
            poll();
        }
        handle
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
    })
}

/// Seconds between progress reports of long work.
pub const PROGRESS_INTERVAL: std::time::Duration = std::time::Duration::from_millis(100);

/// Runs `work` on `threads` workers while the calling thread calls `poll` every
/// [`PROGRESS_INTERVAL`] (it may ask the work to stop by returning false; the work checks
/// a flag of its own).
pub fn run_with_progress<R: Send>(
    threads: Option<usize>,
    work: impl FnOnce() -> R + Send,
    poll: &mut dyn FnMut() -> bool,
) -> Result<R> {
    let mut polling = true;
    run_polling(
        || with_threads(threads, work),
        PROGRESS_INTERVAL,
        &mut || {
            if polling {
                polling = poll();
            }
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `map_in_order` gives `f` of each item in order on one, two and three workers, and
    /// nothing for no items; the items are spread over the workers.
    #[test]
    fn map_in_order_keeps_the_order() {
        let items: Vec<u64> = (0..1000).collect();
        let want: Vec<u64> = items.iter().map(|i| i * i + 1).collect();
        for threads in [1, 2, 3] {
            let workers = std::sync::Mutex::new(std::collections::HashSet::new());
            let got = with_threads(Some(threads), || {
                map_in_order(&items, |i| {
                    workers
                        .lock()
                        .unwrap()
                        .insert(rayon::current_thread_index());
                    std::thread::sleep(std::time::Duration::from_micros(20));
                    i * i + 1
                })
            })
            .unwrap()
            .unwrap();
            assert_eq!(got, want, "{threads} threads");
            assert_eq!(workers.lock().unwrap().len(), threads, "{threads} threads");
            let none: Vec<u64> = with_threads(Some(threads), || map_in_order(&[], |i: &u64| *i))
                .unwrap()
                .unwrap();
            assert!(none.is_empty());
        }
    }

    /// Once the current stop is set no further item is taken and the call says so. Item
    /// 100 sets the stop and later items wait for it (up to ten seconds, so that a
    /// regression fails rather than hangs): each worker then finishes at most the one item
    /// it holds.
    #[test]
    fn map_in_order_stops_taking_items() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        use std::time::{Duration, Instant};
        let items: Vec<usize> = (0..10_000).collect();
        for threads in [1, 2, 3] {
            let stop = Stop::new();
            let ran = AtomicUsize::new(0);
            let out = stop.scope(|| {
                with_threads(Some(threads), || {
                    map_in_order(&items, |&i| {
                        ran.fetch_add(1, Ordering::Relaxed);
                        if i == 100 {
                            stop.set();
                        }
                        let t = Instant::now();
                        while i > 100 && !stop.is_set() && t.elapsed() < Duration::from_secs(10) {
                            std::thread::yield_now();
                        }
                    })
                })
            });
            let e = out.unwrap().unwrap_err();
            assert!(matches!(e, Error::Interrupted { .. }), "{e}");
            let ran = ran.into_inner();
            assert!(
                (101..=100 + threads).contains(&ran),
                "{threads} threads: {ran} ran"
            );
        }
    }

    /// Callers on two threads asking for one worker each get a worker each, and run at the
    /// same time: each call waits (up to ten seconds, so that a regression fails rather
    /// than hangs) until the other has started.
    #[test]
    fn callers_on_different_threads_run_side_by_side() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        use std::time::{Duration, Instant};
        let started = AtomicUsize::new(0);
        let run = || {
            with_threads(Some(1), || {
                started.fetch_add(1, Ordering::SeqCst);
                let t = Instant::now();
                while started.load(Ordering::SeqCst) < 2 && t.elapsed() < Duration::from_secs(10) {
                    std::thread::sleep(Duration::from_millis(1));
                }
                started.load(Ordering::SeqCst) == 2
            })
            .unwrap()
        };
        let both = std::thread::scope(|s| {
            let a = s.spawn(run);
            let b = s.spawn(run);
            [a.join().unwrap(), b.join().unwrap()]
        });
        assert_eq!(both, [true, true]);
    }

    /// A call nested in a pool of the same size stays on it; bad sizes are refused.
    #[test]
    fn nested_calls_stay_and_bad_sizes_are_refused() {
        let outer = with_threads(Some(2), || {
            let pool_thread = std::thread::current().id();
            with_threads(Some(2), || std::thread::current().id() == pool_thread).unwrap()
        });
        assert!(outer.unwrap());
        for bad in [0, MAX_THREADS + 1] {
            let e = with_threads(Some(bad), || ()).unwrap_err().to_string();
            assert!(e.starts_with("threads"), "{e}");
        }
    }
}
