//! The job registry: the cancel flag of each running job and the
//! daemon-wide stop, the two signals a worker checks while it works.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use tokio::sync::watch;

/// Cancel flags by job id (`capture-<n>`, `reconstruction-<n>`), and whether
/// the daemon is stopping; one lock, held only to look a flag up.
#[derive(Debug)]
pub(crate) struct JobRegistry {
    cancels: Mutex<BTreeMap<String, Arc<AtomicBool>>>,
    /// True once the daemon starts draining: the workers stop taking jobs,
    /// and a job stopped from then on ends `interrupted`, not `cancelled`.
    stop: watch::Sender<bool>,
}

impl Default for JobRegistry {
    fn default() -> Self {
        Self {
            cancels: Mutex::new(BTreeMap::new()),
            stop: watch::channel(false).0,
        }
    }
}

impl JobRegistry {
    /// The cancel flag of a job, created on first use by either side (the
    /// worker starting it or a client cancelling it, whichever comes first).
    pub(crate) fn cancel_flag(&self, job: &str) -> Arc<AtomicBool> {
        let mut flags = self.cancels.lock().unwrap_or_else(|e| e.into_inner());
        flags.entry(job.to_string()).or_default().clone()
    }

    /// Drops the flag of a job that ended.
    pub(crate) fn forget(&self, job: &str) {
        let mut flags = self.cancels.lock().unwrap_or_else(|e| e.into_inner());
        flags.remove(job);
    }

    /// Whether [`JobRegistry::stop_all`] has been called.
    pub(crate) fn is_stopping(&self) -> bool {
        *self.stop.borrow()
    }

    /// A receiver that turns true once [`JobRegistry::stop_all`] is called
    /// (for workers to stop waiting for jobs).
    pub(crate) fn stopped(&self) -> watch::Receiver<bool> {
        self.stop.subscribe()
    }

    /// Stops for good: every running job's flag is set, and every later
    /// check of [`JobRegistry::is_stopping`] is true.
    pub(crate) fn stop_all(&self) {
        self.stop.send_replace(true);
        let flags = self.cancels.lock().unwrap_or_else(|e| e.into_inner());
        for flag in flags.values() {
            flag.store(true, Ordering::SeqCst);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flag_is_shared_by_both_sides_and_the_stop_sets_every_running_one() {
        let r = JobRegistry::default();
        let worker = r.cancel_flag("capture-1");
        let client = r.cancel_flag("capture-1");
        client.store(true, Ordering::SeqCst);
        assert!(worker.load(Ordering::SeqCst));
        let other = r.cancel_flag("reconstruction-2");
        let stopped = r.stopped();
        assert!(!r.is_stopping());
        r.stop_all();
        assert!(r.is_stopping());
        assert!(*stopped.borrow());
        assert!(other.load(Ordering::SeqCst));
        r.forget("reconstruction-2");
        assert!(!r.cancel_flag("reconstruction-2").load(Ordering::SeqCst));
    }
}
