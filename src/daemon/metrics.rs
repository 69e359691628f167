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

impl super::Daemon {
    /// The camera, queue and job samples of `GET /metrics`.
    pub fn metric_samples(&self) -> Vec<Sample<'static>> {
        let d = self;
        let s = d.camera.status();
        let c = s.counters;
        let m = &d.metrics;
        let depth =
            |tx: &tokio::sync::mpsc::Sender<i64>| (tx.max_capacity() - tx.capacity()) as f64;
        vec![
            Sample {
                name: "polnlos_camera_connected",
                kind: "gauge",
                help: "1 when a camera is open",
                value: f64::from(u8::from(s.connected)),
            },
            Sample {
                name: "polnlos_camera_frames_completed_total",
                kind: "counter",
                help: "Frames received",
                value: c.completed as f64,
            },
            Sample {
                name: "polnlos_camera_frames_failed_total",
                kind: "counter",
                help: "Broken buffers",
                value: c.failed as f64,
            },
            Sample {
                name: "polnlos_camera_timeouts_total",
                kind: "counter",
                help: "Buffer pops that timed out",
                value: c.timeouts as f64,
            },
            Sample {
                name: "polnlos_camera_underruns_total",
                kind: "counter",
                help: "Frames dropped for lack of buffers",
                value: c.underruns as f64,
            },
            Sample {
                name: "polnlos_camera_missing_packets_total",
                kind: "counter",
                help: "GigE Vision packets missing",
                value: c.missing_packets as f64,
            },
            Sample {
                name: "polnlos_camera_resent_packets_total",
                kind: "counter",
                help: "GigE Vision packets resent",
                value: c.resent_packets as f64,
            },
            Sample {
                name: "polnlos_camera_connects_total",
                kind: "counter",
                help: "Camera (re)connections",
                value: c.connects as f64,
            },
            Sample {
                name: "polnlos_camera_reconnect_failures_total",
                kind: "counter",
                help: "Failed reconnection attempts",
                value: s.reconnect_failures as f64,
            },
            Sample {
                name: "polnlos_capture_queue_depth",
                kind: "gauge",
                help: "Captures waiting",
                value: depth(&d.captures),
            },
            Sample {
                name: "polnlos_reconstruction_queue_depth",
                kind: "gauge",
                help: "Reconstructions waiting",
                value: depth(&d.reconstructions),
            },
            Sample {
                name: "polnlos_captures_done_total",
                kind: "counter",
                help: "Captures finished",
                value: Metrics::get(&m.captures_done),
            },
            Sample {
                name: "polnlos_captures_failed_total",
                kind: "counter",
                help: "Captures failed",
                value: Metrics::get(&m.captures_failed),
            },
            Sample {
                name: "polnlos_capture_seconds_total",
                kind: "counter",
                help: "Time spent capturing",
                value: Metrics::get(&m.capture_micros) * 1e-6,
            },
            Sample {
                name: "polnlos_reconstructions_done_total",
                kind: "counter",
                help: "Reconstructions finished",
                value: Metrics::get(&m.reconstructions_done),
            },
            Sample {
                name: "polnlos_reconstructions_failed_total",
                kind: "counter",
                help: "Reconstructions failed",
                value: Metrics::get(&m.reconstructions_failed),
            },
            Sample {
                name: "polnlos_reconstruction_seconds_total",
                kind: "counter",
                help: "Time spent reconstructing",
                value: Metrics::get(&m.reconstruction_micros) * 1e-6,
            },
            Sample {
                name: "polnlos_requests_rejected_queue_full_total",
                kind: "counter",
                help: "Requests answered 429",
                value: Metrics::get(&m.rejected_full),
            },
        ]
    }
}
