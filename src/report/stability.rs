//! Where reconstruction breaks: each case builds its scene, simulates the
//! letter pattern, runs ADMM-TV and reports whether it converged, its
//! residuals, kappa, PSNR and the warnings it carries. No case may produce a
//! NaN or panic; a case that cannot be trusted must say so.

use serde::Serialize;

use super::{builtin, edit, BenchError};
use crate::scene::{Grid, Scene, SceneParts};
use crate::simulate::patterns::Pattern;
use crate::simulate::{unpolarized_peak, NoiseModel};
use crate::solve::report::{conditioning_notes, mean_snr, snr_warnings};
use crate::solve::{condition, metrics, Problem, SolveRequest, Solver};
use crate::transport::{build, MemoryBudget};

/// Outcome of one stability case.
#[derive(Debug, Clone, Serialize)]
pub struct StabilityRow {
    /// What was stressed.
    pub case: String,
    /// Condition number of `T` (`"inf"` when rank-deficient).
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub kappa: f64,
    /// Mean SNR of the simulated measurement.
    pub snr: f64,
    /// Whether ADMM met its tolerance.
    pub converged: bool,
    /// Iterations run.
    pub iterations: usize,
    /// Final primal residual.
    pub primal_residual: f64,
    /// Final dual residual.
    pub dual_residual: f64,
    /// PSNR against the truth, dB.
    #[serde(serialize_with = "crate::solve::json::finite_or_inf")]
    pub psnr_db: f64,
    /// Whether every recovered value is finite.
    pub finite: bool,
    /// Warnings the result carries (conditioning and solver).
    pub warnings: Vec<String>,
}

struct Case {
    name: String,
    scene: Scene,
    photons: f64,
    lambda_rel: Option<f64>,
}

fn cases() -> Result<Vec<Case>, BenchError> {
    let crossed = builtin("brewster-crossed")?;
    // A moved camera moves its sheet: the edit recomputes the crossed setting there.
    let with = |f: &dyn Fn(&mut SceneParts)| edit("brewster-crossed", crossed.clone(), f);
    let case = |name: &str, scene: Scene, photons: f64, lambda_rel: Option<f64>| Case {
        name: name.into(),
        scene,
        photons,
        lambda_rel,
    };
    // Exact Brewster mirror geometry: the camera on the mirror ray at atan(eta).
    let eta: f64 = crossed.wall().brdf.eta;
    let tb = eta.atan();
    let exact = with(&|s| {
        s.poses[0].camera = nalgebra::Vector3::new(0.5 * tb.sin(), 0.0, 0.5 * tb.cos());
    })?;
    let mirror30 = with(&|s| {
        // Scene and camera both at 30 deg incidence: far from Brewster.
        let t = 30f64.to_radians();
        s.hidden.plane.center = nalgebra::Vector3::new(-0.45 * t.sin(), 0.0, 0.45 * t.cos());
        s.hidden.plane.normal = -s.hidden.plane.center.normalize();
        s.poses[0].camera = nalgebra::Vector3::new(0.5 * t.sin(), 0.0, 0.5 * t.cos());
    })?;
    let fine = with(&|s| s.hidden.plane.grid = Grid { nu: 40, nv: 40 })?;
    Ok(vec![
        case(
            "reference: Brewster bench, crossed, alpha 0.3",
            crossed.clone(),
            2e4,
            None,
        ),
        case(
            "mirror-like wall (alpha 0.01)",
            with(&|s| s.wall.brdf.alpha = 0.01)?,
            2e4,
            None,
        ),
        case(
            "fully diffuse wall (alpha 1.0, kd 1)",
            with(&|s| {
                s.wall.brdf.alpha = 1.0;
                s.wall.brdf.kd = 1.0;
            })?,
            2e4,
            None,
        ),
        case(
            "camera at grazing angle (89.8 deg)",
            with(&|s| s.poses[0].camera = nalgebra::Vector3::new(2.0, 0.0, 0.007))?,
            2e4,
            None,
        ),
        case("polarizer exactly at Brewster", exact, 2e4, None),
        case(
            "far from Brewster (30 deg mirror geometry)",
            mirror30,
            2e4,
            None,
        ),
        case(
            "scene grid 40x40 > 1024 wall rows (rank-deficient)",
            fine,
            2e4,
            None,
        ),
        case("1e6 photons at full scale", crossed.clone(), 1e6, None),
        case("1e4 photons at full scale", crossed.clone(), 1e4, None),
        case("1e2 photons at full scale", crossed.clone(), 1e2, None),
        case(
            "lambda far too small (1e-9 x diag)",
            crossed.clone(),
            2e4,
            Some(1e-9),
        ),
        case("lambda far too large (1e3 x diag)", crossed, 2e4, Some(1e3)),
    ])
}

/// Number of cases, for a progress bar.
pub(crate) const CASES: usize = 12;

/// Runs every case.
pub(crate) fn stability_table(
    budget: MemoryBudget,
    step: &mut dyn FnMut(),
) -> Result<Vec<StabilityRow>, BenchError> {
    let mut rows = Vec::new();
    for c in cases()? {
        let t = build(&c.scene, budget)?;
        let truth = Pattern::Letter.render(t.scene_grid());
        let model = NoiseModel {
            photons: c.photons,
            read_noise: 5.0,
            bits: 12,
            seed: 17,
        };
        let peak = unpolarized_peak(&c.scene, &t, &truth, budget)?;
        let sim = model
            .apply(t.apply(&truth), peak)
            .map_err(|source| BenchError::Simulate {
                case: c.name.clone(),
                source,
            })?;
        // Electrons per element and their shot + read noise variance.
        let e: Vec<f64> = sim
            .clean
            .iter()
            .map(|v| v * sim.electrons_per_unit)
            .collect();
        let var: Vec<f64> = e
            .iter()
            .map(|e| e.max(0.0) + model.read_noise * model.read_noise)
            .collect();
        let snr = mean_snr(&e, &var);
        let unit = t.mean_column_norm2();
        let request = SolveRequest {
            lambda: c.lambda_rel.map(|r| r * unit),
            ..SolveRequest::default()
        };
        let r = Solver::ADMM_TV.run(&Problem::new(&t, &sim.measurement, request))?;
        let cond = condition(&t)?;
        let mut warnings = conditioning_notes(&cond);
        warnings.extend(snr_warnings(snr));
        warnings.extend(r.stats.warnings.iter().cloned());
        rows.push(StabilityRow {
            case: c.name,
            kappa: cond.kappa,
            snr,
            converged: r.stats.converged,
            iterations: r.stats.iterations,
            primal_residual: r.stats.primal_residual.unwrap_or(f64::NAN),
            dual_residual: r.stats.dual_residual.unwrap_or(f64::NAN),
            psnr_db: metrics::psnr(&truth, &r.image),
            finite: r.image.iter().all(|v| v.is_finite()),
            warnings,
        });
        step();
    }
    Ok(rows)
}

/// The stability table as a report.
pub struct Stability(pub Vec<StabilityRow>);

impl super::Report for Stability {
    fn json(&self) -> serde_json::Map<String, serde_json::Value> {
        super::shape::fields(vec![("stability", serde_json::to_value(&self.0))])
    }

    fn charts(&self) -> Result<Vec<(String, super::charts::Chart)>, super::charts::ChartError> {
        Ok(Vec::new())
    }

    fn markdown(&self) -> String {
        use std::fmt::Write as _;
        let mut md = String::from("## Stability where methods fail (ADMM-TV, letter pattern, 8x8 scene)\n\n| case | kappa | mean SNR | converged | iterations | primal / dual residual | PSNR dB | finite | warnings |\n|---|---|---|---|---|---|---|---|---|\n");
        for r in &self.0 {
            let warnings = if r.warnings.is_empty() {
                "none".to_string()
            } else {
                r.warnings.join("; ")
            };
            let _ = writeln!(
                md,
                "| {} | {} | {:.1} | {} | {} | {:.1e} / {:.1e} | {:.2} | {} | {warnings} |",
                r.case,
                super::fmt_kappa(r.kappa),
                r.snr,
                if r.converged { "yes" } else { "no" },
                r.iterations,
                r.primal_residual,
                r.dual_residual,
                r.psnr_db,
                if r.finite { "yes" } else { "NO" },
            );
        }
        md.push('\n');
        md
    }
}
