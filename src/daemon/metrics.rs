//! Counters for `GET /metrics` (Prometheus text format).

use std::fmt::Write;
use std::sync::atomic::{AtomicU64, Ordering};

/// Job counters and summed durations.
#[derive(Debug, Default)]
pub struct Metrics {
    /// Captures that finished.
    pub captures_done: AtomicU64,
    /// Captures that failed.
    pub captures_failed: AtomicU64,
    /// Microseconds spent in captures.
    pub capture_micros: AtomicU64,
    /// Reconstructions that finished.
    pub reconstructions_done: AtomicU64,
    /// Reconstructions that failed.
    pub reconstructions_failed: AtomicU64,
    /// Microseconds spent in reconstructions.
    pub reconstruction_micros: AtomicU64,
    /// Requests refused because a queue was full.
    pub rejected_full: AtomicU64,
}

/// A gauge or counter line set for rendering.
pub struct Sample<'a> {
    /// Metric name.
    pub name: &'a str,
    /// `counter` or `gauge`.
    pub kind: &'a str,
    /// Help text.
    pub help: &'a str,
    /// Value.
    pub value: f64,
}

impl Metrics {
    /// Renders the samples in Prometheus text exposition format.
    pub fn render(samples: &[Sample<'_>]) -> String {
        let mut out = String::new();
        for s in samples {
            let _ = writeln!(
                out,
                "# HELP {} {}\n# TYPE {} {}\n{} {}",
                s.name, s.help, s.name, s.kind, s.name, s.value
            );
        }
        out
    }

    /// Loads a counter as f64.
    pub fn get(c: &AtomicU64) -> f64 {
        c.load(Ordering::Relaxed) as f64
    }
}
