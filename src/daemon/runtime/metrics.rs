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
    /// Jobs cancelled by clients (queued or running).
    pub jobs_cancelled: AtomicU64,
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

/// A gauge sample.
pub(crate) fn gauge(name: &'static str, help: &'static str, value: f64) -> Sample<'static> {
    Sample {
        name,
        kind: "gauge",
        help,
        value,
    }
}

/// A counter sample.
pub(crate) fn counter(name: &'static str, help: &'static str, value: f64) -> Sample<'static> {
    Sample {
        name,
        kind: "counter",
        help,
        value,
    }
}

impl crate::daemon::Daemon {
    /// The camera, queue and job samples of `GET /metrics`.
    // A table reads best one sample per line.
    #[rustfmt::skip]
    pub fn metric_samples(&self) -> Vec<Sample<'static>> {
        let s = self.camera.status();
        let c = s.counters;
        let m = &self.metrics;
        let connected = f64::from(u8::from(s.connected));
        vec![
            gauge("polnlos_camera_connected", "1 when a camera is open", connected),
            counter("polnlos_camera_frames_completed_total", "Frames received", c.completed as f64),
            counter("polnlos_camera_frames_failed_total", "Broken buffers", c.failed as f64),
            counter("polnlos_camera_timeouts_total", "Buffer pops that timed out", c.timeouts as f64),
            counter("polnlos_camera_underruns_total", "Stream packets that found no free buffer (Aravis n_underruns; per packet, including frames sent after a capture had its own)", c.underruns as f64),
            counter("polnlos_camera_missing_packets_total", "GigE Vision packets missing", c.missing_packets as f64),
            counter("polnlos_camera_resent_packets_total", "GigE Vision packets resent", c.resent_packets as f64),
            counter("polnlos_camera_stream_restarts_total", "Streams replaced after stray packets reached them", c.stream_restarts as f64),
            counter("polnlos_camera_connects_total", "Camera (re)connections", c.connects as f64),
            counter("polnlos_camera_reconnect_failures_total", "Failed reconnection attempts", s.reconnect_failures as f64),
            gauge("polnlos_capture_queue_depth", "Captures waiting", self.captures.depth() as f64),
            gauge("polnlos_reconstruction_queue_depth", "Reconstructions waiting", self.reconstructions.depth() as f64),
            counter("polnlos_captures_done_total", "Captures finished", Metrics::get(&m.captures_done)),
            counter("polnlos_captures_failed_total", "Captures failed", Metrics::get(&m.captures_failed)),
            counter("polnlos_capture_seconds_total", "Time spent capturing", Metrics::get(&m.capture_micros) * 1e-6),
            counter("polnlos_reconstructions_done_total", "Reconstructions finished", Metrics::get(&m.reconstructions_done)),
            counter("polnlos_reconstructions_failed_total", "Reconstructions failed", Metrics::get(&m.reconstructions_failed)),
            counter("polnlos_reconstruction_seconds_total", "Time spent reconstructing", Metrics::get(&m.reconstruction_micros) * 1e-6),
            counter("polnlos_requests_rejected_queue_full_total", "Requests answered 429", Metrics::get(&m.rejected_full)),
            counter("polnlos_jobs_cancelled_total", "Jobs cancelled by clients", Metrics::get(&m.jobs_cancelled)),
        ]
    }
}
