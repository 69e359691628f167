//! `polnlos reconstruct`: recover the hidden scene from a measurement.

use std::path::PathBuf;

use anyhow::Context;
use polnlos::files::{image, json, load_grid_image, npy};
use polnlos::solve::lambda::{admm_tv_resolved, NoiseLevel};
use polnlos::solve::report::{mean_snr, snr_warnings, Report};
use polnlos::solve::{
    admm_tv, condition, fista_tv, least_squares, tikhonov, AdmmSettings, FistaSettings,
};

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Solver {
    /// ADMM with isotropic TV and the box 0 <= l <= 1 (MODEL.md Eq. 12).
    AdmmTv,
    /// FISTA with a TV proximal step and the box (Saunders et al. 2019); same objective.
    FistaTv,
    /// Tikhonov (ridge) regularization, clipped to [0, 1].
    Tikhonov,
    /// (Truncated) pseudo-inverse, clipped to [0, 1].
    Lsq,
}

/// Recover the hidden scene from a measurement.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Writes recovered.npy (scene grid, rows = v), recovered.png (16-bit) and report.json. Example:\n  \
polnlos reconstruct config/scenes/brewster-crossed.toml --measurement sim/measurement.npy --truth sim/truth.npy --out rec/"
)]
pub struct Args {
    /// Scene file (TOML) the measurement was taken with.
    scene: PathBuf,
    /// Measurement vector i (.npy, one value per row of T).
    #[arg(long, value_name = "FILE")]
    measurement: PathBuf,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Solver.
    #[arg(long, value_enum, default_value = "admm-tv")]
    solver: Solver,
    /// Regularization weight in MODEL.md units, or `auto` (admm-tv: from the
    /// noise level of --noise-from, the resolved-discrepancy rule). Default:
    /// `auto` when --noise-from is given, else 1e-2 x mean diagonal of T^T T
    /// for admm-tv, 1e-3 x for tikhonov.
    #[arg(long, value_name = "L|auto")]
    lambda: Option<LambdaArg>,
    /// simulate.json whose camera model (photons, read noise, bits) gives the
    /// noise level for --lambda auto.
    #[arg(long = "noise-from", value_name = "FILE")]
    noise_from: Option<PathBuf>,
    /// ADMM penalty (default: equal to lambda).
    #[arg(long, value_name = "R")]
    rho: Option<f64>,
    /// ADMM / FISTA iteration cap.
    #[arg(long = "max-iter", value_name = "N", default_value_t = AdmmSettings::default().max_iter)]
    max_iter: usize,
    /// ADMM relative tolerance on the primal/dual residuals (FISTA: on the
    /// relative change of l between iterations).
    #[arg(long, value_name = "T", default_value_t = AdmmSettings::default().tol)]
    tol: f64,
    /// Relative singular-value cut-off for --solver lsq (default: numerical rank only).
    #[arg(long, value_name = "R")]
    rcond: Option<f64>,
    /// Truth image (.npy or PNG) to compute PSNR, ZNCC and SSIM against.
    #[arg(long, value_name = "FILE")]
    truth: Option<PathBuf>,
}

/// `--lambda`: a number or `auto`.
#[derive(Debug, Clone, Copy)]
enum LambdaArg {
    Auto,
    Value(f64),
}

impl std::str::FromStr for LambdaArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "auto" {
            return Ok(LambdaArg::Auto);
        }
        s.parse()
            .map(LambdaArg::Value)
            .map_err(|_| format!("{s:?} is neither a number nor `auto`"))
    }
}

/// The noise level a simulation implies for its own measurement.
fn noise_from(path: &std::path::Path, measurement: &[f64]) -> anyhow::Result<NoiseLevel> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{} is not JSON", path.display()))?;
    let num = |k: &[&str]| -> anyhow::Result<f64> {
        k.iter()
            .try_fold(&v, |v, k| v.get(*k))
            .and_then(|x| x.as_f64())
            .with_context(|| format!("{} has no number at {}", path.display(), k.join(".")))
    };
    Ok(NoiseLevel::from_camera(
        measurement,
        num(&["electrons_per_unit"])?,
        num(&["noise", "read_noise"])?,
        num(&["units_per_dn"])?,
    ))
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let scene = super::load_scene(&a.scene)?;
    let meas = npy::read(&a.measurement)?;
    let sgrid = scene.scene.plane.grid;
    let truth = a
        .truth
        .as_ref()
        .map(|p| load_grid_image(p, sgrid))
        .transpose()?;
    super::out_dir(&a.out)?;

    let (t, transport_seconds) = super::progress::build_transport(&scene)?;
    let fixed = match a.lambda {
        Some(LambdaArg::Value(l)) => Some(l),
        _ => None,
    };
    let settings = AdmmSettings {
        lambda: fixed,
        rho: a.rho,
        max_iter: a.max_iter,
        tol: a.tol,
    };
    let mut lambda_choice = None;
    let cond = condition(&t)?;
    // No --lambda but a noise level: choose lambda from it.
    let lambda_arg = match (a.lambda, &a.noise_from, a.solver) {
        (None, Some(_), Solver::AdmmTv) => Some(LambdaArg::Auto),
        (l, _, _) => l,
    };
    let noise = a
        .noise_from
        .as_ref()
        .map(|p| noise_from(p, &meas.data))
        .transpose()?;
    let rec = match (a.solver, lambda_arg) {
        (Solver::AdmmTv, Some(LambdaArg::Auto)) => {
            let noise = noise
                .as_ref()
                .context("--lambda auto needs --noise-from simulate.json (the noise level)")?;
            let (r, choice) =
                admm_tv_resolved(&t, &meas.data, noise, &cond.singular_values, &settings)?;
            lambda_choice = Some(choice);
            r
        }
        (Solver::AdmmTv, _) => admm_tv(&t, &meas.data, &settings)?,
        (Solver::FistaTv, Some(LambdaArg::Auto)) => {
            anyhow::bail!("--lambda auto is for --solver admm-tv")
        }
        (Solver::FistaTv, _) => fista_tv(
            &t,
            &meas.data,
            &FistaSettings {
                lambda: fixed,
                max_iter: a.max_iter,
                tol: a.tol,
                ..FistaSettings::default()
            },
        )?,
        (_, Some(LambdaArg::Auto)) => anyhow::bail!("--lambda auto is for --solver admm-tv"),
        (Solver::Tikhonov, _) => tikhonov(&t, &meas.data, fixed)?,
        (Solver::Lsq, _) => least_squares(&t, &meas.data, a.rcond)?,
    };
    let image = rec.image.clone();
    let mut report = Report::new(
        super::scene_name(&a.scene),
        &t,
        transport_seconds,
        &cond,
        rec,
        truth.as_deref(),
        lambda_choice,
    );
    if let Some(n) = &noise {
        report
            .warnings
            .extend(snr_warnings(mean_snr(&meas.data, &n.variance)));
    }
    npy::write_f64(&a.out.join("recovered.npy"), &[sgrid.nv, sgrid.nu], &image)?;
    image::write_png16(
        &a.out.join("recovered.png"),
        sgrid.nu,
        sgrid.nv,
        &image::unit_to_u16(&image),
    )?;
    json::write(&a.out.join("report.json"), &report)?;
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(m) = &report.metrics {
        eprintln!(
            "PSNR {:.2} dB, ZNCC {:.4}, SSIM {:.4}",
            m.psnr_db, m.zncc, m.ssim
        );
    }
    eprintln!(
        "recovered {}x{} scene into {}",
        sgrid.nu,
        sgrid.nv,
        a.out.display()
    );
    Ok(())
}
