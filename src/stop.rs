//! A flag another thread raises to end a long computation early.
//!
//! Why: a daemon job can be cancelled, or the daemon stopped, while it builds
//! `T`, forms a Gram or solves for minutes; every stage of that work looks at
//! the flag often (each column of `T`, each block of rows of a Gram, every
//! [`Stop::EVERY`] iterations of a solver, each trial of a search) and gives
//! up with its room's `Stopped` error, so a cancel takes effect within a
//! fraction of a second instead of after the stage.

use std::sync::atomic::{AtomicBool, Ordering};

/// A flag to look at, or none (the default: never raised).
#[derive(Debug, Clone, Copy, Default)]
pub struct Stop<'a>(Option<&'a AtomicBool>);

impl<'a> Stop<'a> {
    /// Iterations between two looks at the flag in an iterative solver.
    pub const EVERY: usize = 10;

    /// A stop that follows `flag`.
    pub fn on(flag: &'a AtomicBool) -> Self {
        Self(Some(flag))
    }

    /// Whether the flag is raised (never, for the default).
    pub fn raised(self) -> bool {
        self.0.is_some_and(|f| f.load(Ordering::Relaxed))
    }

    /// Whether the flag is raised at a checkpoint iteration (every
    /// [`Stop::EVERY`]).
    pub fn raised_at(self, iterations: usize) -> bool {
        iterations.is_multiple_of(Self::EVERY) && self.raised()
    }
}

/// Two stops are equal when they follow the same flag (or none).
impl PartialEq for Stop<'_> {
    fn eq(&self, other: &Self) -> bool {
        match (self.0, other.0) {
            (Some(a), Some(b)) => std::ptr::eq(a, b),
            (a, b) => a.is_none() && b.is_none(),
        }
    }
}

/// How often [`finish_unless`] looks at its stop while it waits.
const POLL: std::time::Duration = std::time::Duration::from_millis(5);

/// `work`'s result, run on a thread of its own, or `None` once `stop` is
/// raised before it ends (the thread then goes on to its end alone, and
/// whatever it leaves behind, such as a cached value, stays).
///
/// Why: a library call that cannot look at a flag (an SVD) must not hold a
/// cancelled job or a stopping daemon for its whole length. Called on a
/// rayon pool thread, the wait runs the pool's pending work: `work` may
/// itself need the pool (faer's SVD does), and pool threads that only
/// waited could leave it none (two such waits on two cores never ended).
pub(crate) fn finish_unless<R: Send + 'static>(
    stop: Stop<'_>,
    work: impl FnOnce() -> R + Send + 'static,
) -> Option<R> {
    if rayon::current_thread_index().is_some() {
        // On a pool thread the work runs here, inside the pool: a pool
        // thread that waits for it, even lending itself to the pool's jobs
        // meanwhile, hung two reconstructions of the suite (one in two
        // quiet runs). The stop is then seen after the work.
        let r = work();
        return (!stop.raised()).then_some(r);
    }
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    let handle = std::thread::spawn(move || {
        let r = work();
        let _ = tx.send(());
        r
    });
    loop {
        if ended(&rx) {
            // Sent, or the thread ended without sending (it panicked).
            return match handle.join() {
                Ok(r) => Some(r),
                Err(panic) => std::panic::resume_unwind(panic),
            };
        }
        if stop.raised() {
            return None;
        }
    }
}

/// Whether the worker behind `rx` has ended, after waiting up to [`POLL`]
/// for it.
fn ended(rx: &std::sync::mpsc::Receiver<()>) -> bool {
    !matches!(
        rx.recv_timeout(POLL),
        Err(std::sync::mpsc::RecvTimeoutError::Timeout)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stop_sees_its_flag_only_at_checkpoints_and_the_default_never() {
        let flag = AtomicBool::new(false);
        let stop = Stop::on(&flag);
        assert!(!stop.raised());
        flag.store(true, Ordering::Relaxed);
        assert!(stop.raised());
        assert!(stop.raised_at(20) && !stop.raised_at(21));
        assert!(!Stop::default().raised());
        assert_eq!(stop, Stop::on(&flag));
        assert_ne!(stop, Stop::default());
    }

    #[test]
    fn finish_unless_gives_the_result_or_returns_at_the_stop_leaving_the_work_to_end() {
        assert_eq!(finish_unless(Stop::default(), || 6 * 7), Some(42));
        let flag = AtomicBool::new(true);
        let (go, wait) = std::sync::mpsc::channel::<()>();
        let (done, ended) = std::sync::mpsc::channel();
        let r = finish_unless(Stop::on(&flag), move || {
            let _ = wait.recv();
            let _ = done.send(7);
        });
        assert_eq!(r, None, "a raised stop returns before the work ends");
        go.send(()).expect("the work still waits");
        assert_eq!(ended.recv().ok(), Some(7), "the work ended on its own");
    }

    #[test]
    fn finish_unless_on_a_pool_thread_lends_it_to_work_that_needs_the_pool() {
        // One pool thread calls finish_unless with work that needs that
        // very pool: it ends only if the work does not wait for the pool.
        let pool = std::sync::Arc::new(
            rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .expect("a one-thread pool"),
        );
        let inner = pool.clone();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let r =
                pool.install(|| finish_unless(Stop::default(), move || inner.install(|| 6 * 7)));
            let _ = tx.send(r);
        });
        // A bound on a hang, not a timing: the work is a multiplication.
        let r = rx.recv_timeout(std::time::Duration::from_secs(60));
        assert_eq!(r, Ok(Some(42)), "the pool's one thread never ran the work");
    }
}
