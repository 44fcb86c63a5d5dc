//! Ctrl-C during long calls. Python runs signal handlers only on its main thread, between
//! bytecodes; a call that released the GIL and waits for the core's worker threads never
//! gives it the chance. [`detach_interruptible`] therefore runs the core's work on a scoped
//! thread while the calling thread checks for signals every [`POLL`], and sets the work's
//! [`Stop`] when a handler raises. The stop is the work's current stop
//! ([`Stop::current`]), so every loop of the core polls it between chunks, whether the
//! call reports progress or not; progress reports ([`PyProgress`]) say "stop" too.

use std::time::Duration;

use pyo3::prelude::*;

use crate::stop::Stop;

/// How often the calling thread checks for signals while the work runs.
pub const POLL: Duration = Duration::from_millis(20);

/// The stop that Ctrl-C sets: the core's [`Stop`].
pub type StopFlag = Stop;

/// [`detach_interruptible`] with a stop of its own: for calls without a progress reporter.
pub fn detach_stoppable<R: Send>(py: Python<'_>, work: impl FnOnce() -> R + Send) -> PyResult<R> {
    detach_interruptible(py, &Stop::new(), work)
}

/// Runs `work` on a thread of its own (named `name`) with the GIL released, for work that
/// cannot poll a stop (a library's codec or tree builder): on Ctrl-C the call returns at
/// once and the thread runs on until `work` ends, its result then dropped. `Ok(None)`
/// when the thread could not run `work` to its end (it panicked).
pub fn detach_abandonable<R: Send + 'static>(
    py: Python<'_>,
    name: &str,
    work: impl FnOnce() -> R + Send + 'static,
) -> PyResult<Option<R>> {
    let (sent, received) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name(name.into())
        .spawn(move || {
            // The receiver is gone when the call was interrupted.
            let _ = sent.send(work());
        })
        .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(format!("{name}: {e}")))?;
    detach_stoppable(py, move || {
        let stop = Stop::current();
        loop {
            match received.recv_timeout(std::time::Duration::from_millis(10)) {
                Ok(out) => return Some(out),
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) if !stop.is_set() => {}
                Err(_) => return None,
            }
        }
    })
}

/// Runs `work` with the GIL released, on a scoped thread, while this thread runs Python's
/// signal handlers every [`POLL`]. When one raises (`KeyboardInterrupt` for Ctrl-C), `stop`
/// is set, the work is awaited (its loops poll `stop`, the work's current [`Stop`]) and its
/// result is dropped: the handler's exception is returned instead. The work must leave the
/// objects it changed usable when it stops early (the core's long calls stop between
/// chunks, waves or passes, keeping or dropping a step whole).
pub fn detach_interruptible<R: Send>(
    py: Python<'_>,
    stop: &StopFlag,
    work: impl FnOnce() -> R + Send,
) -> PyResult<R> {
    detach_interruptible_with(py, stop, &|| {}, work)
}

/// [`detach_interruptible`] that also calls `on_stop` when a signal handler raises: for work
/// that can stop sooner than at its next progress report.
pub fn detach_interruptible_with<R: Send>(
    py: Python<'_>,
    stop: &StopFlag,
    on_stop: &(dyn Fn() + Sync),
    work: impl FnOnce() -> R + Send,
) -> PyResult<R> {
    let mut raised: Option<PyErr> = None;
    let out = py.detach(|| {
        let work = || stop.scope(work);
        crate::parallel::run_polling(work, POLL, &mut || {
            if raised.is_none() {
                if let Err(e) = Python::attach(|py| py.check_signals()) {
                    raised = Some(e);
                    stop.set();
                    on_stop();
                }
            }
        })
    });
    match raised {
        Some(e) => Err(e),
        None => Ok(out),
    }
}

/// What a [`PyProgress`] does with a report, with the GIL held: `Ok(false)` stops the work.
type Report = Box<dyn FnMut(Python<'_>, u64, u64) -> PyResult<bool> + Send>;

/// Forwards the core's `progress(done, total)` reports to an optional Python
/// `callback(done, total)` (or any [`Report`]), taking the GIL for each call. A falsy
/// return stops the core's work; an exception does too and is kept for [`Self::finish`] to
/// raise, and no further call is made after it. Every report also says "stop" once
/// [`Self::stop_flag`] is set (by [`detach_interruptible`] on Ctrl-C).
pub struct PyProgress {
    report: Option<Report>,
    failure: Option<PyErr>,
    stop: Stop,
}

impl PyProgress {
    /// A reporter calling `callback` (none: every report says "go on" until a stop).
    pub fn new(callback: Option<Py<PyAny>>) -> Self {
        Self::with(callback.map(|cb| -> Report {
            Box::new(move |py, done, total| {
                Ok(cb.call1(py, (done, total))?.is_truthy(py).unwrap_or(true))
            })
        }))
    }

    /// A reporter running `report` (none: every report says "go on" until a stop).
    fn with(report: Option<Report>) -> Self {
        Self {
            report,
            failure: None,
            stop: Stop::new(),
        }
    }

    /// The stop that makes every later report say "stop".
    pub fn stop_flag(&self) -> Stop {
        self.stop.clone()
    }

    /// One report; `false` asks the core to stop.
    pub fn report(&mut self, done: u64, total: u64) -> bool {
        if self.stop.is_set() || self.failure.is_some() {
            return false;
        }
        let Some(report) = &mut self.report else {
            return true;
        };
        let _inside = super::cache::InCallback::enter();
        Python::attach(|py| match report(py, done, total) {
            Ok(go_on) => go_on,
            Err(e) => {
                self.failure = Some(e);
                false
            }
        })
    }

    /// The callback's exception, if it raised one.
    pub fn finish(self) -> PyResult<()> {
        self.failure.map_or(Ok(()), Err)
    }
}
