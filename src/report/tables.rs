//! The paper's Table 1 and Fig. 6 as reports: condition numbers per
//! polarizer configuration, and against wall roughness.

use std::fmt::Write as _;

use super::charts::{self, Chart, ChartError};
use super::shape::{fields, Report};
use super::{fmt_kappa, CondRow, RoughRow, CONFIGS, ROUGHNESS};

/// Table 1: kappa per configuration, with and without the occluder.
pub struct Conditioning(pub Vec<CondRow>);

/// Fig. 6: kappa against wall roughness.
pub(crate) struct Roughness(pub Vec<RoughRow>);

fn occluder(occ: bool) -> &'static str {
    if occ {
        "yes"
    } else {
        "no"
    }
}

impl Report for Conditioning {
    fn json(&self) -> serde_json::Map<String, serde_json::Value> {
        fields(vec![("conditioning", serde_json::to_value(&self.0))])
    }

    fn charts(&self) -> Result<Vec<(String, Chart)>, ChartError> {
        let mut groups: Vec<(String, Vec<f64>)> = Vec::new();
        for r in &self.0 {
            let plus = if r.occluder { " + occluder" } else { "" };
            let label = format!("{}x{}{plus}", r.grid, r.grid);
            match groups.last_mut() {
                Some((l, v)) if *l == label => v.push(r.kappa),
                _ => groups.push((label, vec![r.kappa])),
            }
        }
        let c = charts::log_bars(
            "Condition number of T (Table 1)",
            "kappa(T)",
            &CONFIGS,
            &groups,
        )?;
        Ok(vec![("conditioning".into(), c)])
    }

    fn markdown(&self) -> String {
        let mut md = String::from("## Conditioning (the paper's Table 1)\n\n| grid | occluder | nopol | rotating | crossed | multi | trend nopol > rotating > crossed > multi |\n|---|---|---|---|---|---|---|\n");
        let mut groups: Vec<(usize, bool)> = self.0.iter().map(|r| (r.grid, r.occluder)).collect();
        groups.dedup();
        for (grid, occ) in groups {
            let k = |c: &str| {
                self.0
                    .iter()
                    .find(|r| r.grid == grid && r.occluder == occ && r.config == c)
                    .map_or(f64::NAN, |r| r.kappa)
            };
            let (a, b, c, d) = (k("nopol"), k("rotating"), k("crossed"), k("multi"));
            let trend = if a > b && b > c && c > d {
                "holds"
            } else {
                "does not hold"
            };
            let _ = writeln!(
                md,
                "| {grid}x{grid} | {} | {} | {} | {} | {} | {trend} |",
                occluder(occ),
                fmt_kappa(a),
                fmt_kappa(b),
                fmt_kappa(c),
                fmt_kappa(d)
            );
        }
        md.push_str("\n![conditioning](conditioning.png)\n\n");
        md
    }
}

impl Roughness {
    fn kappa(&self, occ: bool, config: &str, alpha: f64) -> Option<f64> {
        self.0
            .iter()
            .find(|r| r.occluder == occ && r.config == config && r.roughness == alpha)
            .map(|r| r.kappa)
    }
}

impl Report for Roughness {
    fn json(&self) -> serde_json::Map<String, serde_json::Value> {
        fields(vec![("roughness", serde_json::to_value(&self.0))])
    }

    fn charts(&self) -> Result<Vec<(String, Chart)>, ChartError> {
        let mut series = Vec::new();
        for occ in [false, true] {
            for config in ["nopol", "crossed", "multi"] {
                let plus = if occ { " + occluder" } else { "" };
                let points = self
                    .0
                    .iter()
                    .filter(|r| r.occluder == occ && r.config == config)
                    .map(|r| (r.roughness, r.kappa))
                    .collect();
                series.push(charts::Series {
                    thin: occ,
                    ..charts::Series::line(format!("{config}{plus}"), series.len(), points)
                });
            }
        }
        let grid = self.0.first().map_or(3, |r| r.grid);
        let c = charts::log_lines(
            &format!("kappa(T) against wall roughness ({grid}x{grid} scene)"),
            "GGX roughness alpha",
            "kappa(T)",
            series,
        )?;
        Ok(vec![("roughness".into(), c)])
    }

    fn markdown(&self) -> String {
        let mut md = String::from("## Roughness (the paper's Fig. 6)\n\n| config | occluder | ");
        let heads: Vec<String> = ROUGHNESS.iter().map(|a| format!("α = {a}")).collect();
        md.push_str(&heads.join(" | "));
        md.push_str(" |\n|---|---|");
        md.push_str(&"---|".repeat(ROUGHNESS.len()));
        md.push('\n');
        for occ in [false, true] {
            for config in ["nopol", "crossed", "multi"] {
                let ks: Vec<String> = ROUGHNESS
                    .iter()
                    .map(|&a| {
                        self.kappa(occ, config, a)
                            .map(fmt_kappa)
                            .unwrap_or_default()
                    })
                    .collect();
                let _ = writeln!(md, "| {config} | {} | {} |", occluder(occ), ks.join(" | "));
            }
            let ratio: Vec<String> = ROUGHNESS
                .iter()
                .map(|&a| {
                    let k = |c| self.kappa(occ, c, a).unwrap_or(f64::NAN);
                    let (a, b) = (k("nopol"), k("crossed"));
                    if a.is_infinite() && b.is_infinite() {
                        "n/a".to_string()
                    } else {
                        format!("{:.2}", a / b)
                    }
                })
                .collect();
            let _ = writeln!(
                md,
                "| improvement nopol/crossed | {} | {} |",
                occluder(occ),
                ratio.join(" | ")
            );
        }
        md.push_str("\n`inf`: `T` is rank-deficient at that roughness (no line point on the chart).\n\n![roughness](roughness.png)\n\n");
        md
    }
}
