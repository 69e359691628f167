//! Active NLOS (the paper's appendix, Fig. 10): the condition number of the
//! time-resolved `T` ([`crate::transport::active`]) with and without the
//! crossed polarizer, against the voxel grid and the wall roughness, beside
//! the passive (steady-state) `T` of the same scene.

use serde::Serialize;

use super::charts::{panels, Chart, ChartError, Marker, Plot, Series};
use super::{builtin, BenchError, ROUGHNESS};
use crate::scene::Grid;
use crate::solve::condition;
use crate::transport::active::{build_active, ActiveSetup};
use crate::transport::{build, MemoryBudget};

/// One point of the active sweep.
#[derive(Debug, Clone, Serialize)]
pub struct ActiveRow {
    /// `resolution` or `roughness`.
    pub sweep: &'static str,
    /// `nopol` or `crossed` (pose A).
    pub config: &'static str,
    /// Voxel grid side.
    pub grid: usize,
    /// GGX alpha.
    pub roughness: f64,
    /// Time bins of the active `T`.
    pub bins: usize,
    /// kappa of the time-resolved `T`.
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub kappa_active: f64,
    /// kappa of the steady-state `T` of the same scene.
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub kappa_passive: f64,
}

fn point(
    sweep: &'static str,
    config: &'static str,
    grid: usize,
    roughness: f64,
    budget: MemoryBudget,
) -> Result<ActiveRow, BenchError> {
    let name = format!("brewster-{config}");
    let s = super::edit(&name, builtin(&name)?, |s| {
        s.hidden.plane.grid = Grid { nu: grid, nv: grid };
        s.wall.brdf.alpha = roughness;
    })?;
    let a = build_active(&s, &ActiveSetup::default(), budget)?;
    Ok(ActiveRow {
        sweep,
        config,
        grid,
        roughness,
        bins: a.bins,
        kappa_active: condition(&a.t)?.kappa,
        kappa_passive: condition(&build(&s, budget)?)?.kappa,
    })
}

/// Voxel grids of the resolution sweep (alpha 0.3), and the grid of the
/// roughness sweep.
pub(crate) fn active_sweep(
    grids: &[usize],
    rough_grid: usize,
    budget: MemoryBudget,
    step: &mut dyn FnMut(),
) -> Result<Vec<ActiveRow>, BenchError> {
    let mut rows = Vec::new();
    for config in ["nopol", "crossed"] {
        for &g in grids {
            rows.push(point("resolution", config, g, 0.3, budget)?);
            step();
        }
        for &a in &ROUGHNESS {
            rows.push(point("roughness", config, rough_grid, a, budget)?);
            step();
        }
    }
    Ok(rows)
}

/// Points [`active_sweep`] computes.
pub(crate) fn active_len(grids: &[usize]) -> usize {
    2 * (grids.len() + ROUGHNESS.len())
}

/// kappa against voxel grid (left) and roughness (right).
pub fn chart(rows: &[ActiveRow]) -> Result<Chart, ChartError> {
    let plot = |sweep: &str, title: String, x_label: &str, x_log: bool| {
        let mut series = Vec::new();
        for (c, config) in ["nopol", "crossed"].into_iter().enumerate() {
            let pts = |active: bool| -> Vec<(f64, f64)> {
                rows.iter()
                    .filter(|r| r.sweep == sweep && r.config == config)
                    .map(|r| {
                        let x = if sweep == "resolution" {
                            r.grid as f64
                        } else {
                            r.roughness
                        };
                        (
                            x,
                            if active {
                                r.kappa_active
                            } else {
                                r.kappa_passive
                            },
                        )
                    })
                    .collect()
            };
            series.push(Series::line(
                format!("active (time-resolved), {config}"),
                c,
                pts(true),
            ));
            series.push(Series {
                marker: Marker::Cross,
                thin: true,
                ..Series::line(format!("passive, {config}"), c, pts(false))
            });
        }
        Plot {
            title,
            x_label: x_label.into(),
            y_label: "kappa(T)".into(),
            x_log,
            y_log: true,
            x_integer: sweep == "resolution",
            series,
        }
    };
    let rough_grid = rows
        .iter()
        .find(|r| r.sweep == "roughness")
        .map(|r| r.grid)
        .unwrap_or(0);
    panels(&[
        plot(
            "resolution",
            "kappa against voxel grid (alpha 0.3)".into(),
            "voxel grid side",
            false,
        ),
        plot(
            "roughness",
            format!("kappa against roughness ({rough_grid}x{rough_grid} voxels)"),
            "GGX roughness alpha",
            true,
        ),
    ])
}

/// The active-NLOS sweeps as a report.
pub struct Active(pub Vec<ActiveRow>);

impl super::Report for Active {
    fn json(&self) -> serde_json::Map<String, serde_json::Value> {
        super::shape::fields(vec![("active", serde_json::to_value(&self.0))])
    }

    fn charts(&self) -> Result<Vec<(String, Chart)>, ChartError> {
        Ok(vec![("active".into(), chart(&self.0)?)])
    }

    fn markdown(&self) -> String {
        use std::fmt::Write as _;
        let mut md = String::from("## Active NLOS (the paper's appendix, time-resolved T)\n\nLaser and detector at pose A, spot at the wall centre, 1 cm path-length bins (33 ps); voxels on the scene grid. The passive column is the steady-state T of the same scene.\n\n![active](active.png)\n\n| sweep | config | voxel grid | alpha | bins | kappa active | kappa passive |\n|---|---|---|---|---|---|---|\n");
        for r in &self.0 {
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {} | {} | {} |",
                r.sweep,
                r.config,
                r.grid,
                r.roughness,
                r.bins,
                super::fmt_kappa(r.kappa_active),
                super::fmt_kappa(r.kappa_passive)
            );
        }
        md.push('\n');
        md
    }
}
