//! The live-view benchmark's report (issue 49): results a second and
//! frame-to-result latency of `POST /live` against the scene grid and the
//! wall size, beside the offline reconstruction of a capture of the same
//! window, and a long session's memory.
//!
//! Pure: `polnlos bench --live` measures a daemon on the fake camera and
//! hands the rows here; this file only tabulates and draws them.

use std::fmt::Write as _;

use serde::Serialize;
use serde_json::{Map, Value};

use super::charts::{panels, Chart, ChartError, Marker, Plot, Series};
use super::shape::{fields, Report};

/// One bench configuration's live session and its offline reference.
#[derive(Debug, Clone, Serialize)]
pub struct LiveRow {
    /// Wall elements, columns x rows.
    pub wall: [usize; 2],
    /// Hidden-scene elements, columns x rows.
    pub grid: [usize; 2],
    /// Colour channels the camera gives (1 mono, 3 Bayer).
    pub colours: usize,
    /// Frames in each live window (and in the offline capture).
    pub window: usize,
    /// Exposure of each frame, µs.
    pub exposure_us: f64,
    /// Live results over the session.
    pub results: u64,
    /// Frames that only joined a window (the solver was busy).
    pub frames_not_solved: u64,
    /// Results a second over the daemon's newest results (`GET /live`).
    pub results_per_second: f64,
    /// Median time from a window's newest frame to its result, ms.
    pub median_latency_ms: f64,
    /// Median PSNR of the live results against the truth, dB.
    pub live_psnr_db: f64,
    /// PSNR of the offline reconstruction of a capture of one window, dB.
    pub offline_psnr_db: f64,
    /// That reconstruction's time from its request to its result (the
    /// daemon's `T` cached by the live session), s.
    pub offline_seconds: f64,
    /// The daemon's resident memory at the session's end, MiB.
    pub rss_mib: f64,
}

impl LiveRow {
    /// Unknowns solved for per result: scene elements times colours.
    pub fn unknowns(&self) -> usize {
        self.grid[0] * self.grid[1] * self.colours
    }

    /// A short label: wall, scene and camera.
    fn label(&self) -> String {
        format!(
            "wall {}x{}, scene {}x{}{}",
            self.wall[0],
            self.wall[1],
            self.grid[0],
            self.grid[1],
            if self.colours > 1 { ", colour" } else { "" }
        )
    }
}

/// One reading of a long live session.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct SoakSample {
    /// Minutes since the session's first result.
    pub minutes: f64,
    /// The daemon's resident memory, MiB.
    pub rss_mib: f64,
    /// Results so far.
    pub results: u64,
    /// Results a second over the newest results.
    pub results_per_second: f64,
}

/// The live benchmark: the sweep's rows and, when one ran, a long session.
#[derive(Debug, Clone, Default, Serialize)]
pub struct LiveReport {
    /// One row per bench configuration.
    pub rows: Vec<LiveRow>,
    /// The long session's readings (empty unless one ran).
    pub soak: Vec<SoakSample>,
}

impl LiveReport {
    /// The long session's growth of resident memory after its first
    /// minute: (largest after it - first after it) / first after it.
    pub fn soak_growth(&self) -> Option<f64> {
        let mut after = self.soak.iter().filter(|s| s.minutes >= 1.0);
        let first = after.next()?.rss_mib;
        let top = after.map(|s| s.rss_mib).fold(first, f64::max);
        (first > 0.0).then(|| (top - first) / first)
    }

    /// Results a second and latency against unknowns, one line per wall size.
    fn sweep_chart(&self) -> Result<Chart, ChartError> {
        let mut walls: Vec<[usize; 2]> = self.rows.iter().map(|r| r.wall).collect();
        walls.sort_unstable();
        walls.dedup();
        let line = |name: String, k: usize, f: &dyn Fn(&LiveRow) -> f64, w: [usize; 2]| {
            let points = self
                .rows
                .iter()
                .filter(|r| r.wall == w)
                .map(|r| (r.unknowns() as f64, f(r)))
                .collect();
            Series::line(name, k, points)
        };
        let mut rate = Vec::new();
        let mut latency = Vec::new();
        for (k, w) in walls.iter().enumerate() {
            let wall = format!("wall {}x{}", w[0], w[1]);
            rate.push(line(
                format!("{wall}: live"),
                k,
                &|r| r.results_per_second,
                *w,
            ));
            rate.push(Series {
                marker: Marker::Triangle,
                thin: true,
                ..line(
                    format!("{wall}: offline, 1 / reconstruction time"),
                    k,
                    &|r| 1.0 / r.offline_seconds,
                    *w,
                )
            });
            latency.push(line(
                format!("{wall}: frame to result"),
                k,
                &|r| r.median_latency_ms,
                *w,
            ));
        }
        let plot = |title: &str, y: &str, series| Plot {
            title: title.into(),
            x_label: "unknowns (scene elements x colours)".into(),
            y_label: y.into(),
            x_log: true,
            y_log: true,
            x_integer: false,
            series,
        };
        panels(&[
            plot("Live results a second", "results / s", rate),
            plot("Median latency", "ms", latency),
        ])
    }

    /// The long session's memory against time.
    fn soak_chart(&self) -> Result<Chart, ChartError> {
        let points =
            |f: &dyn Fn(&SoakSample) -> f64| self.soak.iter().map(|s| (s.minutes, f(s))).collect();
        panels(&[
            Plot {
                title: "Live view held for a long session: memory".into(),
                x_label: "minutes".into(),
                y_label: "daemon RSS, MiB".into(),
                x_log: false,
                y_log: false,
                x_integer: false,
                series: vec![Series::line("resident memory", 0, points(&|s| s.rss_mib))],
            },
            Plot {
                title: "... and its rate".into(),
                x_label: "minutes".into(),
                y_label: "results / s".into(),
                x_log: false,
                y_log: false,
                x_integer: false,
                series: vec![Series::line(
                    "results a second",
                    1,
                    points(&|s| s.results_per_second),
                )],
            },
        ])
    }
}

impl Report for LiveReport {
    fn json(&self) -> Map<String, Value> {
        fields(vec![
            ("live", serde_json::to_value(&self.rows)),
            ("live_soak", serde_json::to_value(&self.soak)),
            ("live_soak_growth", serde_json::to_value(self.soak_growth())),
        ])
    }

    fn charts(&self) -> Result<Vec<(String, Chart)>, ChartError> {
        let mut out = Vec::new();
        if !self.rows.is_empty() {
            out.push(("live".to_string(), self.sweep_chart()?));
        }
        if self.soak.len() >= 2 {
            out.push(("live-soak".to_string(), self.soak_chart()?));
        }
        Ok(out)
    }

    fn markdown(&self) -> String {
        let mut md = String::from(
            "## Live view\n\n`POST /live` on `polnlos serve` with Aravis's fake camera (the demo bench's crossed pose, the letter, 20 ms frames), one daemon per configuration, read through `GET /live`: results a second and the median time from a window's newest frame to its result over the newest results, and the median PSNR of the results against the truth. Beside it, the same daemon's offline reconstruction (`POST /reconstructions`, automatic λ, `T` cached by the session, `\"radiometry\": \"calibrated\"` as live view's) of a capture of one window, timed from its request to its result. The fake camera renders its frames on the same cores.\n\n",
        );
        if !self.rows.is_empty() {
            md.push_str("![live view against the problem size](live.png)\n\n| configuration | unknowns | window | results / s | latency | live PSNR | offline PSNR | offline time | frames not solved | RSS |\n|---|---|---|---|---|---|---|---|---|---|\n");
            for r in &self.rows {
                let _ = writeln!(
                    md,
                    "| {} | {} | {} | {:.1} | {:.0} ms | {:.2} dB | {:.2} dB | {} | {} of {} | {:.0} MiB |",
                    r.label(),
                    r.unknowns(),
                    r.window,
                    r.results_per_second,
                    r.median_latency_ms,
                    r.live_psnr_db,
                    r.offline_psnr_db,
                    super::fmt_seconds(r.offline_seconds),
                    r.frames_not_solved,
                    r.frames_not_solved + r.results,
                    r.rss_mib,
                );
            }
            md.push('\n');
        }
        if let (Some(first), Some(last)) = (self.soak.first(), self.soak.last()) {
            let growth = self
                .soak_growth()
                .map_or("-".to_string(), |g| format!("{:+.1} %", g * 100.0));
            let _ = writeln!(
                md,
                "A session of {:.0} minutes (first configuration): {} results, RSS {:.0} MiB at the first reading and {:.0} MiB at the last; growth after the first minute {growth}.\n\n![memory over a long session](live-soak.png)\n",
                last.minutes,
                last.results,
                first.rss_mib,
                last.rss_mib,
            );
        }
        md
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(minutes: f64, rss_mib: f64) -> SoakSample {
        SoakSample {
            minutes,
            rss_mib,
            results: 0,
            results_per_second: 0.0,
        }
    }

    #[test]
    fn growth_counts_from_the_first_reading_after_a_minute() {
        let r = LiveReport {
            rows: Vec::new(),
            soak: vec![
                sample(0.5, 50.0),
                sample(1.0, 100.0),
                sample(30.0, 104.0),
                sample(60.0, 102.0),
            ],
        };
        let g = r.soak_growth().unwrap();
        assert!((g - 0.04).abs() < 1e-12, "{g}");
        assert_eq!(LiveReport::default().soak_growth(), None);
    }

    #[test]
    fn unknowns_count_colours() {
        let row = LiveRow {
            wall: [126, 126],
            grid: [36, 29],
            colours: 3,
            window: 8,
            exposure_us: 20000.0,
            results: 10,
            frames_not_solved: 70,
            results_per_second: 2.0,
            median_latency_ms: 450.0,
            live_psnr_db: 12.0,
            offline_psnr_db: 12.1,
            offline_seconds: 3.0,
            rss_mib: 200.0,
        };
        assert_eq!(row.unknowns(), 3132);
        assert_eq!(row.label(), "wall 126x126, scene 36x29, colour");
        let r = LiveReport {
            rows: vec![row],
            soak: Vec::new(),
        };
        assert!(r
            .markdown()
            .contains("| wall 126x126, scene 36x29, colour | 3132 | 8 | 2.0 | 450 ms |"));
        assert_eq!(r.charts().unwrap().len(), 1);
    }
}
