//! Transport accuracy against build time: the error of `T` against a heavily
//! supersampled reference, for uniform wall supersampling `m = 1..4` (and 6,
//! 8) and for adaptive supersampling at several tolerances, on the two cases
//! where one sample per element is not enough: a glossy wall (narrow
//! specular lobe) and the occluder's shadow edges.

use serde::Serialize;

use super::charts::{panels, Chart, ChartError, Marker, Plot, Series};
use super::{builtin, timed3, BenchError};
use crate::scene::Scene;
use crate::transport::adaptive::relative_error;
use crate::transport::{build, build_adaptive, MemoryBudget, Transport};

/// Uniform sub-sampling per side compared.
pub(crate) const UNIFORM: [usize; 6] = [1, 2, 3, 4, 6, 8];

/// Adaptive tolerances compared (relative Frobenius error).
pub(crate) const TOLERANCES: [f64; 5] = [1e-1, 3e-2, 1e-2, 3e-3, 1e-3];

/// Largest adaptive level.
pub(crate) const MAX_M: usize = 16;

/// One build.
#[derive(Debug, Clone, Serialize)]
pub struct SamplingRow {
    /// Case label.
    pub case: String,
    /// `uniform` or `adaptive`.
    pub method: &'static str,
    /// Uniform `m`, or the adaptive tolerance.
    pub setting: f64,
    /// Median build seconds over 3 runs.
    pub seconds: f64,
    /// Wall samples evaluated per wall element.
    pub samples_per_element: f64,
    /// `||T - T_ref||_F / ||T_ref||_F`.
    pub error: f64,
    /// The adaptive build's own error estimate.
    pub estimated_error: Option<f64>,
}

fn case(name: &str, alpha: Option<f64>) -> Result<Scene, BenchError> {
    let s = builtin(name)?;
    match alpha {
        Some(a) => super::edit(name, s, |s| s.wall.brdf.alpha = a),
        None => Ok(s),
    }
}

/// The sweep: `grid` is the scene grid side (3 or 8), `reference_m` the
/// reference's sub-sampling per side. `step()` after each case.
pub(crate) fn sampling_sweep(
    grid: usize,
    reference_m: usize,
    budget: MemoryBudget,
    step: &mut dyn FnMut(),
) -> Result<Vec<SamplingRow>, BenchError> {
    let suffix = if grid == 3 { "-3x3" } else { "" };
    let cases = [
        (
            "glossy wall (alpha 0.05)",
            case(&format!("brewster-crossed{suffix}"), Some(0.05))?,
        ),
        (
            "occluder (alpha 0.3)",
            case(&format!("occluder-crossed{suffix}"), None)?,
        ),
    ];
    let mut rows = Vec::new();
    for (label, scene) in cases {
        let uniform = |m: usize| -> Result<Transport, BenchError> {
            let s = scene.clone().edit(|s| s.wall.plane.supersample = m)?;
            Ok(build(&s, budget)?)
        };
        let reference = uniform(reference_m)?;
        for m in UNIFORM {
            let (t, secs) = timed3(|| uniform(m))?;
            rows.push(SamplingRow {
                case: label.into(),
                method: "uniform",
                setting: m as f64,
                seconds: secs,
                samples_per_element: (m * m) as f64,
                error: relative_error(&t, &reference),
                estimated_error: None,
            });
        }
        let n_wall = scene.wall().plane.grid.count() as f64;
        for tol in TOLERANCES {
            let ((t, st), secs) = timed3(|| Ok(build_adaptive(&scene, tol, MAX_M, budget)?))?;
            rows.push(SamplingRow {
                case: label.into(),
                method: "adaptive",
                setting: tol,
                seconds: secs,
                samples_per_element: st.samples as f64 / n_wall,
                error: relative_error(&t, &reference),
                estimated_error: Some(st.estimated_error),
            });
        }
        step();
    }
    Ok(rows)
}

/// Error against build time, one panel per case, log-log.
pub fn chart(rows: &[SamplingRow], reference_m: usize) -> Result<Chart, ChartError> {
    let mut cases: Vec<&str> = rows.iter().map(|r| r.case.as_str()).collect();
    cases.dedup();
    let plots: Vec<Plot> = cases
        .iter()
        .map(|case| {
            // A curve joins its points in order of build time (the adaptive
            // runs are listed by tolerance, and time need not follow it).
            let pts = |method: &str| -> Vec<(f64, f64)> {
                let mut p: Vec<(f64, f64)> = rows
                    .iter()
                    .filter(|r| r.case == *case && r.method == method)
                    .map(|r| (r.seconds, r.error))
                    .collect();
                p.sort_by(|a, b| a.0.total_cmp(&b.0));
                p
            };
            Plot {
                title: format!("{case}: error of T against m = {reference_m}"),
                x_label: "build time, s".into(),
                y_label: "||T - T_ref||_F / ||T_ref||_F".into(),
                x_log: true,
                y_log: true,
                x_integer: false,
                series: vec![
                    Series::line("uniform m = 1, 2, 3, 4, 6, 8", 0, pts("uniform")),
                    Series {
                        marker: Marker::Triangle,
                        ..Series::line(
                            "adaptive, tol 1e-1 .. 1e-3 (max m = 16)",
                            1,
                            pts("adaptive"),
                        )
                    },
                ],
            }
        })
        .collect();
    panels(&plots)
}

/// The sampling sweep as a report.
pub(crate) struct Sampling {
    /// Samples per element side of the reference `T`.
    pub reference_m: usize,
    /// The sweep.
    pub rows: Vec<SamplingRow>,
}

impl super::Report for Sampling {
    fn json(&self) -> serde_json::Map<String, serde_json::Value> {
        super::shape::fields(vec![
            (
                "sampling_reference_m",
                serde_json::to_value(self.reference_m),
            ),
            ("sampling", serde_json::to_value(&self.rows)),
        ])
    }

    fn charts(&self) -> Result<Vec<(String, Chart)>, ChartError> {
        Ok(vec![(
            "sampling".into(),
            chart(&self.rows, self.reference_m)?,
        )])
    }

    fn markdown(&self) -> String {
        use std::fmt::Write as _;
        let mut md = format!(
            "## Transport accuracy against build time\n\nError of T against uniform m = {} (relative Frobenius), median build time of 3 runs.\n\n![sampling](sampling.png)\n\n| case | method | m or tol | build time | samples per element | error | estimated |\n|---|---|---|---|---|---|---|\n",
            self.reference_m
        );
        for r in &self.rows {
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {:.1} | {:.2e} | {} |",
                r.case,
                r.method,
                r.setting,
                super::fmt_seconds(r.seconds),
                r.samples_per_element,
                r.error,
                r.estimated_error
                    .map_or_else(|| "-".into(), |e| format!("{e:.2e}"))
            );
        }
        md.push('\n');
        md
    }
}
