//! Stopping long work early: one small type, [`Stop`], that Ctrl-C (the bindings'
//! `detach_interruptible`), a progress callback returning false, or a time budget's
//! deadline sets, and that long loops poll between chunks.
//!
//! A call learns of its stop in one of two ways: it is handed one (`&Stop`), or it reads
//! the calling thread's *current* stop ([`Stop::current`]), which [`Stop::scope`] installs
//! for the work it runs. The current stop follows the work onto the threads that run it
//! for [`crate::parallel::with_threads`] and [`crate::parallel::run_polling`]; a loop reads
//! it once, on the thread that starts the loop, and hands it to its chunks. Code that
//! rayon runs inside other work (a chunk's closure) does not see it, and need not: the loop
//! around it polls.
//!
//! A stopped call returns [`Error::Interrupted`] (or, where the call documents it, what it
//! finished), and leaves the objects it was changing as they were before the unfinished
//! step: loops that fill new buffers simply drop them.

use std::cell::RefCell;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::error::{Error, Result};

#[derive(Debug, Default)]
struct Inner {
    /// Set by [`Stop::set`].
    flag: AtomicBool,
    /// Past this instant the stop counts as set.
    deadline: Option<Instant>,
    /// A child is set when its parent is.
    parent: Option<Stop>,
}

/// A request to stop, shared by clones: set once, by anyone holding a clone, or by the
/// passing of a deadline; never cleared. Cheap to clone (one reference count) and to poll
/// (an atomic load per level, plus a clock read when a deadline is set), so chunked loops
/// poll it between chunks and per-pixel loops per pixel.
#[derive(Clone, Debug, Default)]
pub struct Stop(Arc<Inner>);

thread_local! {
    /// The stop of the work this thread runs now ([`Stop::scope`]).
    static CURRENT: RefCell<Option<Stop>> = const { RefCell::new(None) };
}

impl Stop {
    /// A stop that only [`Self::set`] sets.
    pub fn new() -> Self {
        Self::default()
    }

    /// A stop set by [`Self::set`] or once `deadline` has passed (`None`: no deadline).
    pub fn until(deadline: Option<Instant>) -> Self {
        Self(Arc::new(Inner {
            deadline,
            ..Inner::default()
        }))
    }

    /// A stop set by [`Self::set`] or `seconds` from now (a time budget; `None`: none).
    pub fn after(seconds: Option<f64>) -> Self {
        Self::until(seconds.map(|s| Instant::now() + Duration::from_secs_f64(s.clamp(0.0, 1e9))))
    }

    /// A stop of its own that is also set whenever `self` is, or once `deadline` has
    /// passed. Setting the child leaves `self` alone: a progress callback that stops one
    /// pass does not interrupt the whole call.
    pub fn child(&self, deadline: Option<Instant>) -> Self {
        Self(Arc::new(Inner {
            deadline,
            parent: Some(self.clone()),
            ..Inner::default()
        }))
    }

    /// Asks every holder to stop.
    pub fn set(&self) {
        self.0.flag.store(true, Ordering::Relaxed);
    }

    /// True once a stop was asked for, on this stop or a parent, or a deadline passed.
    #[inline]
    pub fn is_set(&self) -> bool {
        let mut s = &self.0;
        loop {
            if s.flag.load(Ordering::Relaxed) || s.deadline.is_some_and(|d| Instant::now() >= d) {
                return true;
            }
            match &s.parent {
                Some(p) => s = &p.0,
                None => return false,
            }
        }
    }

    /// True once [`Self::set`] was called on this stop or a parent, whatever the deadlines:
    /// an interruption, as opposed to a budget running out.
    pub fn is_requested(&self) -> bool {
        let mut s = &self.0;
        loop {
            if s.flag.load(Ordering::Relaxed) {
                return true;
            }
            match &s.parent {
                Some(p) => s = &p.0,
                None => return false,
            }
        }
    }

    /// `Err(Error::Interrupted)` naming `what` once the stop is set.
    #[inline]
    pub fn check(&self, what: &str) -> Result<()> {
        if self.is_set() {
            Err(Error::Interrupted { what: what.into() })
        } else {
            Ok(())
        }
    }

    /// The stop of the work running on this thread ([`Self::scope`]); a stop nobody sets
    /// when there is none.
    pub fn current() -> Self {
        CURRENT.with(|c| c.borrow().clone()).unwrap_or_default()
    }

    /// The stop [`Self::current`] would return, or `None` when none is installed (for
    /// passing it on to other threads without allocating).
    pub fn installed() -> Option<Self> {
        CURRENT.with(|c| c.borrow().clone())
    }

    /// Runs `f` with `self` as this thread's current stop, then restores the one before
    /// (also when `f` panics).
    pub fn scope<R>(&self, f: impl FnOnce() -> R) -> R {
        Self::scope_opt(Some(self.clone()), f)
    }

    /// [`Self::scope`] of `stop` when there is one; `f` as it is otherwise.
    pub fn scope_opt<R>(stop: Option<Self>, f: impl FnOnce() -> R) -> R {
        let Some(stop) = stop else {
            return f();
        };
        struct Restore(Option<Stop>);
        impl Drop for Restore {
            fn drop(&mut self) {
                let before = self.0.take();
                CURRENT.with(|c| *c.borrow_mut() = before);
            }
        }
        let _restore = Restore(CURRENT.with(|c| c.borrow_mut().replace(stop)));
        f()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Clones share the request; a child follows its parent, not the other way round.
    #[test]
    fn clones_and_children_share_requests_one_way() {
        let a = Stop::new();
        let b = a.clone();
        let child = a.child(None);
        assert!(!a.is_set() && !child.is_set());
        assert!(a.check("x").is_ok());
        child.set();
        assert!(
            child.is_set() && !a.is_set(),
            "a child does not set its parent"
        );
        let other = a.child(None);
        b.set();
        assert!(a.is_set() && other.is_set() && other.is_requested());
        let e = other.check("the work").unwrap_err().to_string();
        assert_eq!(e, "the work: interrupted");
    }

    /// A deadline sets the stop once it passes, without counting as a request.
    #[test]
    fn deadlines_set_the_stop_when_they_pass() {
        let past = Stop::until(Some(Instant::now()));
        assert!(past.is_set() && !past.is_requested());
        let far = Stop::after(Some(3600.0));
        assert!(!far.is_set());
        assert!(far.child(Some(Instant::now())).is_set());
        assert!(!Stop::after(None).is_set());
        assert!(Stop::after(Some(0.0)).is_set());
    }

    /// The current stop is the innermost scope's, restored on leaving it (also on a panic),
    /// and a stop nobody sets outside any scope.
    #[test]
    fn scopes_nest_and_restore() {
        assert!(Stop::installed().is_none());
        let outer = Stop::new();
        let inner = Stop::new();
        inner.set();
        outer.scope(|| {
            assert!(!Stop::current().is_set());
            inner.scope(|| assert!(Stop::current().is_set()));
            assert!(!Stop::current().is_set());
            let caught = std::panic::catch_unwind(|| inner.scope(|| panic!("in the scope")));
            assert!(caught.is_err());
            assert!(!Stop::current().is_set(), "restored after a panic");
        });
        assert!(Stop::installed().is_none());
        assert!(!Stop::current().is_set());
    }

    /// The current stop follows work onto a pool's workers and a polled thread.
    #[test]
    fn the_current_stop_follows_the_work() {
        let stop = Stop::new();
        stop.set();
        let on_pool = stop
            .scope(|| crate::parallel::with_threads(Some(2), || Stop::current().is_set()).unwrap());
        assert!(on_pool);
        let polled = stop.scope(|| {
            crate::parallel::run_polling(
                || Stop::current().is_set(),
                Duration::from_millis(1),
                &mut || {},
            )
        });
        assert!(polled);
    }
}
