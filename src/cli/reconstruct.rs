//! `polnlos reconstruct`: recover the hidden scene from a measurement.

use std::path::PathBuf;

use anyhow::Context;
use polnlos::files::truth::TopFirst;
use polnlos::files::{image, json, npy};
use polnlos::solve::lambda::NoiseLevel;
use polnlos::solve::photo::DataTerm;
use polnlos::solve::scene::{reconstruct_scene_with, SceneInput};
use polnlos::solve::{SolveRequest, Solver};
use polnlos::transport::MemoryBudget;

/// Recover the hidden scene from a measurement.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Writes recovered.npy (scene grid, rows = v), recovered.png (16-bit) and report.json. Example:\n  \
polnlos reconstruct config/scenes/brewster-crossed.toml --measurement sim/measurement.npy --truth sim/truth.npy --out rec/"
)]
pub struct Args {
    /// Scene file (TOML) the measurement was taken with.
    pub(super) scene: PathBuf,
    /// Measurement vector i (.npy, one value per row of T).
    #[arg(long, value_name = "FILE")]
    pub(super) measurement: PathBuf,
    /// Output folder.
    #[arg(long, value_name = "DIR")]
    pub(super) out: PathBuf,
    /// The solver and its parameters (--solver, --rho, --max-iter, --tol,
    /// --rcond), declared with the API's in `solve::SolveRequest`.
    #[command(flatten)]
    pub(super) solve: SolveRequest,
    /// Regularization weight in MODEL.md units, or `auto` (the default for
    /// the TV solvers): chosen from the noise by the resolved-discrepancy
    /// rule, the noise of --noise-from when given, else estimated from the
    /// measurement's residual outside range(T). Tikhonov's default is 1e-3 x
    /// mean diagonal of T^T T.
    #[arg(long, value_name = "L|auto")]
    pub(super) lambda: Option<LambdaArg>,
    /// simulate.json whose camera model (photons, read noise, bits) gives the
    /// noise level for the automatic lambda.
    #[arg(long = "noise-from", value_name = "FILE", conflicts_with = "variance")]
    noise_from: Option<PathBuf>,
    /// Variance of each measurement value (.npy, as `polnlos measure` writes
    /// it beside the measurement): the noise level for the automatic lambda.
    #[arg(long, value_name = "FILE")]
    variance: Option<PathBuf>,
    /// Compute the full singular spectrum of T (an SVD) for the report's
    /// kappa and rank. By default a large T (512 or more scene elements, low
    /// numerical rank) takes them from T^T T, which admm-tv forms anyway: to
    /// about 1e-7 of the largest singular value instead of 1e-12, at a
    /// fraction of the time.
    #[arg(long = "full-spectrum")]
    full_spectrum: bool,
    /// Truth image (.npy or PNG) to compute PSNR, ZNCC and SSIM against
    /// (with --photo: a .npy of [nv, nu] or [nv, nu, C]).
    #[arg(long, value_name = "FILE")]
    pub(super) truth: Option<PathBuf>,
    /// The measurement is a photograph whose gain and ambient light are
    /// unknown: fit them with the scene (docs/realphoto.md). The measurement
    /// may be [rows] or [rows, C], one column per colour channel; one T
    /// serves every channel. --max-iter caps each ADMM stage (default 150).
    #[arg(long, conflicts_with_all = ["noise_from", "variance", "solver", "rho", "rcond", "full_spectrum"])]
    pub(super) photo: bool,
    /// With --photo: what the data term fits (differences: blind to a
    /// constant background per block and a smooth model error).
    #[arg(
        long = "data-term",
        value_enum,
        requires = "photo",
        default_value = "differences"
    )]
    pub(super) data_term: DataTerm,
}

/// `--lambda`: a number or `auto`.
#[derive(Debug, Clone, Copy)]
pub(super) enum LambdaArg {
    Auto,
    Value(f64),
}

impl LambdaArg {
    /// The number given; `None` for `auto` (chosen from the data).
    pub(super) fn value(self) -> Option<f64> {
        match self {
            LambdaArg::Value(l) => Some(l),
            LambdaArg::Auto => None,
        }
    }
}

impl std::str::FromStr for LambdaArg {
    type Err = super::ArgError;
    fn from_str(s: &str) -> Result<Self, super::ArgError> {
        if s == "auto" {
            return Ok(LambdaArg::Auto);
        }
        s.parse()
            .map(LambdaArg::Value)
            .map_err(|_| super::ArgError::Lambda(s.to_string()))
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

/// `reconstruct` without `--photo` (the CLI's dispatch sends `--photo` to
/// `cli/photo.rs`, which reads these same arguments).
pub fn run(a: Args, budget: MemoryBudget) -> anyhow::Result<()> {
    let scene = super::load_scene(&a.scene)?;
    let meas = npy::read(&a.measurement)?;
    if let [rows, c] = meas.shape[..] {
        if c > 1 {
            return Err(super::Usage(format!(
                "{} holds {c} colour channels ([{rows}, {c}], a colour camera's measurement): `reconstruct --photo` solves them together with one T; for the calibrated model, give one channel's column as its own .npy",
                a.measurement.display()
            ))
            .into());
        }
    }
    let sgrid = scene.hidden().plane.grid;
    let truth = a
        .truth
        .as_ref()
        .map(|p| {
            TopFirst::read(p)?
                .on_grid(sgrid, 1, &p.display().to_string())
                .map(|mut c| c.swap_remove(0))
        })
        .transpose()?;
    if matches!(a.lambda, Some(LambdaArg::Auto)) && !a.solve.solver.needs().lambda_from_noise {
        let tv: Vec<&str> = Solver::ALL
            .iter()
            .filter(|s| s.needs().lambda_from_noise)
            .map(|s| s.name())
            .collect();
        return Err(super::Usage(format!(
            "--lambda auto is for the solvers that choose it from the noise ({})",
            tv.join(", ")
        ))
        .into());
    }
    let req = SolveRequest {
        lambda: a.lambda.and_then(LambdaArg::value),
        ..a.solve
    };
    req.check()?;
    let noise = match (&a.noise_from, &a.variance) {
        (Some(p), _) => Some(noise_from(p, &meas.data)?),
        (None, Some(p)) => {
            let v = npy::read(p)?;
            anyhow::ensure!(
                v.data.len() == meas.data.len(),
                "{} has {} values but the measurement has {}; give the variance file written with it",
                p.display(),
                v.data.len(),
                meas.data.len()
            );
            // NaN where the measurement is NaN: an element not measured.
            anyhow::ensure!(
                v.data
                    .iter()
                    .zip(&meas.data)
                    .all(|(x, m)| (x.is_finite() && *x >= 0.0) || m.is_nan()),
                "{}: every variance must be finite and not negative (NaN only where the measurement is NaN)",
                p.display()
            );
            Some(NoiseLevel::measured(v.data))
        }
        (None, None) => None,
    };
    super::out_dir(&a.out)?;
    let pb = super::progress::bar(scene.cols(), "building T");
    let cached = std::sync::Mutex::new(None);
    // The shadow model of the scene T is built from (a left-out key is
    // point shadows here: only `--photo` compares; docs/realphoto.md).
    let shadows = std::sync::Mutex::new(None);
    let solved = reconstruct_scene_with(
        &scene,
        SceneInput {
            measurement: &meas.data,
            noise,
            truth: truth.as_deref(),
            full_spectrum: a.full_spectrum,
            name: super::scene_name(&a.scene),
            stop: Default::default(),
        },
        &req,
        budget,
        &|s| {
            let c = super::build_transport(s, budget, &|done| pb.set_position(done as u64))?;
            if let Ok(mut k) = cached.lock() {
                *k = Some(c.source);
            }
            if let (Ok(mut k), false) = (shadows.lock(), s.occluders().is_empty()) {
                *k = Some(s.shadow_choice());
            }
            Ok(c.t)
        },
    )?;
    if let Some(source) = cached.lock().ok().and_then(|k| *k) {
        eprintln!("note: T {}", super::cache_words(source));
    }
    if let Some(c) = shadows.lock().ok().and_then(|mut k| k.take()) {
        eprintln!("note: {} shadows: {}", c.model.name(), c.reason);
    }
    pb.finish_and_clear();
    let (image, report) = (solved.image, solved.report);
    // Written as people look at it: the plane's top (+v) in the first row.
    let image = sgrid.to_top_first(&image, 1);
    npy::write_f64(&a.out.join("recovered.npy"), &[sgrid.nv, sgrid.nu], &image)?;
    image::write_png16(
        &a.out.join("recovered.png"),
        sgrid.nu,
        sgrid.nv,
        &image::unit_to_u16(&image),
    )?;
    json::write(&a.out.join("report.json"), &report)?;
    print_summary(&report);
    println!(
        "recovered {}x{} scene into {}",
        sgrid.nu,
        sgrid.nv,
        a.out.display()
    );
    Ok(())
}

/// Diagnostics to stderr, results to stdout.
fn print_summary(report: &polnlos::solve::report::Report) {
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    for n in &report.notes {
        eprintln!("note: {n}");
    }
    if let Some(c) = &report.lambda_choice {
        println!(
            "lambda {:.3e} (resolved-discrepancy rule, noise from {}, variance {:.3e})",
            c.lambda,
            serde_json::to_value(c.noise)
                .ok()
                .and_then(|v| v.as_str().map(String::from))
                .unwrap_or_default(),
            c.noise_variance
        );
    }
    if let Some(m) = &report.metrics {
        println!(
            "PSNR {:.2} dB, ZNCC {:.4}, SSIM {:.4}",
            m.psnr_db, m.zncc, m.ssim
        );
    }
}
